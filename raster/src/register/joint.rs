//! Joint refinement of camera poses over matched pairs: Gauss–Newton with Huber weights on
//! the reprojection errors of every pair's matches (both directions), all poses at once, so
//! that the errors of a chain of pairwise poses do not add up along it. The same solver
//! refines a single pair's pose (two views, the first held fixed).

use glam::{DMat3, DQuat, DVec3};
use inssplat_proto::camera::Intrinsics;
use nalgebra::{DMatrix, DVector};

use super::relative::{Correspondence, Model, huber, reprojection};

/// Step of the forward-difference Jacobian.
const EPS: f64 = 1e-6;

/// The matches between views `i` and `j` (`point_i` in camera i, `point_j` in camera j).
pub struct Edge<'a> {
    pub i: usize,
    pub j: usize,
    pub ki: &'a Intrinsics,
    pub kj: &'a Intrinsics,
    pub corr: &'a [Correspondence],
}

/// `pose` moved by the 6-vector `d`: R ← exp(d[0..3])·R, t ← t + d[3..6].
fn moved(pose: &Model, d: &[f64]) -> Model {
    Model {
        r: DMat3::from_quat(DQuat::from_scaled_axis(DVec3::new(d[0], d[1], d[2]))) * pose.r,
        t: pose.t + DVec3::new(d[3], d[4], d[5]),
    }
}

fn residuals(poses: &[Model], e: &Edge<'_>, c: &Correspondence) -> Option<[f64; 4]> {
    let (a, b) = (&poses[e.i], &poses[e.j]);
    reprojection(e.ki, e.kj, &Model::of_cameras(a.r, a.t, b.r, b.t), c)
}

/// Refines `poses` (world→camera; those with `free[v] == false` stay) on the matches of
/// `edges` whose symmetric reprojection error is below `gate` pixels at each iteration, with
/// Huber threshold `delta` pixels.
pub fn refine(poses: &mut [Model], free: &[bool], edges: &[Edge<'_>], gate: f64, delta: f64, iterations: usize) {
    let mut block = vec![None; poses.len()];
    let mut params = 0;
    for (v, f) in free.iter().enumerate() {
        if *f {
            block[v] = Some(params);
            params += 6;
        }
    }
    if params == 0 {
        return;
    }
    for _ in 0..iterations {
        let (mut h, mut g) = (DMatrix::<f64>::zeros(params, params), DVector::<f64>::zeros(params));
        let mut used = 0;
        for e in edges {
            let views = [(e.i, block[e.i]), (e.j, block[e.j])];
            for c in e.corr {
                let Some(r0) = residuals(poses, e, c) else { continue };
                if (r0[0] * r0[0] + r0[1] * r0[1]).max(r0[2] * r0[2] + r0[3] * r0[3]) >= gate * gate {
                    continue;
                }
                used += 1;
                // Columns of the Jacobian: (parameter index, d residuals).
                let mut cols: Vec<(usize, [f64; 4])> = Vec::with_capacity(12);
                for (v, b) in views {
                    let Some(b) = b else { continue };
                    for p in 0..6 {
                        let mut d = [0.0; 6];
                        d[p] = EPS;
                        let saved = poses[v];
                        poses[v] = moved(&saved, &d);
                        let r1 = residuals(poses, e, c);
                        poses[v] = saved;
                        let Some(r1) = r1 else { continue };
                        cols.push((b + p, std::array::from_fn(|k| (r1[k] - r0[k]) / EPS)));
                    }
                }
                for k in 0..4 {
                    let w = huber(r0[k], delta);
                    for &(a, ja) in &cols {
                        g[a] += w * ja[k] * r0[k];
                        for &(b, jb) in &cols {
                            h[(a, b)] += w * ja[k] * jb[k];
                        }
                    }
                }
            }
        }
        if used < 4 {
            return;
        }
        let damping = 1e-6 * h.trace().max(1e-12) / params as f64;
        for d in 0..params {
            h[(d, d)] += damping;
        }
        let Some(chol) = h.cholesky() else { return };
        let step = chol.solve(&(-g));
        for (v, b) in block.iter().enumerate() {
            if let Some(b) = b {
                poses[v] = moved(&poses[v], &step.as_slice()[*b..b + 6]);
            }
        }
        if step.norm() < 1e-8 {
            return;
        }
    }
}
