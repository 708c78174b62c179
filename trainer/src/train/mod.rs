//! The training loop: AdamW with warm-up + cosine learning rate, one or more samples per step (side
//! by side on threads, see
//! [`batch`]) of 2–8 input views plus held-out target views each, data from a folder of scenes
//! or synthesized on the fly (prefetched on background threads, one per sample of a step), a
//! validation loss on fixed val samples ([`validation`]), checkpoints every few minutes with exact
//! resume, an
//! indicatif progress bar with the loss terms, and the CSV logs and loss chart of [`log`].
//!
//! A run lives in one folder `RUN`: `checkpoints/`, `train_log.csv`, `val_log.csv`,
//! `loss.png`. [`train`] starts a run, [`resume`] continues the newest checkpoint of one with
//! the configuration and data it was started with, on the CPU or the GPU of [`Compute`].

pub mod batch;
pub mod checkpoint;
mod grow;
pub mod labels;
pub mod log;
mod ray_dropout;
pub mod sample;
pub mod schedule;
mod session;
pub mod step;
mod validation;

pub use grow::grow;
pub use session::{Compute, Session};

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use burn::grad_clipping::GradientClippingConfig;
use burn::module::{ModuleVisitor, Param};
use burn::optim::{AdamWConfig, GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
pub use labels::label_cache;

use crate::loss::{GaussianTraining, LossConfig};
use crate::model::{InsSplatNet, ModelConfig};
use checkpoint::{CHECKPOINT_FORMAT, CheckpointError, CheckpointState};
use log::{CsvLog, TRAIN_HEADER, VAL_HEADER, loss_cells};
pub use ray_dropout::RayPlan;
use sample::{DataSpec, Prefetcher, SampleError, Sampler, Source, ViewPlan};
use schedule::Schedule;
use step::{LossValues, StepError};
pub use validation::{CheckpointScores, DepthScores, ValidationSet, mean_loss, score_checkpoint};
use validation::{val_samples, validate};

/// Everything that defines a run; saved in every checkpoint. A saved configuration with
/// fields of experiments since removed (a backbone learning-rate factor, ray noise, the ray
/// layer trained alone, loss terms and heads that never shipped) reads without them: unknown
/// keys are ignored.
#[derive(Config, Debug)]
pub struct TrainConfig {
    pub model: ModelConfig,
    pub loss: LossConfig,
    /// Optimizer steps of the whole run (the cosine ends here).
    #[config(default = 20000)]
    pub steps: u64,
    #[config(default = 200)]
    pub warmup: u64,
    /// Peak learning rate.
    #[config(default = 5e-4)]
    pub lr: f64,
    /// Final learning rate as a fraction of the peak.
    #[config(default = 0.05)]
    pub lr_floor: f64,
    #[config(default = 0.05)]
    pub weight_decay: f64,
    /// Gradient clipping by norm, per parameter tensor (0 = off).
    #[config(default = 1.0)]
    pub grad_clip: f64,
    #[config(default = 2)]
    pub min_views: usize,
    #[config(default = 8)]
    pub max_views: usize,
    /// Held-out views rendered and supervised each step.
    #[config(default = 1)]
    pub targets: usize,
    /// Consecutive samples that share one scene.
    #[config(default = 2)]
    pub scene_reuse: u64,
    /// The scene of step 0: a later part of training can start on scenes no earlier part saw.
    #[config(default = 0)]
    pub first_scene: u64,
    /// Draw each step's views from this many consecutive frames ([`ViewPlan::window`]); `None`
    /// (also what configs saved before this existed read as): from the whole trajectory.
    pub view_window: Option<usize>,
    #[config(default = 0)]
    pub seed: u64,
    /// Samples per optimizer step, evaluated side by side on threads ([`batch`]), their
    /// gradients averaged; sample i of the run is step i / k's (i mod k)-th. `None` (also what
    /// configs saved before this existed read as) means 1.
    pub samples_per_step: Option<usize>,
    /// The rays a network that reads its cameras gets ([`RayPlan`]); `None` (also what configs
    /// saved before this existed read as): always the true cameras'.
    pub rays: Option<RayPlan>,
    /// The PyTorch file a new run's image encoder ([`ModelConfig::encoder`]) starts from; its
    /// checkpoints carry the weights after that.
    pub encoder_weights: Option<PathBuf>,
    /// The image encoder's weights stay as they started (a first phase, before the whole
    /// network is fine-tuned); `None` (also what configs saved before this existed read as):
    /// trained with the rest.
    pub freeze_encoder: Option<bool>,
}

impl TrainConfig {
    fn plan(&self) -> ViewPlan {
        ViewPlan {
            min_views: self.min_views,
            max_views: self.max_views,
            targets: self.targets,
            reuse: self.scene_reuse,
            first_scene: self.first_scene,
            window: self.view_window,
        }
    }

    /// Samples per optimizer step (k ≥ 1).
    pub fn batch(&self) -> u64 {
        self.samples_per_step.unwrap_or(1) as u64
    }

    fn schedule(&self) -> Schedule {
        Schedule { peak: self.lr, warmup: self.warmup, steps: self.steps, floor: self.lr_floor }
    }

    fn validate(&self) -> Result<(), TrainError> {
        self.model.validate().map_err(|e| TrainError::Config(e.to_string()))?;
        if self.min_views < 1 || self.min_views > self.max_views {
            return Err(TrainError::Config(format!(
                "views {}..{}: need 1 ≤ min ≤ max",
                self.min_views, self.max_views
            )));
        }
        if let Some(plan) = self.rays {
            if self.model.camera_rays.is_none() {
                return Err(TrainError::Config(
                    "ray dropout needs a network that reads camera rays (--camera-rays)".into(),
                ));
            }
            if !(0.0..=1.0).contains(&plan.dropout) {
                return Err(TrainError::Config(format!(
                    "ray dropout {} must be in 0..=1",
                    plan.dropout
                )));
            }
        }
        if self.freeze_encoder == Some(true) && self.model.encoder.is_none() {
            return Err(TrainError::Config(
                "freezing the image encoder needs a network with one (--encoder)".into(),
            ));
        }
        if self.samples_per_step == Some(0) {
            return Err(TrainError::Config("samples per step must be at least 1".into()));
        }
        if !(self.lr > 0.0 && self.lr.is_finite()) {
            return Err(TrainError::Config(format!("learning rate {} must be positive", self.lr)));
        }
        Ok(())
    }
}

/// Why training stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error("training configuration: {0}")]
    Config(String),
    #[error(transparent)]
    Sample(#[from] SampleError),
    #[error("step {step} ({scene}): {source}")]
    Step { step: u64, scene: String, source: StepError },
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error("semantic teacher: {0}")]
    Text(#[from] inssplat_text::TextError),
    #[error("{path}: {problem}")]
    Io { path: PathBuf, problem: String },
    #[error(
        "step {step}: the loss is not finite ({values:?}); lower the learning rate or check the data"
    )]
    Diverged { step: u64, values: LossValues },
    #[error(
        "{0} already holds a run (checkpoints/latest); pass --resume to continue it or choose another folder"
    )]
    Exists(PathBuf),
    #[error("{0} has no checkpoint")]
    NoCheckpoint(PathBuf),
    #[error(transparent)]
    Import(#[from] crate::export::ImportError),
}

/// How a session ended.
#[derive(Debug, Clone)]
pub struct Summary {
    pub first_step: u64,
    /// Steps done in total.
    pub steps: u64,
    /// Mean loss of the first and last (up to) 20 steps of this session.
    pub first_loss: f32,
    pub last_loss: f32,
    pub last_val: Option<LossValues>,
    /// Median step time of this session.
    pub median_step: Duration,
    pub checkpoint: Option<PathBuf>,
    /// The signal that stopped the session early ([`Session::stop`]), if one did.
    pub signal: Option<usize>,
}

/// Starts a new run in `run` (an error if it already has a checkpoint).
pub fn train(
    run: &Path,
    config: TrainConfig,
    data: DataSpec,
    session: &Session,
) -> Result<Summary, TrainError> {
    config.validate()?;
    if checkpoint::latest(run)?.is_some() {
        return Err(TrainError::Exists(run.to_path_buf()));
    }
    let device = session.compute.device()?;
    let mut net = seeded_init(&config.model, config.seed, &device)
        .map_err(|e| TrainError::Config(e.to_string()))?;
    if config.model.encoder.is_some() {
        let path = config.encoder_weights.as_ref().ok_or_else(|| {
            TrainError::Config(
                "the image encoder starts from its pretrained weights: give their file (--encoder-weights; scripts/setup exports INSSPLAT_ENCODER_WEIGHTS)".into(),
            )
        })?;
        net =
            net.with_pretrained_encoder(path).map_err(|e| TrainError::Config(format!("{e:#}")))?;
    }
    let optim = optimizer(&config);
    let state = CheckpointState {
        format: CHECKPOINT_FORMAT,
        step: 0,
        elapsed_s: 0.0,
        config,
        data,
        init_from: None,
        keep: None,
    };
    run_loop(run, net, optim, state, session, &device)
}

/// Starts a new run in `run` from the weights of the newest checkpoint of `from` (a run or a
/// checkpoint folder, or an exported ONNX file) with a fresh optimizer and schedule: a
/// fine-tune, or one arm of an ablation that all start from the same network. The network
/// shape is the source's; `config.model` is replaced by it, except that an image encoder or
/// camera rays asked for by `config.model` are added to a source without them and a wider
/// MLP than the source's widens its blocks' (see [`grow`]; never narrowed), and that a key
/// pooling it asks for replaces the source's (`Some(1)`: every token, for a source that
/// pools; `None` keeps the source's).
pub fn fine_tune(
    run: &Path,
    mut config: TrainConfig,
    data: DataSpec,
    from: &Path,
    session: &Session,
) -> Result<Summary, TrainError> {
    if checkpoint::latest(run)?.is_some() {
        return Err(TrainError::Exists(run.to_path_buf()));
    }
    let device = session.compute.device()?;
    let (net, init_from) = if from.is_file() {
        let (net, meta) = crate::export::import_onnx(from, &device)?;
        (net, checkpoint::InitFrom { checkpoint: from.to_path_buf(), step: meta.train_steps })
    } else {
        let dir = checkpoint::latest(from)?
            .ok_or_else(|| TrainError::NoCheckpoint(from.to_path_buf()))?;
        let source = checkpoint::read_state(&dir)?;
        let net = checkpoint::load_model(&dir, &source, &device)?;
        (net, checkpoint::InitFrom { checkpoint: dir, step: source.step })
    };
    if config.model.encoder.is_some() && net.config().encoder.is_none() {
        return Err(TrainError::Config(format!(
            "{} has no image encoder, and none can be added to it: a network on the encoder starts as a new run",
            from.display()
        )));
    }
    let mut shape = net.config().clone();
    shape.mlp_ratio = shape.mlp_ratio.max(config.model.mlp_ratio);
    shape.sem_dim = shape.sem_dim.max(config.model.sem_dim);
    for (part, asked, has) in [
        ("an image encoder", config.model.image_skips, &mut shape.image_skips),
        ("camera rays", config.model.camera_rays, &mut shape.camera_rays),
    ] {
        match (asked, *has) {
            (Some(asked), None) => *has = Some(asked),
            (Some(asked), Some(had)) if asked != had => {
                return Err(TrainError::Config(format!(
                    "{} has {part} of {had} channels; it cannot become {asked}",
                    from.display()
                )));
            }
            _ => {}
        }
    }
    let net = if shape == *net.config() { net } else { grow(&net, shape, config.seed, &device)? };
    let net = match config.model.global_kv_pool {
        Some(pool) => net
            .with_global_kv_pool((pool > 1).then_some(pool))
            .map_err(|e| TrainError::Config(e.to_string()))?,
        None => net,
    };
    config.model = net.config().clone();
    // The encoder's weights come with the source's.
    config.encoder_weights = None;
    config.validate()?;
    let optim = optimizer(&config);
    let state = CheckpointState {
        format: CHECKPOINT_FORMAT,
        step: 0,
        elapsed_s: 0.0,
        config,
        data,
        init_from: Some(init_from),
        keep: None,
    };
    run_loop(run, net, optim, state, session, &device)
}

/// Continues the newest checkpoint of `run`; `steps` extends (or shortens) the run's length.
pub fn resume(run: &Path, steps: Option<u64>, session: &Session) -> Result<Summary, TrainError> {
    let dir =
        checkpoint::latest(run)?.ok_or_else(|| TrainError::NoCheckpoint(run.to_path_buf()))?;
    let mut state = checkpoint::read_state(&dir)?;
    let device = session.compute.device()?;
    let net = checkpoint::load_model(&dir, &state, &device)?;
    let optim = checkpoint::load_optimizer(&dir, optimizer(&state.config))?;
    if let Some(steps) = steps {
        state.config.steps = steps;
    }
    state.config.validate()?;
    run_loop(run, net, optim, state, session, &device)
}

/// A fresh network whose weights depend only on `seed`. The backend's random generator is
/// process-wide, so seeding and drawing happen under one lock: two runs started in one process
/// (tests) cannot interleave their draws.
pub fn seeded_init(
    model: &ModelConfig,
    seed: u64,
    device: &Device,
) -> Result<InsSplatNet, crate::model::ModelError> {
    static INIT: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _guard = INIT.lock().unwrap_or_else(|e| e.into_inner());
    device.seed(seed);
    let net = model.init(device)?;
    // burn initialises parameters lazily, on first use: draw them now, under the lock.
    net.visit(&mut Materialize);
    Ok(net)
}

/// Forces every lazily initialised float parameter to be drawn.
struct Materialize;

impl ModuleVisitor for Materialize {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let _ = param.val();
    }
}

fn optimizer(config: &TrainConfig) -> ModuleOptimizer {
    let mut adam = AdamWConfig::new().with_weight_decay(config.weight_decay as f32);
    if config.grad_clip > 0.0 {
        adam = adam.with_grad_clipping(Some(GradientClippingConfig::Norm(config.grad_clip as f32)));
    }
    adam.init()
}

fn io_error(path: &Path, e: impl std::fmt::Display) -> TrainError {
    TrainError::Io { path: path.to_path_buf(), problem: e.to_string() }
}

/// One optimizer update of `net` with `grads` (see [`batch::gradients`]) at `lr`; in the
/// frozen-3DGS ablation only the output layer of the dense decoder and Φ_sem move.
pub fn update(
    net: InsSplatNet,
    optim: &mut ModuleOptimizer,
    mut grads: GradientsParams,
    lr: f64,
    config: &TrainConfig,
) -> InsSplatNet {
    if config.loss.gaussians == GaussianTraining::Frozen {
        let mut heads = GradientsParams::new();
        batch::move_gradients(&net.decoder.out, &mut grads, &mut heads);
        batch::move_gradients(&net.sem_proj, &mut grads, &mut heads);
        return optim.step(lr, net, heads);
    }
    optim.step(lr, net, grads)
}

fn progress_bar(state: &CheckpointState, session: &Session) -> ProgressBar {
    let bar = ProgressBar::new(state.config.steps);
    if !session.progress {
        bar.set_draw_target(ProgressDrawTarget::hidden());
    }
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} step {pos}/{len} [{elapsed_precise}<{eta_precise}] {wide_msg}",
        )
        .expect("progress template"),
    );
    bar.set_position(state.step);
    bar.reset_eta();
    bar
}

fn run_loop(
    run: &Path,
    mut net: InsSplatNet,
    mut optim: ModuleOptimizer,
    mut state: CheckpointState,
    session: &Session,
    device: &Device,
) -> Result<Summary, TrainError> {
    std::fs::create_dir_all(run).map_err(|e| io_error(run, e))?;
    if state.config.freeze_encoder == Some(true) {
        net = net.freeze_encoder();
    }
    state.keep = Some(session.keep.or(state.keep).unwrap_or(checkpoint::DEFAULT_KEEP));
    let labels = label_cache()?;
    let source = Source::open(&state.data)?;
    let sampler = Sampler {
        source,
        plan: state.config.plan(),
        seed: state.config.seed,
        labels: labels.clone(),
    };
    let val = val_samples(&state, session, &labels, None)?;
    let first_step = state.step;
    let (train_csv, val_csv, chart) =
        (run.join("train_log.csv"), run.join("val_log.csv"), run.join("loss.png"));
    let mut train_log =
        CsvLog::open(&train_csv, TRAIN_HEADER, first_step).map_err(|e| io_error(&train_csv, e))?;
    let mut val_log =
        CsvLog::open(&val_csv, VAL_HEADER, first_step).map_err(|e| io_error(&val_csv, e))?;
    let schedule = state.config.schedule();
    let bar = progress_bar(&state, session);
    let k = state.config.batch();
    // One data thread per sample of a step: a step of k samples needs up to k scenes made.
    let mut prefetch = Prefetcher::start(
        sampler,
        first_step * k,
        state.config.steps * k,
        3 * k as usize,
        k as usize,
    );
    let session_start = Instant::now();
    let base_elapsed = state.elapsed_s;
    let mut last_checkpoint = Instant::now();
    let mut checkpoint_dir = None;
    let mut totals = Vec::new();
    let mut step_times = Vec::new();
    let mut last_val = None;
    let mut signal = None;
    loop {
        let wait = Instant::now();
        let (mut samples, mut step) = (Vec::with_capacity(k as usize), 0);
        for _ in 0..k {
            let Some((index, sample)) = prefetch.next() else { break };
            step = index / k;
            let mut sample = sample?;
            if let Some(plan) = &state.config.rays {
                plan.apply(&mut sample, index);
            }
            samples.push(sample);
        }
        if samples.is_empty() {
            break;
        }
        let data_wait = wait.elapsed();
        let t0 = Instant::now();
        let lr = schedule.lr(step);
        let g =
            batch::gradients(&net, &samples, &state.config.loss, device).map_err(|failure| {
                TrainError::Step {
                    step,
                    scene: samples[failure.sample].scene.clone(),
                    source: failure.error,
                }
            })?;
        let values = g.values;
        if !values.total.is_finite() {
            return Err(TrainError::Diverged { step, values });
        }
        let t_update = Instant::now();
        net = update(net, &mut optim, g.grads, lr, &state.config);
        let backward = g.backward + t_update.elapsed();
        let step_time = t0.elapsed();
        state.step = step + 1;
        state.elapsed_s = base_elapsed + session_start.elapsed().as_secs_f64();
        totals.push(values.total);
        step_times.push(step_time);
        let mut row = vec![step.to_string(), format!("{lr:.3e}")];
        row.extend(loss_cells(&values));
        row.extend(
            [step_time, g.forward, g.render, backward, data_wait]
                .iter()
                .map(|d| format!("{:.3}", d.as_secs_f64())),
        );
        row.push(format!("{:.1}", state.elapsed_s));
        row.push(format!("{:.4}", g.render_backward.as_secs_f64()));
        train_log.row(&row).map_err(|e| io_error(train_log.path(), e))?;
        bar.set_position(state.step);
        bar.set_message(format!(
            "loss {:.4} rgb {:.4} geom {:.3} ins {:.3} sem {:.3} bd {:.3} | {:.2} s/step",
            values.total,
            values.rgb,
            values.geometry,
            values.instance,
            values.semantic,
            values.boundary,
            step_time.as_secs_f64()
        ));
        let validate_now = session.val_every > 0
            && state.step.is_multiple_of(session.val_every)
            && !val.is_empty();
        if validate_now {
            let v = validate(&net, &val, &state.config.loss, device)
                .map_err(|source| TrainError::Step { step, scene: "validation".into(), source })?;
            let mut row = vec![state.step.to_string()];
            row.extend(loss_cells(&v));
            val_log.row(&row).map_err(|e| io_error(val_log.path(), e))?;
            bar.println(format!(
                "step {}: val loss {:.4} (rgb {:.4}, geom {:.3}, ins {:.3}, sem {:.3})",
                state.step, v.total, v.rgb, v.geometry, v.instance, v.semantic
            ));
            last_val = Some(v);
        }
        let out_of_time = session.time_limit.is_some_and(|limit| session_start.elapsed() >= limit);
        signal = session.stop.as_ref().map(|s| s.load(Ordering::Relaxed)).filter(|&s| s != 0);
        let done = state.step >= state.config.steps;
        if last_checkpoint.elapsed() >= session.checkpoint_every
            || out_of_time
            || signal.is_some()
            || done
        {
            checkpoint_dir = Some(checkpoint::save(run, &net, &optim, &state)?);
            let _ = log::draw_chart(&train_csv, &val_csv, &chart);
            last_checkpoint = Instant::now();
        }
        if out_of_time {
            bar.println(format!("time limit reached at step {}; resume with --resume", state.step));
        }
        if out_of_time || signal.is_some() {
            break;
        }
    }
    bar.finish();
    drop(prefetch);
    let mean = |xs: &[f32]| {
        if xs.is_empty() { f32::NAN } else { xs.iter().sum::<f32>() / xs.len() as f32 }
    };
    let k = totals.len().min(20);
    step_times.sort();
    Ok(Summary {
        first_step,
        steps: state.step,
        first_loss: mean(&totals[..k]),
        last_loss: mean(&totals[totals.len() - k..]),
        last_val,
        median_step: step_times.get(step_times.len() / 2).copied().unwrap_or_default(),
        checkpoint: checkpoint_dir,
        signal,
    })
}
