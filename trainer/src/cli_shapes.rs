//! The `fit-shapes` subcommand: synthesize train- and val-split rooms (progress bar), fit
//! the shape classifier on the train rooms' objects (or on example files of the pipeline's
//! own instances, with their semantic prototypes if asked), report its accuracy on the val
//! rooms' and write a copy of a model file that carries it.

use std::path::PathBuf;

use anyhow::{Context, Result, anyhow};
use indicatif::{ProgressBar, ProgressStyle};
use inssplat_proto::shape::LabelledDescriptor;
use inssplat_synth::{self as synth, Furniture, Split, Structure, SynthConfig};
use inssplat_trainer::shapes::{FitShapesConfig, attach, draw_views, fit, scene_examples};
use inssplat_trainer::train::label_cache;
use rayon::prelude::*;

#[derive(clap::Args)]
pub struct FitShapesArgs {
    /// The model file (ONNX) to carry the classifier.
    #[arg(long)]
    model: PathBuf,
    /// Where to write the model with the classifier (may be --model itself).
    #[arg(long)]
    out: PathBuf,
    /// Fit on these examples (JSON from `inssplat-eval score --shape-examples` on train-split
    /// scenes: the pipeline's own instances) instead of synthesizing rooms; repeat the flag
    /// for several files (taken in order).
    #[arg(long)]
    examples: Vec<PathBuf>,
    /// Report held-out accuracy on these examples (`inssplat-eval score --shape-examples` on val
    /// scenes) instead of synthesizing val rooms.
    #[arg(long)]
    held_out: Option<PathBuf>,
    /// Train-split rooms to fit on.
    #[arg(long, default_value_t = 1500)]
    scenes: u64,
    /// Index of the first train-split room.
    #[arg(long, default_value_t = 0)]
    first_scene: u64,
    /// Val-split rooms to report held-out accuracy on.
    #[arg(long, default_value_t = 200)]
    val_scenes: u64,
    /// Full-batch epochs.
    #[arg(long, default_value_t = FitShapesConfig::default().epochs)]
    epochs: usize,
    /// Width of the two hidden layers.
    #[arg(long, default_value_t = FitShapesConfig::default().hidden)]
    hidden: usize,
    /// Post-hoc logit adjustment τ: each label's score is lowered by τ·ln of its share of
    /// the training examples, trading accuracy on frequent labels for recall on rare ones
    /// (0: none; 1: the balanced-error choice of Menon et al., 2021).
    #[arg(long, default_value_t = FitShapesConfig::default().logit_adjust)]
    logit_adjust: f32,
    /// Also read each instance's semantic prototype: the cosines of it to the labels' texts
    /// join the descriptor (the labels embedded by MiniLM, or the table named by
    /// INSSPLAT_LABEL_TABLE). Needs --examples and --held-out, which record the prototypes.
    #[arg(long, requires_all = ["examples", "held_out"])]
    semantic: bool,
    /// New model version for the written file (default: keep the old one).
    #[arg(long)]
    model_version: Option<String>,
    /// Sweet Home 3D furniture folder (*.sh3f).
    #[arg(long, env = "INSSPLAT_FURNITURE_DIR", default_value = synth::DEFAULT_FURNITURE_DIR)]
    furniture_dir: PathBuf,
    /// Use furniture built from primitives only (no furniture folder needed).
    #[arg(long)]
    primitives_only: bool,
}

pub fn run_fit_shapes(a: FitShapesArgs) -> Result<()> {
    if !(a.logit_adjust.is_finite() && a.logit_adjust >= 0.0) {
        return Err(anyhow!("--logit-adjust {}: must be a number ≥ 0", a.logit_adjust));
    }
    // Furniture is needed only for the rooms synthesized here, not with example files.
    let furniture = || crate::furniture(a.primitives_only, &a.furniture_dir);
    let train = match a.examples.as_slice() {
        [] => examples(Split::Train, a.first_scene, a.scenes, &furniture()?)?,
        files => files
            .iter()
            .map(|f| read_examples(f, "--examples"))
            .collect::<Result<Vec<_>>>()?
            .concat(),
    };
    let held_out = match &a.held_out {
        Some(path) => read_examples(path, "--held-out")?,
        None => examples(Split::Val, 0, a.val_scenes, &furniture()?)?,
    };
    let config = FitShapesConfig {
        epochs: a.epochs,
        hidden: a.hidden,
        logit_adjust: a.logit_adjust,
        ..FitShapesConfig::default()
    };
    let texts =
        if a.semantic { Some(label_cache().context("--semantic: the label texts")?) } else { None };
    let bar = bar(config.epochs as u64, "epochs");
    let (mut classifier, report) =
        fit(&train, &held_out, &config, texts.as_deref(), &|epoch, loss| {
            bar.set_position(epoch as u64 + 1);
            bar.set_message(format!("loss {loss:.3}"));
        })
        .map_err(|e| anyhow!("fitting the shape classifier: {e}"))?;
    bar.finish_and_clear();
    let held = report.held_out_accuracy.map_or("–".into(), |x| format!("{:.1}%", 100.0 * x));
    let source = |files: &[PathBuf], rooms: String| match files {
        [] => rooms,
        files => format!(
            "the instances in {}",
            files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>().join(" + ")
        ),
    };
    classifier.provenance = format!(
        "inssplat-train fit-shapes{}{}: fitted on {} ({} examples), {} epochs, hidden {}; accuracy {:.1}% on them, {held} on {} ({} examples)",
        if a.semantic { " --semantic" } else { "" },
        if a.logit_adjust > 0.0 {
            format!(" --logit-adjust {}", a.logit_adjust)
        } else {
            String::new()
        },
        source(
            &a.examples,
            format!("the objects of train rooms {}..{}", a.first_scene, a.first_scene + a.scenes)
        ),
        train.len(),
        config.epochs,
        config.hidden,
        100.0 * report.train_accuracy,
        source(a.held_out.as_slice(), format!("the objects of val rooms 0..{}", a.val_scenes)),
        held_out.len(),
    );
    println!("{}", classifier.provenance);
    attach(&a.model, &a.out, &classifier, a.model_version.as_deref()).context("--model/--out")?;
    println!("wrote {} ({} labels)", a.out.display(), classifier.labels.len());
    Ok(())
}

fn read_examples(path: &std::path::Path, flag: &str) -> Result<Vec<LabelledDescriptor>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("{flag} {}", path.display()))?;
    serde_json::from_str(&text)
        .with_context(|| format!("{flag} {}: not a list of {{label, descriptor}}", path.display()))
}

fn bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{{spinner}} {{wide_bar}} {{pos}}/{{len}} {what} {{msg}} eta {{eta}}"
        ))
        .expect("template"),
    );
    bar
}

/// Descriptors of the labelled objects (room shell included) of `count` rooms of `split`.
fn examples(
    split: Split,
    first: u64,
    count: u64,
    furniture: &Furniture,
) -> Result<Vec<LabelledDescriptor>> {
    let mut cfg = SynthConfig::new(split, furniture.clone());
    cfg.structure = Structure::Instances;
    let bar = bar(count, &format!("{split} rooms"));
    let per_scene: Vec<Vec<LabelledDescriptor>> = (first..first + count)
        .into_par_iter()
        .map(|i| {
            let s = synth::generate_split(i, &cfg).with_context(|| format!("{split} scene {i}"))?;
            bar.inc(1);
            Ok(scene_examples(&s.scene, &draw_views(s.scene.frames.len(), i)))
        })
        .collect::<Result<_>>()?;
    bar.finish_and_clear();
    Ok(per_scene.into_iter().flatten().collect())
}
