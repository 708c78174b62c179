//! Test-time refinement of a reconstructed scene against its own input photos: Adam on every
//! Gaussian's position, scale, rotation, opacity and colour, and on each input camera's pose
//! but the first (the reference frame), through the rasterizer's hand-written backward,
//! minimizing the mean squared colour error of one input view a step (views in turn, as 3DGS
//! trains; the cameras stay as given where they are known). This is the joint optimization
//! that InstantSplat runs after its feed-forward initialization, kept short: the network's
//! depth places the Gaussians, the photos then correct what the depth got wrong where the
//! views see it. Each photo also gets a brightness gain of its own (its camera's auto
//! exposure; the gains' logs kept at mean zero), so that the Gaussians take the photos' common
//! colour instead of a blend of differently exposed ones. Instance ids, embeddings and
//! semantic features ride along with their Gaussians unchanged. Learning rates decay
//! exponentially to a tenth over the run.

use inssplat_proto::gaussian::rgb_to_sh_dc;
use inssplat_proto::{Camera, GaussianScene};

use crate::adam::{Adam, PoseAdam};
use crate::target_pose::median_distance;
use inssplat_raster::masks::{MaskError, colours, splats};
use inssplat_raster::render::{render, render_backward};

/// Adam's step on the positions, as a share of the median distance from the first camera to
/// the Gaussians (the predicted frame's scale is the depth's, not metres).
const LR_MEAN: f32 = 1e-3;
/// Adam's step on the log-scales.
const LR_LOG_SCALE: f32 = 1e-2;
/// Adam's step on the quaternions' components.
const LR_ROTATION: f32 = 5e-3;
/// Adam's step on the logit opacities.
const LR_OPACITY: f32 = 5e-2;
/// Adam's step on the RGB colours.
const LR_COLOUR: f32 = 1e-2;
/// Adam's step on the cameras' quaternion components (1e-3 turns a camera by about 0.11°).
const LR_POSE_ROTATION: f32 = 1e-3;
/// Adam's step on the cameras' translations, as a share of the median distance.
const LR_POSE_TRANSLATION: f32 = 1e-3;
/// Adam's step on each photo's log brightness gain.
const LR_EXPOSURE: f32 = 2e-2;
/// The rates at the last step, as a share of those at the first.
const FINAL_LR_SHARE: f32 = 0.1;

/// One input view: its photo, planar `[3][H][W]` in 0..1 at its camera's size, and the
/// pixels of it that show the photo (`[x0, y0, x1, y1)`; letterbox bars outside are not
/// compared).
#[derive(Debug, Clone, Copy)]
pub struct RefineView<'a> {
    pub photo: &'a [f32],
    pub rect: [u32; 4],
}

/// What [`refine_scene`] did: the Adam steps it took, the input views' mean squared colour
/// error (inside their rects, averaged over views; the scene as it renders, without the
/// gains) before and after, and each photo's brightness gain that the fit found.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneRefinement {
    pub steps: usize,
    pub mse_before: f64,
    pub mse_after: f64,
    pub gains: Vec<f32>,
}

impl SceneRefinement {
    /// The input views' fit before and after as PSNR (dB, of the mean squared error; colours
    /// in 0..1).
    pub fn psnr(&self) -> [f64; 2] {
        [self.mse_before, self.mse_after].map(|mse| -10.0 * mse.max(1e-12).log10())
    }
}

/// What [`refine_scene`] optimizes, and for how long.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RefineParams {
    /// Adam steps, one view each.
    pub steps: usize,
    /// Refine the cameras' poses too (all but the first); `false` keeps them, as for cameras
    /// the user gave.
    pub cameras: bool,
}

/// Refines `scene` (and `cameras`, one per view, where `params` says so; the first stays
/// fixed) against `views`. The scene's quaternions come back normalized and its colours as
/// SH DC.
///
/// # Panics
/// If `cameras` and `views` differ in length.
pub fn refine_scene(
    scene: &mut GaussianScene,
    cameras: &mut [Camera],
    views: &[RefineView<'_>],
    params: RefineParams,
) -> Result<SceneRefinement, MaskError> {
    let steps = params.steps;
    scene.validate()?;
    assert_eq!(cameras.len(), views.len(), "one camera per view");
    for (camera, view) in cameras.iter().zip(views) {
        let (w, h) = (camera.intrinsics.width as usize, camera.intrinsics.height as usize);
        if view.photo.len() != 3 * w * h {
            return Err(MaskError::PhotoSize { expected: 3 * w * h, got: view.photo.len() });
        }
    }
    let mut colours = colours(scene);
    let mse_before = mean_error(scene, &colours, cameras, views)?;
    if steps == 0 || views.is_empty() || scene.is_empty() {
        return Ok(SceneRefinement {
            steps: 0,
            mse_before,
            mse_after: mse_before,
            gains: vec![1.0; views.len()],
        });
    }
    let n = scene.len();
    let distance = median_distance(scene, &cameras[0]);
    let mut adam = Groups {
        means: Adam::new(3 * n),
        log_scales: Adam::new(3 * n),
        rotations: Adam::new(4 * n),
        opacity: Adam::new(n),
        colours: Adam::new(3 * n),
        poses: vec![PoseAdam::default(); cameras.len()],
        exposure: vec![Adam::new(1); views.len()],
    };
    let mut log_gains = vec![0.0f32; views.len()];
    for step in 0..steps {
        let decay = FINAL_LR_SHARE.powf(step as f32 / steps.saturating_sub(1).max(1) as f32);
        let v = step % views.len();
        let (camera, view) = (cameras[v], views[v]);
        let splats = splats(scene, &colours, 3);
        let (image, state) = render(&splats, &camera, &[0.0; 3])?;
        let gain = log_gains[v].exp();
        // The residual is the gradient w.r.t. the gained render; times the gain, w.r.t. the render.
        let mut d_features = residual(&image.features, view, &camera, gain);
        let d_gain: f32 = d_features.iter().zip(&image.features).map(|(d, a)| d * gain * a).sum();
        d_features.iter_mut().for_each(|d| *d *= gain);
        let pixels = image.alpha.len();
        let zeros = vec![0.0; pixels];
        let g = render_backward(&splats, &camera, &state, &d_features, &zeros, &zeros);
        adam.means.step(
            scene.means.as_flattened_mut(),
            g.means.as_flattened(),
            &[decay * LR_MEAN * distance],
        );
        adam.log_scales.step(
            scene.log_scales.as_flattened_mut(),
            g.log_scales.as_flattened(),
            &[decay * LR_LOG_SCALE],
        );
        adam.rotations.step(
            scene.rotations.as_flattened_mut(),
            g.rotations.as_flattened(),
            &[decay * LR_ROTATION],
        );
        adam.opacity.step(&mut scene.logit_opacity, &g.logit_opacity, &[decay * LR_OPACITY]);
        adam.colours.step(&mut colours, &g.features, &[decay * LR_COLOUR]);
        if params.cameras && v > 0 {
            adam.poses[v].step(
                &mut cameras[v],
                &g.camera,
                decay * LR_POSE_ROTATION,
                decay * LR_POSE_TRANSLATION * distance,
            );
        }
        adam.exposure[v].step(&mut log_gains[v..=v], &[d_gain], &[decay * LR_EXPOSURE]);
        let mean = log_gains.iter().sum::<f32>() / log_gains.len() as f32;
        log_gains.iter_mut().for_each(|e| *e -= mean);
    }
    for q in &mut scene.rotations {
        let norm = q.iter().map(|c| c * c).sum::<f32>().sqrt();
        if norm > 0.0 {
            *q = q.map(|c| c / norm);
        }
    }
    for (sh, rgb) in scene.sh_dc.iter_mut().zip(colours.chunks_exact(3)) {
        *sh = [0, 1, 2].map(|c| rgb_to_sh_dc(rgb[c]));
    }
    let mse_after = mean_error(scene, &colours, cameras, views)?;
    Ok(SceneRefinement {
        steps,
        mse_before,
        mse_after,
        gains: log_gains.iter().map(|e| e.exp()).collect(),
    })
}

/// The Adam moments of each parameter group.
struct Groups {
    means: Adam,
    log_scales: Adam,
    rotations: Adam,
    opacity: Adam,
    colours: Adam,
    poses: Vec<PoseAdam>,
    /// One per photo, for its log gain.
    exposure: Vec<Adam>,
}

/// The gradient of the mean squared error inside `view.rect` w.r.t. the rendered planes
/// times `gain`.
fn residual(rendered: &[f32], view: RefineView<'_>, camera: &Camera, gain: f32) -> Vec<f32> {
    let w = camera.intrinsics.width as usize;
    let [x0, y0, x1, y1] = view.rect.map(|c| c as usize);
    let count = (3 * (x1.saturating_sub(x0)) * (y1.saturating_sub(y0))).max(1) as f32;
    let plane = rendered.len() / 3;
    rendered
        .iter()
        .zip(view.photo)
        .enumerate()
        .map(|(i, (a, b))| {
            let (x, y) = (i % plane % w, i % plane / w);
            match (x0..x1).contains(&x) && (y0..y1).contains(&y) {
                true => 2.0 * (gain * a - b) / count,
                false => 0.0,
            }
        })
        .collect()
}

/// Mean over the views of the mean squared colour error inside each view's rect.
fn mean_error(
    scene: &GaussianScene,
    colours: &[f32],
    cameras: &[Camera],
    views: &[RefineView<'_>],
) -> Result<f64, MaskError> {
    let splats = splats(scene, colours, 3);
    let mut total = 0.0;
    for (camera, view) in cameras.iter().zip(views) {
        let (image, _) = render(&splats, camera, &[0.0; 3])?;
        let gradient = residual(&image.features, *view, camera, 1.0);
        // Each entry of the residual is 2(a − b)/count, so Σ (a − b)² / count = Σ g·(a − b) / 2.
        total += gradient
            .iter()
            .zip(&image.features)
            .zip(view.photo)
            .map(|((g, a), b)| f64::from(g * (a - b)) / 2.0)
            .sum::<f64>();
    }
    Ok(total / views.len().max(1) as f64)
}
