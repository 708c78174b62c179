//! The `inssplat-eval` command line: the research bench over the library's evaluation
//! protocol (`score`) and per-stage benchmark (`bench`). The user's binary, `inssplat`, has
//! none of these switches.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Parser, Subcommand};
use inssplat_eval::{ClusterMode, EvalRequest, EvalSwitches, PerturbKind, bench};
use inssplat_geometry::heading::HeadingParams;
use inssplat_geometry::register::RegisterParams;
use inssplat_geometry::voxel::{OpacityMerge, VoxelParams};
use inssplat_pipeline::backend::{Model, threads_or_all};
use inssplat_pipeline::output::write_atomic;
use inssplat_pipeline::reconstruct::{DEFAULT_SHAPE_WEIGHT, PipelineConfig, VoteScope};
use inssplat_pipeline::switches::{DetectorSwitches, MatcherSwitches, PipelineSwitches};
use inssplat_pipeline::vocab::{label_cache, vocabulary};
use inssplat_raster::render::GpuRenderer;
use inssplat_understand::cluster::ClusterParams;
use inssplat_understand::cluster::split::SplitParams;
use inssplat_understand::superpixel::SuperpixelParams;

/// inssplat-eval: score inssplat on dataset scenes and time its stages.
#[derive(Parser)]
#[command(version)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Score the model on test-split scenes (docs/EVALUATION.md): a markdown table, JSON.
    Score(Box<ScoreArgs>),
    /// Time the pipeline per stage at several view counts on one scene.
    Bench(BenchArgs),
    /// Score what `inssplat reconstruct` made of a rectified stereo pair against its true
    /// disparity: the first view's depth (AbsRel at the median scale; depth ∝ 1 / (disparity
    /// + doffs)) and the registered baseline's direction.
    Stereo(StereoArgs),
    /// Compare training runs at equal compute: checkpoints' `score` reports placed at the
    /// CPU hours their runs had spent, drawn against them (OUT/curve.png, curve.svg, curve.md).
    Curve(CurveArgs),
}

/// The points of a compute curve.
#[derive(Args)]
struct CurveArgs {
    /// One checkpoint: its run's name, the CPU hours the run had spent, and the checkpoint's
    /// `score` report (eval.json), as RUN:HOURS:FILE. Repeat for every checkpoint.
    #[arg(long = "point", required = true, value_name = "RUN:HOURS:FILE")]
    points: Vec<String>,
    /// The view count whose scores are drawn.
    #[arg(long, default_value_t = 8)]
    views: usize,
    /// Folder to write the chart and the table into.
    #[arg(long)]
    out: PathBuf,
}

fn run_curve(args: CurveArgs) -> anyhow::Result<()> {
    use inssplat_eval::curve;
    let points = args
        .points
        .iter()
        .map(|spec| {
            let (run, hours, file) = curve::parse_point(spec)?;
            curve::read_point(&run, hours, &file, args.views)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    curve::write(&points, &args.out)?;
    print!("{}", curve::markdown(&points));
    println!("chart: {} and curve.svg", args.out.join("curve.png").display());
    Ok(())
}

/// A reconstructed stereo pair and its truth.
#[derive(Args)]
struct StereoArgs {
    /// Output folder of `inssplat reconstruct` on the pair, the left photo first.
    out: PathBuf,
    /// The left photo's true disparity: a .npz whose first array is float32 `[H][W]`, unknown
    /// where not finite or not positive.
    #[arg(long)]
    disparity: PathBuf,
    /// Disparity between the two principal points (Middlebury's `doffs`), photo pixels.
    #[arg(long, default_value_t = 0.0)]
    doffs: f64,
    /// Print the JSON report instead of the text.
    #[arg(long)]
    json: bool,
}

fn run_stereo(args: StereoArgs) -> anyhow::Result<()> {
    let s = inssplat_eval::stereo::score(&args.out, &args.disparity, args.doffs)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&s)?);
    } else {
        println!("{}", inssplat_eval::stereo::describe(&s));
    }
    Ok(())
}

/// The network and the threads it runs on.
#[derive(Args)]
struct ModelArgs {
    /// The network (ONNX file exported by inssplat-train).
    #[arg(long, env = "INSSPLAT_MODEL", default_value = "models/inssplat-default.onnx")]
    model: PathBuf,
    /// Threads for ONNX Runtime (default: all cores).
    #[arg(long, env = "INSSPLAT_THREADS")]
    threads: Option<usize>,
}

#[derive(Args)]
struct ScoreArgs {
    /// A folder of test scenes (or one scene folder) with `eval` context/target sets.
    #[arg(long)]
    data: PathBuf,
    /// View counts to evaluate, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "2,4,8,16")]
    views: Vec<usize>,
    /// Evaluate at most this many scenes (the first ones, sorted by name).
    #[arg(long)]
    max_scenes: Option<usize>,
    /// Output folder for eval.json and eval.md (default: print the table only).
    #[arg(short, long)]
    out: Option<PathBuf>,
    #[command(flatten)]
    model: ModelArgs,
    /// Labels added to the scenes' own label vocabulary (file or comma-separated list).
    #[arg(long)]
    vocab: Option<String>,
    #[command(flatten)]
    post: PostArgs,
    #[command(flatten)]
    switches: PipelineSwitches,
    #[command(flatten)]
    oracles: OracleArgs,
    #[command(flatten)]
    ablations: AblationArgs,
    #[command(flatten)]
    protocol: ProtocolArgs,
    /// Print the JSON report on stdout instead of the table (progress still goes to
    /// stderr: a bar on a terminal, else a line per scene and view count).
    #[arg(long, env = "INSSPLAT_JSON")]
    json: bool,
}

/// The post-processing knobs: clustering, superpixels, split, heading, naming.
#[derive(Args)]
struct PostArgs {
    /// Where instances are clustered: once on the Gaussians, or per view (the paper's mode).
    #[arg(long, value_enum, default_value = "3d")]
    cluster: ClusterMode,
    /// Weight of the Gaussians' positions beside their instance embeddings when clustering
    /// in 3D; 0 clusters the embeddings alone (the paper).
    #[arg(long, default_value_t = ClusterParams::default().position_weight)]
    position_weight: f32,
    /// HDBSCAN's smallest cluster, as a share of the points it sees.
    #[arg(long, default_value_t = ClusterParams::default().min_cluster_share)]
    min_cluster_share: f32,
    /// HDBSCAN's neighbours per core distance.
    #[arg(long, default_value_t = ClusterParams::default().min_samples)]
    min_samples: usize,
    /// A Gaussian joins its nearest instance prototype only at this cosine or more.
    #[arg(long, default_value_t = ClusterParams::default().min_cosine)]
    min_cosine: f32,
    /// Weight of the shape classifier (size, height above the floor, colour) beside the
    /// semantic features when naming instances; 0 names by the features alone (the paper).
    #[arg(long, default_value_t = DEFAULT_SHAPE_WEIGHT)]
    shape_weight: f32,
    /// Split each clustered instance into its parts apart in 3D: Gaussians in touching
    /// cells of a grid of this edge (in voxel edges) are connected; 0 keeps the
    /// clustering's instances.
    #[arg(long, default_value_t = SplitParams::default().cell_voxels)]
    split_cell: f32,
    /// Scale of the colour superpixels the instance embeddings are snapped to and the
    /// input views' masks voted over (larger: larger superpixels); 0 leaves the network's
    /// maps and each pixel's own id as they are.
    #[arg(long, default_value_t = SuperpixelParams::default().scale)]
    superpixel_scale: f32,
    /// What the input views' superpixel vote corrects: their masks alone, or the merged
    /// Gaussians too (each takes the voted id of most of its pixels), which the target
    /// views are rendered from.
    #[arg(long, value_enum, default_value_t = PipelineConfig::default().vote)]
    vote: VoteScope,
    /// Headings tried, over the full turn, for each group of views that registration
    /// could not link to the first photo; 0 keeps the continued poses.
    #[arg(long, default_value_t = HeadingParams::default().candidates)]
    heading_candidates: usize,
    /// Long side in pixels of the copy of each photo that registration finds its keypoints
    /// in, when the photo is larger than the network's input; at most the input's size
    /// finds them in the input itself.
    #[arg(long, default_value_t = RegisterParams::default().photo_size, value_name = "PIXELS")]
    register_photo_size: u32,
}

/// Stages swapped for the truth: what the rest achieves with one stage out of the question.
#[derive(Args)]
struct OracleArgs {
    /// Place the network's outputs with the scenes' true context cameras instead of the
    /// predicted ones (scores everything but the camera head).
    #[arg(long)]
    known_poses: bool,
    /// Place the network's outputs at the scenes' true context depth instead of the depth
    /// head's (scores everything but the depth head; combine with --known-poses).
    #[arg(long)]
    known_depth: bool,
    /// Name every found instance with the true label most of its context pixels carry
    /// instead of the classifier's (3D clustering only).
    #[arg(long)]
    known_names: bool,
}

/// Ablations: each leaves one rule of the pipeline out.
#[derive(Args)]
struct AblationArgs {
    /// How voxelization merges the opacities of a voxel's Gaussians: their optical depth
    /// over the merged footprint (coverage), or their mean (the ablation).
    #[arg(long, value_enum, default_value_t = MergeOpacity::Coverage)]
    merge_opacity: MergeOpacity,
    /// Use the camera head's poses as they are, without the registration stage.
    #[arg(long)]
    no_register: bool,
    /// Keep the camera head's field of view in registration instead of measuring one focal
    /// length for all views from the matches.
    #[arg(long)]
    keep_focal: bool,
    /// Name every pixel from its own rendered semantic feature instead of its instance's
    /// prototype (the ablation of instance-grounded aggregation).
    #[arg(long)]
    no_aggregation: bool,
    /// Score the target views' raw renders, with what no Gaussian covers left black and
    /// without an instance, instead of filled from around it as `render` fills a new view.
    #[arg(long)]
    no_fill: bool,
}

/// What is measured beyond the protocol's table.
#[derive(Args)]
struct ProtocolArgs {
    /// Reconstruct from the context photos of this folder's scenes of the same names (the
    /// same scenes synthesized at another size, `inssplat-train synth --size 512`), as a
    /// camera gives them; every ground truth stays --data's, at the model resolution.
    #[arg(long, value_name = "DIR", conflicts_with = "perturb")]
    photos: Option<PathBuf>,
    /// Refine each target camera's pose against its photo for this many Adam steps before
    /// scoring it, the Gaussians frozen (0, the default, scores at the mapped camera).
    #[arg(long, default_value_t = 0, value_name = "STEPS")]
    target_pose_steps: usize,
    /// Also score the text queries under a grid of query rules (minimum score, margin to
    /// the best, margin to the instance's own label) and add the best to the report.
    #[arg(long)]
    query_rules: bool,
    /// Robustness sweeps at 8 views (noise, blur, exposure, overlap, repeats), a table of
    /// each metric against the strength, and the worst scenes' previews under --out.
    #[arg(long, value_enum, value_delimiter = ',')]
    perturb: Vec<PerturbKind>,
    /// Run every speed/accuracy knob (views × voxel size × clustering subsample) through the
    /// evaluation and draw OUT/sweep.png and sweep.svg (needs --out).
    #[arg(long, requires = "out")]
    sweep: bool,
    /// Write every found instance's shape descriptor and unfused semantic prototype with
    /// its majority true label here (JSON), for `inssplat-train fit-shapes --examples`
    /// (use train-split scenes).
    #[arg(long)]
    shape_examples: Option<PathBuf>,
}

#[derive(Args)]
struct BenchArgs {
    /// A dataset scene folder (or a folder of them: the first is used) with ≥ 16 frames.
    #[arg(long)]
    data: PathBuf,
    #[arg(long, value_delimiter = ',', default_value = "2,4,8,16")]
    views: Vec<usize>,
    /// Timed runs per view count (after one warm-up); medians are reported.
    #[arg(long, default_value_t = 5)]
    runs: usize,
    #[command(flatten)]
    model: ModelArgs,
    /// A second model to time against --model: the two run in turns, and the table gives
    /// each one's medians and the ratios (this one over --model) instead of the stages.
    #[arg(long)]
    against: Option<PathBuf>,
    /// Time the pipeline with this many steps of test-time refinement (stage `refine`, as
    /// `inssplat reconstruct --refine-steps`; 0, the default, times the feed-forward pipeline).
    #[arg(long, default_value_t = 0, value_name = "STEPS", conflicts_with = "against")]
    refine_steps: usize,
    /// Long side in pixels of the copy of each photo that registration finds its keypoints
    /// in, when the scene's photos are larger than the network's input.
    #[arg(long, default_value_t = RegisterParams::default().photo_size, value_name = "PIXELS", conflicts_with = "against")]
    register_photo_size: u32,
    #[command(flatten)]
    matcher: MatcherSwitches,
    #[command(flatten)]
    detector: DetectorSwitches,
    /// Print JSON instead of the table.
    #[arg(long, env = "INSSPLAT_JSON")]
    json: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum MergeOpacity {
    Coverage,
    Mean,
}

impl From<MergeOpacity> for OpacityMerge {
    fn from(m: MergeOpacity) -> Self {
        match m {
            MergeOpacity::Coverage => OpacityMerge::Coverage,
            MergeOpacity::Mean => OpacityMerge::Mean,
        }
    }
}

fn check_views(views: &[usize]) -> anyhow::Result<()> {
    match views.iter().find(|v| !(2..=16).contains(*v)) {
        Some(v) => anyhow::bail!("--views: {v} is outside 2-16"),
        None => Ok(()),
    }
}

impl PostArgs {
    /// The pipeline these knobs and the ablations ask for.
    fn pipeline(&self, ablations: &AblationArgs) -> anyhow::Result<PipelineConfig> {
        if !(self.superpixel_scale.is_finite() && self.superpixel_scale >= 0.0) {
            anyhow::bail!(
                "--superpixel-scale: {} must be a finite number ≥ 0 (0 turns the superpixels off)",
                self.superpixel_scale
            );
        }
        let cluster = ClusterParams {
            position_weight: self.position_weight,
            min_cluster_share: self.min_cluster_share,
            min_samples: self.min_samples,
            min_cosine: self.min_cosine,
            ..ClusterParams::default()
        };
        cluster.validate()?;
        Ok(PipelineConfig {
            register: (!ablations.no_register).then(|| RegisterParams {
                estimate_focal: !ablations.keep_focal,
                photo_size: self.register_photo_size,
                ..RegisterParams::default()
            }),
            cluster,
            split: (self.split_cell > 0.0)
                .then(|| SplitParams { cell_voxels: self.split_cell, ..SplitParams::default() }),
            shape_weight: self.shape_weight,
            voxel: VoxelParams {
                opacity: ablations.merge_opacity.into(),
                ..VoxelParams::default()
            },
            superpixels: (self.superpixel_scale > 0.0).then(|| SuperpixelParams {
                scale: self.superpixel_scale,
                ..SuperpixelParams::default()
            }),
            heading: (self.heading_candidates > 0).then(|| HeadingParams {
                candidates: self.heading_candidates,
                ..HeadingParams::default()
            }),
            vote: self.vote,
            ..PipelineConfig::default()
        })
    }
}

fn score(args: ScoreArgs) -> anyhow::Result<()> {
    let ScoreArgs {
        data,
        views,
        max_scenes,
        out,
        model,
        vocab,
        post,
        switches,
        oracles,
        ablations,
        protocol,
        json,
    } = args;
    check_views(&views)?;
    if oracles.known_names && post.cluster == ClusterMode::TwoD {
        anyhow::bail!(
            "--known-names names the instances of the 3D clustering; --cluster 2d names each view's own groups"
        );
    }
    if oracles.known_names && ablations.no_aggregation {
        anyhow::bail!(
            "--known-names names the instances; --no-aggregation names each pixel by its own features instead"
        );
    }
    let pipeline =
        switches.apply(post.pipeline(&ablations)?, &model.model, threads_or_all(model.threads))?;
    let mut dirs = inssplat_eval::scene_dirs(&data)?;
    dirs.truncate(max_scenes.unwrap_or(usize::MAX));
    let extra = match vocab.as_deref() {
        Some(v) => vocabulary(Some(v))?,
        None => Vec::new(),
    };
    let mut network = Model::load(&model.model, threads_or_all(model.threads))?;
    let labels = label_cache()?;
    let request = EvalRequest {
        views,
        extra_vocab: extra,
        pipeline,
        cluster: post.cluster,
        switches: EvalSwitches {
            known_poses: oracles.known_poses,
            known_depth: oracles.known_depth,
            known_names: oracles.known_names,
            no_aggregation: ablations.no_aggregation,
            no_fill: ablations.no_fill,
            target_pose_steps: protocol.target_pose_steps,
        },
        query_rules: protocol.query_rules,
        photos: protocol.photos,
        perturb: protocol.perturb,
        out: out.clone(),
        progress: true,
    };
    if protocol.sweep {
        let out = out.as_deref().expect("clap requires --out with --sweep");
        let points = inssplat_eval::run_sweep(&mut network, &labels, &dirs, &request, out)?;
        write_atomic(&out.join("sweep.json"), serde_json::to_string_pretty(&points)?.as_bytes())?;
        let table = inssplat_eval::sweep_markdown(&points);
        write_atomic(&out.join("sweep.md"), table.as_bytes())?;
        print!("{table}");
        println!("chart: {} and sweep.svg", out.join("sweep.png").display());
        return Ok(());
    }
    let report = inssplat_eval::evaluate(&mut network, &labels, &dirs, &request)?;
    let table = inssplat_eval::markdown(&report);
    if let Some(path) = &protocol.shape_examples {
        write_atomic(path, serde_json::to_string(&report.shape_examples)?.as_bytes())
            .with_context(|| format!("--shape-examples {}", path.display()))?;
        eprintln!("{} shape examples written to {}", report.shape_examples.len(), path.display());
    }
    if let Some(out) = &out {
        std::fs::create_dir_all(out)
            .with_context(|| format!("--out: cannot create {}", out.display()))?;
        write_atomic(&out.join("eval.json"), serde_json::to_string_pretty(&report)?.as_bytes())?;
        write_atomic(&out.join("eval.md"), table.as_bytes())?;
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{table}");
    }
    Ok(())
}

fn run_bench(args: BenchArgs) -> anyhow::Result<()> {
    let BenchArgs {
        data,
        views,
        runs,
        model,
        against,
        refine_steps,
        register_photo_size,
        matcher,
        detector,
        json,
    } = args;
    check_views(&views)?;
    let dir = inssplat_eval::scene_dirs(&data)?.remove(0);
    let scene = inssplat_proto::dataset::Scene::load(&dir)
        .with_context(|| format!("loading {}", dir.display()))?;
    let threads = threads_or_all(model.threads);
    let mut network = Model::load(&model.model, threads)?;
    let labels = label_cache()?;
    let vocabulary = vocabulary(None)?;
    let matcher = matcher.load(&model.model, threads)?;
    let detector = detector.load(&model.model, threads)?;
    if let Some(other) = against {
        let mut other = Model::load(&other, threads)?;
        let config = PipelineConfig { matcher, detector, ..PipelineConfig::default() };
        let models = [&mut network, &mut other];
        let rows = bench::compare(models, &labels, &scene, &views, runs, &vocabulary, &config)?;
        if json {
            println!("{}", serde_json::to_string_pretty(&rows)?);
        } else {
            let name = |m: &Model| format!("{} (`{}`)", m.network.model_version, m.path.display());
            print!("{}", bench::compare_markdown(&rows, [&name(&network), &name(&other)], threads));
        }
        return Ok(());
    }
    let gpu = GpuRenderer::new().ok();
    let config = PipelineConfig {
        refine_steps,
        register: Some(RegisterParams {
            photo_size: register_photo_size,
            ..RegisterParams::default()
        }),
        matcher,
        detector,
        ..PipelineConfig::default()
    };
    let plan = bench::BenchPlan { views: &views, runs, vocabulary: &vocabulary, config: &config };
    let rows = bench::bench(&mut network, &labels, &scene, &plan, gpu.as_ref())?;
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        let adapter = gpu.as_ref().map(|g| {
            format!("{}{}", g.adapter(), if g.is_software() { " (software)" } else { "" })
        });
        print!("{}", bench::markdown(&rows, threads, adapter.as_deref()));
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Score(args) => score(*args),
        Command::Bench(args) => run_bench(args),
        Command::Stereo(args) => run_stereo(args),
        Command::Curve(args) => run_curve(args),
    }
}
