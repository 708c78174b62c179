//! inssplat-eval: the research bench, out of the service. The evaluation protocol
//! (docs/EVALUATION.md) over a folder of test-split scenes at several view counts, with its
//! oracles, perturbations and sweeps, and the per-stage benchmark ([`bench`]). Each (scene, view
//! count) is scored by [`scene::evaluate_scene`]; the
//! report averages every metric per view count over the scenes that have it, and is written as
//! JSON (`eval.json`, every scene's numbers included) and a markdown table (`eval.md`,
//! [`markdown`]).

pub mod bench;
pub mod ceiling;
pub mod confusion;
pub mod curve;
mod markdown;
pub mod perturb;
pub mod photos;
mod progress;
pub mod query_rules;
pub mod scene;
pub mod stereo;
pub mod sweep;
mod targets;
pub mod views;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use inssplat_proto::dataset::Scene;
use inssplat_proto::shape::LabelledDescriptor;
use inssplat_text::LabelCache;
use serde::Serialize;

use inssplat_pipeline::backend::Model;
use inssplat_pipeline::reconstruct::PipelineConfig;
pub use markdown::{markdown, sweep_markdown};
use perturb::most_repeated;
pub use perturb::{PerturbKind, Perturbation};
use progress::Progress;
pub use scene::EvalSwitches;
use scene::{SceneScores, Settings, evaluate_scene};
pub use views::ClusterMode;

/// Scene folders to evaluate: `path` itself if it is a scene, else its sub-folders that are.
pub fn scene_dirs(path: &Path) -> Result<Vec<PathBuf>> {
    if path.join("transforms.json").is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    let entries = std::fs::read_dir(path)
        .with_context(|| format!("--data {}: cannot read the folder", path.display()))?;
    let mut dirs: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("transforms.json").is_file())
        .collect();
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
    /// Per true label on the target views: named right, and named most often as.
    pub labels: Vec<confusion::LabelRow>,
    /// Query IoU per rule of [`query_rules::grid`], best first (with `--query-rules`).
    pub query_rules: Vec<query_rules::RuleRow>,
}

/// The whole evaluation.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub model_version: String,
    pub data: String,
    pub vocabulary: Vec<String>,
    pub cluster: ClusterMode,
    /// Weight of the Gaussians' positions beside their embeddings in 3D clustering.
    pub position_weight: f32,
    /// HDBSCAN's smallest cluster (share of the points it sees) and core neighbours, and the
    /// cosine a point needs to join a prototype (both modes).
    pub min_cluster_share: f32,
    pub min_samples: usize,
    pub min_cosine: f32,
    /// The stages swapped for the truth, the ablations and the protocol's options (their
    /// fields at the top level of the JSON).
    #[serde(flatten)]
    pub switches: EvalSwitches,
    /// Adam steps of test-time refinement of the Gaussians and context cameras (0: none).
    pub refine_steps: usize,
    pub summaries: Vec<Summary>,
    /// Every scene's [`SceneScores::shape_examples`] (the plain view-count runs).
    #[serde(skip)]
    pub shape_examples: Vec<LabelledDescriptor>,
    /// Robustness sweeps: metric means per perturbation and strength.
    pub robustness: Vec<RobustRow>,
    /// The worst scenes (with `--perturb`).
    pub failures: Vec<Failure>,
    pub scenes: Vec<SceneScores>,
    /// How target views were placed and what was aligned.
    pub protocol: String,
}

const METRICS: [&str; 24] = [
    "semantic_miou",
    "semantic_macc",
    "instance_miou",
    "instance_acc25",
    "instance_pq",
    "context_instance_miou",
    "context_ceiling_miou",
    "instances_found",
    "instances_true",
    "query_iou",
    "query_false_positive",
    "t_miou",
    "t_sr50",
    "psnr",
    "ssim",
    "depth_abs_rel",
    "depth_abs_rel_objects",
    "depth_abs_rel_shell",
    "rotation_deg",
    "translation",
    "photo_instance_miou",
    "photo_instance_miou_nearest",
    "photo_boundary_f",
    "photo_boundary_f_nearest",
];

fn metric(s: &SceneScores, name: &str) -> Option<f64> {
    match name {
        "semantic_miou" => s.semantic_miou,
        "semantic_macc" => s.semantic_macc,
        "instance_miou" => s.instance_miou,
        "instance_acc25" => s.instance_acc25,
        "instance_pq" => s.instance_pq,
        "context_instance_miou" => s.context_instance_miou,
        "context_ceiling_miou" => s.context_ceiling_miou,
        "instances_found" => Some(s.instances_found as f64),
        "instances_true" => Some(s.instances_true as f64),
        "query_iou" => s.query_iou,
        "query_false_positive" => s.query_false_positive,
        "t_miou" => s.t_miou,
        "t_sr50" => s.t_sr50,
        "psnr" => s.psnr,
        "ssim" => s.ssim,
        "depth_abs_rel" => s.depth_abs_rel,
        "depth_abs_rel_objects" => s.depth_abs_rel_objects,
        "depth_abs_rel_shell" => s.depth_abs_rel_shell,
        "rotation_deg" => s.rotation_deg,
        "translation" => s.translation,
        "photo_instance_miou" => s.photo_instance_miou,
        "photo_instance_miou_nearest" => s.photo_instance_miou_nearest,
        "photo_boundary_f" => s.photo_boundary_f,
        "photo_boundary_f_nearest" => s.photo_boundary_f_nearest,
        _ => None,
    }
}

/// The mean of `v`, `None` when it is empty.
fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

fn summarize(views: usize, scores: &[&SceneScores], vocabulary: &[String]) -> Summary {
    let metrics = METRICS
        .iter()
        .filter_map(|m| {
            let v: Vec<f64> =
                scores.iter().filter_map(|s| metric(s, m)).filter(|x| x.is_finite()).collect();
            Some((m.to_string(), (mean(&v)?, v.len())))
        })
        .collect();
    let mut secs: Vec<f64> = scores.iter().map(|s| s.seconds).collect();
    secs.sort_by(f64::total_cmp);
    let mut labels = confusion::Confusion::default();
    scores.iter().for_each(|s| labels.merge(&s.labels));
    Summary {
        views,
        scenes: scores.len(),
        metrics,
        seconds_median: secs.get(secs.len() / 2).copied().unwrap_or(f64::NAN),
        gaussians_kept_mean: scores.iter().map(|s| s.gaussians_kept as f64).sum::<f64>()
            / scores.len().max(1) as f64,
        labels: labels.rows(vocabulary),
        query_rules: query_rules::summarize(
            &scores.iter().map(|s| s.query_by_rule.as_slice()).collect::<Vec<_>>(),
        ),
    }
}

/// What to evaluate and how.
#[derive(Debug, Clone)]
pub struct EvalRequest {
    pub views: Vec<usize>,
    /// Labels added to the scenes' own.
    pub extra_vocab: Vec<String>,
    pub pipeline: PipelineConfig,
    pub cluster: ClusterMode,
    /// The stages swapped for the truth, the ablations and the protocol's options.
    pub switches: EvalSwitches,
    /// Score the text queries under every rule of [`query_rules::grid`] too.
    pub query_rules: bool,
    /// Context photos from this folder's scenes of the same names ([`photos`]).
    pub photos: Option<PathBuf>,
    /// Robustness sweeps to run (at [`EvalRequest::robust_views`] views).
    pub perturb: Vec<PerturbKind>,
    /// Where failure previews go (with `perturb`).
    pub out: Option<PathBuf>,
    /// Report progress on stderr ([`progress::Progress`]); off for the runs a sweep nests.
    pub progress: bool,
}

impl EvalRequest {
    /// The view count robustness is measured at: 8 if evaluated, else the first.
    pub fn robust_views(&self) -> usize {
        if self.views.contains(&8) { 8 } else { self.views[0] }
    }
}

/// One row of the robustness table.
#[derive(Debug, Clone, Serialize)]
pub struct RobustRow {
    pub kind: PerturbKind,
    pub strength: f32,
    pub summary: Summary,
}

/// A scene among the worst, with where its reconstruction was written.
#[derive(Debug, Clone, Serialize)]
pub struct Failure {
    pub scene: String,
    pub instance_miou: Option<f64>,
    pub semantic_miou: Option<f64>,
    pub preview: Option<PathBuf>,
}

/// Evaluates every scene in `dirs` at every requested view count, then the robustness sweeps.
pub fn evaluate(
    model: &mut Model,
    labels: &LabelCache,
    dirs: &[PathBuf],
    req: &EvalRequest,
) -> Result<Report> {
    let scenes: Vec<Scene> = dirs
        .iter()
        .map(|d| Scene::load(d).with_context(|| format!("loading {}", d.display())))
        .collect::<Result<_>>()?;
    let mut vocabulary: Vec<String> = scenes
        .iter()
        .flat_map(Scene::label_vocabulary)
        .chain(req.extra_vocab.iter().cloned())
        .collect();
    vocabulary.sort();
    vocabulary.dedup();
    let image_sweeps: Vec<Perturbation> = req
        .perturb
        .iter()
        .filter(|k| **k != PerturbKind::Repeats)
        .flat_map(|&kind| {
            kind.strengths().iter().map(move |&strength| Perturbation { kind, strength })
        })
        .collect();
    let runs = scenes.len() * (req.views.len() + image_sweeps.len());
    let bar = Progress::new("eval", runs as u64, req.progress);
    let rules = if req.query_rules { query_rules::grid() } else { Vec::new() };
    let run = |views: usize,
               perturbation: Option<Perturbation>,
               model: &mut Model|
     -> Result<Vec<SceneScores>> {
        let settings = Settings {
            vocabulary: &vocabulary,
            pipeline: &req.pipeline,
            cluster: req.cluster,
            perturbation,
            switches: req.switches,
            query_rules: &rules,
            photos: req.photos.as_deref(),
        };
        scenes
            .iter()
            .map(|scene| {
                bar.set_message(format!(
                    "{views} views{}, {}",
                    perturbation
                        .map_or(String::new(), |p| format!(", {:?} {}", p.kind, p.strength)),
                    scene.dir.display()
                ));
                let s = evaluate_scene(model, labels, scene, views, &settings)?;
                bar.inc();
                Ok(s)
            })
            .collect()
    };
    let mut all = Vec::new();
    for &v in &req.views {
        all.extend(run(v, None, model)?);
    }
    let rv = req.robust_views();
    let mut robustness = Vec::new();
    for p in &image_sweeps {
        let scores = run(rv, Some(*p), model)?;
        robustness.push(RobustRow {
            kind: p.kind,
            strength: p.strength,
            summary: summarize(rv, &scores.iter().collect::<Vec<_>>(), &vocabulary),
        });
    }
    bar.finish_and_clear();
    let at_rv: Vec<&SceneScores> = all.iter().filter(|s| s.views == rv).collect();
    let mut failures = Vec::new();
    if req.perturb.contains(&PerturbKind::Repeats) {
        for bucket in [1usize, 2, 3] {
            let group: Vec<&SceneScores> = at_rv
                .iter()
                .zip(&scenes)
                .filter(|(_, scene)| {
                    let r = most_repeated(scene);
                    if bucket == 3 { r >= 3 } else { r == bucket }
                })
                .map(|(s, _)| *s)
                .collect();
            if !group.is_empty() {
                robustness.push(RobustRow {
                    kind: PerturbKind::Repeats,
                    strength: bucket as f32,
                    summary: summarize(rv, &group, &vocabulary),
                });
            }
        }
    }
    if !req.perturb.is_empty() {
        failures = worst_scenes(model, labels, &scenes, &at_rv, &vocabulary, req)?;
    }
    let summaries = req
        .views
        .iter()
        .map(|&v| {
            summarize(v, &all.iter().filter(|s| s.views == v).collect::<Vec<_>>(), &vocabulary)
        })
        .collect();
    Ok(Report {
        model_version: model.network.model_version.clone(),
        data: dirs.first().and_then(|d| d.parent()).map_or_else(String::new, |p| p.display().to_string()),
        vocabulary,
        cluster: req.cluster,
        position_weight: req.pipeline.cluster.position_weight,
        min_cluster_share: req.pipeline.cluster.min_cluster_share,
        min_samples: req.pipeline.cluster.min_samples,
        min_cosine: req.pipeline.cluster.min_cosine,
        switches: req.switches,
        refine_steps: req.pipeline.refine_steps,
        summaries,
        shape_examples: all.iter_mut().flat_map(|s| std::mem::take(&mut s.shape_examples)).collect(),
        robustness,
        failures,
        scenes: all,
        protocol: format!(
            "context views reconstructed{}; instance mIoU per target view, pooled; predicted context cameras aligned to the true ones by the \
             similarity fitted to their orientations (chordal mean) and their centres, at the scale of the predicted depth (median ratio; the centres' least squares \
             with --known-poses); true target cameras mapped into the predicted frame and \
             the clustered scene rendered there{}{}; depth AbsRel (the network's) after median scale; {}{}{}{}{}",
            match (req.switches.known_poses, req.switches.known_depth) {
                (false, false) => "",
                (true, false) => " with the TRUE context cameras (--known-poses), not the predicted ones",
                (false, true) => " with the TRUE context depth (--known-depth), not the predicted one",
                (true, true) => " with the TRUE context cameras and depth (--known-poses --known-depth), not the predicted ones",
            },
            match req.switches.target_pose_steps {
                0 => String::new(),
                n => format!(
                    ", after TEST-TIME OPTIMIZATION of each target camera's pose against its photo (--target-pose-steps {n}: Adam on the pose, \
                     the Gaussians frozen, coarse to fine; kept only where it lowers the colour error)"
                ),
            },
            match req.switches.no_fill {
                true => "; the RAW renders scored (--no-fill): what no Gaussian covers black and without an instance",
                false => "; what no Gaussian covers there filled from around it (colours by push-pull, ids and labels from the nearest covered pixel)",
            },
            match req.pipeline.refine_steps {
                0 => "no test-time optimization of the Gaussians".to_string(),
                n => format!(
                    "TEST-TIME OPTIMIZATION of the Gaussians and context cameras against the context photos after clustering and naming \
                     (--refine-steps {n}: Adam, one view a step, the first camera fixed)"
                ),
            },
            match (&req.pipeline.register, req.switches.known_poses) {
                (_, true) => "",
                (Some(p), false) if p.estimate_focal => "; cameras registered from keypoint matches and the predicted depth, with one focal length measured from the matches where they pin it down, else the camera head's (stage `register`)",
                (Some(_), false) => "; cameras registered from keypoint matches and the predicted depth, at the camera head's field of view (stage `register`, --keep-focal)",
                (None, false) => "; the camera head's poses as they are (--no-register)",
            },
            match (&req.pipeline.register, &req.pipeline.heading, req.switches.known_poses) {
                (Some(_), Some(h), false) => format!(
                    "; the views no match links turned to the best of {} headings against the views placed before them (stage `heading`)",
                    h.candidates
                ),
                (Some(_), None, false) => "; the views no match links kept where the camera's motion continues (--heading-candidates 0)".to_string(),
                _ => String::new(),
            },
            match (model.network.rays, req.switches.known_poses, req.pipeline.ray_pass) {
                (None, _, _) => "",
                (Some(_), true, _) => "; the network given the true context cameras as rays (over the context frames' median true depth)",
                (Some(_), false, true) => "; the network run first with zero camera rays, then again on the registered cameras' rays for the instance and semantic features (stage `rays`)",
                (Some(_), false, false) => "; the network run once, with zero camera rays (--no-ray-pass)",
            },
            match req.switches.known_names {
                true => "; every found instance NAMED WITH THE TRUE LABEL most of its context pixels carry (--known-names), not the classifier's",
                false => "",
            }
        ),
    })
}

/// The five scenes with the lowest instance mIoU at the robustness view count; their
/// reconstructions (with `preview.png`) go to `OUT/failures/<scene>/` when `out` is set.
fn worst_scenes(
    model: &mut Model,
    labels: &LabelCache,
    scenes: &[Scene],
    scores: &[&SceneScores],
    vocabulary: &[String],
    req: &EvalRequest,
) -> Result<Vec<Failure>> {
    let mut order: Vec<usize> = (0..scores.len()).collect();
    order.sort_by(|&a, &b| {
        scores[a].instance_miou.unwrap_or(0.0).total_cmp(&scores[b].instance_miou.unwrap_or(0.0))
    });
    order
        .into_iter()
        .take(5)
        .map(|i| {
            let preview = match &req.out {
                Some(out) => {
                    let dir = out.join("failures").join(&scores[i].scene);
                    let (rec, photos) = scene::reconstruct_context(
                        model,
                        labels,
                        &scenes[i],
                        req.robust_views(),
                        vocabulary,
                        &req.pipeline,
                    )?;
                    inssplat_pipeline::output::write_reconstruction(&rec, &photos, &dir)?;
                    Some(dir.join("preview.png"))
                }
                None => None,
            };
            Ok(Failure {
                scene: scores[i].scene.clone(),
                instance_miou: scores[i].instance_miou,
                semantic_miou: scores[i].semantic_miou,
                preview,
            })
        })
        .collect()
}

/// Runs the sweep grid over `req.views` (each configuration a full evaluation of `dirs`),
/// marks the Pareto fronts and draws the chart into `out`.
pub fn run_sweep(
    model: &mut Model,
    labels: &LabelCache,
    dirs: &[PathBuf],
    req: &EvalRequest,
    out: &Path,
) -> Result<Vec<sweep::SweepPoint>> {
    let grid = sweep::grid(&req.views);
    let bar = Progress::new("sweep", grid.len() as u64, req.progress);
    let mut points = Vec::with_capacity(grid.len());
    for knobs in grid {
        bar.set_message(knobs.label());
        let mut pipeline = req.pipeline.clone();
        pipeline.voxel.extent_fraction = knobs.voxel_fraction;
        pipeline.cluster.max_samples = knobs.cluster_samples;
        let one = EvalRequest {
            views: vec![knobs.views],
            pipeline,
            perturb: Vec::new(),
            progress: false,
            ..req.clone()
        };
        let report = evaluate(model, labels, dirs, &one)?;
        let s = &report.summaries[0];
        points.push(sweep::SweepPoint {
            knobs,
            seconds: s.seconds_median,
            instance_miou: s.metrics.get("instance_miou").map(|m| m.0),
            psnr: s.metrics.get("psnr").map(|m| m.0),
            pareto_instance: false,
            pareto_psnr: false,
        });
        bar.inc();
    }
    bar.finish_and_clear();
    sweep::mark_pareto(&mut points);
    std::fs::create_dir_all(out)
        .with_context(|| format!("--out: cannot create {}", out.display()))?;
    sweep::chart(&points, out)?;
    Ok(points)
}
