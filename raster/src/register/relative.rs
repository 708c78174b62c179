//! The relative pose of two views from matched keypoints lifted by each view's predicted
//! depth: x_j = R·x_i + t (camera i → camera j, metres of the depth). RANSAC draws two kinds
//! of minimal hypotheses — three matches' 3-D points aligned rigidly (Kabsch), and two
//! matches' viewing rays aligned as a pure rotation, which holds for a phone turned on the
//! spot and does not suffer from depth error — and scores each by its symmetric reprojection
//! error (MSAC). The best is refined by Gauss–Newton with Huber weights on the inliers'
//! reprojection errors in both views. Reprojection, not 3-D distance, is what is minimised:
//! a depth that is off by 20% moves a point along its ray, which changes its projection in
//! the other view only through the parallax of the baseline.

use glam::{DMat3, DQuat, DVec3, Quat, Vec2, Vec3};
use inssplat_proto::camera::Intrinsics;
use nalgebra::{Matrix6, Vector6};
use rand::Rng;
use rand::seq::index::sample;

use super::RegisterParams;
use crate::rotation::nearest_rotation;

/// One match: the keypoint in each view and its point lifted by that view's depth (camera
/// frame).
#[derive(Debug, Clone, Copy)]
pub struct Correspondence {
    pub pixel_i: Vec2,
    pub point_i: Vec3,
    pub pixel_j: Vec2,
    pub point_j: Vec3,
}

/// A relative pose and the matches that agree with it.
#[derive(Debug, Clone, Copy)]
pub struct RelativePose {
    pub rotation: Quat,
    pub translation: Vec3,
    pub inliers: usize,
}

impl RelativePose {
    /// The pose of the opposite direction (camera j → camera i).
    pub fn inverse(&self) -> Self {
        let rotation = self.rotation.conjugate();
        Self { rotation, translation: -(rotation * self.translation), inliers: self.inliers }
    }
}

#[derive(Clone, Copy)]
struct Model {
    r: DMat3,
    t: DVec3,
}

struct Pair<'a> {
    corr: &'a [Correspondence],
    ki: &'a Intrinsics,
    kj: &'a Intrinsics,
}

fn project(k: &Intrinsics, p: DVec3) -> Option<[f64; 2]> {
    (p.z > 1e-6).then(|| [k.fx as f64 * p.x / p.z + k.cx as f64, k.fy as f64 * p.y / p.z + k.cy as f64])
}

impl Pair<'_> {
    /// The four reprojection residuals of match `c` (i's point in j, j's point in i), or `None`
    /// when a point falls behind the other camera.
    fn residuals(&self, m: &Model, c: &Correspondence) -> Option<[f64; 4]> {
        let pj = project(self.kj, m.r * c.point_i.as_dvec3() + m.t)?;
        let pi = project(self.ki, m.r.transpose() * (c.point_j.as_dvec3() - m.t))?;
        let (uj, ui) = (c.pixel_j.as_dvec2(), c.pixel_i.as_dvec2());
        Some([pj[0] - uj.x, pj[1] - uj.y, pi[0] - ui.x, pi[1] - ui.y])
    }

    /// Symmetric squared error of `c` in pixels²: the larger of its two squared reprojection
    /// distances.
    fn error2(&self, m: &Model, c: &Correspondence) -> f64 {
        self.residuals(m, c).map_or(f64::INFINITY, |r| (r[0] * r[0] + r[1] * r[1]).max(r[2] * r[2] + r[3] * r[3]))
    }

    /// MSAC cost and inlier count of `m` at threshold `tau`.
    fn score(&self, m: &Model, tau: f64) -> (f64, usize) {
        let tau2 = tau * tau;
        self.corr.iter().fold((0.0, 0), |(cost, n), c| {
            let e2 = self.error2(m, c);
            if e2 < tau2 { (cost + e2, n + 1) } else { (cost + tau2, n) }
        })
    }

    /// Gauss–Newton (Huber-weighted, forward-difference Jacobian) on the matches within `tau`
    /// of `m`, updating the rotation on the left: R ← exp(ω)·R, t ← t + δ.
    fn refine(&self, mut m: Model, tau: f64, iterations: usize) -> Model {
        let huber = 0.5 * tau;
        let moved = |m: &Model, d: &Vector6<f64>| Model {
            r: DMat3::from_quat(DQuat::from_scaled_axis(DVec3::new(d[0], d[1], d[2]))) * m.r,
            t: m.t + DVec3::new(d[3], d[4], d[5]),
        };
        for _ in 0..iterations {
            let inliers: Vec<&Correspondence> = self.corr.iter().filter(|c| self.error2(&m, c) < tau * tau).collect();
            if inliers.len() < 4 {
                break;
            }
            let (mut h, mut g) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
            for c in inliers {
                let Some(r0) = self.residuals(&m, c) else { continue };
                let mut jac = [[0.0; 6]; 4];
                for (p, col) in (0..6).map(|p| (p, Vector6::from_fn(|i, _| if i == p { 1e-6 } else { 0.0 }))) {
                    let Some(r1) = self.residuals(&moved(&m, &col), c) else { continue };
                    for k in 0..4 {
                        jac[k][p] = (r1[k] - r0[k]) / 1e-6;
                    }
                }
                for k in 0..4 {
                    let w = if r0[k].abs() <= huber { 1.0 } else { huber / r0[k].abs() };
                    let row = Vector6::from_row_slice(&jac[k]);
                    h += w * row * row.transpose();
                    g += w * r0[k] * row;
                }
            }
            h += Matrix6::from_diagonal_element(1e-6 * h.trace().max(1e-12));
            let Some(step) = h.cholesky().map(|ch| ch.solve(&(-g))) else { break };
            m = moved(&m, &step);
            if step.norm() < 1e-8 {
                break;
            }
        }
        m
    }
}

/// Rotation taking the unit vectors `from` onto `to` (Kabsch; least squares).
fn fit_rotation(from: impl Iterator<Item = DVec3>, to: impl Iterator<Item = DVec3>) -> Option<DMat3> {
    let h = from.zip(to).fold(DMat3::ZERO, |h, (a, b)| h + outer(b, a));
    nearest_rotation(h)
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// Rigid motion taking the 3-D points `from` onto `to` (Kabsch with centroids).
fn fit_rigid(from: &[DVec3], to: &[DVec3]) -> Option<Model> {
    let n = from.len() as f64;
    let (ca, cb) = (from.iter().sum::<DVec3>() / n, to.iter().sum::<DVec3>() / n);
    let r = fit_rotation(from.iter().map(|a| *a - ca), to.iter().map(|b| *b - cb))?;
    Some(Model { r, t: cb - r * ca })
}

/// Hypotheses that draw at least one all-inlier triple with 99% probability when a share `w`
/// of the matches are inliers (the standard adaptive RANSAC bound, at least 16).
fn iterations_for(w: f64) -> usize {
    let all = w.powi(3).clamp(1e-9, 1.0 - 1e-9);
    (((0.01f64).ln() / (1.0 - all).ln()).ceil() as usize).max(16)
}

/// The relative pose of views i and j from `corr`, or `None` when fewer than
/// `params.min_inliers` matches agree on one.
pub fn relative_pose(
    corr: &[Correspondence],
    ki: &Intrinsics,
    kj: &Intrinsics,
    params: &RegisterParams,
    rng: &mut impl Rng,
) -> Option<RelativePose> {
    if corr.len() < params.min_inliers.max(3) {
        return None;
    }
    let pair = Pair { corr, ki, kj };
    let tau = params.inlier_px as f64;
    let mut best: Option<(f64, Model)> = None;
    let mut needed = params.ransac_iterations;
    let mut it = 0;
    while it < needed {
        it += 1;
        let model = if it % 2 == 1 {
            let pick = sample(rng, corr.len(), 3);
            let a: Vec<DVec3> = pick.iter().map(|k| corr[k].point_i.as_dvec3()).collect();
            let b: Vec<DVec3> = pick.iter().map(|k| corr[k].point_j.as_dvec3()).collect();
            fit_rigid(&a, &b)
        } else {
            let pick = sample(rng, corr.len(), 2);
            let ray = |p: Vec3| p.as_dvec3().normalize();
            fit_rotation(pick.iter().map(|k| ray(corr[k].point_i)), pick.iter().map(|k| ray(corr[k].point_j)))
                .map(|r| Model { r, t: DVec3::ZERO })
        };
        let Some(model) = model else { continue };
        let (cost, inliers) = pair.score(&model, tau);
        if best.is_none_or(|(c, _)| cost < c) {
            best = Some((cost, model));
            needed = needed.min(iterations_for(inliers as f64 / corr.len() as f64));
        }
    }
    let (_, model) = best?;
    let model = pair.refine(model, tau, params.refine_iterations);
    let (_, inliers) = pair.score(&model, tau);
    (inliers >= params.min_inliers).then(|| RelativePose {
        rotation: DQuat::from_mat3(&model.r).normalize().as_quat(),
        translation: model.t.as_vec3(),
        inliers,
    })
}
