//! `inssplat eval`: the DESIGN.md evaluation protocol over a folder of test-split scenes at
//! several view counts. Each (scene, view count) is scored by [`scene::evaluate_scene`]; the
//! report averages every metric per view count over the scenes that have it, and is written as
//! JSON (`eval.json`, every scene's numbers included) and a markdown table (`eval.md`).

pub mod scene;
pub mod views;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use indicatif::{ProgressBar, ProgressStyle};
use inssplat_proto::dataset::Scene;
use inssplat_text::LabelCache;
use serde::Serialize;

use crate::pipeline::reconstruct::PipelineConfig;
use crate::runtime::Model;
use scene::{SceneScores, evaluate_scene};
pub use views::ClusterMode;

/// Scene folders to evaluate: `path` itself if it is a scene, else its sub-folders that are.
pub fn scene_dirs(path: &Path) -> Result<Vec<PathBuf>> {
    if path.join("transforms.json").is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    let entries = std::fs::read_dir(path).with_context(|| format!("--data {}: cannot read the folder", path.display()))?;
    let mut dirs: Vec<PathBuf> =
        entries.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.join("transforms.json").is_file()).collect();
    if dirs.is_empty() {
        bail!("--data {}: no scene folders (with a transforms.json) in it", path.display());
    }
    dirs.sort();
    Ok(dirs)
}

/// Means over scenes of one view count.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub views: usize,
    pub scenes: usize,
    /// Metric name → (mean, scenes that had it).
    pub metrics: BTreeMap<String, (f64, usize)>,
    pub seconds_median: f64,
    pub gaussians_kept_mean: f64,
}

/// The whole evaluation.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub model_version: String,
    pub data: String,
    pub vocabulary: Vec<String>,
    pub cluster: ClusterMode,
    pub summaries: Vec<Summary>,
    pub scenes: Vec<SceneScores>,
    /// How target views were placed and what was aligned.
    pub protocol: String,
}

const METRICS: [&str; 12] = [
    "semantic_miou",
    "semantic_macc",
    "instance_miou",
    "instance_acc25",
    "query_iou",
    "t_miou",
    "t_sr50",
    "psnr",
    "ssim",
    "depth_abs_rel",
    "rotation_deg",
    "translation",
];

fn metric(s: &SceneScores, name: &str) -> Option<f64> {
    match name {
        "semantic_miou" => s.semantic_miou,
        "semantic_macc" => s.semantic_macc,
        "instance_miou" => s.instance_miou,
        "instance_acc25" => s.instance_acc25,
        "query_iou" => s.query_iou,
        "t_miou" => s.t_miou,
        "t_sr50" => s.t_sr50,
        "psnr" => s.psnr,
        "ssim" => s.ssim,
        "depth_abs_rel" => s.depth_abs_rel,
        "rotation_deg" => s.rotation_deg,
        "translation" => s.translation,
        _ => None,
    }
}

fn summarize(views: usize, scores: &[&SceneScores]) -> Summary {
    let metrics = METRICS
        .iter()
        .filter_map(|m| {
            let v: Vec<f64> = scores.iter().filter_map(|s| metric(s, m)).filter(|x| x.is_finite()).collect();
            (!v.is_empty()).then(|| (m.to_string(), (v.iter().sum::<f64>() / v.len() as f64, v.len())))
        })
        .collect();
    let mut secs: Vec<f64> = scores.iter().map(|s| s.seconds).collect();
    secs.sort_by(f64::total_cmp);
    Summary {
        views,
        scenes: scores.len(),
        metrics,
        seconds_median: secs.get(secs.len() / 2).copied().unwrap_or(f64::NAN),
        gaussians_kept_mean: scores.iter().map(|s| s.gaussians_kept as f64).sum::<f64>() / scores.len().max(1) as f64,
    }
}

/// Evaluates every scene in `dirs` at every count in `views`.
pub fn evaluate(
    model: &mut Model,
    labels: &LabelCache,
    dirs: &[PathBuf],
    views: &[usize],
    extra_vocab: &[String],
    config: &PipelineConfig,
    mode: ClusterMode,
    progress: bool,
) -> Result<Report> {
    let scenes: Vec<Scene> =
        dirs.iter().map(|d| Scene::load(d).with_context(|| format!("loading {}", d.display()))).collect::<Result<_>>()?;
    let mut vocabulary: Vec<String> = scenes.iter().flat_map(Scene::label_vocabulary).chain(extra_vocab.iter().cloned()).collect();
    vocabulary.sort();
    vocabulary.dedup();
    let bar = if progress { ProgressBar::new((scenes.len() * views.len()) as u64) } else { ProgressBar::hidden() };
    bar.set_style(ProgressStyle::with_template("{spinner} eval {pos}/{len} [{elapsed_precise}<{eta_precise}] {wide_msg}").expect("template"));
    let mut all = Vec::new();
    for &v in views {
        for scene in &scenes {
            bar.set_message(format!("{} views, {}", v, scene.dir.display()));
            all.push(evaluate_scene(model, labels, scene, v, &vocabulary, config, mode)?);
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    let summaries = views.iter().map(|&v| summarize(v, &all.iter().filter(|s| s.views == v).collect::<Vec<_>>())).collect();
    Ok(Report {
        model_version: model.model_version.clone(),
        data: dirs.first().and_then(|d| d.parent()).map_or_else(String::new, |p| p.display().to_string()),
        vocabulary,
        cluster: mode,
        summaries,
        scenes: all,
        protocol: "context views reconstructed; instance mIoU per target view, pooled; predicted context cameras aligned to the true ones by Umeyama on \
                   camera centres (view 0 when degenerate); true target cameras mapped into the predicted frame and \
                   the clustered scene rendered there; depth AbsRel after median scale; no test-time optimization"
            .into(),
    })
}

/// Percent with one decimal, for IoU-like metrics.
fn pct(v: Option<&(f64, usize)>) -> String {
    v.map_or("n/a".into(), |(m, _)| format!("{:.1}", 100.0 * m))
}

fn num(v: Option<&(f64, usize)>, digits: usize) -> String {
    v.map_or("n/a".into(), |(m, _)| format!("{m:.digits$}"))
}

/// The markdown table of a report.
pub fn markdown(r: &Report) -> String {
    let mode = match r.cluster {
        ClusterMode::ThreeD => "instances clustered once in 3D",
        ClusterMode::TwoD => "instances clustered per view in 2D (the paper's mode)",
    };
    let mut out = format!("Model `{}`, {} scenes from `{}`, {mode}.\n\n", r.model_version, r.scenes.len() / r.summaries.len().max(1), r.data);
    out += "| views | sem mIoU | sem mAcc | inst mIoU | inst Acc@0.25 | query IoU | T-mIoU | T-SR@0.5 | PSNR | SSIM | depth AbsRel | rot err ° | trans err | s/scene | Gaussians kept |\n";
    out += "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    for s in &r.summaries {
        let m = |k: &str| s.metrics.get(k);
        out += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2} | {:.0} |\n",
            s.views,
            pct(m("semantic_miou")),
            pct(m("semantic_macc")),
            pct(m("instance_miou")),
            pct(m("instance_acc25")),
            pct(m("query_iou")),
            pct(m("t_miou")),
            pct(m("t_sr50")),
            num(m("psnr"), 2),
            num(m("ssim"), 3),
            num(m("depth_abs_rel"), 3),
            num(m("rotation_deg"), 2),
            num(m("translation"), 3),
            s.seconds_median,
            s.gaussians_kept_mean
        );
    }
    out += &format!("\nProtocol: {}.\n", r.protocol);
    out
}
