//! The `inssplat` command line, what a user runs: check, reconstruct, query, render, serve.
//! A thin shell over `inssplat-pipeline` and the service; evaluation lives in `inssplat-eval`.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Parser, Subcommand};
use inssplat_pipeline::backend::{Model, threads_or_all};
use inssplat_pipeline::detector::{Detector, DetectorParams};
use inssplat_pipeline::reconstruct::{DEFAULT_SHAPE_WEIGHT, PipelineConfig, reconstruct_with};
use inssplat_pipeline::switches::{DetectorSwitches, PipelineSwitches};
use inssplat_pipeline::vocab::label_cache;
use inssplat_pipeline::{inputs, output, query, render_view, saved, vocab};
use inssplat_raster::render::{Backend, GpuRenderer};
use inssplat_server::check;

/// inssplat: instance-aware 3D Gaussians from a few unposed photos.
#[derive(Parser)]
#[command(version)]
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
    /// Find objects in photos with the object detector that helps name the instances (COCO's
    /// 80 classes): each photo's boxes in its pixels, with class and score.
    Detect {
        /// Photo files, or folders of photos.
        #[arg(required = true)]
        photos: Vec<PathBuf>,
        /// The network file whose `detector/` folder is the default.
        #[arg(long, env = "INSSPLAT_MODEL", default_value = "models/inssplat-default.onnx")]
        model: PathBuf,
        /// The detector's folder (`nanodet_g_416.onnx`, `coco80.txt`); default: `detector/`
        /// beside the network's file, else the workspace's `models/detector`.
        #[arg(long, env = "INSSPLAT_DETECTOR", value_name = "DIR")]
        detector: Option<PathBuf>,
        /// Print JSON.
        #[arg(long, env = "INSSPLAT_JSON")]
        json: bool,
        /// Threads for ONNX Runtime (default: all cores).
        #[arg(long, env = "INSSPLAT_THREADS")]
        threads: Option<usize>,
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
    /// Run the HTTP service: reconstruct, query, batch jobs (see /docs once it runs).
    Serve {
        #[command(flatten)]
        args: inssplat_server::http::ServeArgs,
    },
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
        Command::Reconstruct {
            inputs,
            out,
            model,
            vocab,
            shape_weight,
            switches,
            json,
            threads,
        } => {
            let paths = inputs::photo_paths(&inputs)?;
            let photos = inputs::read_photos(&paths)?;
            let vocabulary = vocab::vocabulary(vocab.as_deref())?;
            let mut model = Model::load(&model, threads_or_all(threads))?;
            let labels = label_cache()?;
            let bar = if json {
                indicatif::ProgressBar::hidden()
            } else {
                indicatif::ProgressBar::new_spinner()
            };
            bar.set_style(
                indicatif::ProgressStyle::with_template("{spinner} {elapsed_precise} {msg}")
                    .expect("template"),
            );
            bar.enable_steady_tick(std::time::Duration::from_millis(100));
            let views = photos.len();
            let base = PipelineConfig { shape_weight, ..PipelineConfig::default() };
            let config = switches.apply(base, &model.path, threads_or_all(threads))?;
            let rec =
                reconstruct_with(&mut model, &labels, &photos, &vocabulary, &config, &|stage| {
                    bar.set_message(format!("{views} views: {stage}"))
                });
            bar.finish_and_clear();
            let rec = rec?;
            output::write_reconstruction(&rec, &photos, &out)?;
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
            let labels = label_cache()?;
            let (answer, dir) = query::run_query(&saved, &labels, &text)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&answer)?);
            } else {
                for m in &answer.matches {
                    let px: usize =
                        m.masks.iter().map(|v| v.rle.decode().iter().filter(|b| **b).count()).sum();
                    println!(
                        "#{:<3} {:<20} score {:.2}  {px} mask pixels over {} views",
                        m.instance_id,
                        m.label,
                        m.score,
                        m.masks.len()
                    );
                }
                if let Some(msg) = &answer.message {
                    println!("{msg}");
                } else {
                    println!("masks in {}", dir.display());
                }
            }
            Ok(())
        }
        Command::Detect { photos, model, detector, json, threads } => {
            let paths = inputs::photo_paths(&photos)?;
            let photos = inputs::read_photos(&paths)?;
            let dir = DetectorSwitches { detector, ..Default::default() }.dir(&model);
            let found = Detector::load(&dir, threads_or_all(threads), DetectorParams::default())?
                .detect_photos(&photos)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&found)?);
            } else {
                for photo in &found {
                    println!("{} ({}×{}):", photo.photo, photo.width, photo.height);
                    for d in &photo.detections {
                        let [x0, y0, x1, y1] = d.bbox.map(|v| v.round());
                        println!("  {:<14} {:.2}  [{x0}, {y0}, {x1}, {y1}]", d.class, d.score);
                    }
                }
            }
            Ok(())
        }
        Command::Render { out, camera, to, render, no_fill } => {
            let saved = saved::Saved::load(&out)?;
            let cameras = render_view::cameras(&saved, &camera)?;
            let dir = to.unwrap_or_else(|| out.join("render"));
            let gpu = gpu_renderer(render)?;
            let (files, backend) =
                render_view::render_views(&saved, &cameras, &dir, gpu.as_ref(), !no_fill)?;
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
        Command::Serve { args } => inssplat_server::http::serve(args),
    }
}
