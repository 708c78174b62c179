//! Stage "detect": the object detector ([`crate::detector`]) on each input photo (the decode
//! stage's copy for it, [`ModelImage::detect`]), its boxes carried into the model's pixels,
//! where the views' instance maps are, for naming ([`super::label`]).

use inssplat_understand::label::detections::DetectedBox;
use rayon::prelude::*;

use super::decode::ModelImage;
use super::stage_err;
use crate::detector::{Detector, input};
use crate::reconstruct::PipelineError;

/// A photo's input for the detector and the size of the copy it was made from.
type Prepared = (Vec<f32>, (u32, u32));

/// Each view's detections, boxes in the model's pixels; a view without a copy for the
/// detector, or whose photo is shorter than [`crate::detector::DetectorParams::min_photo_side`],
/// has none.
pub fn run(
    detector: &Detector,
    decoded: &[ModelImage],
) -> Result<Vec<Vec<DetectedBox>>, PipelineError> {
    // The inputs are made in parallel; the detector runs one photo at a time on its threads.
    let min_side = detector.params.min_photo_side;
    let inputs: Vec<Option<Prepared>> = decoded
        .par_iter()
        .map(|d| {
            let lb = &d.letterbox;
            let photo = d.detect.as_ref().filter(|_| lb.width.max(lb.height) >= min_side)?;
            Some((input(photo), photo.dimensions()))
        })
        .collect();
    decoded
        .iter()
        .zip(inputs)
        .map(|(d, prepared)| {
            let Some((input, size)) = prepared else { return Ok(Vec::new()) };
            let lb = &d.letterbox;
            // Model pixels per pixel of the detector's copy.
            let per = lb.scale * lb.width as f32 / size.0 as f32;
            let found = detector.detect_input(&input, size).map_err(|e| stage_err("detect")(&e))?;
            Ok(found
                .into_iter()
                .map(|f| {
                    let [x0, y0, x1, y1] = f.bbox;
                    let bbox = [
                        lb.pad_x + x0 * per,
                        lb.pad_y + y0 * per,
                        lb.pad_x + x1 * per,
                        lb.pad_y + y1 * per,
                    ];
                    DetectedBox { class: f.class, score: f.score, bbox }
                })
                .collect())
        })
        .collect()
}
