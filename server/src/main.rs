//! The `inssplat` command line: a thin shell over the library's modules.

use std::path::PathBuf;

use clap::{Parser, Subcommand};

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
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Check { scenes, json } => {
            for dir in &scenes {
                let s = inssplat_server::check::check_scene(dir)?;
                if json {
                    println!("{}", serde_json::to_string(&s)?);
                } else {
                    println!(
                        "{}: ok, {} frames {}×{}, depth in {}, instance masks in {}, {} instances ({}){}",
                        s.path,
                        s.frames,
                        s.width,
                        s.height,
                        s.with_depth,
                        s.with_instances,
                        s.instances,
                        s.labels.join(", "),
                        if s.has_eval_split { ", eval split" } else { "" }
                    );
                }
            }
            Ok(())
        }
    }
}
