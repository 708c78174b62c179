//! The shipped detector (`models/detector/`), with our resize, normalization, box decoding and
//! suppression, against TensorFlow run once on the TF.js model it was converted from
//! (`scripts/convert/detector.py --reference`) on a real photo: the Middlebury motorcycle from
//! the scikit-image wheel that `scripts/setup` unpacks.

use std::collections::BTreeMap;
use std::path::PathBuf;

use inssplat_pipeline::detector::{Detector, DetectorParams, boxes::STRIDES, input};
use serde::Deserialize;

#[derive(Deserialize)]
struct Stats {
    shape: Vec<usize>,
    sum: f64,
    /// Values at flat indices.
    at: Vec<(usize, f32)>,
}

#[derive(Deserialize)]
struct Found {
    class: String,
    score: f32,
    #[serde(rename = "box")]
    bbox: [f32; 4],
}

#[derive(Deserialize)]
struct Reference {
    min_score: f32,
    nms_iou: f32,
    input: Stats,
    outputs: BTreeMap<String, Stats>,
    detections: Vec<Found>,
}

fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn photo() -> image::RgbImage {
    let dir = std::env::var_os("INSSPLAT_PHOTOS_DIR")
        .map(PathBuf::from)
        .expect("INSSPLAT_PHOTOS_DIR (set by `source .deps/env` after scripts/setup)");
    let path = dir.join("motorcycle/motorcycle_left.png");
    image::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_rgb8()
}

fn close(what: &str, got: f64, want: f64, tolerance: f64) {
    assert!((got - want).abs() <= tolerance, "{what}: {got} against TensorFlow's {want}");
}

#[test]
fn input_raw_outputs_and_detections_agree_with_tensorflow() {
    let text = std::fs::read_to_string(
        workspace().join("pipeline/tests/fixtures/detector_reference.json"),
    )
    .expect("the reference file");
    let reference: Reference = serde_json::from_str(&text).expect("the reference parses");
    let params = DetectorParams {
        min_score: reference.min_score,
        nms_iou: reference.nms_iou,
        ..DetectorParams::default()
    };
    let detector = Detector::load(&workspace().join("models/detector"), 2, params)
        .expect("the shipped detector loads");
    let photo = photo();

    let prepared = input(&photo);
    assert_eq!(prepared.len(), reference.input.shape.iter().product::<usize>());
    for &(i, want) in &reference.input.at {
        close(&format!("input[{i}]"), prepared[i] as f64, want as f64, 1e-4);
    }
    let sum: f64 = prepared.iter().map(|&v| v as f64).sum();
    close("input sum", sum, reference.input.sum, 1e-6 * prepared.len() as f64);

    let levels = detector.raw(&prepared).expect("the detector runs");
    for (level, stride) in levels.iter().zip(STRIDES) {
        for (name, values) in
            [(format!("cls_{stride}"), &level.scores), (format!("reg_{stride}"), &level.distances)]
        {
            let want = &reference.outputs[&name];
            assert_eq!(values.len(), want.shape.iter().product::<usize>(), "{name}");
            for &(i, v) in &want.at {
                close(&format!("{name}[{i}]"), values[i] as f64, v as f64, 1e-4);
            }
            let sum: f64 = values.iter().map(|&v| v as f64).sum();
            close(&format!("{name} sum"), sum, want.sum, 0.05);
        }
    }

    let found = detector.detect(&photo).expect("the detector runs");
    assert_eq!(found.len(), reference.detections.len(), "{found:?}");
    for (got, want) in found.iter().zip(&reference.detections) {
        assert_eq!(detector.classes[got.class], want.class);
        close(&format!("{} score", want.class), got.score as f64, want.score as f64, 1e-4);
        for (g, w) in got.bbox.iter().zip(want.bbox) {
            close(&format!("{} box", want.class), *g as f64, w as f64, 0.05);
        }
    }
}
