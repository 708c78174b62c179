//! `inssplat-eval score --photos DIR`: the context photos come from the same scenes synthesized at
//! another size (`inssplat-train synth --size 512`: the same seeds give the same rooms and
//! cameras), as a user's camera would give them, larger than the network's input; every ground
//! truth stays the evaluated scene's, at the model resolution. What that measures is what the
//! pipeline makes of the detail the network's input has lost (registration finds its keypoints
//! in it).

use std::path::Path;

use inssplat_proto::dataset::{Scene, TransformsJson};

use inssplat_pipeline::reconstruct::InputImage;

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
