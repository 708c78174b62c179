//! `inssplat-eval score --photos DIR`: the context photos come from the same scenes synthesized at
//! another size (`inssplat-train synth --size 512`: the same seeds give the same rooms and
//! cameras), as a user's camera would give them, larger than the network's input; every ground
//! truth stays the evaluated scene's, at the model resolution. What that measures is what the
//! pipeline makes of the detail the network's input has lost (registration finds its keypoints
//! in it). The context views' masks at the photos' resolution are scored against the twin's
//! instance masks there ([`photo_mask_scores`]): as the pipeline upsamples them along the
//! photo's edges, and as each photo pixel's nearest model pixel would have them.

use std::path::Path;

use inssplat_proto::dataset::{Scene, TransformsJson};

use inssplat_metrics::segmentation::{boundary_f, instance_scores};
use inssplat_pipeline::reconstruct::{InputImage, Reconstruction};
use inssplat_pipeline::stages::masks::nearest_map;

/// Tolerance of the boundary F-score, photo pixels.
const BOUNDARY_TOLERANCE: usize = 2;

/// The context views' instance maps at the photos' resolution against the twin's: instance
/// mIoU (pooled over the views) and mean boundary F-score, upsampled (`.0`) and nearest (`.1`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhotoMaskScores {
    pub miou: (f64, f64),
    pub boundary_f: (f64, f64),
}

/// [`PhotoMaskScores`] of `rec`, reconstructed from the frames `context` of the twin of scene
/// `name` under `dir`; `None` when the twin has no instance masks or `rec` no photo maps.
pub fn photo_mask_scores(
    dir: &Path,
    name: &str,
    context: &[usize],
    rec: &Reconstruction,
) -> Result<Option<PhotoMaskScores>, String> {
    let twin = Scene::load(dir.join(name)).map_err(|e| format!("--photos: {e}"))?;
    let (mut gt, mut up, mut near) = (Vec::new(), Vec::new(), Vec::new());
    let mut edges = (Vec::new(), Vec::new());
    for (view, &f) in rec.views.iter().zip(context) {
        let (Some(truth), Some(maps)) = (&twin.frames[f].instances, &view.photo_maps) else {
            return Ok(None);
        };
        let truth: Vec<u32> = truth.iter().map(|&i| u32::from(i)).collect();
        if truth.len() != maps.instance_ids.len() {
            return Err(format!("--photos: frame {f}'s masks are not at the photo's size"));
        }
        let nearest = nearest_map(&view.instance_ids, &view.letterbox, maps.width, maps.height);
        let w = maps.width as usize;
        let f_of = |pred: &[u32]| boundary_f(pred, &truth, w, BOUNDARY_TOLERANCE);
        edges.0.extend(f_of(&maps.instance_ids).map_err(|e| e.to_string())?);
        edges.1.extend(f_of(&nearest).map_err(|e| e.to_string())?);
        gt.extend(truth);
        up.extend_from_slice(&maps.instance_ids);
        near.extend(nearest);
    }
    let miou = |pred: &[u32]| -> Result<f64, String> {
        Ok(instance_scores(pred, &gt).map_err(|e| e.to_string())?.map_or(0.0, |s| s.miou))
    };
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    Ok(Some(PhotoMaskScores {
        miou: (miou(&up)?, miou(&near)?),
        boundary_f: (mean(&edges.0), mean(&edges.1)),
    }))
}

/// Largest difference between a photo's camera pose and the scene's (rotation entries and
/// metres); more means the folder holds another scene.
const POSE_TOLERANCE: f32 = 1e-4;

/// The frames `context` of `scene` as the photo files of its twin under `dir`, after checking
/// that the twin has the same frames at the same poses; a problem comes back as a sentence
/// that names the file.
pub fn photo_images(
    dir: &Path,
    scene: &Scene,
    context: &[usize],
) -> Result<Vec<InputImage>, String> {
    let name = scene.name();
    let json_path = dir.join(&name).join("transforms.json");
    let twin = TransformsJson::read(&json_path).map_err(|e| format!("--photos: {e}"))?;
    if twin.frames.len() != scene.frames.len() {
        return Err(format!(
            "--photos: {} has {} frames where the scene has {} (not the same scene)",
            json_path.display(),
            twin.frames.len(),
            scene.frames.len()
        ));
    }
    let cameras = twin.cameras(&json_path).map_err(|e| format!("--photos: {e}"))?;
    context
        .iter()
        .map(|&i| {
            let (ours, theirs) = (&scene.frames[i].camera, &cameras[i]);
            let apart = (ours.translation - theirs.translation).abs().max_element().max(
                (glam::Mat3::from_quat(ours.rotation) - glam::Mat3::from_quat(theirs.rotation))
                    .to_cols_array()
                    .iter()
                    .fold(0.0f32, |m, x| m.max(x.abs())),
            );
            if apart.is_nan() || apart > POSE_TOLERANCE {
                return Err(format!(
                    "--photos: {}: frame {i}'s camera differs from the scene's by {apart} (not the same scene)",
                    json_path.display()
                ));
            }
            let file = dir.join(&name).join(&twin.frames[i].file_path);
            let bytes = std::fs::read(&file).map_err(|e| format!("--photos: {}: {e}", file.display()))?;
            Ok(InputImage { name: format!("{name}/frame {i}"), bytes })
        })
        .collect()
}
