//! The `train` subcommand of `inssplat-train`: flags (in groups, or a TOML recipe) to a
//! [`TrainConfig`] and a [`Session`], and a summary at the end.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize};
use std::time::Duration;

use anyhow::{Context, Result};
use burn::prelude::*;
use inssplat_synth::{self as synth, Furniture, Split, Structure};
use inssplat_trainer::loss::{
    BoundaryTerm, CrossView, GaussianTraining, HardNegatives, LossConfig,
};
use inssplat_trainer::model::{Encoder, ModelConfig};
use inssplat_trainer::train::sample::{DataSpec, describe};
use inssplat_trainer::train::{self, Compute, RayPlan, Session, TrainConfig, checkpoint};

#[derive(clap::Args)]
pub struct TrainArgs {
    /// A training run as a TOML file: each key a flag of `train` without its dashes
    /// (`lr = 1.5e-4`, `semantic-objects-only = true`); flags on the command line win
    /// (trainer/recipes/ holds the shipped network's).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Run folder: checkpoints, logs and the loss chart go here.
    #[arg(long, env = "INSSPLAT_TRAIN_OUT")]
    out: PathBuf,
    /// Continue the newest checkpoint in --out with its own configuration and data.
    #[arg(long)]
    resume: bool,
    /// Start from the weights of this run's newest checkpoint (or this checkpoint folder, or an
    /// ONNX file this trainer exported, such as a shipped model), with a fresh optimizer and
    /// schedule; the network shape flags are then ignored, but for --image-skips, a larger
    /// --mlp-ratio or --sem-dim, --global-kv-pool and --camera-rays.
    #[arg(long, conflicts_with = "resume")]
    init_from: Option<PathBuf>,
    #[command(flatten)]
    input: DataArgs,
    #[command(flatten)]
    schedule: ScheduleArgs,
    #[command(flatten)]
    network: NetworkArgs,
    #[command(flatten)]
    loss: LossArgs,
    #[command(flatten)]
    run: RunArgs,
}

/// The scenes a run trains and validates on, and how each step draws its views.
#[derive(clap::Args)]
#[command(next_help_heading = "Data")]
struct DataArgs {
    /// Folder of training scenes (docs/DATASET.md format), instead of synthesizing them.
    #[arg(long, conflicts_with = "resume")]
    data: Option<PathBuf>,
    /// Folder of validation scenes (default: the val split, synthesized).
    #[arg(long)]
    val_data: Option<PathBuf>,
    /// Sweet Home 3D furniture folder for synthesized scenes.
    #[arg(long, env = "INSSPLAT_FURNITURE_DIR", default_value = synth::DEFAULT_FURNITURE_DIR)]
    furniture_dir: PathBuf,
    /// Synthesized walls, floor and ceiling as unlabelled background (default: instances
    /// labelled wall/floor/ceiling, so the network separates and names them).
    #[arg(long)]
    shell_background: bool,
    /// Synthesize with furniture from primitives only.
    #[arg(long)]
    primitives_only: bool,
    /// Rays per pixel side for the synthesized colour (`inssplat-train synth --antialias`):
    /// 2 renders edges as a camera or a downscaled photo has them.
    #[arg(long, default_value_t = 1, conflicts_with_all = ["data", "resume"], value_parser = clap::value_parser!(u32).range(1..=synth::MAX_ANTIALIAS as i64))]
    antialias: u32,
    #[arg(long, default_value_t = 2)]
    min_views: usize,
    #[arg(long, default_value_t = 8)]
    max_views: usize,
    /// Held-out views rendered and supervised per step.
    #[arg(long, default_value_t = 1)]
    targets: usize,
    /// Consecutive samples sharing one scene (with one sample per step: consecutive steps).
    #[arg(long, default_value_t = 2)]
    scene_reuse: u64,
    /// The scene of the first step (scene i is seed split base + i): a fine-tune can start on
    /// scenes the earlier runs never saw.
    #[arg(long, default_value_t = 0)]
    first_scene: u64,
    /// Draw each step's views from a random window of this many consecutive frames of the
    /// trajectory, so that they overlap (default: from the whole trajectory).
    #[arg(long, value_parser = clap::value_parser!(u16).range(2..))]
    view_window: Option<u16>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

/// How long and how fast the run learns.
#[derive(clap::Args)]
#[command(next_help_heading = "Schedule")]
struct ScheduleArgs {
    /// Optimizer steps of the whole run (with --resume: extends or shortens it).
    #[arg(long)]
    steps: Option<u64>,
    #[arg(long, default_value_t = 200)]
    warmup: u64,
    /// Peak learning rate.
    #[arg(long, default_value_t = 5e-4)]
    lr: f64,
    /// Samples per optimizer step, evaluated side by side on threads (one per core is what a
    /// CPU step leaves idle), their gradients averaged.
    #[arg(long, default_value_t = 1)]
    samples_per_step: usize,
}

/// The network's shape (for a new network; with --init-from, what may be grown onto it) and its camera input.
#[derive(clap::Args)]
#[command(next_help_heading = "Network")]
struct NetworkArgs {
    /// Square input resolution.
    #[arg(long, default_value_t = 128)]
    image_size: usize,
    #[arg(long, default_value_t = 8)]
    patch: usize,
    /// Token width.
    #[arg(long, default_value_t = 192)]
    dim: usize,
    /// Transformer layers (frame/global pairs, even).
    #[arg(long, default_value_t = 6)]
    depth: usize,
    #[arg(long, default_value_t = 3)]
    heads: usize,
    /// Hidden width of each block's MLP, as a multiple of the token width. With --init-from,
    /// a larger ratio than the source's widens its MLPs: every weight is kept and the new
    /// hidden units start with no effect on the output.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u16).range(1..))]
    mlp_ratio: u16,
    #[arg(long, default_value_t = 128)]
    decoder_dim: usize,
    /// Width of the compact semantic feature. With --init-from, a wider one than the source's
    /// adds channels that Φ_sem reads through zeros, so the network starts where it was.
    #[arg(long, default_value_t = 16)]
    sem_dim: usize,
    /// Add a convolutional image encoder whose features reach every decoder stage through
    /// skips, with this many channels at full resolution (doubled per halving). With
    /// --init-from, grows a network that has none: its weights are kept and the encoder starts
    /// with no effect on the output.
    #[arg(long)]
    image_skips: Option<usize>,
    /// The global layers read keys and values averaged over squares of this many patches a
    /// side (every token still queries; the global attention costs its square less; 1 reads
    /// every token, as leaving it out does for a new network). With --init-from, the source's
    /// weights are read through it (the pooling has no weights; 1 undoes a source's pooling);
    /// left out, the source's own pooling stays.
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
    global_kv_pool: Option<u16>,
    /// Give the network the true cameras as input: K × K Plücker rays a patch, added to its
    /// tokens (grown onto an --init-from network at zero). Its exported file has a `rays`
    /// input, which `inssplat-eval score --known-poses` fills from the true cameras.
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
    camera_rays: Option<u16>,
    /// Build the network around this pretrained image encoder: its features make the tokens
    /// (patch 8, sizes multiples of 32) and its fine maps reach the decoder.
    #[arg(long, value_enum)]
    encoder: Option<Encoder>,
    /// The encoder's pretrained weights (a new run with --encoder starts from them).
    #[arg(long, env = "INSSPLAT_ENCODER_WEIGHTS", value_name = "FILE")]
    encoder_weights: Option<PathBuf>,
    /// Keep the encoder's weights as they are (the first phase; fine-tune the whole network
    /// after it with --init-from and a lower --lr).
    #[arg(long)]
    freeze_encoder: bool,
    /// With --camera-rays: the share of samples whose rays are all zero, so that the network
    /// also runs before any camera is known.
    #[arg(long, default_value_t = 0.0)]
    ray_dropout: f32,
}

/// The loss terms' weights and forms, and the ablation switches.
#[derive(clap::Args)]
#[command(next_help_heading = "Losses")]
struct LossArgs {
    /// w_rgb, the weight of L_rgb in the total (the paper's 1).
    #[arg(long, default_value_t = 1.0)]
    rgb_weight: f64,
    /// w_geom, the weight of L_geom in the total (the paper's 1).
    #[arg(long, default_value_t = 1.0)]
    geometry_weight: f64,
    /// β of L_depth's pixel weights, in [0, 1]: 0 weighs every pixel alike, 1 every instance
    /// alike (a chair as much as the floor), between them a mixture.
    #[arg(long, default_value_t = 0.0, value_parser = unit_interval)]
    depth_instance_balance: f64,
    /// w_ins, the weight of L_ins in the total (the paper's 0.01).
    #[arg(long, default_value_t = 0.01)]
    instance_weight: f64,
    /// δ_pull of L_ins: the cosine distance to its instance's prototype within which a
    /// pixel's embedding is no longer pulled (0: pulled all the way, into the tightest groups).
    #[arg(long, default_value_t = LossConfig::new().pull_margin, value_parser = unit_interval)]
    pull_margin: f64,
    /// Weight of the camera term inside L_geom.
    #[arg(long, default_value_t = 1.0)]
    camera_weight: f64,
    /// w_sem, the weight of L_sem in the total (the paper's 0.02).
    #[arg(long, default_value_t = 0.02)]
    semantic_weight: f64,
    /// τ > 0: L_sem as the cross-entropy of cos/τ over the label vocabulary, balanced per
    /// instance, instead of the paper's per-pixel cosine (0).
    #[arg(long, default_value_t = 0.0)]
    semantic_temperature: f64,
    /// Weight of L_ins on the network's own per-pixel embeddings of the input views (what
    /// inference clusters), added inside L_ins to L_ins on the renders (the paper's: 0).
    #[arg(long, default_value_t = 0.0)]
    direct_instance_weight: f64,
    /// L_sem on the furniture alone: the room shell's pixels (wall, floor, ceiling) are left out
    /// of it, while L_ins still separates the shell's instances.
    #[arg(long)]
    semantic_objects_only: bool,
    /// Ablation: no semantic hard-negative weights in the push term.
    #[arg(long)]
    no_hard_negatives: bool,
    /// Ablation: no cross-view term in L_ins.
    #[arg(long)]
    no_cross_view: bool,
    /// Ablation: no boundary RGB loss.
    #[arg(long)]
    no_boundary: bool,
    /// Ablation: train only the instance and semantic heads.
    #[arg(long)]
    frozen_gaussians: bool,
}

/// Checkpoints, validation, time limit and device of the session.
#[derive(clap::Args)]
#[command(next_help_heading = "Run")]
struct RunArgs {
    /// Minutes between checkpoints.
    #[arg(long, default_value_t = 5.0)]
    checkpoint_minutes: f64,
    /// Checkpoints kept (default 2; with --resume, as many as the session that wrote the
    /// newest checkpoint kept).
    #[arg(long)]
    keep: Option<usize>,
    /// Validate every N steps (0 = never).
    #[arg(long, default_value_t = 250)]
    val_every: u64,
    #[arg(long, default_value_t = 4)]
    val_samples: usize,
    /// Stop with a checkpoint after this many minutes (resume later with --resume).
    #[arg(long)]
    time_limit: Option<f64>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Where the network trains: the CPU cores, or the GPU (a build with `--features gpu`; the
    /// rasterizer stays on the CPU cores). A run may change it between sessions.
    #[arg(long, value_enum, default_value_t = Compute::Cpu)]
    device: Compute,
}

/// `on`, or `off_value` when the ablation flag `off` is set.
fn pick<T>(off: bool, on: T, off_value: T) -> T {
    if off { off_value } else { on }
}

/// A number in [0, 1], for clap.
fn unit_interval(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if (0.0..=1.0).contains(&x) => Ok(x),
        Ok(x) => Err(format!("{x} is outside [0, 1]")),
        Err(e) => Err(format!("{s:?} is not a number: {e}")),
    }
}

fn minutes(m: f64, flag: &str) -> Result<Duration> {
    Duration::try_from_secs_f64(m * 60.0)
        .with_context(|| format!("{flag}: {m} is not a number of minutes"))
}

impl TrainArgs {
    fn config(&self) -> TrainConfig {
        let model = ModelConfig::new()
            .with_image_size(self.network.image_size)
            .with_patch(self.network.patch)
            .with_dim(self.network.dim)
            .with_depth(self.network.depth)
            .with_heads(self.network.heads)
            .with_mlp_ratio(usize::from(self.network.mlp_ratio))
            .with_decoder_dim(self.network.decoder_dim)
            .with_sem_dim(self.network.sem_dim)
            .with_image_skips(self.network.image_skips)
            // A new network pools or not; --init-from passes 1 on to undo a source's pooling.
            .with_global_kv_pool(
                self.network
                    .global_kv_pool
                    .map(usize::from)
                    .filter(|&p| p > 1 || self.init_from.is_some()),
            )
            .with_camera_rays(self.network.camera_rays.map(usize::from))
            .with_encoder(self.network.encoder);
        let loss = LossConfig::new()
            .with_rgb_weight(self.loss.rgb_weight)
            .with_geometry_weight(self.loss.geometry_weight)
            .with_depth_instance_balance(
                (self.loss.depth_instance_balance > 0.0)
                    .then_some(self.loss.depth_instance_balance),
            )
            .with_instance_weight(self.loss.instance_weight)
            .with_pull_margin(self.loss.pull_margin)
            .with_camera_weight(self.loss.camera_weight)
            .with_semantic_weight(self.loss.semantic_weight)
            .with_semantic_temperature(
                (self.loss.semantic_temperature > 0.0).then_some(self.loss.semantic_temperature),
            )
            .with_direct_instance_weight(
                (self.loss.direct_instance_weight > 0.0)
                    .then_some(self.loss.direct_instance_weight),
            )
            .with_semantic_objects_only(self.loss.semantic_objects_only.then_some(true))
            .with_hard_negatives(pick(
                self.loss.no_hard_negatives,
                HardNegatives::SemanticWeighted,
                HardNegatives::Uniform,
            ))
            .with_cross_view(pick(self.loss.no_cross_view, CrossView::On, CrossView::Off))
            .with_boundary(pick(self.loss.no_boundary, BoundaryTerm::On, BoundaryTerm::Off))
            .with_gaussians(pick(
                self.loss.frozen_gaussians,
                GaussianTraining::Trained,
                GaussianTraining::Frozen,
            ));
        TrainConfig::new(model, loss)
            .with_steps(self.schedule.steps.unwrap_or(20_000))
            .with_warmup(self.schedule.warmup)
            .with_lr(self.schedule.lr)
            .with_min_views(self.input.min_views)
            .with_max_views(self.input.max_views)
            .with_targets(self.input.targets)
            .with_scene_reuse(self.input.scene_reuse)
            .with_first_scene(self.input.first_scene)
            .with_view_window(self.input.view_window.map(usize::from))
            .with_seed(self.input.seed)
            .with_samples_per_step(
                (self.schedule.samples_per_step != 1).then_some(self.schedule.samples_per_step),
            )
            .with_rays(
                (self.network.ray_dropout > 0.0)
                    .then_some(RayPlan { dropout: self.network.ray_dropout }),
            )
            .with_encoder_weights(self.network.encoder.and(self.network.encoder_weights.clone()))
            .with_freeze_encoder(self.network.freeze_encoder.then_some(true))
    }

    fn furniture(&self) -> Result<Option<PathBuf>> {
        Ok(match crate::furniture(self.input.primitives_only, &self.input.furniture_dir)? {
            Furniture::Catalog(dir) => Some(dir),
            Furniture::Primitives => None,
        })
    }

    fn session(&self) -> Result<Session> {
        Ok(Session {
            checkpoint_every: minutes(self.run.checkpoint_minutes, "--checkpoint-minutes")?,
            keep: self.run.keep,
            val_every: self.run.val_every,
            val_samples: self.run.val_samples,
            val_data: self.input.val_data.clone().map(DataSpec::Folder),
            time_limit: self.run.time_limit.map(|m| minutes(m, "--time-limit")).transpose()?,
            stop: None,
            progress: !self.run.quiet,
            compute: self.run.device,
        })
    }
}

pub fn run_train(args: TrainArgs) -> Result<()> {
    if let Some(recipe) = &args.config {
        eprintln!("train: flags from {} (the command line's win)", recipe.display());
    }
    let session = Session { stop: Some(stop_on_signals()?), ..args.session()? };
    let summary = if args.resume {
        let dir = checkpoint::latest(&args.out)?
            .with_context(|| format!("--resume: {} has no checkpoint", args.out.display()))?;
        let state = checkpoint::read_state(&dir)?;
        eprintln!(
            "resuming {} at step {} of {} ({})",
            dir.display(),
            state.step,
            args.schedule.steps.unwrap_or(state.config.steps),
            describe(&state.data)
        );
        train::resume(&args.out, args.schedule.steps, &session)?
    } else {
        let data = match &args.input.data {
            Some(dir) => DataSpec::Folder(dir.clone()),
            None => DataSpec::Synth {
                split: Split::Train,
                furniture_dir: args.furniture()?,
                size: args.network.image_size as u32,
                structure: if args.input.shell_background {
                    Structure::Background
                } else {
                    Structure::Instances
                },
                antialias: args.input.antialias,
            },
        };
        let config = args.config();
        if let Some(from) = &args.init_from {
            eprintln!(
                "new run in {} from the weights of {}: {} steps, {}",
                args.out.display(),
                from.display(),
                config.steps,
                describe(&data)
            );
            train::fine_tune(&args.out, config, data, from, &session)
                .with_context(|| format!("--init-from {}", from.display()))?
        } else {
            let net = config.model.init(&Device::flex()).map_err(anyhow::Error::msg)?;
            eprintln!(
                "new run in {}: {:.2} M parameters, {} steps, {}",
                args.out.display(),
                burn::module::Module::num_params(&net) as f64 / 1e6,
                config.steps,
                describe(&data)
            );
            train::train(&args.out, config, data, &session)?
        }
    };
    println!(
        "steps {}..{}: loss {:.4} -> {:.4} (mean of first/last 20), median {:.2} s/step{}",
        summary.first_step,
        summary.steps,
        summary.first_loss,
        summary.last_loss,
        summary.median_step.as_secs_f64(),
        summary.last_val.map_or(String::new(), |v| format!(", val loss {:.4}", v.total))
    );
    if let Some(dir) = &summary.checkpoint {
        println!("checkpoint {}; chart {}", dir.display(), args.out.join("loss.png").display());
    }
    if let Some(number) = summary.signal {
        let at = summary
            .checkpoint
            .as_ref()
            .map_or(String::new(), |dir| format!(" in {}", dir.display()));
        eprintln!(
            "stopped by signal {number} after step {}, checkpoint written{at}; go on with --resume --out {}",
            summary.steps,
            args.out.display()
        );
        std::process::exit(128 + number as i32);
    }
    Ok(())
}

/// A flag that SIGINT and SIGTERM set to their number, so that training stops after the step
/// in progress with a checkpoint ([`Session::stop`]); a second such signal ends the process at
/// once, as the first would have without the handler.
fn stop_on_signals() -> Result<Arc<AtomicUsize>> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    use signal_hook::flag;
    let (stop, seen) = (Arc::new(AtomicUsize::new(0)), Arc::new(AtomicBool::new(false)));
    for number in [SIGINT, SIGTERM] {
        // Handlers run in the order they were registered: exit if one came before, else note it.
        flag::register_conditional_shutdown(number, 128 + number, Arc::clone(&seen))
            .context("installing the signal handlers")?;
        flag::register(number, Arc::clone(&seen)).context("installing the signal handlers")?;
        flag::register_usize(number, Arc::clone(&stop), number as usize)
            .context("installing the signal handlers")?;
    }
    Ok(stop)
}
