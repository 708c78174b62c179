//! Camera registration from the photos and the network's depth: the test-time pose stage that VGGT
//! follows with bundle adjustment, here in its cheapest form. The keypoint matches of every pair of
//! views come from outside ([`PairMatches`]: the pipeline's learned matcher, or FAST + BRIEF here,
//! [`brief_matches`], found in the photo at up to [`RegisterParams::photo_size`] pixels where it is
//! larger than the network's input); each pair with enough matches gets a relative pose
//! ([`relative`]). The views are chained to view 0 along the maximum spanning tree of the pairs'
//! inlier counts, each view through its best-supported path; then all chained poses are refined at
//! once on every pair's matches ([`joint`]), so that errors do not add up along a chain. The camera
//! head's field of view is a guess (65° ± 2° on rooms shot at 50–80°), so one focal-length
//! multiplier for all views is measured first: each matched pair's pose is refined with a free
//! focal length, the pairs' estimates are pooled by their precision-weighted median (a pair with
//! little rotation cannot see the focal length and counts for little), every pair is solved again
//! at that focal length (RANSAC included: inliers chosen through a wrong focal length favour the
//! matches it fits), and the joint refinement refines it once more with all poses. When the pairs
//! together pin it down less than [`MIN_FOCAL_PRECISION`] asks (few pairs, little rotation), the
//! head's guess stays. Views that no chain reaches from view 0 (no overlap, or too little for a
//! match) form components of their own, and then the photos' order is the best evidence left: the
//! first view of each such component continues the motion of the two views before it (the step from
//! the second-last to the last, applied once more; view 1, with nothing before it to continue,
//! keeps the camera head's pose), and the rest are chained to it. On the 40 test scenes with their
//! true depth this places such views far better than the camera head's near-identity poses did (8
//! views: rotation error 13.2° → 8.4°). The result is in the network's frame (world = view 0's
//! camera), with the measured focal length and the depth's metric scale, so it replaces the
//! predicted cameras one for one.

mod essential;
pub mod features;
mod joint;
pub mod relative;

pub use features::KeypointImage;

use glam::{DMat3, DQuat, Quat, Vec2, Vec3};
use inssplat_proto::Camera;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use joint::{Edge, Focal};
use relative::{Correspondence, Model, RelativePose, relative_pose};

/// Gate of the joint refinement, in inlier thresholds.
const JOINT_GATE: f64 = 3.0;

/// Tunables of [`register`].
#[derive(Debug, Clone, PartialEq)]
pub struct RegisterParams {
    /// FAST-9 intensity threshold (0–255) on the grey image keypoints are found in.
    pub fast_threshold: u8,
    /// One keypoint per cell of this side, in view pixels.
    pub grid_cell: u32,
    /// Strongest keypoints kept per view.
    pub max_keypoints: usize,
    /// Largest Hamming distance of a match (of 256 bits).
    pub max_hamming: u32,
    /// Best match below this × the second best.
    pub ratio: f32,
    /// RANSAC hypotheses per pair.
    pub ransac_iterations: usize,
    /// Gauss–Newton iterations of the best hypothesis.
    pub refine_iterations: usize,
    /// Reprojection error of an inlier, view pixels.
    pub inlier_px: f32,
    /// Inliers a pair needs to count as an edge.
    pub min_inliers: usize,
    /// RANSAC seed (each pair draws from its own stream).
    pub seed: u64,
    /// Estimate one focal-length multiplier for all views from the matches (the camera
    /// head's field of view is a guess); `false` keeps the intrinsics as given.
    pub estimate_focal: bool,
    /// Long side, in pixels, of the copy of each photo that keypoints are found in when the
    /// photo is larger than the model's input (see [`RegisterView::detail`]); no larger than
    /// the input finds them in the input. 512 against the input (128) on 120 val scenes
    /// photographed at 512² (8 views, `inssplat-eval score --photos`): rotation error −1.19 ±
    /// 0.36°, instance mIoU +0.84 ± 0.56, PSNR +0.37 ± 0.15 dB, for 17 ms more registration
    /// (`inssplat-eval bench`, 8 views; the model card); 256 gained about half as much.
    pub photo_size: u32,
    /// Sampson distance, in view pixels, within which a match agrees with a pair's depth-free
    /// (essential-matrix) pose ([`relative`]); 0 leaves that hypothesis out. A tight threshold:
    /// at the network's 128 px the parallax that tells a sideways step from a turn is a few
    /// pixels. On the Middlebury motorcycle pair it takes the baseline from 89° off the true
    /// direction to 2°; on 40 val scenes at 8 views it changes 3% of the pairs and no metric
    /// beyond the noise (instance mIoU −0.19 ± 0.28, rotation +0.12 ± 0.10°), for 50 ms of
    /// registration.
    pub essential_px: f32,
}

impl Default for RegisterParams {
    fn default() -> Self {
        Self {
            fast_threshold: 10,
            grid_cell: 4,
            max_keypoints: 400,
            max_hamming: 64,
            ratio: 0.85,
            ransac_iterations: 400,
            refine_iterations: 10,
            inlier_px: 2.5,
            min_inliers: 10,
            seed: 0x5eed,
            estimate_focal: true,
            photo_size: 512,
            essential_px: 0.2,
        }
    }
}

/// One view: its photo, the network's depth and its predicted camera (whose intrinsics are
/// used, and whose pose places view 1 when no pair links it to view 0).
#[derive(Debug, Clone, Copy)]
pub struct RegisterView<'a> {
    /// Planar RGB `[3][H][W]` in [0, 1].
    pub rgb: &'a [f32],
    /// `[H][W]` metres along the camera z axis; ≤ 0 or non-finite = none.
    pub depth: &'a [f32],
    /// The photo's rectangle in the view, `[x0, y0, x1, y1)` pixels: all of it, or the part
    /// that is not letterbox padding.
    pub photo: [u32; 4],
    pub camera: &'a Camera,
    /// The photo at a finer scale than the view, to find keypoints in; `None` finds them in
    /// the view's own photo rectangle, upsampled.
    pub detail: Option<&'a KeypointImage>,
}

/// A pair of views with its relative pose.
struct PairPose {
    i: usize,
    j: usize,
    /// Camera i → camera j; `None` when too few matches agree.
    pose: Option<RelativePose>,
    /// The matches that agree with `pose`.
    inliers: Vec<Correspondence>,
}

/// The registered cameras and how they were found.
#[derive(Debug, Clone)]
pub struct Registration {
    pub cameras: Vec<Camera>,
    /// Each view's component: the view its pose is chained from (0 = registered to the
    /// reference view; any other root is placed by continuing the motion before it, or by the
    /// camera head for view 1).
    pub component: Vec<usize>,
    /// How well each view's matches fit its registered pose.
    pub fit: Vec<ViewFit>,
    /// The multiplier applied to every view's focal lengths; `None` when the given
    /// intrinsics stand ([`RegisterParams::estimate_focal`] off, or the matched pairs do not
    /// pin the focal length down: [`MIN_FOCAL_PRECISION`]).
    pub focal_scale: Option<f64>,
}

/// Keypoint matches of one pair of views `i` < `j`, in view pixels (pixel centres at +0.5):
/// from any matcher ([`brief_matches`] here, a learned one in the pipeline).
#[derive(Debug, Clone, Default)]
pub struct PairMatches {
    pub i: usize,
    pub j: usize,
    pub pixels: Vec<(Vec2, Vec2)>,
}

/// Every pair `i` < `j` of `n` views, in the order [`register`] takes their matches.
pub fn view_pairs(n: usize) -> Vec<(usize, usize)> {
    (0..n).flat_map(|i| (i + 1..n).map(move |j| (i, j))).collect()
}

/// FAST + BRIEF matches of every pair of `views` ([`features`]), in [`view_pairs`] order;
/// with each view's keypoint count.
pub fn brief_matches(
    views: &[RegisterView<'_>],
    params: &RegisterParams,
) -> (Vec<PairMatches>, Vec<usize>) {
    let brief_tests = features::test_pairs();
    let feats: Vec<features::Features> = views
        .par_iter()
        .map(|v| {
            let k = &v.camera.intrinsics;
            let own;
            let image = match v.detail {
                Some(detail) => detail,
                None => {
                    own = KeypointImage::of_view(v.rgb, k.width, k.height, v.photo);
                    &own
                }
            };
            features::detect(image, &brief_tests, params)
        })
        .collect();
    let pairs = view_pairs(views.len())
        .par_iter()
        .map(|&(i, j)| {
            let (a, b) = (&feats[i], &feats[j]);
            let pixels = features::match_features(a, b, params)
                .into_iter()
                .map(|(ia, ib)| (a.points[ia], b.points[ib]))
                .collect();
            PairMatches { i, j, pixels }
        })
        .collect();
    (pairs, feats.iter().map(features::Features::len).collect())
}

/// How well one view's matches fit the registered poses: what tells a user which photo to
/// retake.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ViewFit {
    /// Matches that agree with the view's pose, over all the pairs linking it to views of its
    /// component.
    pub matches: usize,
    /// Median distance, in view pixels, between the view's keypoints and where the matched
    /// keypoints of the other views, lifted by their depth, land in it under the registered
    /// poses; `None` without matches.
    pub reprojection_px: Option<f32>,
}

/// Registers `views`, in the order they were taken (see the module documentation), from the
/// keypoint `matches` of their pairs (any order; a pair left out has none). View 0 gets the
/// identity pose.
pub fn register(
    views: &[RegisterView<'_>],
    matches: &[PairMatches],
    params: &RegisterParams,
) -> Registration {
    let n = views.len();
    let jobs = view_pairs(n);
    let matches: Vec<Vec<Correspondence>> = jobs
        .par_iter()
        .map(|&(i, j)| {
            let found = matches.iter().filter(|m| (m.i, m.j) == (i, j));
            lifted(&views[i], &views[j], found.flat_map(|m| m.pixels.iter().copied()))
        })
        .collect();
    let mut cameras: Vec<Camera> = views.iter().map(|v| *v.camera).collect();
    let mut pairs = pair_poses(&jobs, &matches, &cameras, params);
    let measured =
        if params.estimate_focal { shared_focal(&cameras, &pairs, params) } else { None };
    if let Some(scale) = measured {
        // The inliers chosen through a wrong focal length favour the matches it fits, so the
        // pairs are solved again, RANSAC included, at the focal length they measured.
        for cam in &mut cameras {
            scale_focal(cam, scale);
        }
        let matches: Vec<Vec<Correspondence>> =
            matches.iter().map(|m| m.iter().map(|c| c.with_focal(scale)).collect()).collect();
        pairs = pair_poses(&jobs, &matches, &cameras, params);
    }
    // Prim's algorithm on inlier counts from view 0; when no pair reaches further, the first
    // view left (every view before it is placed) continues the motion before it and anchors
    // its own component.
    let mut component: Vec<Option<usize>> = vec![None; n];
    let mut root = 0;
    while root < n {
        component[root] = Some(root);
        if root == 0 {
            cameras[0].rotation = Quat::IDENTITY;
            cameras[0].translation = Vec3::ZERO;
        } else if root >= 2 {
            let (rotation, translation) = continued_motion(&cameras[root - 2], &cameras[root - 1]);
            cameras[root].rotation = rotation;
            cameras[root].translation = translation;
        }
        loop {
            let next = pairs
                .iter()
                .filter_map(|p| p.pose.map(|pose| (p, pose)))
                .filter_map(|(p, pose)| match (component[p.i], component[p.j]) {
                    (Some(c), None) => Some((p.i, p.j, pose, c)),
                    (None, Some(c)) => Some((p.j, p.i, pose.inverse(), c)),
                    _ => None,
                })
                .max_by_key(|&(_, _, pose, _)| pose.inliers);
            let Some((from, to, pose, c)) = next else { break };
            let parent = cameras[from];
            let cam = &mut cameras[to];
            cam.rotation = (pose.rotation * parent.rotation).normalize();
            cam.translation = pose.rotation * parent.translation + pose.translation;
            component[to] = Some(c);
        }
        root = component.iter().position(Option::is_none).unwrap_or(n);
    }
    let component: Vec<usize> =
        component.into_iter().map(|c| c.expect("every view is placed")).collect();
    let focal = Focal { scale: 1.0, free: measured.is_some() };
    let polish = refine_jointly(&mut cameras, &component, &pairs, focal, params);
    let fit = view_fits(&cameras, &component, &pairs, polish);
    for cam in &mut cameras {
        scale_focal(cam, polish);
    }
    Registration { cameras, component, fit, focal_scale: measured.map(|scale| scale * polish) }
}

/// Every pair's relative pose from its `matches` (in the order of `jobs`), at the intrinsics of
/// `cameras`.
fn pair_poses(
    jobs: &[(usize, usize)],
    matches: &[Vec<Correspondence>],
    cameras: &[Camera],
    params: &RegisterParams,
) -> Vec<PairPose> {
    let n = cameras.len();
    jobs.par_iter()
        .zip(matches)
        .map(|(&(i, j), corr)| {
            let mut rng = pair_rng(params, n, i, j);
            let (pose, inliers) = relative_pose(
                corr,
                &cameras[i].intrinsics,
                &cameras[j].intrinsics,
                params,
                &mut rng,
            )
            .unzip();
            PairPose { i, j, pose, inliers: inliers.unwrap_or_default() }
        })
        .collect()
}

/// The RANSAC stream of pair (`i`, `j`) of `n` views: its own, from [`RegisterParams::seed`].
fn pair_rng(params: &RegisterParams, n: usize, i: usize, j: usize) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(
        params.seed ^ ((i * n + j) as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15),
    )
}

fn scale_focal(camera: &mut Camera, scale: f64) {
    camera.intrinsics.fx *= scale as f32;
    camera.intrinsics.fy *= scale as f32;
}

/// Summed precision (1 / variance of the log focal length, from each pair's Gauss–Newton) the
/// matched pairs need before their focal length replaces the camera head's: a nominal standard
/// error of 2.5%. Those variances are optimistic: on the 40 val scenes at 8 views, 11 of the
/// 12 whose pairs summed less erred 3–21° in the field of view, and keeping the head's there
/// scored their input views' instance mIoU 2 points higher (`inssplat-default-history.md`).
pub const MIN_FOCAL_PRECISION: f64 = 1600.0;

/// The focal multiplier the matched pairs agree on: the median of their own estimates (each
/// pair's pose refined with a free focal length), weighted by their precision, so that pairs
/// whose motion cannot see the focal length (little rotation) count for little; `None` when
/// their summed precision is under [`MIN_FOCAL_PRECISION`] (no pair matched, or too few).
fn shared_focal(cameras: &[Camera], pairs: &[PairPose], params: &RegisterParams) -> Option<f64> {
    let mut estimates: Vec<(f64, f64)> = pairs
        .par_iter()
        .filter_map(|p| {
            let (ki, kj) = (&cameras[p.i].intrinsics, &cameras[p.j].intrinsics);
            let (scale, variance) =
                relative::pair_focal(p.pose.as_ref()?, &p.inliers, ki, kj, params)?;
            (variance > 0.0 && scale.is_finite()).then(|| (scale.ln(), 1.0 / variance))
        })
        .collect();
    estimates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total = estimates.iter().map(|e| e.1).sum::<f64>();
    if total < MIN_FOCAL_PRECISION {
        return None;
    }
    let mut seen = 0.0;
    estimates
        .iter()
        .find(|e| {
            seen += e.1;
            seen >= 0.5 * total
        })
        .map(|e| e.0.exp())
}

/// The pose after `last` if the camera moves once more as it did from `prev` to `last`
/// (world-to-camera: the step D = last ∘ prev⁻¹, then D ∘ last).
fn continued_motion(prev: &Camera, last: &Camera) -> (Quat, Vec3) {
    let step = (last.rotation * prev.rotation.conjugate()).normalize();
    let step_t = last.translation - step * prev.translation;
    ((step * last.rotation).normalize(), step * last.translation + step_t)
}

/// Refines all chained poses at once on every pair within a component (each component's root
/// stays), gating matches at [`JOINT_GATE`] × the inlier threshold: a chain's drift may have
/// moved a pair's inliers beyond it. The refinement lifts the matches by the depth, so the pairs
/// whose pose the depth-free hypothesis gave (the depth there disagreeing with the rays) take no
/// part: they would pull their pose back to the depth's (on the Middlebury aloe pair, from the
/// true sideways baseline to 96° off it), and a view that only such pairs reach keeps its
/// chained pose.
/// Returns the focal multiplier, refined with the poses when `focal` is free.
fn refine_jointly(
    cameras: &mut [Camera],
    component: &[usize],
    pairs: &[PairPose],
    mut focal: Focal,
    params: &RegisterParams,
) -> f64 {
    let edges: Vec<Edge<'_>> = pairs
        .iter()
        .filter(|p| p.pose.is_some_and(|pose| !pose.depth_free))
        .filter(|p| component[p.i] == component[p.j])
        .map(|p| Edge {
            i: p.i,
            j: p.j,
            ki: &cameras[p.i].intrinsics,
            kj: &cameras[p.j].intrinsics,
            corr: &p.inliers,
        })
        .collect();
    let mut poses: Vec<Model> = cameras
        .iter()
        .map(|c| Model { r: DMat3::from_quat(c.rotation.as_dquat()), t: c.translation.as_dvec3() })
        .collect();
    let linked = |v: usize| edges.iter().any(|e| e.i == v || e.j == v);
    let free: Vec<bool> = component.iter().enumerate().map(|(v, c)| *c != v && linked(v)).collect();
    let tau = params.inlier_px as f64;
    joint::refine(
        &mut poses,
        &free,
        &mut focal,
        &edges,
        JOINT_GATE * tau,
        0.5 * tau,
        params.refine_iterations,
    );
    for (cam, pose) in cameras.iter_mut().zip(&poses) {
        cam.rotation = DQuat::from_mat3(&pose.r).normalize().as_quat();
        cam.translation = pose.t.as_vec3();
    }
    focal.scale
}

/// Each view's [`ViewFit`] over the pairs within its component, under `cameras` and the focal
/// multiplier `focal` that the joint refinement left.
fn view_fits(
    cameras: &[Camera],
    component: &[usize],
    pairs: &[PairPose],
    focal: f64,
) -> Vec<ViewFit> {
    let pose = |c: &Camera| (DMat3::from_quat(c.rotation.as_dquat()), c.translation.as_dvec3());
    let mut errors: Vec<Vec<f64>> = vec![Vec::new(); cameras.len()];
    for p in pairs.iter().filter(|p| p.pose.is_some() && component[p.i] == component[p.j]) {
        let ((ri, ti), (rj, tj)) = (pose(&cameras[p.i]), pose(&cameras[p.j]));
        let model = Model::of_cameras(ri, ti, rj, tj);
        let (ki, kj) = (&cameras[p.i].intrinsics, &cameras[p.j].intrinsics);
        for c in &p.inliers {
            if let Some(r) = relative::reprojection(ki, kj, &model, c, focal) {
                errors[p.j].push(r[0].hypot(r[1]));
                errors[p.i].push(r[2].hypot(r[3]));
            }
        }
    }
    errors
        .into_iter()
        .map(|mut e| {
            e.sort_by(f64::total_cmp);
            ViewFit { matches: e.len(), reprojection_px: e.get(e.len() / 2).map(|&m| m as f32) }
        })
        .collect()
}

/// Pixel matches of views a and b whose pixels both have depth, lifted into each camera.
fn lifted(
    a: &RegisterView<'_>,
    b: &RegisterView<'_>,
    matches: impl IntoIterator<Item = (Vec2, Vec2)>,
) -> Vec<Correspondence> {
    let lift = |v: &RegisterView<'_>, p: Vec2| {
        let k = &v.camera.intrinsics;
        let z = *v.depth.get(p.y as usize * k.width as usize + p.x as usize)?;
        (z.is_finite() && z > 0.0).then(|| v.camera.unproject(p.x, p.y, z))
    };
    matches
        .into_iter()
        .filter_map(|(pa, pb)| {
            Some(Correspondence {
                pixel_i: pa,
                point_i: lift(a, pa)?,
                pixel_j: pb,
                point_j: lift(b, pb)?,
            })
        })
        .collect()
}
