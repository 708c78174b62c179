//! The `export`, `quantize`, `pool-keys` and `average` subcommands of `inssplat-train`: the
//! ONNX files the pipeline runs, written from runs and checkpoints or from other ONNX files.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use inssplat_trainer::export::{
    ExportMeta, Weights, average_file, export_keeping_metadata, export_onnx, pool_keys_file,
    quantize_file,
};
use inssplat_trainer::train::checkpoint;

#[derive(clap::Args)]
pub struct ExportArgs {
    /// A run folder (its newest checkpoint) or a checkpoint folder.
    #[arg(long)]
    checkpoint: PathBuf,
    /// The ONNX file to write.
    #[arg(long)]
    out: PathBuf,
    /// Model version recorded in the ONNX metadata (default: the run folder's name and step).
    #[arg(long)]
    model_version: Option<String>,
    /// Keep this ONNX file's metadata that the exporter does not write itself (its shape
    /// classifier), for a network of another shape than the file's (`average` needs one shape).
    #[arg(long)]
    metadata_from: Option<PathBuf>,
}

pub fn run_export(args: ExportArgs) -> Result<()> {
    let dir = checkpoint::latest(&args.checkpoint)?.with_context(|| {
        format!(
            "--checkpoint: {} is neither a run with checkpoints nor a checkpoint",
            args.checkpoint.display()
        )
    })?;
    let state = checkpoint::read_state(&dir)?;
    let net = checkpoint::load_model(&dir, &state, &Device::flex())?;
    let version = args.model_version.unwrap_or_else(|| {
        let run = args.checkpoint.file_name().and_then(|n| n.to_str()).unwrap_or("run");
        format!("inssplat-{}+{run}.{}", env!("CARGO_PKG_VERSION"), state.step)
    });
    let meta = ExportMeta {
        model_version: version.clone(),
        train_steps: state.step,
        weights: Weights::F32,
    };
    match &args.metadata_from {
        None => export_onnx(&net, &args.out, &meta)
            .with_context(|| format!("exporting to {}", args.out.display()))?,
        Some(from) => export_keeping_metadata(&net, &meta, from, &args.out).with_context(|| {
            format!(
                "exporting to {} with the metadata of --metadata-from {}",
                args.out.display(),
                from.display()
            )
        })?,
    }
    println!(
        "wrote {} ({version}, {} steps, {:.1} MB)",
        args.out.display(),
        state.step,
        std::fs::metadata(&args.out)?.len() as f64 / 1e6
    );
    Ok(())
}

#[derive(clap::Args)]
pub struct QuantizeArgs {
    /// The ONNX file to read (as `inssplat-train export`, `fit-shapes` or `quantize` wrote it).
    #[arg(long)]
    model: PathBuf,
    /// The ONNX file to write.
    #[arg(long)]
    out: PathBuf,
    /// Model version recorded in the metadata (default: the input's with `+int8`).
    #[arg(long)]
    model_version: Option<String>,
}

#[derive(clap::Args)]
pub struct PoolKeysArgs {
    /// The ONNX file to read (as `inssplat-train export`, `fit-shapes` or `quantize` wrote it).
    #[arg(long)]
    model: PathBuf,
    /// The ONNX file to write.
    #[arg(long)]
    out: PathBuf,
    /// Patches a side of the squares whose keys and values the global layers average (1:
    /// every token, as trained before pooling existed).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
    pool: u16,
    /// Model version recorded in the metadata (default: the input's with `+kvP`).
    #[arg(long)]
    model_version: Option<String>,
}

pub fn run_pool_keys(args: PoolKeysArgs) -> Result<()> {
    let pool = Some(usize::from(args.pool)).filter(|&p| p > 1);
    let meta = pool_keys_file(&args.model, &args.out, pool, args.model_version.as_deref())
        .with_context(|| format!("--model {} --pool {}", args.model.display(), args.pool))?;
    println!(
        "wrote {} ({}, global keys and values pooled {p}×{p})",
        args.out.display(),
        meta.model_version,
        p = args.pool
    );
    Ok(())
}

pub fn run_quantize(args: QuantizeArgs) -> Result<()> {
    let meta = quantize_file(&args.model, &args.out, args.model_version.as_deref())?;
    let mb = |p: &PathBuf| std::fs::metadata(p).map_or(0.0, |m| m.len() as f64 / 1e6);
    println!(
        "wrote {} ({}, int8 linear weights, {:.1} MB; {} is {:.1} MB)",
        args.out.display(),
        meta.model_version,
        mb(&args.out),
        args.model.display(),
        mb(&args.model)
    );
    Ok(())
}

#[derive(clap::Args)]
pub struct AverageArgs {
    /// The model file whose network shape and metadata (the shape classifier) the result
    /// keeps, such as the file the run started from.
    #[arg(long)]
    model: PathBuf,
    /// The ONNX file to write.
    #[arg(long)]
    out: PathBuf,
    /// Checkpoint folders, or run folders (every checkpoint they keep), to average.
    #[arg(required = true)]
    checkpoints: Vec<PathBuf>,
    /// Only the checkpoints of this step or later.
    #[arg(long, default_value_t = 0)]
    from_step: u64,
    /// Model version recorded in the metadata (default: the first checkpoint's run and the
    /// steps averaged over).
    #[arg(long)]
    model_version: Option<String>,
}

pub fn run_average(args: AverageArgs) -> Result<()> {
    let mut dirs = Vec::new();
    for path in &args.checkpoints {
        let found = checkpoint::all(path);
        if found.is_empty() {
            bail!("{} is neither a run with checkpoints nor a checkpoint", path.display());
        }
        dirs.extend(found);
    }
    let (mut nets, mut names, mut steps) = (Vec::new(), Vec::new(), Vec::new());
    for dir in dirs {
        let state = checkpoint::read_state(&dir)?;
        if state.step < args.from_step {
            continue;
        }
        nets.push(checkpoint::load_model(&dir, &state, &Device::flex())?);
        names.push(dir.display().to_string());
        steps.push(state.step);
    }
    let (Some(&first), Some(&last)) = (steps.iter().min(), steps.iter().max()) else {
        bail!("no checkpoint of step {} or later among {:?}", args.from_step, args.checkpoints);
    };
    let version = args.model_version.unwrap_or_else(|| {
        let run = args.checkpoints[0].file_name().and_then(|n| n.to_str()).unwrap_or("run");
        format!("inssplat-{}+{run}.avg{first}-{last}", env!("CARGO_PKG_VERSION"))
    });
    let meta =
        average_file(&args.model, &args.out, &nets, &names, &version, last).with_context(|| {
            format!("--model {} --out {}", args.model.display(), args.out.display())
        })?;
    println!(
        "wrote {} ({}, the mean of {} checkpoints, steps {first}..={last})",
        args.out.display(),
        meta.model_version,
        nets.len()
    );
    Ok(())
}
