//! The `fit-scene` subcommand: the per-scene optimization baseline on test-split scenes,
//! with a progress bar, a markdown table and optional JSON.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use inssplat_proto::dataset::Scene;
use inssplat_trainer::fit::{FitConfig, FitReport, fit_scene};
use inssplat_trainer::train::sample::{DataSpec, Source};

#[derive(clap::Args)]
pub struct FitArgs {
    /// A test-split scene folder, or a folder of them.
    #[arg(long)]
    data: PathBuf,
    /// Context views (the scene's eval context set of this size).
    #[arg(long, default_value_t = 8)]
    views: usize,
    /// Fit at most this many scenes (in name order).
    #[arg(long)]
    max_scenes: Option<usize>,
    /// One Gaussian per STRIDE×STRIDE context pixels.
    #[arg(long, default_value_t = 2)]
    stride: usize,
    /// Upper bound on optimizer steps per scene.
    #[arg(long, default_value_t = 1500)]
    max_steps: usize,
    /// Adam learning rate.
    #[arg(long, default_value_t = 5e-3)]
    lr: f64,
    /// Write every scene's report here as JSON, again after each scene (a run stopped midway
    /// keeps the scenes it finished).
    #[arg(long)]
    json: Option<PathBuf>,
    /// Keep the reports already in --json and fit only the scenes it lacks (matched by folder
    /// name; they must have been fitted with this run's --views, --stride, --max-steps and --lr).
    #[arg(long, requires = "json")]
    resume: bool,
}

pub fn run_fit(args: FitArgs) -> Result<()> {
    let dirs = if args.data.join("transforms.json").is_file() {
        vec![args.data.clone()]
    } else {
        match Source::open(&DataSpec::Folder(args.data.clone())).context("--data")? {
            Source::Folder(list) => list.to_vec(),
            Source::Synth(_) => bail!("--data {}: not a folder of scenes", args.data.display()),
        }
    };
    let config = FitConfig { views: args.views, stride: args.stride, max_steps: args.max_steps, lr: args.lr, ..FitConfig::default() };
    let mut reports = match &args.json {
        Some(path) if args.resume && path.exists() => finished(path, &config)?,
        _ => Vec::new(),
    };
    for dir in dirs.iter().take(args.max_scenes.unwrap_or(usize::MAX)) {
        let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if reports.iter().any(|r| r.scene == name) {
            eprintln!("{name}: kept from --json");
            continue;
        }
        let scene = Scene::load(dir).with_context(|| format!("--data: loading {}", dir.display()))?;
        let bar = ProgressBar::new(config.max_steps as u64);
        bar.set_style(ProgressStyle::with_template("{spinner} fit {msg} {pos}/{len} steps [{elapsed_precise}]").expect("template"));
        let report = fit_scene(&scene, &config, &|step, loss| {
            bar.set_position(step as u64 + 1);
            bar.set_message(format!("{name} loss {loss:.4}"));
        })?;
        bar.finish_and_clear();
        eprintln!("{}: {} steps in {:.1} s, instance mIoU {}, PQ {}", report.scene, report.steps, report.seconds, pct(report.instance_miou), pct(report.instance_pq));
        reports.push(report);
        if let Some(path) = &args.json {
            save(path, &reports)?;
        }
    }
    reports.sort_by(|a, b| a.scene.cmp(&b.scene));
    print!("{}", markdown(&reports));
    Ok(())
}

/// The reports of an earlier run in `path`, checked against this run's settings.
fn finished(path: &Path, config: &FitConfig) -> Result<Vec<FitReport>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("--resume: reading {}", path.display()))?;
    let reports: Vec<FitReport> = serde_json::from_str(&text).with_context(|| format!("--resume: {} is not a list of fit-scene reports", path.display()))?;
    for r in &reports {
        let theirs = (r.views, r.stride, r.max_steps, r.lr);
        if theirs != (config.views, config.stride, config.max_steps, config.lr) {
            bail!(
                "--resume: {} fitted {} with views {}, stride {}, max_steps {}, lr {}; this run asks for views {}, stride {}, max_steps {}, lr {}",
                path.display(),
                r.scene,
                r.views,
                r.stride,
                r.max_steps,
                r.lr,
                config.views,
                config.stride,
                config.max_steps,
                config.lr
            );
        }
    }
    Ok(reports)
}

/// Writes the reports to `path` through a temporary file beside it, so that a run stopped
/// while writing leaves the last whole file.
fn save(path: &Path, reports: &[FitReport]) -> Result<()> {
    let tmp = path.with_extension("json.partial");
    std::fs::write(&tmp, serde_json::to_string_pretty(reports)?).with_context(|| format!("--json {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("--json {}", path.display()))
}

fn pct(v: Option<f64>) -> String {
    v.map_or("–".into(), |v| format!("{:.1}", 100.0 * v))
}

fn markdown(reports: &[FitReport]) -> String {
    let mut out = String::from("| scene | views | Gaussians | steps | converged | seconds | inst mIoU | inst Acc@0.25 | inst PQ | instances |\n|---|---|---|---|---|---|---|---|---|---|\n");
    for r in reports {
        out += &format!(
            "| {} | {} | {} | {} | {} | {:.1} | {} | {} | {} | {} |\n",
            r.scene,
            r.views,
            r.gaussians,
            r.steps,
            r.converged,
            r.seconds,
            pct(r.instance_miou),
            pct(r.instance_acc25),
            pct(r.instance_pq),
            r.instances_found
        );
    }
    let mean = |f: &dyn Fn(&FitReport) -> Option<f64>| {
        let v: Vec<f64> = reports.iter().filter_map(f).collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    out += &format!(
        "| mean of {} | | | | | {:.1} | {} | {} | {} | |\n",
        reports.len(),
        mean(&|r| Some(r.seconds)).unwrap_or(0.0),
        pct(mean(&|r| r.instance_miou)),
        pct(mean(&|r| r.instance_acc25)),
        pct(mean(&|r| r.instance_pq))
    );
    out
}
