//! The target views of one scene: the context cameras aligned to the true ones (camera
//! errors), then each target view rendered at its true camera mapped into the predicted frame
//! (its pose refined against its photo when asked) and scored: semantic, instance and query
//! masks, PSNR and SSIM.

use inssplat_geometry::rotation::turn_deg;
use inssplat_geometry::target_pose::refine_pose;
use inssplat_metrics::image::{psnr, ssim};
use inssplat_metrics::pose::{AlignScale, Similarity, camera_errors};
use inssplat_metrics::segmentation::{InstancePool, instance_scores, semantic_scores};
use inssplat_pipeline::reconstruct::Reconstruction;
use inssplat_proto::dataset::Scene;
use inssplat_raster::masks::{fill_uncovered, render_colour};
use inssplat_text::LabelCache;
use inssplat_understand::label::QueryRule;

use crate::mean;
use crate::query_rules::query_scores;
use crate::scene::{SHELL, SceneScores, Settings, true_labels};
use crate::views::{pixel_labels, segment};

/// Camera errors of the context views after the alignment of `scale`; returns the map from
/// the true frame to the predicted one (`None` without cameras).
pub(crate) fn align_cameras(
    s: &mut SceneScores,
    scene: &Scene,
    context: &[usize],
    rec: &Reconstruction,
    scale: AlignScale,
) -> Result<Option<Similarity>, String> {
    let pred_cams: Vec<_> = rec.views.iter().map(|v| v.camera).collect();
    let true_cams: Vec<_> = context.iter().map(|&i| scene.frames[i].camera).collect();
    let Some(pose) = camera_errors(&pred_cams, &true_cams, scale).map_err(|e| e.to_string())?
    else {
        return Ok(None);
    };
    s.rotation_deg = Some(pose.rotation_deg);
    s.translation = Some(pose.translation);
    Ok(Some(pose.alignment.inverse()))
}

/// Novel-view semantic, instance and query scores and PSNR/SSIM on the target views, rendered
/// at the target cameras mapped into the predicted frame by `to_pred`.
/// Instance mIoU pools every (target view, visible true instance) pair: each instance's best
/// IoU with one predicted id of that view (the per-image OpenGaussian/LERF protocol, the same
/// for both clustering modes; cross-view agreement is what T-mIoU measures).
pub(crate) fn target_scores(
    s: &mut SceneScores,
    scene: &Scene,
    targets: &[usize],
    rec: &Reconstruction,
    labels: &LabelCache,
    settings: &Settings<'_>,
    to_pred: &Similarity,
) -> Result<(), String> {
    let mode = settings.cluster;
    let err = |e: &dyn std::fmt::Display| e.to_string();

    let vocabulary = &rec.vocabulary;
    let words: Vec<&str> = vocabulary.iter().map(String::as_str).collect();
    let texts = labels.embed(&words).map_err(|e| err(&e))?;
    let params = &settings.pipeline.cluster;
    let (mut pred_labels, mut gt_labels, mut segs) = (Vec::new(), Vec::new(), Vec::new());
    let mut instances = InstancePool::default();
    let (mut psnrs, mut ssims, mut turns) = (Vec::new(), Vec::new(), Vec::new());
    for &t in targets {
        let frame = &scene.frames[t];
        let truth = frame.planar_rgb();
        let mut camera = to_pred.map_camera(&frame.camera);
        if settings.switches.target_pose_steps > 0 {
            let refined =
                refine_pose(&rec.scene, &camera, &truth, settings.switches.target_pose_steps)
                    .map_err(|e| err(&e))?;
            turns.push(turn_deg(&refined.camera, &camera));
            camera = refined.camera;
        }
        let colour =
            render_colour(&rec.scene, &camera, !settings.switches.no_fill).map_err(|e| err(&e))?;
        let colour: Vec<f32> = colour.iter().map(|v| v.clamp(0.0, 1.0)).collect();
        psnrs.push(psnr(&colour, &truth).map_err(|e| err(&e))?);
        ssims.push(
            ssim(&colour, &truth, 3, frame.width() as usize, frame.height() as usize)
                .map_err(|e| err(&e))?,
        );
        let Some(gt) = &frame.instances else { continue };
        let mut seg = segment(rec, &camera, mode, &texts, params)?;
        if settings.switches.no_aggregation {
            seg.labels = pixel_labels(rec, &camera, &texts)?;
        }
        if !settings.switches.no_fill {
            fill_uncovered(
                &mut seg.ids,
                Some(&mut seg.labels),
                frame.width() as usize,
                frame.height() as usize,
            );
        }
        let gt_ids: Vec<u32> = gt.iter().map(|&i| u32::from(i)).collect();
        if let Some(ins) = instance_scores(&seg.ids, &gt_ids).map_err(|e| err(&e))? {
            instances.add(&ins);
        }
        pred_labels.extend_from_slice(&seg.labels);
        gt_labels.extend(true_labels(scene, gt, vocabulary));
        segs.push(seg);
    }
    s.psnr = mean(&psnrs);
    s.ssim = mean(&ssims);
    s.target_pose_turn_deg = mean(&turns);
    if let Some(sem) = semantic_scores(&pred_labels, &gt_labels).map_err(|e| err(&e))? {
        s.labels.add(&pred_labels, &gt_labels);
        s.semantic_miou = Some(sem.miou);
        s.semantic_macc = Some(sem.macc);
    }
    s.instance_miou = instances.miou();
    s.instance_acc25 = instances.acc_25();
    s.instance_pq = instances.pq();
    // Text queries: the default rule first, then the rules being compared.
    let rules: Vec<QueryRule> =
        std::iter::once(QueryRule::default()).chain(settings.query_rules.iter().copied()).collect();
    let held = scene.label_vocabulary();
    let absent: Vec<u32> = (0..vocabulary.len() as u32)
        .filter(|&i| {
            !held.contains(&vocabulary[i as usize])
                && !SHELL.contains(&vocabulary[i as usize].as_str())
        })
        .collect();
    let mut by_rule = query_scores(&segs, &gt_labels, &absent, &texts, &rules)?;
    let default = by_rule.remove(0);
    s.query_iou = default.iou;
    s.query_false_positive = default.false_positive;
    s.query_by_rule = by_rule;
    Ok(())
}
