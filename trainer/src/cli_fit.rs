//! The `fit-scene` subcommand: the per-scene optimization baseline on test-split scenes,
//! with a progress bar, a markdown table and optional JSON.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use inssplat_proto::dataset::Scene;
use inssplat_trainer::fit::{FitConfig, FitReport, FitScores, fit_scene};
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
    /// Also score each fit after these step counts (comma-separated): its instance mIoU
    /// against its optimization time so far.
    #[arg(long, value_delimiter = ',')]
    score_at: Vec<usize>,
    /// Write every scene's report here as JSON, again after each scene (a run stopped midway
    /// keeps the scenes it finished).
    #[arg(long)]
    json: Option<PathBuf>,
    /// Keep the reports already in --json and fit only the scenes it lacks (matched by folder
    /// name; they must have been fitted with this run's --views, --stride, --max-steps, --lr
    /// and --score-at).
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
    let mut score_at = args.score_at.clone();
    score_at.sort_unstable();
    score_at.dedup();
    if let Some(&bad) = score_at.iter().find(|&&n| n == 0 || n > args.max_steps) {
        bail!("--score-at {bad}: each step count must lie in 1..=--max-steps ({})", args.max_steps);
    }
    let config = FitConfig {
        views: args.views,
        stride: args.stride,
        max_steps: args.max_steps,
        lr: args.lr,
        score_at,
        ..FitConfig::default()
    };
    let mut reports = match &args.json {
        Some(path) if args.resume && path.exists() => finished(path, &config)?,
        _ => Vec::new(),
    };
    let dirs = &dirs[..dirs.len().min(args.max_scenes.unwrap_or(usize::MAX))];
    for (i, dir) in dirs.iter().enumerate() {
        let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if reports.iter().any(|r| r.scene == name) {
            eprintln!("{name}: kept from --json");
            continue;
        }
        let scene =
            Scene::load(dir).with_context(|| format!("--data: loading {}", dir.display()))?;
        let bar = ProgressBar::new(config.max_steps as u64);
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} fit {msg} {pos}/{len} steps [{elapsed_precise}]",
            )
            .expect("template"),
        );
        let report = fit_scene(&scene, &config, &|step, loss| {
            bar.set_position(step as u64 + 1);
            bar.set_message(format!("{name} ({} of {}) loss {loss:.4}", i + 1, dirs.len()));
        })?;
        bar.finish_and_clear();
        eprintln!(
            "{}: {} steps in {:.1} s, instance mIoU {}, PQ {}",
            report.scene,
            report.steps,
            report.seconds,
            pct(report.scores.instance_miou),
            pct(report.scores.instance_pq)
        );
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
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("--resume: reading {}", path.display()))?;
    let reports: Vec<FitReport> = serde_json::from_str(&text).with_context(|| {
        format!("--resume: {} is not a list of fit-scene reports", path.display())
    })?;
    let asked = config.settings();
    if let Some(r) = reports.iter().find(|r| r.settings != asked) {
        bail!(
            "--resume: {} fitted {} with {}; this run asks for {asked}",
            path.display(),
            r.scene,
            r.settings
        );
    }
    Ok(reports)
}

/// Writes the reports to `path` through a temporary file beside it, so that a run stopped
/// while writing leaves the last whole file.
fn save(path: &Path, reports: &[FitReport]) -> Result<()> {
    let tmp = path.with_extension("json.partial");
    std::fs::write(&tmp, serde_json::to_string_pretty(reports)?)
        .with_context(|| format!("--json {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("--json {}", path.display()))
}

fn pct(v: Option<f64>) -> String {
    v.map_or("–".into(), |v| format!("{:.1}", 100.0 * v))
}

fn markdown(reports: &[FitReport]) -> String {
    let mut out = String::from(
        "| scene | views | Gaussians | steps | converged | seconds | inst mIoU | inst Acc@0.25 | inst PQ | instances |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let row = |s: &FitScores| {
        format!(
            "{} | {} | {} | {}",
            pct(s.instance_miou),
            pct(s.instance_acc25),
            pct(s.instance_pq),
            s.instances_found
        )
    };
    for r in reports {
        out += &format!(
            "| {} | {} | {} | {} | {} | {:.1} | {} |\n",
            r.scene,
            r.settings.views,
            r.gaussians,
            r.steps,
            r.converged,
            r.seconds,
            row(&r.scores)
        );
    }
    out += &format!(
        "| mean of {} | | | {:.0} | | {:.1} | {} | |\n",
        reports.len(),
        mean(reports, |r| r.steps as f64),
        mean(reports, |r| r.seconds),
        means(reports.iter().map(|r| &r.scores))
    );
    // Along the way: each step count's means over the fits that were scored there, and over
    // the fits that had already converged before it (their final scores), so that every
    // row covers every scene.
    let at: Vec<usize> = reports.first().map(|r| r.settings.score_at.clone()).unwrap_or_default();
    if !at.is_empty() {
        out += "\n| after steps | fits scored there | seconds (mean) | inst mIoU | inst Acc@0.25 | inst PQ |\n|---|---|---|---|---|---|\n";
        for n in at {
            let points: Vec<(f64, &FitScores)> = reports
                .iter()
                .map(|r| {
                    r.curve
                        .iter()
                        .find(|p| p.steps == n)
                        .map_or((r.seconds, &r.scores), |p| (p.seconds, &p.scores))
                })
                .collect();
            let scored = reports.iter().filter(|r| r.curve.iter().any(|p| p.steps == n)).count();
            let seconds = points.iter().map(|p| p.0).sum::<f64>() / points.len() as f64;
            out += &format!(
                "| {n} | {scored} of {} | {seconds:.1} | {} |\n",
                reports.len(),
                means(points.iter().map(|p| p.1))
            );
        }
    }
    out
}

/// The mean of `f` over the reports.
fn mean(reports: &[FitReport], f: impl Fn(&FitReport) -> f64) -> f64 {
    reports.iter().map(f).sum::<f64>() / reports.len().max(1) as f64
}

/// "mIoU | Acc@0.25 | PQ", each the mean over the scores that have it.
fn means<'a>(scores: impl Iterator<Item = &'a FitScores> + Clone) -> String {
    let m = |f: fn(&FitScores) -> Option<f64>| {
        let v: Vec<f64> = scores.clone().filter_map(f).collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    format!(
        "{} | {} | {}",
        pct(m(|s| s.instance_miou)),
        pct(m(|s| s.instance_acc25)),
        pct(m(|s| s.instance_pq))
    )
}
