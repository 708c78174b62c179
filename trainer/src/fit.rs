//! `fit-scene`: the per-scene optimization baseline (the setting of OpenGaussian-like
//! methods). Gaussians are seeded one per `stride`² pixels of each context view at its
//! ground-truth depth with the ground-truth cameras, then their positions, shapes, opacities,
//! colours and 8-d instance embeddings are optimized on that one scene with the trainer's
//! renderer and losses (L_rgb + w·L_ins against the context views' true instance masks) until
//! the loss stops falling. The fitted scene is then clustered in 3D exactly as the pipeline
//! clusters a network's output (instances split into their parts apart in 3D included),
//! rendered at the scene's target cameras (what no Gaussian covers taking the nearest covered
//! pixel's id, as `inssplat-eval score` fills a new view), and scored with the evaluation's
//! instance metric (pooled over target views and visible instances), so its time and instance mIoU
//! stand
//! next to `inssplat-eval score`'s numbers for the feed-forward model. Scored also along the way
//! (`score_at`), it gives its accuracy against its optimization time.

use std::time::Instant;

use burn::module::{Module, Param};
use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use inssplat_geometry::voxel::{VoxelParams, robust_extent};
use inssplat_metrics::segmentation::{InstancePool, instance_scores};
use inssplat_proto::dataset::Scene;
use inssplat_proto::gaussian::{Gaussian, rgb_to_sh_dc};
use inssplat_proto::{GaussianScene, INSTANCE_DIM};
use inssplat_raster::masks::{fill_uncovered, render_instance_ids};
use inssplat_raster::render::RenderOptions;
use inssplat_understand::cluster::split::{SplitParams, split_disconnected};
use inssplat_understand::cluster::{ClusterParams, cluster_instances};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::loss::{HardNegatives, LossConfig, instance_loss, rgb_loss};
use crate::render_op::{SplatTensors, render};

/// Knobs of one fit.
#[derive(Debug, Clone)]
pub struct FitConfig {
    /// Context views (the scene's `eval.context` set of this size).
    pub views: usize,
    /// One Gaussian per `stride`×`stride` pixels of each context view.
    pub stride: usize,
    /// Adam learning rate.
    pub lr: f64,
    /// Weight of L_ins against L_rgb.
    pub instance_weight: f64,
    /// Upper bound on optimizer steps.
    pub max_steps: usize,
    /// Converged when the mean loss of the last `window` steps is within `tolerance` (relative)
    /// of the mean of the `window` before.
    pub window: usize,
    pub tolerance: f32,
    /// Also score the fit after each of these step counts (its speed against its accuracy).
    pub score_at: Vec<usize>,
}

impl Default for FitConfig {
    fn default() -> Self {
        Self {
            views: 8,
            stride: 2,
            lr: 5e-3,
            instance_weight: 1.0,
            max_steps: 1500,
            window: 50,
            tolerance: 0.005,
            score_at: Vec::new(),
        }
    }
}

impl FitConfig {
    /// The settings a report records of this configuration.
    pub fn settings(&self) -> FitSettings {
        FitSettings {
            views: self.views,
            stride: self.stride,
            max_steps: self.max_steps,
            lr: self.lr,
            score_at: self.score_at.clone(),
        }
    }
}

/// The settings a fit ran under, as its report records them: two fits are comparable only
/// where these agree.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitSettings {
    pub views: usize,
    pub stride: usize,
    pub max_steps: usize,
    pub lr: f64,
    /// The step counts at which the fit was also scored along the way.
    pub score_at: Vec<usize>,
}

impl std::fmt::Display for FitSettings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "views {}, stride {}, max_steps {}, lr {}, score_at {:?}",
            self.views, self.stride, self.max_steps, self.lr, self.score_at
        )
    }
}

/// What one fit cost and scored, with the settings it ran under.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FitReport {
    pub scene: String,
    #[serde(flatten)]
    pub settings: FitSettings,
    pub gaussians: usize,
    pub steps: usize,
    pub converged: bool,
    /// Optimization wall time (seeding and scoring excluded).
    pub seconds: f64,
    pub first_loss: f32,
    pub final_loss: f32,
    /// The finished fit's scores.
    #[serde(flatten)]
    pub scores: FitScores,
    /// The fit scored at each of `score_at`'s step counts it reached.
    pub curve: Vec<CurvePoint>,
}

/// How a fit's clustered instances score on the scene's target views.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitScores {
    pub instances_found: usize,
    /// Pooled over target views and their visible true instances, as `inssplat-eval score` does.
    pub instance_miou: Option<f64>,
    pub instance_acc25: Option<f64>,
    /// Panoptic quality, pooled over the target views as `inssplat-eval score` pools it.
    pub instance_pq: Option<f64>,
}

/// The fit scored after `steps` steps and `seconds` of optimization.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CurvePoint {
    pub steps: usize,
    pub seconds: f64,
    #[serde(flatten)]
    pub scores: FitScores,
}

#[derive(Debug, thiserror::Error)]
pub enum FitError {
    #[error("{scene}: {problem}")]
    Scene { scene: String, problem: String },
    #[error("{scene}: step {step}: {problem}")]
    Step { scene: String, step: usize, problem: String },
}

/// The optimized quantities.
#[derive(Module, Debug)]
struct Fitted {
    means: Param<Tensor<2>>,
    log_scales: Param<Tensor<2>>,
    rotations: Param<Tensor<2>>,
    logit_opacity: Param<Tensor<1>>,
    colour: Param<Tensor<2>>,
    instance: Param<Tensor<2>>,
}

impl Fitted {
    fn splats(&self) -> SplatTensors {
        SplatTensors {
            means: self.means.val(),
            log_scales: self.log_scales.val(),
            rotations: self.rotations.val(),
            logit_opacity: self.logit_opacity.val(),
            features: Tensor::cat(vec![self.colour.val(), self.instance.val()], 1),
        }
    }
}

/// Host-side seed values, row-major.
#[derive(Default)]
struct Seed {
    means: Vec<f32>,
    log_scales: Vec<f32>,
    colour: Vec<f32>,
}

/// One Gaussian per `stride`² pixels with a true depth, lifted with the true camera.
fn seed(scene: &Scene, context: &[usize], stride: usize) -> Seed {
    let mut s = Seed::default();
    for &f in context {
        let frame = &scene.frames[f];
        let Some(depth) = &frame.depth else { continue };
        let (w, h) = (frame.width() as usize, frame.height() as usize);
        let k = frame.camera.intrinsics;
        for y in (0..h).step_by(stride) {
            for x in (0..w).step_by(stride) {
                let d = depth[y * w + x];
                if !(d > 0.0 && d.is_finite()) {
                    continue;
                }
                let p = frame.camera.camera_to_world(frame.camera.unproject(
                    x as f32 + 0.5,
                    y as f32 + 0.5,
                    d,
                ));
                s.means.extend(p.to_array());
                s.log_scales.extend([(0.5 * d * stride as f32 / k.fx).ln(); 3]);
                s.colour.extend((0..3).map(|c| f32::from(frame.rgb[(y * w + x) * 3 + c]) / 255.0));
            }
        }
    }
    s
}

/// Fits `scene` from its `config.views`-view context set and scores it on its target views.
/// `on_step(step, loss)` is called after every step (for progress).
pub fn fit_scene(
    scene: &Scene,
    config: &FitConfig,
    on_step: &dyn Fn(usize, f32),
) -> Result<FitReport, FitError> {
    let name = scene.name();
    let bad = |problem: String| FitError::Scene { scene: name.clone(), problem };
    let eval = scene.eval.as_ref().ok_or_else(|| {
        bad("transforms.json has no `eval` split (synthesize with --split test)".into())
    })?;
    let context = eval
        .context_for(config.views)
        .ok_or_else(|| bad(format!("no {}-view context set in `eval.context`", config.views)))?;
    if config.stride == 0 || config.window == 0 || config.max_steps == 0 {
        return Err(bad("--stride, --max-steps and the convergence window must be ≥ 1".into()));
    }
    let frames: Vec<_> = context.iter().map(|&f| &scene.frames[f]).collect();
    let (w, h) = (frames[0].width() as usize, frames[0].height() as usize);
    if frames
        .iter()
        .any(|f| f.width() as usize != w || f.height() as usize != h || f.instances.is_none())
    {
        return Err(bad("context frames must share one size and carry instance masks".into()));
    }
    let seeded = seed(scene, context, config.stride);
    let n = seeded.means.len() / 3;
    if n == 0 {
        return Err(bad("no context pixel has a true depth to seed Gaussians from".into()));
    }

    let device = Device::flex().autodiff();
    let mut rng = ChaCha8Rng::seed_from_u64(
        name.bytes().fold(0u64, |a, b| a.wrapping_mul(31).wrapping_add(u64::from(b))),
    );
    // Small start: a pixel's rendered feature sums several Gaussians, so large random
    // embeddings would average out in the render while staying random per Gaussian, and the 3D
    // clustering (which sees Gaussians, not pixels) would find only noise.
    let instance_seed: Vec<f32> =
        (0..n * INSTANCE_DIM).map(|_| rng.random_range(-0.01..0.01)).collect();
    let param2 = |v: Vec<f32>, c: usize| {
        Param::from_tensor(Tensor::<2>::from_data(TensorData::new(v, [n, c]), &device))
    };
    let identity: Vec<f32> = (0..n).flat_map(|_| [1.0, 0.0, 0.0, 0.0]).collect();
    let mut fitted = Fitted {
        means: param2(seeded.means, 3),
        log_scales: param2(seeded.log_scales, 3),
        rotations: param2(identity, 4),
        logit_opacity: Param::from_tensor(Tensor::<1>::from_data(
            TensorData::new(vec![2.0f32; n], [n]),
            &device,
        )),
        colour: param2(seeded.colour, 3),
        instance: param2(instance_seed, INSTANCE_DIM),
    };

    let images: Vec<f32> = frames.iter().flat_map(|f| f.planar_rgb()).collect();
    let v = frames.len();
    let images = Tensor::<4>::from_data(TensorData::new(images, [v, 3, h, w]), &device);
    let ids: Vec<u32> = frames
        .iter()
        .flat_map(|f| f.instances.as_ref().into_iter().flatten().map(|&i| u32::from(i)))
        .collect();
    let no_semantic = Tensor::<4>::zeros([v, 1, h, w], &device);
    let loss_config = LossConfig::new().with_hard_negatives(HardNegatives::Uniform);

    let mut optim = AdamConfig::new().init();
    let mut losses: Vec<f32> = Vec::new();
    let mut converged = false;
    let mut curve: Vec<CurvePoint> = Vec::new();
    // Optimization time only: the clock stops while the fit is scored along the way.
    let mut seconds = 0.0;
    let mut start = Instant::now();
    for step in 0..config.max_steps {
        let step_err = |problem: String| FitError::Step { scene: name.clone(), step, problem };
        let splats = fitted.splats();
        let renders = frames
            .iter()
            .map(|f| {
                render(splats.clone(), &f.camera, &[], &RenderOptions::default())
                    .map(|r| r.features)
            })
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| step_err(e.to_string()))?;
        let rendered = Tensor::stack::<4>(renders, 0);
        let rgb = rgb_loss(rendered.clone().narrow(1, 0, 3), images.clone())
            .map_err(|e| step_err(e.to_string()))?;
        let ins =
            instance_loss(rendered.narrow(1, 3, INSTANCE_DIM), &no_semantic, &ids, &loss_config)
                .map_err(|e| step_err(e.to_string()))?
                .total(&loss_config);
        let loss = rgb + ins.mul_scalar(config.instance_weight);
        let value = loss.clone().into_scalar::<f32>();
        if !value.is_finite() {
            return Err(step_err(format!("the loss is not finite ({value})")));
        }
        losses.push(value);
        on_step(step, value);
        let grads = GradientsParams::from_grads(loss.backward(), &fitted);
        fitted = optim.step(config.lr, fitted, grads);
        if plateaued(&losses, config.window, config.tolerance) {
            converged = true;
            break;
        }
        if config.score_at.contains(&losses.len()) {
            seconds += start.elapsed().as_secs_f64();
            let scores = score(&fitted, scene, &eval.target).map_err(bad)?;
            curve.push(CurvePoint { steps: losses.len(), seconds, scores });
            start = Instant::now();
        }
    }
    seconds += start.elapsed().as_secs_f64();
    // A fit that ran to a step count it was scored at ends with that score.
    let scores = match curve.last() {
        Some(p) if p.steps == losses.len() => p.scores.clone(),
        _ => score(&fitted, scene, &eval.target).map_err(bad)?,
    };
    Ok(FitReport {
        scene: name,
        settings: FitSettings { views: v, ..config.settings() },
        gaussians: n,
        steps: losses.len(),
        converged,
        seconds,
        first_loss: losses[0],
        final_loss: losses[losses.len() - 1],
        scores,
        curve,
    })
}

/// Clusters the fitted Gaussians as the pipeline clusters a network's and scores the
/// instances on the target frames `targets`.
fn score(fitted: &Fitted, scene: &Scene, targets: &[usize]) -> Result<FitScores, String> {
    let mut fitted_scene = to_scene(&fitted.valid());
    let clustering = cluster_instances(&mut fitted_scene, &ClusterParams::default())
        .map_err(|e| e.to_string())?;
    // The pipeline's split of instances into their parts apart in 3D, with its cell: the
    // voxel edge the pipeline would use for these Gaussians.
    let split = SplitParams::default();
    let cell =
        split.cell_voxels * VoxelParams::default().voxel_size(robust_extent(&fitted_scene.means));
    let added =
        split_disconnected(&fitted_scene.means, &mut fitted_scene.instance_id, cell, &split);
    let k = clustering.prototypes.len() + added;
    let mut instances = InstancePool::default();
    for &t in targets {
        let frame = &scene.frames[t];
        let Some(gt) = &frame.instances else { continue };
        let mut pred =
            render_instance_ids(&fitted_scene, &frame.camera, k).map_err(|e| e.to_string())?;
        // Filled as `inssplat-eval score` fills a target view's ids, so that both sides score
        // alike.
        let (w, h) =
            (frame.camera.intrinsics.width as usize, frame.camera.intrinsics.height as usize);
        fill_uncovered(&mut pred, None, w, h);
        let gt: Vec<u32> = gt.iter().map(|&i| u32::from(i)).collect();
        if let Some(s) = instance_scores(&pred, &gt).map_err(|e| e.to_string())? {
            instances.add(&s);
        }
    }
    Ok(FitScores {
        instances_found: k,
        instance_miou: instances.miou(),
        instance_acc25: instances.acc_25(),
        instance_pq: instances.pq(),
    })
}

/// Whether the last `window` losses' mean is within `tolerance` (relative) of the `window`
/// before them.
fn plateaued(losses: &[f32], window: usize, tolerance: f32) -> bool {
    if losses.len() < 2 * window {
        return false;
    }
    let mean = |s: &[f32]| s.iter().sum::<f32>() / s.len() as f32;
    let recent = mean(&losses[losses.len() - window..]);
    let before = mean(&losses[losses.len() - 2 * window..losses.len() - window]);
    before - recent <= tolerance * before.abs()
}

/// The fitted Gaussians as a scene the pipeline's clustering and renderer take.
fn to_scene(fitted: &Fitted) -> GaussianScene {
    let rows = |t: Tensor<2>| t.into_data().try_to_vec::<f32>().expect("f32 parameters");
    let means = rows(fitted.means.val());
    let log_scales = rows(fitted.log_scales.val());
    let rotations = rows(fitted.rotations.val());
    let colour = rows(fitted.colour.val());
    let instance = rows(fitted.instance.val());
    let opacity =
        fitted.logit_opacity.val().into_data().try_to_vec::<f32>().expect("f32 parameters");
    let n = opacity.len();
    let mut scene = GaussianScene::with_sem_dim(0);
    scene.reserve(n);
    for i in 0..n {
        let q = glam::Vec4::from_slice(&rotations[i * 4..i * 4 + 4]);
        let q = if q.length() > 1e-8 { q.normalize() } else { glam::Vec4::X };
        scene.push(Gaussian {
            mean: std::array::from_fn(|k| means[i * 3 + k]),
            log_scale: std::array::from_fn(|k| log_scales[i * 3 + k]),
            rotation: q.to_array(),
            logit_opacity: opacity[i],
            sh_dc: std::array::from_fn(|c| rgb_to_sh_dc(colour[i * 3 + c])),
            confidence: 1.0,
            instance_embedding: std::array::from_fn(|e| instance[i * INSTANCE_DIM + e]),
            semantic: &[],
            instance_id: 0,
        });
    }
    scene
}

#[cfg(test)]
mod tests {
    use super::plateaued;

    #[test]
    fn a_plateau_needs_two_windows_that_barely_differ() {
        assert!(!plateaued(&[1.0; 3], 2, 0.01), "too short");
        assert!(!plateaued(&[4.0, 4.0, 2.0, 2.0], 2, 0.01), "still falling");
        assert!(plateaued(&[2.0, 2.0, 1.999, 1.999], 2, 0.01));
        assert!(plateaued(&[2.0, 2.0, 2.5, 2.5], 2, 0.01), "rising counts as done");
    }
}
