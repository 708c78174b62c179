//! The `validate` subcommand of `inssplat-train`: a run's (or checkpoint's) loss on fixed
//! validation samples, with `--matching` whether its attention and descriptors match the views
//! and its depth's AbsRel, and with `--csv` every sample's scores, to pair checkpoints.

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
    /// For a network trained with `--camera-rays`: turn every input view's camera but the
    /// first by this many degrees about its centre (each about a random axis) before it
    /// becomes rays, as registration's errors would.
    #[arg(long, default_value_t = 0.0)]
    ray_noise: f32,
    /// Also score whether the last global layer's first attention head looks at the view-0
    /// token that sees the same point (what `--attention-match-weight` trains), the depth's
    /// AbsRel, and, for a network with a descriptor head, whether each pixel's most alike
    /// descriptor in another view sees the same point (what `--descriptor-weight` trains).
    #[arg(long)]
    matching: bool,
    /// Write each sample's loss terms (and its depth AbsRel, with --matching) to this CSV, to
    /// pair checkpoints sample by sample (`scripts/analysis/paired_samples.py`).
    #[arg(long)]
    csv: Option<PathBuf>,
}

pub fn run_validate(args: ValidateArgs) -> Result<()> {
    if args.samples == 0 {
        bail!("--samples must be at least 1");
    }
    if !(0.0..=180.0).contains(&args.ray_noise) {
        bail!("--ray-noise {} must be between 0 and 180 degrees", args.ray_noise);
    }
    let set = train::ValidationSet {
        samples: args.samples,
        data: args.val_data.clone().map(DataSpec::Folder),
        window: args.view_window.map(usize::from),
        ray_noise_deg: args.ray_noise,
    };
    let mut csv = String::from(
        "checkpoint,step,sample,total,rgb,geometry,instance,semantic,boundary,abs_rel\n",
    );
    for path in &args.checkpoints {
        let train::CheckpointScores { dir, step, losses, matching } =
            train::score_checkpoint(path, &set, args.matching)
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
        if let Some(matching) = matching {
            let m = matching.attention;
            println!(
                "  attention matching over {} tokens with a match in view 0: cross-entropy {:.3}, most-attended token right {:.2}%, within one token {:.2}%",
                m.tokens,
                m.cross_entropy,
                100.0 * m.top1,
                100.0 * m.within_one
            );
            if let Some(mean) = matching.mean_depth_abs_rel() {
                println!("  depth AbsRel at each sample's median scale: {mean:.4}");
            }
            abs_rel = matching.depth_abs_rel;
            if let Some(d) = matching.descriptors {
                println!(
                    "  descriptor matching over {} sampled matches: most alike descriptor on the {}-pixel grid within {} pixels of the match {:.2}%",
                    d.samples,
                    d.stride,
                    d.stride,
                    100.0 * d.within_stride
                );
            }
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
