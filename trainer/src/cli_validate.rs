//! The `validate` subcommand of `inssplat-train`: a run's (or checkpoint's) loss on fixed
//! validation samples, with `--depth-abs-rel` its depth's AbsRel, and with `--csv` every sample's
//! scores, to pair checkpoints.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use inssplat_trainer::train;
use inssplat_trainer::train::sample::DataSpec;

#[derive(clap::Args)]
pub struct ValidateArgs {
    /// Run folders (each one's newest checkpoint) or checkpoint folders.
    #[arg(required = true)]
    checkpoints: Vec<PathBuf>,
    /// Fixed validation samples (the first 4 are those a run validates on while training).
    #[arg(long, default_value_t = 32)]
    samples: usize,
    /// Folder of validation scenes (default: the val split, synthesized at the run's size).
    #[arg(long)]
    val_data: Option<PathBuf>,
    /// Draw each sample's views from this many consecutive frames, so that they overlap (as
    /// `train --view-window`; default: from the whole trajectory, as a run validates).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
    view_window: Option<u16>,
    /// Also score the depth's AbsRel at each sample's median scale.
    #[arg(long)]
    depth_abs_rel: bool,
    /// Write each sample's loss terms (and its depth AbsRel, with --depth-abs-rel) to this CSV, to
    /// pair checkpoints sample by sample (`scripts/analysis/paired_samples.py`).
    #[arg(long)]
    csv: Option<PathBuf>,
}

pub fn run_validate(args: ValidateArgs) -> Result<()> {
    if args.samples == 0 {
        bail!("--samples must be at least 1");
    }
    let set = train::ValidationSet {
        samples: args.samples,
        data: args.val_data.clone().map(DataSpec::Folder),
        window: args.view_window.map(usize::from),
    };
    let mut csv = String::from(
        "checkpoint,step,sample,total,rgb,geometry,instance,semantic,boundary,abs_rel\n",
    );
    for path in &args.checkpoints {
        let train::CheckpointScores { dir, step, losses, depth } =
            train::score_checkpoint(path, &set, args.depth_abs_rel)
                .with_context(|| format!("validating {}", path.display()))?;
        let v = train::mean_loss(&losses);
        println!(
            "{} (step {step}): val loss {:.4} (rgb {:.4}, geom {:.4}, ins {:.4}, sem {:.4}, bd {:.4}) over {} samples",
            dir.display(),
            v.total,
            v.rgb,
            v.geometry,
            v.instance,
            v.semantic,
            v.boundary,
            args.samples
        );
        let mut abs_rel = vec![None; losses.len()];
        if let Some(depth) = depth {
            if let Some(mean) = depth.mean_abs_rel() {
                println!("  depth AbsRel at each sample's median scale: {mean:.4}");
            }
            abs_rel = depth.abs_rel;
        }
        for (i, (l, a)) in losses.iter().zip(&abs_rel).enumerate() {
            let a = a.map_or(String::new(), |a| format!("{a:.6}"));
            csv.push_str(&format!(
                "{},{step},{i},{},{},{},{},{},{},{a}\n",
                dir.display(),
                l.total,
                l.rgb,
                l.geometry,
                l.instance,
                l.semantic,
                l.boundary
            ));
        }
    }
    if let Some(path) = &args.csv {
        std::fs::write(path, csv).with_context(|| format!("writing --csv {}", path.display()))?;
    }
    Ok(())
}
