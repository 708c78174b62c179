//! `inssplat-eval bench`: the pipeline's speed on one test scene, per stage, at several view
//! counts:
//! median milliseconds of each stage over repeated runs, Gaussians in and kept, and the ratios
//! that say how cost grows with views (16 vs 8 views per stage) and how post-processing compares
//! with the network; and the paper's per-view 2D clustering timed on the same views against
//! inssplat's single 3D clustering. One process, one run of the table, so ratios compare like
//! with like. With a second model ([`compare`]), the two take turns run by run on the same
//! views, so that a machine's drift falls on both alike, and the table gives each one's
//! medians and the median of the paired ratios.

use std::collections::BTreeMap;

use inssplat_proto::dataset::Scene;
use inssplat_text::LabelCache;
use rayon::prelude::*;
use serde::Serialize;

use std::time::Instant;

use inssplat_raster::masks::render_instance_ids_on;
use inssplat_raster::render::GpuRenderer;
use inssplat_understand::cluster::ClusterParams;

use crate::scene::context_images;
use crate::views::{ClusterMode, segment};
use inssplat_pipeline::backend::Model;
use inssplat_pipeline::reconstruct::{InputImage, PipelineConfig, max_instance_id, reconstruct};

/// Medians of one view count.
#[derive(Debug, Clone, Serialize)]
pub struct BenchRow {
    pub views: usize,
    pub runs: usize,
    /// Stage → median milliseconds.
    pub stage_ms: BTreeMap<String, f64>,
    /// Median of the end-to-end time (sum of the stages).
    pub total_ms: f64,
    pub gaussians_in: usize,
    pub gaussians_kept: usize,
    pub instances: usize,
    /// The paper's mode on the same views: render each view's feature map and cluster it in
    /// 2D (median ms), against inssplat's cluster-once, superpixel vote and input-view masks
    /// (`cluster` + `vote` + `masks`).
    pub cluster_2d_ms: f64,
    /// Rendering the clustered scene's id maps at the input cameras, as for novel views
    /// (`inssplat render`, eval's target views), on the CPU (median ms) ...
    pub render_cpu_ms: f64,
    /// ... and on the GPU adapter, if there is one.
    pub render_gpu_ms: Option<f64>,
}

impl BenchRow {
    /// Everything after the network (and its second pass, stage "rays"; the detector's
    /// network, stage "detect", is no post-processing either).
    pub fn post_ms(&self) -> f64 {
        self.stage_ms
            .iter()
            .filter(|(s, _)| !matches!(s.as_str(), "decode" | "detect" | "model" | "rays"))
            .map(|(_, v)| v)
            .sum()
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Frames `0, n/v, 2n/v, ...` of `scene` as PNG-encoded inputs.
fn inputs(scene: &Scene, views: usize) -> anyhow::Result<Vec<InputImage>> {
    let n = scene.frames.len();
    anyhow::ensure!(n >= views, "{}: {n} frames, fewer than {views} views", scene.dir.display());
    let frames: Vec<usize> = (0..views).map(|i| i * n / views).collect();
    Ok(context_images(scene, &frames, None))
}

/// What [`bench`] times: the view counts, the timed runs of each, the label vocabulary and
/// the pipeline's settings.
pub struct BenchPlan<'a> {
    pub views: &'a [usize],
    pub runs: usize,
    pub vocabulary: &'a [String],
    pub config: &'a PipelineConfig,
}

/// Runs the pipeline `plan.runs` times (after one warm-up) at each of `plan.views`, and times
/// rendering id maps at the input cameras on the CPU and on `gpu` when given.
pub fn bench(
    model: &mut Model,
    labels: &LabelCache,
    scene: &Scene,
    plan: &BenchPlan<'_>,
    gpu: Option<&GpuRenderer>,
) -> anyhow::Result<Vec<BenchRow>> {
    let BenchPlan { views, runs, vocabulary, config } = *plan;
    views
        .iter()
        .map(|&v| {
            let images = inputs(scene, v)?;
            reconstruct(model, labels, &images, vocabulary, config)?;
            let mut per_stage: BTreeMap<String, Vec<f64>> = BTreeMap::new();
            let (mut totals, mut last) = (Vec::new(), None);
            for _ in 0..runs.max(1) {
                let rec = reconstruct(model, labels, &images, vocabulary, config)?;
                totals.push(rec.timings.iter().map(|t| t.ms).sum());
                for t in &rec.timings {
                    per_stage.entry(t.stage.clone()).or_default().push(t.ms);
                }
                last = Some(rec);
            }
            let rec = last.expect("at least one timed run");
            let words: Vec<&str> = vocabulary.iter().map(String::as_str).collect();
            let texts = labels.embed(&words)?;
            let params = ClusterParams::default();
            let cluster_2d = (0..runs.max(1))
                .map(|_| -> anyhow::Result<f64> {
                    let start = Instant::now();
                    for view in &rec.views {
                        segment(&rec, &view.camera, ClusterMode::TwoD, &texts, &params)
                            .map_err(anyhow::Error::msg)?;
                    }
                    Ok(start.elapsed().as_secs_f64() * 1e3)
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            let k = max_instance_id(&rec.instances);
            let render_on = |gpu: Option<&GpuRenderer>| {
                (0..runs.max(1))
                    .map(|_| -> anyhow::Result<f64> {
                        let start = Instant::now();
                        match gpu {
                            // One device queue: views in turn.
                            Some(_) => rec.views.iter().try_for_each(|view| {
                                render_instance_ids_on(gpu, &rec.scene, &view.camera, k).map(drop)
                            })?,
                            None => rec.views.par_iter().try_for_each(|view| {
                                render_instance_ids_on(None, &rec.scene, &view.camera, k).map(drop)
                            })?,
                        }
                        Ok(start.elapsed().as_secs_f64() * 1e3)
                    })
                    .collect::<anyhow::Result<Vec<_>>>()
                    .map(median)
            };
            let render_cpu = render_on(None)?;
            let render_gpu = gpu.map(|gpu| render_on(Some(gpu))).transpose()?;
            Ok(BenchRow {
                views: v,
                runs: runs.max(1),
                stage_ms: per_stage.into_iter().map(|(s, t)| (s, median(t))).collect(),
                total_ms: median(totals),
                gaussians_in: rec.voxel.gaussians_in,
                gaussians_kept: rec.voxel.gaussians_out,
                instances: rec.instances.len(),
                cluster_2d_ms: median(cluster_2d),
                render_cpu_ms: render_cpu,
                render_gpu_ms: render_gpu,
            })
        })
        .collect()
}

/// Two models timed in turns at one view count: medians of each one's network stage and whole
/// request, and the medians of the run-by-run ratios (second over first).
#[derive(Debug, Clone, Serialize)]
pub struct CompareRow {
    pub views: usize,
    pub runs: usize,
    pub model_ms: [f64; 2],
    pub total_ms: [f64; 2],
    pub model_ratio: f64,
    pub total_ratio: f64,
}

/// One turn of [`compare`]: each model's `[network ms, whole request ms]`.
type Turn = ([f64; 2], [f64; 2]);

/// Runs the pipeline with `models[0]` and `models[1]` in turns, `runs` times each (after one
/// warm-up each), at each count in `views`.
pub fn compare(
    models: [&mut Model; 2],
    labels: &LabelCache,
    scene: &Scene,
    views: &[usize],
    runs: usize,
    vocabulary: &[String],
    config: &PipelineConfig,
) -> anyhow::Result<Vec<CompareRow>> {
    let [a, b] = models;
    let time = |model: &mut Model, images: &[InputImage]| -> anyhow::Result<[f64; 2]> {
        let rec = reconstruct(model, labels, images, vocabulary, config)?;
        let stage =
            |name: &str| rec.timings.iter().filter(|t| t.stage == name).map(|t| t.ms).sum::<f64>();
        Ok([stage("model"), rec.timings.iter().map(|t| t.ms).sum()])
    };
    views
        .iter()
        .map(|&v| {
            let images = inputs(scene, v)?;
            time(a, &images)?;
            time(b, &images)?;
            let mut pairs = Vec::new();
            for _ in 0..runs.max(1) {
                pairs.push((time(a, &images)?, time(b, &images)?));
            }
            let of = |f: &dyn Fn(&Turn) -> f64| median(pairs.iter().map(f).collect());
            Ok(CompareRow {
                views: v,
                runs: pairs.len(),
                model_ms: [of(&|p| p.0[0]), of(&|p| p.1[0])],
                total_ms: [of(&|p| p.0[1]), of(&|p| p.1[1])],
                model_ratio: of(&|p| p.1[0] / p.0[0]),
                total_ratio: of(&|p| p.1[1] / p.0[1]),
            })
        })
        .collect()
}

/// [`compare`]'s table in markdown, the models named by `names`.
pub fn compare_markdown(rows: &[CompareRow], names: [&str; 2], threads: usize) -> String {
    let [a, b] = names;
    let mut out = format!(
        "Median milliseconds ({} runs each, the two models in turns, {threads} ONNX Runtime threads). A: {a}. B: {b}. \
         The ratios are medians of the run-by-run B / A.\n\n\
         | views | model, A | model, B | model, B / A | end to end, A | end to end, B | end to end, B / A |\n\
         |---|---|---|---|---|---|---|\n",
        rows.first().map_or(0, |r| r.runs)
    );
    for r in rows {
        out += &format!(
            "| {} | {:.0} | {:.0} | {:.2} | {:.0} | {:.0} | {:.2} |\n",
            r.views,
            r.model_ms[0],
            r.model_ms[1],
            r.model_ratio,
            r.total_ms[0],
            r.total_ms[1],
            r.total_ratio
        );
    }
    out
}

/// The table and the growth ratios, in markdown.
pub fn markdown(rows: &[BenchRow], threads: usize, gpu: Option<&str>) -> String {
    // The refine stage only runs when asked for (`--refine-steps`), the rays stage only for a
    // network that reads its cameras, the detect stage only with a detector.
    let ran = |stage: &str| rows.iter().any(|r| r.stage_ms.contains_key(stage));
    let stages: Vec<&str> = ["decode"]
        .into_iter()
        .chain(ran("detect").then_some("detect"))
        .chain(["model", "superpixels", "register", "heading"])
        .chain(ran("rays").then_some("rays"))
        .chain(["backproject", "voxelize", "cluster", "vote", "label"])
        .chain(ran("refine").then_some("refine"))
        .chain(["masks"])
        .chain(ran("upsample").then_some("upsample"))
        .collect();
    let mut out = format!(
        "Median milliseconds per stage ({} runs each, {threads} ONNX Runtime threads; stages on the CPU; GPU: {}). \
         Input-view masks take each pixel's merged Gaussian's id; the render columns time id maps rendered at \
         the input cameras, as for novel views.\n\n| views |",
        rows.first().map_or(0, |r| r.runs),
        gpu.unwrap_or("no adapter")
    );
    for s in &stages {
        out += &format!(" {s} |");
    }
    out += " total | post / model | Gaussians in | kept | instances | 3D: cluster + vote + masks | 2D: per-view render + cluster | render on CPU | render on GPU |\n|---|";
    out += &"---|".repeat(stages.len() + 9);
    out += "\n";
    for r in rows {
        out += &format!("| {} |", r.views);
        for s in &stages {
            out += &format!(" {:.0} |", r.stage_ms.get(*s).copied().unwrap_or(f64::NAN));
        }
        let model = r.stage_ms.get("model").copied().unwrap_or(f64::NAN);
        let three_d = ["cluster", "vote", "masks"]
            .iter()
            .map(|s| r.stage_ms.get(*s).copied().unwrap_or(0.0))
            .sum::<f64>();
        out += &format!(
            " {:.0} | {:.2} | {} | {} | {} | {three_d:.0} | {:.0} | {:.0} | {} |\n",
            r.total_ms,
            r.post_ms() / model,
            r.gaussians_in,
            r.gaussians_kept,
            r.instances,
            r.cluster_2d_ms,
            r.render_cpu_ms,
            r.render_gpu_ms.map_or("n/a".into(), |v| format!("{v:.0}"))
        );
    }
    let find = |v: usize| rows.iter().find(|r| r.views == v);
    if let (Some(a), Some(b)) = (find(8), find(16)) {
        out += "\nGrowth from 8 to 16 views (time ratio):";
        for s in &stages {
            if let (Some(x), Some(y)) = (a.stage_ms.get(*s), b.stage_ms.get(*s)) {
                out += &format!(" {s} {:.2}×,", y / x);
            }
        }
        out += &format!(
            " total {:.2}×; Gaussians kept {:.2}×; 2D clustering {:.2}×.\n",
            b.total_ms / a.total_ms,
            b.gaussians_kept as f64 / a.gaussians_kept.max(1) as f64,
            b.cluster_2d_ms / a.cluster_2d_ms
        );
    }
    out
}
