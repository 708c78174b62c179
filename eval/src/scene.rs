//! One scene at one view count, scored by the protocol of docs/EVALUATION.md: reconstruct from the
//! scene's context views, align the predicted cameras to the true ones (the similarity fitted to
//! their orientations and centres, [`inssplat_metrics::pose::pose_alignment`], with the
//! scale of the predicted depth: its median ratio to the true depth, which the centres of
//! cameras turning nearly on the spot do not fix), render the clustered scene at every target
//! camera mapped into the predicted frame, and compare with the ground truth. With the true
//! cameras (`--known-poses`) the frame is the true one and the centres' scale (1) is kept.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

use image::RgbImage;
use inssplat_metrics::image::{depth_abs_rel, depth_abs_rel_where};
use inssplat_metrics::pose::AlignScale;
use inssplat_metrics::segmentation::consistency_scores;
use inssplat_proto::dataset::Scene;
use inssplat_proto::shape::LabelledDescriptor;
use inssplat_raster::masks::NO_LABEL;
use inssplat_text::LabelCache;
use inssplat_understand::label::QueryRule;
use serde::Serialize;

use super::ceiling::{ContextView, context_instances};
use super::confusion::Confusion;
use super::perturb::{self, Perturbation};
use super::photos::{photo_images, photo_mask_scores};
use super::query_rules::QueryScores;
use super::targets::{align_cameras, target_scores};
use super::views::{ClusterMode, segment};
use inssplat_pipeline::backend::Model;
use inssplat_pipeline::output::png_bytes;
use inssplat_pipeline::reconstruct::{
    InputImage, Known, PipelineConfig, Reconstruction, reconstruct,
};

/// Every number of one (scene, view count); `None` where the scene cannot give it.
#[derive(Debug, Clone, Default, Serialize)]
pub struct SceneScores {
    pub scene: String,
    pub views: usize,
    pub semantic_miou: Option<f64>,
    pub semantic_macc: Option<f64>,
    pub instance_miou: Option<f64>,
    pub instance_acc25: Option<f64>,
    /// Panoptic quality of the target views' instance maps, their counts pooled
    /// ([`InstancePool`]): charges the pieces mIoU forgives.
    pub instance_pq: Option<f64>,
    /// Instance mIoU of the clustering on the context views, and the ceiling its embeddings
    /// allow there ([`super::ceiling`]; 3D clustering only).
    pub context_instance_miou: Option<f64>,
    pub context_ceiling_miou: Option<f64>,
    pub query_iou: Option<f64>,
    /// Share of queries for labels the scene lacks (the room shell aside) that returned an
    /// instance ([`super::query_rules::QueryScores::false_positive`]).
    pub query_false_positive: Option<f64>,
    pub t_miou: Option<f64>,
    pub t_sr50: Option<f64>,
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    pub depth_abs_rel: Option<f64>,
    /// Depth AbsRel, at the whole views' scale, on the pixels of objects and on those of the
    /// room shell (walls, floor, ceiling and unlabelled pixels), when every context view with
    /// depth has instances.
    pub depth_abs_rel_objects: Option<f64>,
    pub depth_abs_rel_shell: Option<f64>,
    pub rotation_deg: Option<f64>,
    pub translation: Option<f64>,
    /// With `--photos`: the context views' instance mIoU and boundary F-score at the photos'
    /// resolution, as upsampled along the photos' edges and as sampled at the nearest model
    /// pixel ([`super::photos::photo_mask_scores`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub photo_instance_miou: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub photo_instance_miou_nearest: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub photo_boundary_f: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub photo_boundary_f_nearest: Option<f64>,
    /// Mean angle by which `--target-pose-steps` turned the target cameras (degrees).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_pose_turn_deg: Option<f64>,
    /// PSNR of the input views rendered from the scene before and after `--refine-steps`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refine_context_psnr: Option<[f64; 2]>,
    pub gaussians_in: usize,
    pub gaussians_kept: usize,
    pub instances_found: usize,
    pub instances_true: usize,
    /// Reconstruction wall time (all stages), seconds.
    pub seconds: f64,
    pub stage_ms: BTreeMap<String, f64>,
    /// Target-view pixels per (true, predicted) label, summed into [`super::Summary::labels`].
    #[serde(skip)]
    pub labels: Confusion,
    /// Each found instance's shape descriptor with its true label ([`shape_examples`]), for
    /// `inssplat-train fit-shapes --examples`.
    #[serde(skip)]
    pub shape_examples: Vec<LabelledDescriptor>,
    /// The queries under each of [`Settings::query_rules`].
    #[serde(skip)]
    pub query_by_rule: Vec<QueryScores>,
}

/// Why a scene could not be evaluated.
#[derive(Debug, thiserror::Error)]
pub enum SceneEvalError {
    #[error("{scene}: {problem}")]
    Scene { scene: String, problem: String },
    #[error("{scene}: {source}")]
    Pipeline { scene: String, source: inssplat_pipeline::reconstruct::PipelineError },
}

/// Ground-truth label map of a frame: vocabulary index of each pixel's instance label.
pub(crate) fn true_labels(scene: &Scene, ids: &[u16], vocabulary: &[String]) -> Vec<u32> {
    let mut memo: BTreeMap<u16, u32> = BTreeMap::new();
    ids.iter()
        .map(|&id| {
            *memo.entry(id).or_insert_with(|| {
                if id == 0 {
                    return NO_LABEL;
                }
                scene
                    .label_of(id)
                    .and_then(|l| vocabulary.iter().position(|v| v == l))
                    .map_or(NO_LABEL, |i| i as u32)
            })
        })
        .collect()
}

/// What an evaluation swaps for the truth, leaves out or adds to the protocol; recorded in
/// the report as it was run (`inssplat-eval score`'s switches of the same names).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct EvalSwitches {
    /// Reconstruct with the true context cameras instead of the predicted ones: what the rest
    /// of the network achieves when the camera head is taken out of the question.
    pub known_poses: bool,
    /// Reconstruct with the context frames' true depth instead of the depth head's: what the
    /// rest of the network achieves when its depth is taken out of the question.
    pub known_depth: bool,
    /// Name every found instance with the true label most of its context pixels carry, the
    /// unlabelled shell's pixels voting as one (3D clustering): what the semantic scores
    /// would be with perfect naming of these instances.
    pub known_names: bool,
    /// Name pixels from their own semantic features instead of their instance's prototype
    /// (the "no instance-grounded aggregation" ablation; instances and queries unchanged).
    pub no_aggregation: bool,
    /// Score the target views' raw renders: what no Gaussian covers left black and without an
    /// instance, instead of filled from around it ([`inssplat_raster::fill`]), as a new
    /// view's render is.
    pub no_fill: bool,
    /// Adam steps of test-time refinement of each target camera's pose against its photo, the
    /// Gaussians frozen ([`inssplat_geometry::target_pose`]; 0 scores at the mapped camera, the
    /// protocol's default).
    pub target_pose_steps: usize,
}

/// How each scene is evaluated.
pub struct Settings<'a> {
    pub vocabulary: &'a [String],
    pub pipeline: &'a PipelineConfig,
    pub cluster: ClusterMode,
    pub perturbation: Option<Perturbation>,
    /// The stages swapped for the truth, the ablations and the protocol's options.
    pub switches: EvalSwitches,
    /// Query rules scored beside the default one (`--query-rules`).
    pub query_rules: &'a [QueryRule],
    /// Take the context photos from the scenes of this folder that have the same names
    /// (`--photos`, [`super::photos`]).
    pub photos: Option<&'a Path>,
}

/// The context frames of `scene` for `views` views (after an overlap perturbation), checked.
fn context_frames(
    scene: &Scene,
    views: usize,
    perturbation: Option<Perturbation>,
    resolution: usize,
) -> Result<Vec<usize>, String> {
    let eval = scene
        .eval
        .as_ref()
        .ok_or("transforms.json has no `eval` split (synthesize with --split test)")?;
    let context = eval
        .context_for(views)
        .ok_or_else(|| format!("no {views}-view context set in `eval.context`"))?;
    let res = resolution as u32;
    if scene.frames.iter().any(|f| f.width() != res || f.height() != res) {
        return Err(format!(
            "frames must be {res}×{res}, the model resolution (synthesize with --size {res})"
        ));
    }
    Ok(match perturbation {
        Some(p) => p.context(context, &eval.target, scene.frames.len(), views),
        None => context.to_vec(),
    })
}

/// The frames `context` of `scene` (perturbed if asked) as PNG-encoded photos.
pub fn context_images(
    scene: &Scene,
    context: &[usize],
    perturbation: Option<Perturbation>,
) -> Vec<InputImage> {
    let name = scene.name();
    context
        .iter()
        .map(|&i| {
            let frame = &scene.frames[i];
            let mut rgb = frame.rgb.clone();
            if let Some(p) = perturbation {
                p.apply(
                    &mut rgb,
                    frame.width() as usize,
                    frame.height() as usize,
                    perturb::seed(&name, i),
                );
            }
            let img =
                RgbImage::from_raw(frame.width(), frame.height(), rgb).expect("frame rgb is w·h·3");
            InputImage { name: format!("{name}/frame {i}"), bytes: png_bytes(&img) }
        })
        .collect()
}

/// Reconstructs `scene` from its `views`-view context set (for failure previews).
pub fn reconstruct_context(
    model: &mut Model,
    labels: &LabelCache,
    scene: &Scene,
    views: usize,
    vocabulary: &[String],
    config: &PipelineConfig,
) -> anyhow::Result<(Reconstruction, Vec<InputImage>)> {
    let context =
        context_frames(scene, views, None, model.network.resolution).map_err(anyhow::Error::msg)?;
    let images = context_images(scene, &context, None);
    Ok((reconstruct(model, labels, &images, vocabulary, config)?, images))
}

/// Scores `scene` reconstructed from its `views`-view context set.
pub fn evaluate_scene(
    model: &mut Model,
    labels: &LabelCache,
    scene: &Scene,
    views: usize,
    settings: &Settings<'_>,
) -> Result<SceneScores, SceneEvalError> {
    evaluate_scene_keeping(model, labels, scene, views, settings).map(|(scores, _, _)| scores)
}

/// [`evaluate_scene`], also returning the reconstruction and its input photos (a batch job
/// keeps it as the scene's result).
pub fn evaluate_scene_keeping(
    model: &mut Model,
    labels: &LabelCache,
    scene: &Scene,
    views: usize,
    settings: &Settings<'_>,
) -> Result<(SceneScores, Reconstruction, Vec<InputImage>), SceneEvalError> {
    let name = scene.name();
    let bad = |problem: String| SceneEvalError::Scene { scene: name.clone(), problem };
    let context = context_frames(scene, views, settings.perturbation, model.network.resolution)
        .map_err(&bad)?;
    let images = match settings.photos {
        Some(dir) => photo_images(dir, scene, &context).map_err(&bad)?,
        None => context_images(scene, &context, settings.perturbation),
    };
    let known;
    let pipeline = if settings.switches.known_poses || settings.switches.known_depth {
        let poses = settings
            .switches
            .known_poses
            .then(|| context.iter().map(|&i| scene.frames[i].camera).collect());
        let depth = match settings.switches.known_depth {
            false => None,
            true => Some(
                context
                    .iter()
                    .map(|&i| {
                        scene.frames[i].depth.as_deref().ok_or_else(|| {
                            bad(format!("frame {i} has no depth (--known-depth needs it)"))
                        })
                    })
                    .collect::<Result<Vec<_>, _>>()?
                    .concat(),
            ),
        };
        let median_depth = match (settings.switches.known_poses, model.network.rays) {
            (true, Some(_)) => Some(median_true_depth(scene, &context).ok_or_else(|| bad("the context frames have no depth (a network that reads camera rays needs the scene's scale with --known-poses)".into()))?),
            _ => None,
        };
        known = PipelineConfig {
            known: Known { poses, depth, median_depth },
            ..settings.pipeline.clone()
        };
        &known
    } else {
        settings.pipeline
    };
    let start = Instant::now();
    let mut rec = reconstruct(model, labels, &images, settings.vocabulary, pipeline)
        .map_err(|source| SceneEvalError::Pipeline { scene: name.clone(), source })?;
    let seconds = start.elapsed().as_secs_f64();
    if settings.switches.known_names {
        name_by_truth(&mut rec, scene, &context);
    }
    let targets = scene.eval.as_ref().map(|e| e.target.clone()).unwrap_or_default();
    let mut s = SceneScores {
        scene: name.clone(),
        views,
        gaussians_in: rec.voxel.gaussians_in,
        gaussians_kept: rec.voxel.gaussians_out,
        instances_found: rec.instances.len(),
        instances_true: scene.instances.len(),
        seconds,
        stage_ms: rec.timings.iter().map(|t| (t.stage.clone(), t.ms)).collect(),
        refine_context_psnr: rec.refinement.as_ref().map(|r| r.psnr()),
        ..SceneScores::default()
    };
    if let Some(dir) = settings.photos
        && let Some(p) = photo_mask_scores(dir, &name, &context, &rec).map_err(&bad)?
    {
        (s.photo_instance_miou, s.photo_instance_miou_nearest) = (Some(p.miou.0), Some(p.miou.1));
        (s.photo_boundary_f, s.photo_boundary_f_nearest) =
            (Some(p.boundary_f.0), Some(p.boundary_f.1));
    }
    let depth_scale =
        context_scores(&mut s, scene, &context, &rec, labels, settings).map_err(&bad)?;
    let scale = match depth_scale {
        Some(d) if !settings.switches.known_poses => AlignScale::Fixed(d),
        _ => AlignScale::Centres,
    };
    if let Some(to_pred) = align_cameras(&mut s, scene, &context, &rec, scale).map_err(&bad)? {
        target_scores(&mut s, scene, &targets, &rec, labels, settings, &to_pred).map_err(&bad)?;
    }
    Ok((s, rec, images))
}

/// The median of the true depth over the surface pixels of the `context` frames, the scale
/// the trainer divides camera rays by.
fn median_true_depth(scene: &Scene, context: &[usize]) -> Option<f32> {
    let depth: Vec<f32> = context
        .iter()
        .filter_map(|&i| scene.frames[i].depth.as_deref())
        .flatten()
        .copied()
        .collect();
    inssplat_proto::rays::median_depth(&depth)
}

/// Depth, cameras and cross-view consistency on the context views (in 2D mode each view's
/// ids are its own, kept distinct from other views'); returns the depth's median scale (true /
/// predicted), when the frames have depth.
fn context_scores(
    s: &mut SceneScores,
    scene: &Scene,
    context: &[usize],
    rec: &Reconstruction,
    labels: &LabelCache,
    settings: &Settings<'_>,
) -> Result<Option<f64>, String> {
    let mode = settings.cluster;
    let err = |e: &dyn std::fmt::Display| e.to_string();
    let (mut pred_depth, mut true_depth) = (Vec::new(), Vec::new());
    let mut pairs: Vec<(Vec<u32>, Vec<u32>)> = Vec::new();
    let texts = match mode {
        ClusterMode::ThreeD => Vec::new(),
        ClusterMode::TwoD => labels
            .embed(&rec.vocabulary.iter().map(String::as_str).collect::<Vec<_>>())
            .map_err(|e| err(&e))?,
    };
    // Per depth pixel: whether it shows an object (`None` once a view with depth has no ids).
    let mut objects = Some(Vec::new());
    for (v, (view, &f)) in rec.views.iter().zip(context).enumerate() {
        let frame = &scene.frames[f];
        if let Some(d) = &frame.depth {
            pred_depth.extend_from_slice(&view.depth);
            true_depth.extend_from_slice(d);
            objects = objects.zip(frame.instances.as_ref()).map(|(mut o, ids)| {
                o.extend(
                    ids.iter().map(|&id| scene.label_of(id).is_some_and(|l| !SHELL.contains(&l))),
                );
                o
            });
        }
        if let Some(ids) = &frame.instances {
            let pred = match mode {
                ClusterMode::ThreeD => view.instance_ids.clone(),
                ClusterMode::TwoD => {
                    let seg = segment(rec, &view.camera, mode, &texts, &settings.pipeline.cluster)?;
                    let offset = (v as u32 + 1) << 16;
                    seg.ids.iter().map(|&i| if i == 0 { 0 } else { i + offset }).collect()
                }
            };
            pairs.push((pred, ids.iter().map(|&i| u32::from(i)).collect()));
        }
    }
    let depth = depth_abs_rel(&pred_depth, &true_depth).map_err(|e| err(&e))?;
    s.depth_abs_rel = depth.as_ref().map(|d| d.abs_rel);
    if let (Some(d), Some(objects)) = (&depth, &objects) {
        let shell: Vec<bool> = objects.iter().map(|o| !o).collect();
        s.depth_abs_rel_objects =
            depth_abs_rel_where(&pred_depth, &true_depth, d.scale, objects).map_err(|e| err(&e))?;
        s.depth_abs_rel_shell =
            depth_abs_rel_where(&pred_depth, &true_depth, d.scale, &shell).map_err(|e| err(&e))?;
    }
    let pairs: Vec<(&[u32], &[u32])> =
        pairs.iter().map(|(p, g)| (p.as_slice(), g.as_slice())).collect();
    if mode == ClusterMode::ThreeD {
        s.shape_examples = shape_examples(scene, rec, &pairs);
    }
    if mode == ClusterMode::ThreeD && pairs.len() == rec.views.len() {
        let views: Vec<ContextView<'_>> = rec
            .views
            .iter()
            .zip(&pairs)
            .map(|(v, (ids, truth))| ContextView { gaussians: &v.gaussians, ids, truth })
            .collect();
        if let Some((clustered, ceiling)) =
            context_instances(&rec.scene.instance_embedding, &views).map_err(|e| err(&e))?
        {
            s.context_instance_miou = Some(clustered);
            s.context_ceiling_miou = Some(ceiling);
        }
    }
    if let Some(c) = consistency_scores(&pairs).map_err(|e| err(&e))? {
        s.t_miou = Some(c.t_miou);
        s.t_sr50 = Some(c.t_sr);
    }
    Ok(depth.map(|d| d.scale))
}

/// Labels of the room shell, which an instance is named for only when they hold most of it
/// and objects hold under [`OBJECT_SHARE`] of its labelled pixels.
pub(crate) const SHELL: [&str; 3] = ["wall", "floor", "ceiling"];
/// Share of an instance's labelled context pixels an object needs to name it.
const OBJECT_SHARE: f64 = 0.25;

/// The true label of each found instance (`pairs` of found and true id maps of the context
/// views): the label with the most of its pixels, or with `object_first`, the object label with
/// the most when objects hold at least [`OBJECT_SHARE`] of its labelled pixels (clusters that
/// hold an object and a piece of floor are named for the object, as a user would).
/// Instances without labelled pixels are left out.
fn true_instance_labels<'s>(
    label_of: impl Fn(u16) -> Option<&'s str>,
    pairs: &[(&[u32], &[u32])],
    object_first: bool,
) -> BTreeMap<u32, &'s str> {
    let mut votes: BTreeMap<u32, BTreeMap<&str, usize>> = BTreeMap::new();
    for (found, truth) in pairs {
        for (&f, &t) in found.iter().zip(*truth) {
            if let (true, Some(label)) = (f > 0, label_of(t as u16)) {
                *votes.entry(f).or_default().entry(label).or_default() += 1;
            }
        }
    }
    let top = |it: &mut dyn Iterator<Item = (&&'s str, &usize)>| {
        it.max_by_key(|(_, n)| **n).map(|(l, _)| *l)
    };
    votes
        .iter()
        .filter_map(|(&id, v)| {
            let total: usize = v.values().sum();
            let objects: usize = v.iter().filter(|(l, _)| !SHELL.contains(l)).map(|(_, n)| n).sum();
            let label = if object_first && objects as f64 >= OBJECT_SHARE * total as f64 {
                top(&mut v.iter().filter(|(l, _)| !SHELL.contains(l)))
            } else {
                top(&mut v.iter())
            }?;
            Some((id, label))
        })
        .collect()
}

/// Each found instance with its true label ([`true_instance_labels`], objects first) and its
/// descriptor. Where a scene leaves the shell unlabelled (val and test), its pixels vote as
/// `wall` ([`truth_label`]), so that an instance of shell with a lamp's edge in it is labelled
/// as in a train room, where the shell has labels: the shell's, unless objects hold a quarter
/// of it. The prototype is the unfused one (as a semantic classifier reads it), whatever
/// `--shape-weight` named the instances with.
fn shape_examples(
    scene: &Scene,
    rec: &Reconstruction,
    pairs: &[(&[u32], &[u32])],
) -> Vec<LabelledDescriptor> {
    let labels = true_instance_labels(|id| truth_label(scene, id), pairs, true);
    rec.descriptors
        .iter()
        .filter_map(|(id, d)| {
            let label = labels.get(id)?.to_string();
            let prototype = rec
                .unfused_prototypes
                .iter()
                .find(|p| p.id == *id)
                .map(|p| p.embedding.clone())
                .unwrap_or_default();
            Some(LabelledDescriptor { label, descriptor: *d, prototype, scene: scene.name() })
        })
        .collect()
}

/// Names every found instance with the true label most of its context pixels carry
/// ([`true_instance_labels`]), for `--known-names`: what the semantic scores would be if naming
/// were perfect and the instances what they are. Where a scene leaves the room's shell
/// unlabelled (id 0, as val and test scenes do), those pixels vote for `wall`, so that an
/// instance mostly of floor with a rug's edge in it is named for the shell, as a perfect namer
/// would, not for the rug that alone of its pixels is scored. Instances without any voting
/// pixel keep their name.
fn name_by_truth(rec: &mut Reconstruction, scene: &Scene, context: &[usize]) {
    let pairs: Vec<(&[u32], Vec<u32>)> = rec
        .views
        .iter()
        .zip(context)
        .filter_map(|(view, &f)| {
            Some((
                view.instance_ids.as_slice(),
                scene.frames[f].instances.as_ref()?.iter().map(|&i| u32::from(i)).collect(),
            ))
        })
        .collect();
    let pairs: Vec<(&[u32], &[u32])> = pairs.iter().map(|(p, t)| (*p, t.as_slice())).collect();
    let labels = true_instance_labels(|id| truth_label(scene, id), &pairs, false);
    for instance in &mut rec.instances {
        if let Some(label) = labels.get(&instance.id) {
            instance.label = (*label).to_string();
        }
    }
}

/// The true label of ground-truth id `id` for [`name_by_truth`] and [`shape_examples`]: `wall`
/// for id 0 (the shell a val or test scene leaves unlabelled, and nothing else: a room's every
/// pixel is shell or object), else the scene's label of it.
fn truth_label(scene: &Scene, id: u16) -> Option<&str> {
    if id == 0 { Some(SHELL[0]) } else { scene.label_of(id) }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An instance is named for what holds the most of its pixels, or objects first, for the
    /// object that holds the most once objects hold a quarter of them; unlabelled pixels and
    /// the background (found id 0) do not vote, and an instance with no labelled pixel gets no
    /// name.
    #[test]
    fn instances_are_named_by_their_pixels_majority_or_objects_first() {
        let label_of = |id: u16| match id {
            1 => Some("floor"),
            2 => Some("chair"),
            3 => Some("table"),
            _ => None,
        };
        // Found 7: 6 floor, 2 chair (a quarter), 1 unlabelled. Found 8: 7 floor, 2 table (under
        // a quarter). Found 9: 2 chair, 3 table. Found 10: unlabelled only. Found 0: background.
        let found = [7, 7, 7, 7, 7, 7, 7, 7, 7, 8, 8, 8, 8, 8, 8, 8, 8, 8, 9, 9, 9, 9, 9, 10, 0];
        let truth = [1, 1, 1, 1, 1, 1, 2, 2, 0, 1, 1, 1, 1, 1, 1, 1, 3, 3, 2, 2, 3, 3, 3, 0, 2];
        let pairs = [(&found[..], &truth[..])];
        assert_eq!(
            true_instance_labels(label_of, &pairs, true),
            BTreeMap::from([(7, "chair"), (8, "floor"), (9, "table")])
        );
        assert_eq!(
            true_instance_labels(label_of, &pairs, false),
            BTreeMap::from([(7, "floor"), (8, "floor"), (9, "table")])
        );
    }

    /// Where the shell is left unlabelled (id 0), `--known-names` counts its pixels as the
    /// shell's: an instance of 5 shell pixels and 3 rug pixels is named for the shell, not for
    /// the rug, the one part of it that a val or test scene labels. The classifier's examples
    /// count them too, objects first.
    #[test]
    fn known_names_count_the_unlabelled_shell() {
        use inssplat_proto::dataset::InstanceLabel;
        let scene = Scene {
            dir: Default::default(),
            instances: vec![InstanceLabel { id: 4, label: "rug".into() }],
            frames: Vec::new(),
            eval: None,
            depth_unit_m: 0.001,
        };
        let found = [3, 3, 3, 3, 3, 3, 3, 3, 5, 5];
        let truth = [0, 0, 0, 0, 0, 4, 4, 4, 4, 9];
        let labels =
            true_instance_labels(|id| truth_label(&scene, id), &[(&found[..], &truth[..])], false);
        assert_eq!(labels, BTreeMap::from([(3, "wall"), (5, "rug")]));
        // The classifier's examples put objects first: 3 rug pixels of 8 (over a quarter) name
        // instance 3 for the rug, and 1 of 6 leaves instance 6 the shell's.
        let found = [3, 3, 3, 3, 3, 3, 3, 3, 6, 6, 6, 6, 6, 6];
        let truth = [0, 0, 0, 0, 0, 4, 4, 4, 0, 0, 0, 0, 0, 4];
        let labels =
            true_instance_labels(|id| truth_label(&scene, id), &[(&found[..], &truth[..])], true);
        assert_eq!(labels, BTreeMap::from([(3, "rug"), (6, "wall")]));
    }
}
