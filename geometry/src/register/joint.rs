//! Joint refinement of camera poses over matched pairs: Gauss–Newton with Huber weights on
//! the reprojection errors of every pair's matches (both directions), all poses at once, so
//! that the errors of a chain of pairwise poses do not add up along it. The same solver
//! refines a single pair's pose (two views, the first held fixed). A focal-length multiplier
//! shared by all views ([`Focal`]) can be refined with the poses: the camera head's field of
//! view is a guess (on val40 it says 65° ± 2° for rooms shot at 50–80°), and rotations seen
//! through a wrong focal length come out scaled.

use glam::{DMat3, DQuat, DVec3};
use inssplat_proto::camera::Intrinsics;
use nalgebra::{DMatrix, DVector};

use super::relative::{Correspondence, Model, huber, reprojection};

/// Step of the forward-difference Jacobian.
const EPS: f64 = 1e-6;
/// Prior on the log of the focal multiplier: one pixel of residual per this much, so that
/// matches that cannot see the focal length (a camera moving straight ahead) leave it at the
/// camera head's.
const FOCAL_PRIOR_LOG: f64 = 0.3;

/// The focal-length multiplier of every view (1 = the intrinsics as given), and whether
/// [`refine`] refines it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Focal {
    pub scale: f64,
    pub free: bool,
}

impl Focal {
    /// The intrinsics as given, held.
    pub const GIVEN: Focal = Focal { scale: 1.0, free: false };
}

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

fn residuals(poses: &[Model], e: &Edge<'_>, c: &Correspondence, focal: f64) -> Option<[f64; 4]> {
    let (a, b) = (&poses[e.i], &poses[e.j]);
    reprojection(e.ki, e.kj, &Model::of_cameras(a.r, a.t, b.r, b.t), c, focal)
}

/// Refines `poses` (world→camera; those with `free[v] == false` stay), and `focal` when it is
/// free, on the matches of `edges` whose symmetric reprojection error is below `gate` pixels at
/// each iteration, with Huber threshold `delta` pixels. Returns the variance of the log focal
/// multiplier at the solution (Gauss–Newton's, with its prior) when it was refined.
pub fn refine(
    poses: &mut [Model],
    free: &[bool],
    focal: &mut Focal,
    edges: &[Edge<'_>],
    gate: f64,
    delta: f64,
    iterations: usize,
) -> Option<f64> {
    let mut block = vec![None; poses.len()];
    let mut params = 0;
    for (v, f) in free.iter().enumerate() {
        if *f {
            block[v] = Some(params);
            params += 6;
        }
    }
    let focal_at = focal.free.then_some(params);
    params += usize::from(focal.free);
    if params == 0 {
        return None;
    }
    let mut variance = None;
    for _ in 0..iterations {
        let (mut h, mut g) = (DMatrix::<f64>::zeros(params, params), DVector::<f64>::zeros(params));
        if let Some(f) = focal_at {
            let w = 1.0 / FOCAL_PRIOR_LOG;
            g[f] += w * w * focal.scale.ln();
            h[(f, f)] += w * w;
        }
        let mut used = 0;
        for e in edges {
            let views = [(e.i, block[e.i]), (e.j, block[e.j])];
            for c in e.corr {
                let Some(r0) = residuals(poses, e, c, focal.scale) else { continue };
                if (r0[0] * r0[0] + r0[1] * r0[1]).max(r0[2] * r0[2] + r0[3] * r0[3]) >= gate * gate
                {
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
                        let r1 = residuals(poses, e, c, focal.scale);
                        poses[v] = saved;
                        let Some(r1) = r1 else { continue };
                        cols.push((b + p, std::array::from_fn(|k| (r1[k] - r0[k]) / EPS)));
                    }
                }
                if let Some(f) = focal_at
                    && let Some(r1) = residuals(poses, e, c, focal.scale * EPS.exp())
                {
                    cols.push((f, std::array::from_fn(|k| (r1[k] - r0[k]) / EPS)));
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
            return variance;
        }
        let damping = 1e-6 * h.trace().max(1e-12) / params as f64;
        for d in 0..params {
            h[(d, d)] += damping;
        }
        let Some(chol) = h.cholesky() else { return variance };
        let step = chol.solve(&(-g));
        for (v, b) in block.iter().enumerate() {
            if let Some(b) = b {
                poses[v] = moved(&poses[v], &step.as_slice()[*b..b + 6]);
            }
        }
        if let Some(f) = focal_at {
            focal.scale *= step[f].clamp(-0.5, 0.5).exp();
            variance = Some(chol.inverse()[(f, f)]);
        }
        if step.norm() < 1e-8 {
            return variance;
        }
    }
    variance
}
