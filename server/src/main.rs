//! The `inssplat` command line: a thin shell over the library's modules.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Parser, Subcommand};
use inssplat_raster::cluster::ClusterParams;
use inssplat_raster::cluster::split::SplitParams;
use inssplat_raster::heading::HeadingParams;
use inssplat_raster::superpixel::SuperpixelParams;
use inssplat_raster::register::RegisterParams;
use inssplat_raster::voxel::{OpacityMerge, VoxelParams};
use inssplat_server::pipeline::reconstruct::{DEFAULT_SHAPE_WEIGHT, PipelineConfig, VoteScope, reconstruct_with};
use inssplat_server::pipeline::switches::PipelineSwitches;
use inssplat_raster::render::{Backend, GpuRenderer};
use inssplat_server::runtime::Model;
use inssplat_server::{bench, check, eval, inputs, output, query, render_view, saved, vocab};
use inssplat_text::{LabelCache, TextEmbedder};

/// inssplat: instance-aware 3D Gaussians from a few unposed photos.
#[derive(Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Validate dataset scene folders (transforms.json + images, depth, instance masks).
    Check {
        /// Scene folders to check.
        #[arg(required = true)]
        scenes: Vec<PathBuf>,
        /// Print one JSON object per scene instead of text.
        #[arg(long, env = "INSSPLAT_JSON")]
        json: bool,
    },
    /// Reconstruct a scene from 2–16 photos: Gaussians, cameras, instance and label masks.
    Reconstruct {
        /// A folder of photos, a dataset scene folder, or photo files.
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Output folder.
        #[arg(short, long)]
        out: PathBuf,
        /// The network (ONNX file exported by inssplat-train).
        #[arg(long, env = "INSSPLAT_MODEL", default_value = "models/inssplat-default.onnx")]
        model: PathBuf,
        /// Label vocabulary: a file with one label per line, or a comma-separated list.
        #[arg(long, env = "INSSPLAT_VOCAB")]
        vocab: Option<String>,
        /// Weight of the model's shape classifier (size, height above the floor, colour)
        /// beside the semantic features when naming instances; 0 names by the features alone.
        #[arg(long, default_value_t = DEFAULT_SHAPE_WEIGHT)]
        shape_weight: f32,
        #[command(flatten)]
        switches: PipelineSwitches,
        /// Print the result as JSON on stdout.
        #[arg(long, env = "INSSPLAT_JSON")]
        json: bool,
        /// Threads for ONNX Runtime (default: all cores).
        #[arg(long, env = "INSSPLAT_THREADS")]
        threads: Option<usize>,
    },
    /// Ask a reconstruction where something is: matching instances and their masks per view.
    Query {
        /// A folder written by `inssplat reconstruct`.
        out: PathBuf,
        /// What to look for, e.g. "the lamp".
        text: String,
        /// Print the answer as JSON.
        #[arg(long, env = "INSSPLAT_JSON")]
        json: bool,
    },
    /// Render a reconstruction from new cameras: RGB, instance and label images.
    Render {
        /// A folder written by `inssplat reconstruct`.
        out: PathBuf,
        /// `interp:i,j,t` (a pose between input views i and j) or a transforms.json of cameras.
        #[arg(long)]
        camera: String,
        /// Where the images go (default OUT/render).
        #[arg(short = 'o', long = "to")]
        to: Option<PathBuf>,
        /// Where to render the instance masks: a hardware GPU if one is found (auto), the CPU,
        /// or the GPU (any adapter, software included; an error if there is none).
        #[arg(long, value_enum, default_value = "auto", env = "INSSPLAT_RENDER")]
        render: RenderChoice,
        /// Keep the raw renders: what no Gaussian covers black and without an instance,
        /// instead of filled from the colours, ids and labels around it.
        #[arg(long)]
        no_fill: bool,
    },
    /// Time the pipeline per stage at several view counts on one scene.
    Bench {
        /// A dataset scene folder (or a folder of them: the first is used) with ≥ 16 frames.
        #[arg(long)]
        data: PathBuf,
        #[arg(long, value_delimiter = ',', default_value = "2,4,8,16")]
        views: Vec<usize>,
        /// Timed runs per view count (after one warm-up); medians are reported.
        #[arg(long, default_value_t = 5)]
        runs: usize,
        #[arg(long, env = "INSSPLAT_MODEL", default_value = "models/inssplat-default.onnx")]
        model: PathBuf,
        /// A second model to time against --model: the two run in turns, and the table gives
        /// each one's medians and the ratios (this one over --model) instead of the stages.
        #[arg(long)]
        against: Option<PathBuf>,
        /// Time the pipeline with this many steps of test-time refinement (stage `refine`, as
        /// `reconstruct --refine-steps`; 0, the default, times the feed-forward pipeline).
        #[arg(long, default_value_t = 0, value_name = "STEPS", conflicts_with = "against")]
        refine_steps: usize,
        /// Long side in pixels of the copy of each photo that registration finds its keypoints
        /// in, when the scene's photos are larger than the network's input (as `eval
        /// --register-photo-size`).
        #[arg(long, default_value_t = RegisterParams::default().photo_size, value_name = "PIXELS", conflicts_with = "against")]
        register_photo_size: u32,
        /// Print JSON instead of the table.
        #[arg(long, env = "INSSPLAT_JSON")]
        json: bool,
        #[arg(long, env = "INSSPLAT_THREADS")]
        threads: Option<usize>,
    },
    /// Run the HTTP service: reconstruct, query, batch jobs (see /docs once it runs).
    Serve {
        #[command(flatten)]
        args: inssplat_server::http::ServeArgs,
    },
    /// Score the model on test-split scenes (DESIGN.md protocol): JSON + a markdown table.
    Eval {
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
        /// The network (ONNX file exported by inssplat-train).
        #[arg(long, env = "INSSPLAT_MODEL", default_value = "models/inssplat-default.onnx")]
        model: PathBuf,
        /// Labels added to the scenes' own label vocabulary (file or comma-separated list).
        #[arg(long)]
        vocab: Option<String>,
        /// Where instances are clustered: once on the Gaussians, or per view (the paper's mode).
        #[arg(long, value_enum, default_value = "3d")]
        cluster: eval::ClusterMode,
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
        /// could not link to the first photo (each is turned to the heading at which the
        /// linked views' Gaussians match its photos best); 0 keeps the continued poses.
        #[arg(long, default_value_t = HeadingParams::default().candidates)]
        heading_candidates: usize,
        /// Write every found instance's shape descriptor and unfused semantic prototype with
        /// its majority true label here (JSON), for `inssplat-train fit-shapes --examples`
        /// (use train-split scenes).
        #[arg(long)]
        shape_examples: Option<PathBuf>,
        /// Place the network's outputs with the scenes' true context cameras instead of the
        /// predicted ones (scores everything but the camera head).
        #[arg(long)]
        known_poses: bool,
        /// Place the network's outputs at the scenes' true context depth instead of the depth
        /// head's (scores everything but the depth head; combine with --known-poses).
        #[arg(long)]
        known_depth: bool,
        /// Name every found instance with the true label most of its context pixels carry
        /// instead of the classifier's (scores the instances' naming out of the question; 3D
        /// clustering only).
        #[arg(long)]
        known_names: bool,
        /// How voxelization merges the opacities of a voxel's Gaussians: their optical depth
        /// over the merged footprint (coverage), or their mean (the ablation).
        #[arg(long, value_enum, default_value_t = MergeOpacity::Coverage)]
        merge_opacity: MergeOpacity,
        /// Use the camera head's poses as they are, without the keypoint registration stage
        /// (the ablation of registration).
        #[arg(long)]
        no_register: bool,
        /// Keep the camera head's field of view in registration instead of measuring one
        /// focal length for all views from the matches (the ablation of that estimate).
        #[arg(long)]
        keep_focal: bool,
        /// Long side in pixels of the copy of each photo that registration finds its keypoints
        /// in, when the photo is larger than the network's input; at most the input's size
        /// finds them in the input itself.
        #[arg(long, default_value_t = RegisterParams::default().photo_size, value_name = "PIXELS")]
        register_photo_size: u32,
        /// Reconstruct from the context photos of this folder's scenes of the same names (the
        /// same scenes synthesized at another size, `inssplat-train synth --size 512`), as a
        /// camera gives them; every ground truth stays --data's, at the model resolution.
        #[arg(long, value_name = "DIR", conflicts_with = "perturb")]
        photos: Option<PathBuf>,
        /// Register on keypoint matches alone, ignoring the network's learned descriptors
        /// (the A/B of learned matches; a model without a descriptor head registers so anyway).
        #[arg(long)]
        no_learned_matches: bool,
        /// Name every pixel from its own rendered semantic feature instead of its instance's
        /// prototype (the ablation of instance-grounded aggregation).
        #[arg(long)]
        no_aggregation: bool,
        /// Score the target views' raw renders, with what no Gaussian covers left black and
        /// without an instance, instead of filled from around it as `render` fills a new view.
        #[arg(long)]
        no_fill: bool,
        #[command(flatten)]
        switches: PipelineSwitches,
        /// Refine each target camera's pose against its photo for this many Adam steps before
        /// scoring it, the Gaussians frozen (the test-time pose optimization of pose-free
        /// novel-view evaluations; 0, the default, scores at the mapped camera). The protocol
        /// line says so when it is used.
        #[arg(long, default_value_t = 0, value_name = "STEPS")]
        target_pose_steps: usize,
        /// Also score the text queries under a grid of query rules (minimum score, margin to
        /// the best, margin to the instance's own label) and add the best to the report.
        #[arg(long)]
        query_rules: bool,
        /// Robustness sweeps at 8 views (noise, blur, exposure, overlap, repeats), a table of
        /// each metric against the strength, and the worst scenes' previews under --out.
        #[arg(long, value_enum, value_delimiter = ',')]
        perturb: Vec<eval::PerturbKind>,
        /// Run every speed/accuracy knob (views × voxel size × clustering subsample) through the
        /// evaluation and draw OUT/sweep.png and sweep.svg (needs --out).
        #[arg(long, requires = "out")]
        sweep: bool,
        /// Print the JSON report on stdout instead of the table (progress still goes to
        /// stderr: a bar on a terminal, else a line per scene and view count).
        #[arg(long, env = "INSSPLAT_JSON")]
        json: bool,
        /// Threads for ONNX Runtime (default: all cores).
        #[arg(long, env = "INSSPLAT_THREADS")]
        threads: Option<usize>,
    },
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

#[derive(Clone, Copy, clap::ValueEnum)]
enum RenderChoice {
    Auto,
    Cpu,
    Gpu,
}

/// The GPU renderer `choice` asks for: auto takes a hardware adapter only (a software one such
/// as lavapipe is slower than the CPU path).
fn gpu_renderer(choice: RenderChoice) -> anyhow::Result<Option<GpuRenderer>> {
    Ok(match choice {
        RenderChoice::Cpu => None,
        RenderChoice::Auto => GpuRenderer::new().ok().filter(|g| !g.is_software()),
        RenderChoice::Gpu => Some(GpuRenderer::new().context("--render gpu: no GPU adapter")?),
    })
}

fn default_threads(threads: Option<usize>) -> usize {
    threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, usize::from))
}

fn text_labels() -> anyhow::Result<LabelCache> {
    Ok(LabelCache::new(TextEmbedder::from_env().context("loading the text encoder")?))
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Check { scenes, json } => {
            for dir in &scenes {
                let s = check::check_scene(dir)?;
                if json {
                    println!("{}", serde_json::to_string(&s)?);
                } else {
                    println!("{}", s.describe());
                }
            }
            Ok(())
        }
        Command::Reconstruct { inputs, out, model, vocab, shape_weight, switches, json, threads } => {
            let paths = inputs::photo_paths(&inputs)?;
            let photos = inputs::read_photos(&paths)?;
            let vocabulary = vocab::vocabulary(vocab.as_deref())?;
            let mut model = Model::load(&model, default_threads(threads))?;
            let labels = text_labels()?;
            let bar = if json { indicatif::ProgressBar::hidden() } else { indicatif::ProgressBar::new_spinner() };
            bar.set_style(indicatif::ProgressStyle::with_template("{spinner} {elapsed_precise} {msg}").expect("template"));
            bar.enable_steady_tick(std::time::Duration::from_millis(100));
            let views = photos.len();
            let config = switches.apply(PipelineConfig { shape_weight, ..PipelineConfig::default() });
            let rec = reconstruct_with(&mut model, &labels, &photos, &vocabulary, &config, &|stage| {
                bar.set_message(format!("{views} views: {stage}"))
            });
            bar.finish_and_clear();
            let rec = rec?;
            let names: Vec<String> = paths.iter().map(|p| p.display().to_string()).collect();
            output::write_reconstruction(&rec, &names, &out)?;
            let summary = output::summary(&rec);
            if json {
                println!("{}", serde_json::to_string_pretty(&summary)?);
            } else {
                eprintln!("{}", output::describe(&summary, &out));
            }
            Ok(())
        }
        Command::Query { out, text, json } => {
            let saved = saved::Saved::load(&out)?;
            let labels = text_labels()?;
            let (answer, dir) = query::run_query(&saved, &labels, &text)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&answer)?);
            } else {
                for m in &answer.matches {
                    let px: usize = m.masks.iter().map(|v| v.rle.decode().iter().filter(|b| **b).count()).sum();
                    println!("#{:<3} {:<20} score {:.2}  {px} mask pixels over {} views", m.instance_id, m.label, m.score, m.masks.len());
                }
                if let Some(msg) = &answer.message {
                    println!("{msg}");
                } else {
                    println!("masks in {}", dir.display());
                }
            }
            Ok(())
        }
        Command::Render { out, camera, to, render, no_fill } => {
            let saved = saved::Saved::load(&out)?;
            let cameras = render_view::cameras(&saved, &camera)?;
            let dir = to.unwrap_or_else(|| out.join("render"));
            let gpu = gpu_renderer(render)?;
            let (files, backend) = render_view::render_views(&saved, &cameras, &dir, gpu.as_ref(), !no_fill)?;
            println!(
                "{} images from {} camera(s) in {} (masks rendered on {})",
                files.len(),
                cameras.len(),
                dir.display(),
                match backend {
                    Backend::Cpu => "cpu",
                    Backend::Wgpu => "wgpu",
                }
            );
            Ok(())
        }
        Command::Bench { data, views, runs, model, against, refine_steps, register_photo_size, json, threads } => {
            if let Some(v) = views.iter().find(|v| !(2..=16).contains(*v)) {
                anyhow::bail!("--views: {v} is outside 2-16");
            }
            let dir = eval::scene_dirs(&data)?.remove(0);
            let scene = inssplat_proto::dataset::Scene::load(&dir).with_context(|| format!("loading {}", dir.display()))?;
            let threads = default_threads(threads);
            let mut model = Model::load(&model, threads)?;
            let labels = text_labels()?;
            if let Some(other) = against {
                let mut other = Model::load(&other, threads)?;
                let rows = bench::compare([&mut model, &mut other], &labels, &scene, &views, runs, &vocab::vocabulary(None)?)?;
                if json {
                    println!("{}", serde_json::to_string_pretty(&rows)?);
                } else {
                    let name = |m: &Model| format!("{} (`{}`)", m.model_version, m.path.display());
                    print!("{}", bench::compare_markdown(&rows, [&name(&model), &name(&other)], threads));
                }
                return Ok(());
            }
            let gpu = GpuRenderer::new().ok();
            let config = PipelineConfig {
                refine_steps,
                register: Some(RegisterParams { photo_size: register_photo_size, ..RegisterParams::default() }),
                ..PipelineConfig::default()
            };
            let vocabulary = vocab::vocabulary(None)?;
            let plan = bench::BenchPlan { views: &views, runs, vocabulary: &vocabulary, config: &config };
            let rows = bench::bench(&mut model, &labels, &scene, &plan, gpu.as_ref())?;
            if json {
                println!("{}", serde_json::to_string_pretty(&rows)?);
            } else {
                let adapter = gpu.as_ref().map(|g| format!("{}{}", g.adapter(), if g.is_software() { " (software)" } else { "" }));
                print!("{}", bench::markdown(&rows, threads, adapter.as_deref()));
            }
            Ok(())
        }
        Command::Serve { args } => inssplat_server::http::serve(args),
        Command::Eval {
            data,
            views,
            max_scenes,
            out,
            model,
            vocab,
            cluster,
            position_weight,
            min_cluster_share,
            min_samples,
            min_cosine,
            shape_weight,
            split_cell,
            superpixel_scale,
            vote,
            heading_candidates,
            shape_examples,
            known_poses,
            known_depth,
            known_names,
            merge_opacity,
            no_register,
            keep_focal,
            register_photo_size,
            photos,
            no_learned_matches,
            no_aggregation,
            no_fill,
            switches,
            target_pose_steps,
            query_rules,
            perturb,
            sweep,
            json,
            threads,
        } => {
            if let Some(v) = views.iter().find(|v| !(2..=16).contains(*v)) {
                anyhow::bail!("--views: {v} is outside 2-16");
            }
            if !(superpixel_scale.is_finite() && superpixel_scale >= 0.0) {
                anyhow::bail!("--superpixel-scale: {superpixel_scale} must be a finite number ≥ 0 (0 turns the superpixels off)");
            }
            if known_names && cluster == eval::ClusterMode::TwoD {
                anyhow::bail!("--known-names names the instances of the 3D clustering; --cluster 2d names each view's own groups");
            }
            if known_names && no_aggregation {
                anyhow::bail!("--known-names names the instances; --no-aggregation names each pixel by its own features instead");
            }
            let cluster_params = ClusterParams { position_weight, min_cluster_share, min_samples, min_cosine, ..ClusterParams::default() };
            cluster_params.validate()?;
            let mut dirs = eval::scene_dirs(&data)?;
            dirs.truncate(max_scenes.unwrap_or(usize::MAX));
            let extra = match vocab.as_deref() {
                Some(v) => vocab::vocabulary(Some(v))?,
                None => Vec::new(),
            };
            let mut model = Model::load(&model, default_threads(threads))?;
            let labels = text_labels()?;
            let request = eval::EvalRequest {
                views,
                extra_vocab: extra,
                pipeline: switches.apply(PipelineConfig {
                    register: (!no_register).then(|| RegisterParams {
                        estimate_focal: !keep_focal,
                        use_descriptors: !no_learned_matches,
                        photo_size: register_photo_size,
                        ..RegisterParams::default()
                    }),
                    cluster: cluster_params,
                    split: (split_cell > 0.0).then(|| SplitParams { cell_voxels: split_cell, ..SplitParams::default() }),
                    shape_weight,
                    voxel: VoxelParams { opacity: merge_opacity.into(), ..VoxelParams::default() },
                    superpixels: (superpixel_scale > 0.0).then(|| SuperpixelParams { scale: superpixel_scale, ..SuperpixelParams::default() }),
                    heading: (heading_candidates > 0).then(|| HeadingParams { candidates: heading_candidates, ..HeadingParams::default() }),
                    vote,
                    ..PipelineConfig::default()
                }),
                cluster,
                switches: eval::EvalSwitches { known_poses, known_depth, known_names, no_aggregation, no_fill, target_pose_steps },
                query_rules,
                photos,
                perturb,
                out: out.clone(),
                progress: true,
            };
            if sweep {
                let out = out.as_deref().expect("clap requires --out with --sweep");
                let points = eval::run_sweep(&mut model, &labels, &dirs, &request, out)?;
                output::write_atomic(&out.join("sweep.json"), serde_json::to_string_pretty(&points)?.as_bytes())?;
                let table = eval::sweep_markdown(&points);
                output::write_atomic(&out.join("sweep.md"), table.as_bytes())?;
                print!("{table}");
                println!("chart: {} and sweep.svg", out.join("sweep.png").display());
                return Ok(());
            }
            let report = eval::evaluate(&mut model, &labels, &dirs, &request)?;
            let table = eval::markdown(&report);
            if let Some(path) = &shape_examples {
                output::write_atomic(path, serde_json::to_string(&report.shape_examples)?.as_bytes())
                    .with_context(|| format!("--shape-examples {}", path.display()))?;
                eprintln!("{} shape examples written to {}", report.shape_examples.len(), path.display());
            }
            if let Some(out) = &out {
                std::fs::create_dir_all(out).with_context(|| format!("--out: cannot create {}", out.display()))?;
                output::write_atomic(&out.join("eval.json"), serde_json::to_string_pretty(&report)?.as_bytes())?;
                output::write_atomic(&out.join("eval.md"), table.as_bytes())?;
            }
            if json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                print!("{table}");
            }
            Ok(())
        }
    }
}
