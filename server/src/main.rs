//! The `inssplat` command line: a thin shell over the library's modules.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Parser, Subcommand};
use inssplat_server::pipeline::reconstruct::{PipelineConfig, reconstruct};
use inssplat_server::runtime::Model;
use inssplat_server::{check, inputs, output, vocab};
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
        /// Print the result as JSON on stdout.
        #[arg(long, env = "INSSPLAT_JSON")]
        json: bool,
        /// Threads for ONNX Runtime (default: all cores).
        #[arg(long, env = "INSSPLAT_THREADS")]
        threads: Option<usize>,
    },
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
        Command::Reconstruct { inputs, out, model, vocab, json, threads } => {
            let paths = inputs::photo_paths(&inputs)?;
            let photos = inputs::read_photos(&paths)?;
            let vocabulary = vocab::vocabulary(vocab.as_deref())?;
            let threads = threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, usize::from));
            let mut model = Model::load(&model, threads)?;
            let labels = LabelCache::new(TextEmbedder::from_env().context("loading the text encoder")?);
            let rec = reconstruct(&mut model, &labels, &photos, &vocabulary, &PipelineConfig::default())?;
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
    }
}
