//! One scene at one view count, scored by the DESIGN.md protocol: reconstruct from the
//! scene's context views, align the predicted cameras to the true ones (Umeyama on the camera
//! centres, or view 0 where the centres cannot fix a similarity), render the clustered scene at
//! every target camera mapped into the predicted frame, and compare with the ground truth.

use std::collections::BTreeMap;
use std::io::Cursor;
use std::time::Instant;

use image::{ImageFormat, RgbImage};
use inssplat_proto::dataset::{Frame, Scene};
use inssplat_raster::label::masks::{ids_mask, label_map, render_colour, render_instance_ids};
use inssplat_raster::label::{QueryRule, query};
use inssplat_raster::metrics::image::{depth_abs_rel, psnr, ssim};
use inssplat_raster::metrics::pose::camera_errors;
use inssplat_raster::metrics::segmentation::{NO_LABEL, consistency_scores, instance_scores, mask_iou, semantic_scores};
use inssplat_text::LabelCache;
use serde::Serialize;

use crate::pipeline::reconstruct::{InputImage, PipelineConfig, Reconstruction, reconstruct};
use crate::runtime::Model;

/// Every number of one (scene, view count); `None` where the scene cannot give it.
#[derive(Debug, Clone, Default, Serialize)]
pub struct SceneScores {
    pub scene: String,
    pub views: usize,
    pub semantic_miou: Option<f64>,
    pub semantic_macc: Option<f64>,
    pub instance_miou: Option<f64>,
    pub instance_acc25: Option<f64>,
    pub query_iou: Option<f64>,
    pub t_miou: Option<f64>,
    pub t_sr50: Option<f64>,
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    pub depth_abs_rel: Option<f64>,
    pub rotation_deg: Option<f64>,
    pub translation: Option<f64>,
    /// "umeyama" or "view 0" (see the module docs).
    pub alignment: String,
    pub gaussians_in: usize,
    pub gaussians_kept: usize,
    pub instances_found: usize,
    pub instances_true: usize,
    /// Reconstruction wall time (all stages), seconds.
    pub seconds: f64,
    pub stage_ms: BTreeMap<String, f64>,
}

/// Why a scene could not be evaluated.
#[derive(Debug, thiserror::Error)]
pub enum SceneEvalError {
    #[error("{scene}: {problem}")]
    Scene { scene: String, problem: String },
    #[error("{scene}: {source}")]
    Pipeline { scene: String, source: crate::pipeline::reconstruct::PipelineError },
}

fn png(frame: &Frame) -> Vec<u8> {
    let img = RgbImage::from_raw(frame.width(), frame.height(), frame.rgb.clone()).expect("frame rgb is w·h·3");
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, ImageFormat::Png).expect("PNG encoding to memory");
    out.into_inner()
}

/// Ground-truth label map of a frame: vocabulary index of each pixel's instance label.
fn true_labels(scene: &Scene, ids: &[u16], vocabulary: &[String]) -> Vec<u32> {
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

/// Scores `scene` reconstructed from its `views`-view context set.
pub fn evaluate_scene(
    model: &mut Model,
    labels: &LabelCache,
    scene: &Scene,
    views: usize,
    vocabulary: &[String],
    config: &PipelineConfig,
) -> Result<SceneScores, SceneEvalError> {
    let name = scene.dir.file_name().map_or_else(|| scene.dir.display().to_string(), |n| n.to_string_lossy().into_owned());
    let bad = |problem: String| SceneEvalError::Scene { scene: name.clone(), problem };
    let eval = scene.eval.as_ref().ok_or_else(|| bad("transforms.json has no `eval` split (synthesize with --split test)".into()))?;
    let context = eval.context_for(views).ok_or_else(|| bad(format!("no {views}-view context set in `eval.context`")))?;
    let res = model.resolution as u32;
    if scene.frames.iter().any(|f| f.width() != res || f.height() != res) {
        return Err(bad(format!("frames must be {res}×{res}, the model resolution (synthesize with --size {res})")));
    }
    let images: Vec<InputImage> =
        context.iter().map(|&i| InputImage { name: format!("{name}/frame {i}"), bytes: png(&scene.frames[i]) }).collect();
    let start = Instant::now();
    let rec = reconstruct(model, labels, &images, vocabulary, config)
        .map_err(|source| SceneEvalError::Pipeline { scene: name.clone(), source })?;
    let seconds = start.elapsed().as_secs_f64();
    let mut s = SceneScores {
        scene: name.clone(),
        views,
        gaussians_in: rec.voxel.gaussians_in,
        gaussians_kept: rec.voxel.gaussians_out,
        instances_found: rec.instances.len(),
        instances_true: scene.instances.len(),
        seconds,
        stage_ms: rec.timings.iter().map(|t| (t.stage.clone(), t.ms)).collect(),
        ..SceneScores::default()
    };
    context_scores(&mut s, scene, context, &rec).map_err(|e| bad(e))?;
    target_scores(&mut s, scene, context, &eval.target, &rec, labels).map_err(|e| bad(e))?;
    Ok(s)
}

/// Depth, cameras and cross-view consistency on the context views.
fn context_scores(s: &mut SceneScores, scene: &Scene, context: &[usize], rec: &Reconstruction) -> Result<(), String> {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    let (mut pred_depth, mut true_depth) = (Vec::new(), Vec::new());
    let mut pairs: Vec<(&[u32], Vec<u32>)> = Vec::new();
    for (view, &f) in rec.views.iter().zip(context) {
        let frame = &scene.frames[f];
        if let Some(d) = &frame.depth {
            pred_depth.extend_from_slice(&view.depth);
            true_depth.extend_from_slice(d);
        }
        if let Some(ids) = &frame.instances {
            pairs.push((&view.instance_ids, ids.iter().map(|&i| u32::from(i)).collect()));
        }
    }
    s.depth_abs_rel = depth_abs_rel(&pred_depth, &true_depth).map_err(|e| err(&e))?.map(|d| d.abs_rel);
    let pairs: Vec<(&[u32], &[u32])> = pairs.iter().map(|(p, g)| (*p, g.as_slice())).collect();
    if let Some(c) = consistency_scores(&pairs).map_err(|e| err(&e))? {
        s.t_miou = Some(c.t_miou);
        s.t_sr50 = Some(c.t_sr);
    }
    Ok(())
}

/// Novel-view semantic, instance and query scores and PSNR/SSIM on the target views.
fn target_scores(
    s: &mut SceneScores,
    scene: &Scene,
    context: &[usize],
    targets: &[usize],
    rec: &Reconstruction,
    labels: &LabelCache,
) -> Result<(), String> {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    let pred_cams: Vec<_> = rec.views.iter().map(|v| v.camera).collect();
    let true_cams: Vec<_> = context.iter().map(|&i| scene.frames[i].camera).collect();
    let Some(pose) = camera_errors(&pred_cams, &true_cams).map_err(|e| err(&e))? else { return Ok(()) };
    s.rotation_deg = Some(pose.rotation_deg);
    s.translation = Some(pose.translation);
    s.alignment = if pose.umeyama { "umeyama" } else { "view 0" }.into();
    let to_pred = pose.alignment.inverse();

    let vocabulary = &rec.vocabulary;
    let instances = rec.instances.iter().map(|i| i.id as usize).max().unwrap_or(0);
    let mut label_of_id = vec![None; instances];
    for i in &rec.instances {
        label_of_id[i.id as usize - 1] = vocabulary.iter().position(|v| *v == i.label);
    }
    let (mut pred_ids, mut true_ids, mut pred_labels, mut gt_labels) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut psnrs, mut ssims) = (Vec::new(), Vec::new());
    for &t in targets {
        let frame = &scene.frames[t];
        let camera = to_pred.map_camera(&frame.camera);
        let ids = render_instance_ids(&rec.scene, &camera, instances).map_err(|e| err(&e))?;
        let colour = render_colour(&rec.scene, &camera).map_err(|e| err(&e))?;
        let pixels = frame.rgb.len() / 3;
        let truth: Vec<f32> = (0..3).flat_map(|c| frame.rgb.iter().skip(c).step_by(3).map(|v| f32::from(*v) / 255.0)).collect();
        let colour: Vec<f32> = colour.iter().map(|v| v.clamp(0.0, 1.0)).collect();
        debug_assert_eq!(truth.len(), 3 * pixels);
        psnrs.push(psnr(&colour, &truth).map_err(|e| err(&e))?);
        ssims.push(ssim(&colour, &truth, 3, frame.width() as usize, frame.height() as usize).map_err(|e| err(&e))?);
        if let Some(gt) = &frame.instances {
            pred_labels.extend(label_map(&ids, &label_of_id));
            gt_labels.extend(true_labels(scene, gt, vocabulary));
            true_ids.extend(gt.iter().map(|&i| u32::from(i)));
            pred_ids.extend(ids);
        }
    }
    let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
    s.psnr = mean(&psnrs);
    s.ssim = mean(&ssims);
    if let Some(sem) = semantic_scores(&pred_labels, &gt_labels).map_err(|e| err(&e))? {
        s.semantic_miou = Some(sem.miou);
        s.semantic_macc = Some(sem.macc);
    }
    if let Some(ins) = instance_scores(&pred_ids, &true_ids).map_err(|e| err(&e))? {
        s.instance_miou = Some(ins.miou);
        s.instance_acc25 = Some(ins.acc_25);
    }
    // Text queries: each label present in the target views, its returned instances' mask vs
    // the union of that label's true instances.
    let present: std::collections::BTreeSet<u32> = gt_labels.iter().copied().filter(|l| *l != NO_LABEL).collect();
    let own_scores: Vec<f32> =
        rec.prototypes.iter().map(|p| rec.instances.iter().find(|i| i.id == p.id).map_or(f32::MIN, |i| i.score)).collect();
    let mut ious = Vec::new();
    for l in present {
        let text = labels.embed(&[vocabulary[l as usize].as_str()]).map_err(|e| err(&e))?.remove(0);
        let hits: Vec<u32> = query(&rec.prototypes, &text, &own_scores, &QueryRule::default()).map_err(|e| err(&e))?.iter().map(|h| h.id).collect();
        let got = ids_mask(&pred_ids, &hits);
        let want: Vec<bool> = gt_labels.iter().map(|g| *g == l).collect();
        if let Some(iou) = mask_iou(&got, &want).map_err(|e| err(&e))? {
            ious.push(iou);
        }
    }
    s.query_iou = mean(&ious);
    Ok(())
}
