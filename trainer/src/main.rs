//! `inssplat-train`: the trainer's command line. Each job is a subcommand: `synth` writes
//! procedural scenes in the docs/DATASET.md format (with a progress bar, dataset statistics at
//! the end and optional contact-sheet previews); `train` starts or resumes a training run;
//! `export` writes a run's network as the ONNX file the server loads; `fit-shapes` adds the
//! shape classifier to one.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use inssplat_synth::{
    self as synth, DatasetStats, Furniture, Reserved, Split, Structure, SynthConfig,
};
use rayon::prelude::*;

#[derive(Parser)]
#[command(
    name = "inssplat-train",
    version,
    about = "Train, evaluate and export the inssplat network"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Synthesize procedural indoor scenes (RGB, depth, instance masks, labels, cameras).
    Synth(SynthArgs),
    /// Train the network (or continue a run with --resume).
    #[command(args_override_self = true)]
    Train(Box<cli_train::TrainArgs>),
    /// The validation loss of a run's newest checkpoint (or a checkpoint) on fixed val samples,
    /// for choosing between runs and checkpoints.
    Validate(cli_validate::ValidateArgs),
    /// Export a checkpoint's network to ONNX for the server.
    Export(cli_export::ExportArgs),
    /// Write an exported model with int8 weights in its linear layers (ONNX Runtime's dynamic
    /// quantization: a smaller file and a faster CPU forward), its metadata kept.
    Quantize(cli_export::QuantizeArgs),
    /// Write an exported model whose global layers read keys and values averaged over squares
    /// of patches (the same weights, a cheaper global attention), its metadata kept.
    PoolKeys(cli_export::PoolKeysArgs),
    /// Write the mean of several checkpoints' weights (weight averaging) into a copy of a
    /// model file, its metadata kept.
    Average(cli_export::AverageArgs),
    /// The per-scene baseline: optimize Gaussians and instance features on each test scene's
    /// context views (true cameras), then score instance mIoU on its target views.
    FitScene(cli_fit::FitArgs),
    /// Fit the shape classifier (objects' size, height above the floor and colour → label)
    /// on synthesized rooms and store it in a model file.
    FitShapes(cli_shapes::FitShapesArgs),
    /// Write the MiniLM embeddings of every synthesizable label to a file, for training
    /// without the text model (INSSPLAT_LABEL_TABLE=FILE).
    LabelTable {
        /// The JSON file to write.
        #[arg(long)]
        out: PathBuf,
    },
}

mod cli_export;
mod cli_fit;
mod cli_shapes;
mod cli_train;
mod cli_validate;

#[derive(Clone, Copy, ValueEnum)]
enum StructureArg {
    /// Walls, floor and ceiling are background (id 0).
    Background,
    /// Each wall, the floor and the ceiling are instances of their own.
    Instances,
}

#[derive(Clone, Copy, ValueEnum)]
enum ReservedArg {
    /// Never use the models reserved for evaluation.
    Exclude,
    /// Use them alongside the others (test split only).
    Include,
    /// Use only them among catalog models (test split only).
    Only,
}

#[derive(clap::Args)]
struct SynthArgs {
    /// Dataset split: train, val or test (disjoint seed ranges; test also marks context/target
    /// views).
    #[arg(long, env = "INSSPLAT_SYNTH_SPLIT")]
    split: Split,
    /// Number of scenes.
    #[arg(long, env = "INSSPLAT_SYNTH_COUNT")]
    count: u64,
    /// Output folder; scenes go to OUT/scene_NNNNNN.
    #[arg(long, env = "INSSPLAT_SYNTH_OUT")]
    out: PathBuf,
    /// Image width and height in pixels.
    #[arg(long, default_value_t = 128, env = "INSSPLAT_SYNTH_SIZE")]
    size: u32,
    /// Image width, overriding --size.
    #[arg(long)]
    width: Option<u32>,
    /// Image height, overriding --size.
    #[arg(long)]
    height: Option<u32>,
    /// Index of the first scene within the split (scene i has seed split_base + offset + i).
    #[arg(long, default_value_t = 0, env = "INSSPLAT_SYNTH_SEED_OFFSET")]
    seed_offset: u64,
    /// Frames per scene, `N` or `MIN-MAX` (default 12-24, test 24).
    #[arg(long, value_parser = parse_range::<usize>)]
    frames: Option<(usize, usize)>,
    /// Objects per scene, `N` or `MIN-MAX`.
    #[arg(long, value_parser = parse_range::<usize>, default_value = "6-14")]
    objects: (usize, usize),
    /// Probability (0-1) that an extra object repeats one already placed.
    #[arg(long, default_value_t = 0.3)]
    repeat: f32,
    /// Contrast multiplier of procedural textures (0 = flat colours, 1 = normal).
    #[arg(long, default_value_t = 1.0)]
    texture_contrast: f32,
    /// Maximum sensor noise per frame, standard deviation as a fraction of full scale.
    #[arg(long, default_value_t = 0.01)]
    noise: f32,
    /// Maximum Gaussian blur per frame, sigma in pixels.
    #[arg(long, default_value_t = 0.0)]
    blur: f32,
    /// Maximum exposure jitter per frame, in stops (±).
    #[arg(long, default_value_t = 0.3)]
    exposure: f32,
    /// View overlap, `X` or `MIN-MAX` in 0-1 (1 = the camera barely moves).
    #[arg(long, value_parser = parse_range::<f32>, default_value = "0.2-0.8")]
    overlap: (f32, f32),
    /// Vertical field of view in degrees, `X` or `MIN-MAX`.
    #[arg(long, value_parser = parse_range::<f32>, default_value = "50-80")]
    fov: (f32, f32),
    /// Walls/floor/ceiling as background or as instances.
    #[arg(long, value_enum, default_value = "background")]
    structure: StructureArg,
    /// Sweet Home 3D furniture folder (*.sh3f).
    #[arg(long, env = "INSSPLAT_FURNITURE_DIR", default_value = synth::DEFAULT_FURNITURE_DIR)]
    furniture_dir: PathBuf,
    /// Use furniture built from primitives only (no furniture folder needed).
    #[arg(long)]
    primitives_only: bool,
    /// Models reserved for evaluation (default: exclude, include for test).
    #[arg(long, value_enum)]
    reserved: Option<ReservedArg>,
    /// Probability (0-1) of a catalog mesh where a primitive could stand in.
    #[arg(long, default_value_t = 0.6)]
    mesh_share: f32,
    /// Mark context/target views in every scene, as the test split always does (for choosing
    /// between models with `inssplat-eval score` on val scenes).
    #[arg(long)]
    eval_views: bool,
    /// Rays per pixel side for the colour: 1 casts one ray through each pixel's centre (sharp,
    /// aliased edges, as the released evaluation sets are); 2 averages 2×2 (edges as a camera
    /// or a downscaled photo has them). Depth and masks stay the centre ray's.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=synth::MAX_ANTIALIAS as i64))]
    antialias: u32,
    /// Write contact sheets (RGB, depth, instances) of the first N scenes to OUT/preview/.
    #[arg(long, num_args = 0..=1, default_missing_value = "1", default_value_t = 0)]
    preview: u64,
}

/// `N` or `MIN-MAX`.
fn parse_range<T: std::str::FromStr + PartialOrd + Copy>(s: &str) -> Result<(T, T), String> {
    let parse = |x: &str| x.trim().parse::<T>().map_err(|_| format!("`{x}` is not a number"));
    let (a, b) = match s.split_once('-') {
        Some((a, b)) => (parse(a)?, parse(b)?),
        None => (parse(s)?, parse(s)?),
    };
    if a > b {
        return Err(format!("`{s}`: minimum above maximum"));
    }
    Ok((a, b))
}

/// Keeps freed memory in the process instead of handing it back to the kernel. A training
/// step frees and allocates the same tensors of several megabytes each time; glibc serves
/// those with fresh mappings (above its mmap threshold) or trims them off the heap, so every
/// step faulted its pages in again and the kernel zeroed them. The largest buffers (the
/// global attention's, over 32 MiB) stay mapped: glibc allows no higher threshold.
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters; it is called before any thread starts.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}

fn main() -> Result<()> {
    keep_freed_memory();
    let args = inssplat_trainer::recipe::expand(std::env::args_os().collect())?;
    match Cli::parse_from(args).command {
        Command::Synth(args) => run_synth(args),
        Command::Train(args) => cli_train::run_train(*args),
        Command::Validate(args) => cli_validate::run_validate(args),
        Command::Export(args) => cli_export::run_export(args),
        Command::Quantize(args) => cli_export::run_quantize(args),
        Command::PoolKeys(args) => cli_export::run_pool_keys(args),
        Command::Average(args) => cli_export::run_average(args),
        Command::FitScene(args) => cli_fit::run_fit(args),
        Command::FitShapes(args) => cli_shapes::run_fit_shapes(args),
        Command::LabelTable { out } => {
            let n = inssplat_trainer::train::labels::write_label_table(&out)?;
            println!("wrote {} ({n} labels)", out.display());
            Ok(())
        }
    }
}

/// Where synthesized furniture comes from, per `--primitives-only` and `--furniture-dir`
/// (shared by every subcommand that synthesizes); a missing folder is an error naming the flag.
fn furniture(primitives_only: bool, dir: &Path) -> Result<Furniture> {
    if primitives_only {
        return Ok(Furniture::Primitives);
    }
    if !dir.is_dir() {
        bail!(
            "--furniture-dir / INSSPLAT_FURNITURE_DIR: {} is not a folder (install the Debian package \
             sweethome3d-furniture, or pass --primitives-only)",
            dir.display()
        );
    }
    Ok(Furniture::Catalog(dir.to_path_buf()))
}

fn config(a: &SynthArgs) -> Result<SynthConfig> {
    let mut cfg = SynthConfig::new(a.split, furniture(a.primitives_only, &a.furniture_dir)?);
    cfg.width = a.width.unwrap_or(a.size);
    cfg.height = a.height.unwrap_or(a.size);
    if let Some(f) = a.frames {
        cfg.frames = f;
    }
    cfg.objects = a.objects;
    cfg.eval_views |= a.eval_views;
    cfg.repeat = a.repeat;
    cfg.texture_contrast = a.texture_contrast;
    cfg.noise = a.noise;
    cfg.blur = a.blur;
    cfg.exposure = a.exposure;
    cfg.overlap = a.overlap;
    cfg.fov_y_deg = a.fov;
    cfg.structure = match a.structure {
        StructureArg::Background => Structure::Background,
        StructureArg::Instances => Structure::Instances,
    };
    if let Some(r) = a.reserved {
        cfg.reserved = match r {
            ReservedArg::Exclude => Reserved::Exclude,
            ReservedArg::Include => Reserved::Include,
            ReservedArg::Only => Reserved::Only,
        };
    }
    cfg.mesh_share = a.mesh_share;
    cfg.antialias = a.antialias;
    cfg.validate().context("check the synth flags")?;
    Ok(cfg)
}

fn run_synth(a: SynthArgs) -> Result<()> {
    let cfg = config(&a)?;
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("--out: cannot create {}", a.out.display()))?;
    let preview_dir = a.out.join("preview");
    if a.preview > 0 {
        std::fs::create_dir_all(&preview_dir)
            .with_context(|| format!("cannot create {}", preview_dir.display()))?;
    }
    let bar = ProgressBar::new(a.count);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} {wide_bar} {pos}/{len} scenes  {per_sec}  eta {eta}",
        )
        .expect("progress template"),
    );
    let start = Instant::now();
    let results: Vec<(DatasetStats, Vec<synth::Credit>)> = (0..a.count)
        .into_par_iter()
        .map(|i| {
            let index = a.seed_offset + i;
            let s = synth::generate_split(index, &cfg)
                .with_context(|| format!("{} scene {index}", cfg.split))?;
            let dir = a.out.join(format!("scene_{index:06}"));
            s.write(&dir).with_context(|| format!("writing {}", dir.display()))?;
            if i < a.preview {
                write_preview(&s.scene, &preview_dir.join(format!("scene_{index:06}.png")))?;
            }
            let mut st = DatasetStats::default();
            st.add(&s.scene);
            bar.inc(1);
            Ok((st, s.credits))
        })
        .collect::<Result<_>>()?;
    bar.finish();
    let secs = start.elapsed().as_secs_f64();
    let mut stats = DatasetStats::default();
    let mut credits = std::collections::BTreeSet::new();
    for (s, c) in results {
        stats.merge(s);
        credits.extend(c);
    }
    let credits: Vec<_> = credits.into_iter().collect();
    let path = a.out.join("credits.json");
    std::fs::write(&path, serde_json::to_string_pretty(&credits)?)
        .with_context(|| format!("writing {}", path.display()))?;
    println!(
        "{} split, {} scenes in {secs:.1} s: {:.2} scenes/s on {} threads",
        cfg.split,
        a.count,
        a.count as f64 / secs.max(1e-9),
        rayon::current_num_threads()
    );
    println!("{} catalog models credited in {}", credits.len(), path.display());
    print!("{stats}");
    Ok(())
}

fn write_preview(scene: &inssplat_proto::dataset::Scene, path: &Path) -> Result<()> {
    synth::preview::contact_sheet(scene)
        .save(path)
        .with_context(|| format!("writing preview {}", path.display()))
}
