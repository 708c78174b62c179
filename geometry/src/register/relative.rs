//! The relative pose of two views from matched keypoints lifted by each view's predicted
//! depth: x_j = R·x_i + t (camera i → camera j, metres of the depth). RANSAC draws two kinds
//! of minimal hypotheses — three matches' 3-D points aligned rigidly (Kabsch), and two
//! matches' viewing rays aligned as a pure rotation, which holds for a phone turned on the
//! spot and does not suffer from depth error — and scores each by its symmetric reprojection
//! error (MSAC). The best is refined on the inliers' reprojection errors in both views
//! ([`super::joint`]). Reprojection, not 3-D distance, is what is minimised:
//! a depth that is off by 20% moves a point along its ray, which changes its projection in
//! the other view only through the parallax of the baseline. Where the depth is wrong in its
//! shape (a real photo unlike the training rooms), a yaw and a forward step can fit the matches
//! lifted by it better than the true sideways step; so a pose from the rays alone is sought
//! too ([`super::essential`], [`RegisterParams::essential_px`]) and replaces the depth-lifted one
//! when clearly more matches lie on its epipolar lines.

use glam::{DMat3, DQuat, DVec3, Quat, Vec2, Vec3};
use inssplat_proto::camera::Intrinsics;
use rand::Rng;
use rand::seq::index::sample;

use super::RegisterParams;
use super::essential::{epipolar_inliers, essential_pose};
use super::joint::{self, Edge, Focal};
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

impl Correspondence {
    /// The match with both points lifted again through focal lengths `scale` × those that
    /// lifted them (x and y divided by it).
    pub fn with_focal(&self, scale: f64) -> Self {
        let s = scale as f32;
        let relift = |p: Vec3| Vec3::new(p.x / s, p.y / s, p.z);
        Self { point_i: relift(self.point_i), point_j: relift(self.point_j), ..*self }
    }
}

/// A relative pose and how many matches agree with it.
#[derive(Debug, Clone, Copy)]
pub struct RelativePose {
    pub rotation: Quat,
    pub translation: Vec3,
    pub inliers: usize,
    /// Found from the matches' rays alone (the essential matrix), the depth disagreeing.
    pub depth_free: bool,
}

impl RelativePose {
    fn of_model(m: &Model, inliers: usize, depth_free: bool) -> Self {
        Self {
            rotation: DQuat::from_mat3(&m.r).normalize().as_quat(),
            translation: m.t.as_vec3(),
            inliers,
            depth_free,
        }
    }

    fn model(&self) -> Model {
        Model { r: DMat3::from_quat(self.rotation.as_dquat()), t: self.translation.as_dvec3() }
    }

    /// The pose of the opposite direction (camera j → camera i).
    pub fn inverse(&self) -> Self {
        let rotation = self.rotation.conjugate();
        Self { rotation, translation: -(rotation * self.translation), ..*self }
    }
}

/// x_j = r·x_i + t, in double precision.
#[derive(Clone, Copy)]
pub(super) struct Model {
    pub r: DMat3,
    pub t: DVec3,
}

impl Model {
    /// Camera i's pose → camera j's pose (world→camera), given i's.
    pub fn of_cameras(ri: DMat3, ti: DVec3, rj: DMat3, tj: DVec3) -> Self {
        let r = rj * ri.transpose();
        Model { r, t: tj - r * ti }
    }
}

/// The four reprojection residuals of `c` under `m` (i's point in j, j's point in i), or
/// `None` when a point falls behind the other camera. `focal` multiplies both views' focal
/// lengths: the points, lifted with the intrinsics as given, are lifted again with the scaled
/// ones (their x and y divided by it) and projected with them.
pub(super) fn reprojection(
    ki: &Intrinsics,
    kj: &Intrinsics,
    m: &Model,
    c: &Correspondence,
    focal: f64,
) -> Option<[f64; 4]> {
    let lift = |p: Vec3| DVec3::new(p.x as f64 / focal, p.y as f64 / focal, p.z as f64);
    let pj = project(kj, focal, m.r * lift(c.point_i) + m.t)?;
    let pi = project(ki, focal, m.r.transpose() * (lift(c.point_j) - m.t))?;
    let (uj, ui) = (c.pixel_j.as_dvec2(), c.pixel_i.as_dvec2());
    Some([pj[0] - uj.x, pj[1] - uj.y, pi[0] - ui.x, pi[1] - ui.y])
}

/// Huber weight of a residual `r` with threshold `delta`.
pub(super) fn huber(r: f64, delta: f64) -> f64 {
    if r.abs() <= delta { 1.0 } else { delta / r.abs() }
}

struct Pair<'a> {
    corr: &'a [Correspondence],
    ki: &'a Intrinsics,
    kj: &'a Intrinsics,
}

fn project(k: &Intrinsics, focal: f64, p: DVec3) -> Option<[f64; 2]> {
    (p.z > 1e-6).then(|| {
        [
            focal * k.fx as f64 * p.x / p.z + k.cx as f64,
            focal * k.fy as f64 * p.y / p.z + k.cy as f64,
        ]
    })
}

impl Pair<'_> {
    fn residuals(&self, m: &Model, c: &Correspondence) -> Option<[f64; 4]> {
        reprojection(self.ki, self.kj, m, c, 1.0)
    }

    /// Symmetric squared error of `c` in pixels²: the larger of its two squared reprojection
    /// distances.
    fn error2(&self, m: &Model, c: &Correspondence) -> f64 {
        self.residuals(m, c)
            .map_or(f64::INFINITY, |r| (r[0] * r[0] + r[1] * r[1]).max(r[2] * r[2] + r[3] * r[3]))
    }

    /// MSAC cost and inlier count of `m` at threshold `tau`.
    fn score(&self, m: &Model, tau: f64) -> (f64, usize) {
        let tau2 = tau * tau;
        self.corr.iter().fold((0.0, 0), |(cost, n), c| {
            let e2 = self.error2(m, c);
            if e2 < tau2 { (cost + e2, n + 1) } else { (cost + tau2, n) }
        })
    }
}

/// Rotation taking the unit vectors `from` onto `to` (Kabsch; least squares).
fn fit_rotation(
    from: impl Iterator<Item = DVec3>,
    to: impl Iterator<Item = DVec3>,
) -> Option<DMat3> {
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

/// RANSAC hypotheses of the depth-free (essential-matrix) pose.
const ESSENTIAL_ITERATIONS: usize = 300;
/// How many times the depth-lifted pose's count of matches on its epipolar lines the
/// essential-matrix pose must reach (plus 5) to replace it.
const ESSENTIAL_MARGIN: f64 = 1.5;

/// Hypotheses that draw at least one all-inlier triple with 99% probability when a share `w`
/// of the matches are inliers (the standard adaptive RANSAC bound, at least 16).
fn iterations_for(w: f64) -> usize {
    let all = w.powi(3).clamp(1e-9, 1.0 - 1e-9);
    (((0.01f64).ln() / (1.0 - all).ln()).ceil() as usize).max(16)
}

/// The relative pose of views i and j from `corr` and the matches that agree with it, or
/// `None` when fewer than `params.min_inliers` do.
pub fn relative_pose(
    corr: &[Correspondence],
    ki: &Intrinsics,
    kj: &Intrinsics,
    params: &RegisterParams,
    rng: &mut impl Rng,
) -> Option<(RelativePose, Vec<Correspondence>)> {
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
            fit_rotation(
                pick.iter().map(|k| ray(corr[k].point_i)),
                pick.iter().map(|k| ray(corr[k].point_j)),
            )
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
    let mut given = Focal::GIVEN;
    let (model, _) = refine_pair(model, corr, ki, kj, &mut given, tau, params);
    let mut inliers: Vec<Correspondence> =
        corr.iter().filter(|c| pair.error2(&model, c) < tau * tau).copied().collect();
    let mut model = model;
    let mut depth_free = false;
    if params.essential_px > 0.0 {
        // The depth-free hypothesis, where the matches' rays agree with it clearly better.
        let (f, tau_e) = (ki.fx as f64, params.essential_px as f64);
        let depth_fits = epipolar_inliers(&model, corr, f, tau_e);
        if let Some((m, idx)) = essential_pose(corr, f, tau_e, ESSENTIAL_ITERATIONS, rng)
            && idx.len() as f64 > ESSENTIAL_MARGIN * depth_fits as f64 + 5.0
        {
            model = m;
            inliers = idx.iter().map(|&k| corr[k]).collect();
            depth_free = true;
        }
    }
    (inliers.len() >= params.min_inliers)
        .then(|| (RelativePose::of_model(&model, inliers.len(), depth_free), inliers))
}

/// Gauss–Newton on one pair's matches from `model`, with `focal` (refined when free), on the
/// matches within `gate` pixels at each iteration; returns the pose and, with a free focal,
/// the variance of its log.
fn refine_pair(
    model: Model,
    corr: &[Correspondence],
    ki: &Intrinsics,
    kj: &Intrinsics,
    focal: &mut Focal,
    gate: f64,
    params: &RegisterParams,
) -> (Model, Option<f64>) {
    let tau = params.inlier_px as f64;
    let mut poses = [Model { r: DMat3::IDENTITY, t: DVec3::ZERO }, model];
    let edge = Edge { i: 0, j: 1, ki, kj, corr };
    let variance = joint::refine(
        &mut poses,
        &[false, true],
        focal,
        &[edge],
        gate,
        0.5 * tau,
        params.refine_iterations,
    );
    (poses[1], variance)
}

/// The matches of a pose are its inliers already, so refining them with a free focal length
/// gates only far outliers (in inlier thresholds): a focal length 15% off moves the matches
/// near the image edge by several thresholds before the pose follows.
const FOCAL_GATE: f64 = 4.0;

/// The focal multiplier that `pose`'s `inliers` prefer, refined with the pose from 1 (the
/// intrinsics as given), and the variance of its log; `None` when the solve fails.
pub(super) fn pair_focal(
    pose: &RelativePose,
    inliers: &[Correspondence],
    ki: &Intrinsics,
    kj: &Intrinsics,
    params: &RegisterParams,
) -> Option<(f64, f64)> {
    let mut focal = Focal { scale: 1.0, free: true };
    let gate = FOCAL_GATE * params.inlier_px as f64;
    let (_, variance) = refine_pair(pose.model(), inliers, ki, kj, &mut focal, gate, params);
    variance.map(|variance| (focal.scale, variance))
}

#[cfg(test)]
mod tests {
    use glam::{Quat, Vec2, Vec3};
    use inssplat_proto::camera::Intrinsics;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::{Correspondence, pair_focal, relative_pose};
    use crate::register::RegisterParams;

    fn k() -> Intrinsics {
        Intrinsics::from_fov_y(128, 128, 1.1)
    }

    fn project(p: Vec3) -> Vec2 {
        let k = k();
        Vec2::new(k.fx * p.x / p.z + k.cx, k.fy * p.y / p.z + k.cy)
    }

    /// `n` points of a room 2–5 m in front of camera i seen from camera j = (r, t); a share
    /// `outliers` of the matches point at random pixels; camera j's depths are scaled by
    /// `depth_scale_j` (a biased depth prediction).
    fn matches(
        r: Quat,
        t: Vec3,
        n: usize,
        outliers: f32,
        depth_scale_j: f32,
        rng: &mut ChaCha8Rng,
    ) -> Vec<Correspondence> {
        (0..n)
            .map(|_| {
                let pi = Vec3::new(rng.random_range(-1.5..1.5), rng.random_range(-1.5..1.5), 1.0)
                    * rng.random_range(2.0..5.0);
                let mut pj = r * pi + t;
                if rng.random::<f32>() < outliers {
                    pj = Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), 1.0)
                        * rng.random_range(2.0..5.0);
                }
                Correspondence {
                    pixel_i: project(pi),
                    point_i: pi,
                    pixel_j: project(pj),
                    point_j: pj * depth_scale_j,
                }
            })
            .collect()
    }

    fn angle_deg(a: Quat, b: Quat) -> f32 {
        (a * b.conjugate()).normalize().angle_between(Quat::IDENTITY).to_degrees()
    }

    #[test]
    fn recovers_a_general_motion_despite_outliers() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let (r, t) =
            (Quat::from_euler(glam::EulerRot::YXZ, 0.35, -0.1, 0.05), Vec3::new(0.4, -0.05, 0.2));
        let corr = matches(r, t, 120, 0.4, 1.0, &mut rng);
        let (pose, _) =
            relative_pose(&corr, &k(), &k(), &RegisterParams::default(), &mut rng).expect("a pose");
        assert!(
            angle_deg(pose.rotation, r) < 0.05,
            "rotation off by {}°",
            angle_deg(pose.rotation, r)
        );
        assert!(
            (pose.translation - t).length() < 0.005,
            "translation {:?} vs {t:?}",
            pose.translation
        );
        assert!((65..=85).contains(&pose.inliers), "{} inliers of ~72 true", pose.inliers);
    }

    #[test]
    fn a_turn_on_the_spot_survives_biased_depth() {
        // Pure rotation: reprojection does not depend on depth, so a 25% depth bias in one view
        // must not bend the rotation, where a 3-D fit of the points alone would.
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let r = Quat::from_euler(glam::EulerRot::YXZ, -0.5, 0.08, 0.0);
        let corr = matches(r, Vec3::ZERO, 80, 0.3, 1.25, &mut rng);
        let (pose, _) =
            relative_pose(&corr, &k(), &k(), &RegisterParams::default(), &mut rng).expect("a pose");
        assert!(
            angle_deg(pose.rotation, r) < 0.1,
            "rotation off by {}°",
            angle_deg(pose.rotation, r)
        );
        assert!(pose.translation.length() < 0.05, "{:?}", pose.translation);
    }

    #[test]
    fn a_pair_measures_the_focal_length_the_intrinsics_missed() {
        // The intrinsics given say a focal length 0.9 of the true one, so the points lifted with
        // them spread 1/0.9 wider than the room; the pair's matches must say so.
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let (r, t) =
            (Quat::from_euler(glam::EulerRot::YXZ, 0.35, -0.1, 0.05), Vec3::new(0.4, -0.05, 0.2));
        let widen = |p: Vec3| Vec3::new(p.x / 0.9, p.y / 0.9, p.z);
        let corr: Vec<Correspondence> = matches(r, t, 120, 0.2, 1.0, &mut rng)
            .into_iter()
            .map(|c| Correspondence { point_i: widen(c.point_i), point_j: widen(c.point_j), ..c })
            .collect();
        let given = Intrinsics { fx: 0.9 * k().fx, fy: 0.9 * k().fy, ..k() };
        let params = RegisterParams::default();
        let (pose, inliers) =
            relative_pose(&corr, &given, &given, &params, &mut rng).expect("a pose");
        let (scale, variance) =
            pair_focal(&pose, &inliers, &given, &given, &params).expect("a focal length");
        assert!((scale - 1.0 / 0.9).abs() < 0.005, "focal multiplier {scale}, true {}", 1.0 / 0.9);
        assert!(variance.sqrt() < 0.01, "log focal known to ±{}", variance.sqrt());
        // Solved again at the measured focal length, the pose is the true one.
        let k = Intrinsics { fx: given.fx * scale as f32, fy: given.fy * scale as f32, ..given };
        let relifted: Vec<Correspondence> = corr.iter().map(|c| c.with_focal(scale)).collect();
        let (fitted, _) = relative_pose(&relifted, &k, &k, &params, &mut rng).expect("a pose");
        assert!(
            angle_deg(fitted.rotation, r) < 0.05,
            "rotation off by {}°",
            angle_deg(fitted.rotation, r)
        );
        assert!(
            angle_deg(pose.rotation, r) > 5.0 * angle_deg(fitted.rotation, r),
            "the given focal length bent the rotation by only {}°",
            angle_deg(pose.rotation, r)
        );
    }

    #[test]
    fn a_sideways_step_survives_a_depth_of_the_wrong_shape() {
        // A stereo pair (camera j 0.3 m to the right, not turned) over points 1.5–6 m away,
        // whose predicted depth has the wrong shape (the near far and the far near): the
        // depth-lifted fit takes a turn and a step forward for the sideways step; the
        // matches' rays alone do not.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let t = Vec3::new(-0.3, 0.0, 0.0);
        let lift = |p: Vec2, z: f32| {
            let k = k();
            Vec3::new((p.x - k.cx) / k.fx * z, (p.y - k.cy) / k.fy * z, z)
        };
        let corr: Vec<Correspondence> = (0..150)
            .map(|_| {
                let z = rng.random_range(1.5..6.0);
                let pi =
                    Vec3::new(rng.random_range(-0.6..0.6), rng.random_range(-0.6..0.6), 1.0) * z;
                let (a, b) = (project(pi), project(pi + t));
                Correspondence {
                    pixel_i: a,
                    point_i: lift(a, 7.5 - z),
                    pixel_j: b,
                    point_j: lift(b, 7.5 - z),
                }
            })
            .collect();
        let off = |params: &RegisterParams, rng: &mut ChaCha8Rng| {
            let (pose, _) = relative_pose(&corr, &k(), &k(), params, rng).expect("a pose");
            pose.translation.normalize().dot(t.normalize()).clamp(-1.0, 1.0).acos().to_degrees()
        };
        let rays = off(&RegisterParams::default(), &mut rng);
        assert!(rays < 3.0, "the baseline is {rays}° off");
        let depth_only =
            off(&RegisterParams { essential_px: 0.0, ..RegisterParams::default() }, &mut rng);
        assert!(depth_only > 10.0, "the depth-lifted fit alone was {depth_only}° off: no test");
    }

    #[test]
    fn unrelated_matches_give_no_pose() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let corr = matches(Quat::IDENTITY, Vec3::ZERO, 60, 1.0, 1.0, &mut rng);
        assert!(relative_pose(&corr, &k(), &k(), &RegisterParams::default(), &mut rng).is_none());
        assert!(
            relative_pose(&corr[..5], &k(), &k(), &RegisterParams::default(), &mut rng).is_none()
        );
    }
}
