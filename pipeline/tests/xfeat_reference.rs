//! The shipped XFeat and LighterGlue ONNX files (`models/matcher/`), with our keypoint
//! selection, descriptor sampling and mutual check, against the reference code run once in
//! torch (`scripts/convert/xfeat.py --reference`) on a real stereo pair: the Middlebury
//! motorcycle from the scikit-image wheel that `scripts/setup` unpacks.

use std::path::PathBuf;

use inssplat_pipeline::matcher::{DESCRIPTOR, Grey, LearnedMatcher, MatcherParams};
use serde::Deserialize;

#[derive(Deserialize)]
struct View {
    count: usize,
    keypoints: Vec<[f32; 2]>,
    scores: Vec<f32>,
    descriptors: Vec<Vec<f32>>,
}

#[derive(Deserialize)]
struct Reference {
    top_k: usize,
    min_conf: f32,
    views: Vec<View>,
    matches: usize,
    first_matches: Vec<[usize; 2]>,
}

fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The photo cropped to 736 × 480 as the reference was (no resampling), grey as numpy made it.
fn crop(name: &str) -> Grey {
    let dir = std::env::var_os("INSSPLAT_PHOTOS_DIR")
        .map(PathBuf::from)
        .expect("INSSPLAT_PHOTOS_DIR (set by `source .deps/env` after scripts/setup)");
    let path = dir.join("motorcycle").join(name);
    let rgb = image::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_rgb8();
    let (width, height) = (736, 480);
    let data = (0..height)
        .flat_map(|y| (0..width).map(move |x| (x, y)))
        .map(|(x, y)| {
            let p = rgb.get_pixel(x, y).0.map(f32::from);
            (p[0] + p[1] + p[2]) / 3.0 / 255.0
        })
        .collect();
    Grey { data, width: width as usize, height: height as usize }
}

#[test]
fn keypoints_descriptors_and_matches_agree_with_the_torch_reference() {
    let text =
        std::fs::read_to_string(workspace().join("pipeline/tests/fixtures/xfeat_reference.json"))
            .expect("the reference file");
    let reference: Reference = serde_json::from_str(&text).expect("the reference parses");
    let params = MatcherParams { min_confidence: reference.min_conf, ..MatcherParams::default() };
    let matcher = LearnedMatcher::load(&workspace().join("models/matcher"), 2, params)
        .expect("the shipped matcher loads");
    let found: Vec<_> = ["motorcycle_left.png", "motorcycle_right.png"]
        .iter()
        .map(|name| matcher.keypoints(&crop(name), reference.top_k).expect("XFeat runs"))
        .collect();
    for (ours, theirs) in found.iter().zip(&reference.views) {
        assert_eq!(ours.len(), theirs.count);
        for (k, (p, q)) in ours.points.iter().zip(&theirs.keypoints).enumerate() {
            assert_eq!([p.x, p.y], *q, "keypoint {k}");
            assert!((ours.scores[k] - theirs.scores[k]).abs() < 1e-5, "score {k}");
            let d = &ours.descriptors[k * DESCRIPTOR..(k + 1) * DESCRIPTOR];
            let worst = d.iter().zip(&theirs.descriptors[k]).map(|(a, b)| (a - b).abs());
            assert!(worst.fold(0.0, f32::max) < 1e-4, "descriptor {k}");
        }
    }
    let matches = matcher.matches(&found[0], &found[1]).expect("LighterGlue runs");
    let diff = matches.len().abs_diff(reference.matches);
    assert!(
        diff * 100 <= reference.matches,
        "{} matches, torch {}",
        matches.len(),
        reference.matches
    );
    let pairs: Vec<[usize; 2]> = matches.iter().map(|m| [m.0, m.1]).collect();
    let shared = reference.first_matches.iter().filter(|m| pairs.contains(m)).count();
    assert!(shared + 1 >= reference.first_matches.len(), "{shared} of the first matches");
}

#[test]
fn a_missing_matcher_file_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let err = LearnedMatcher::load(dir.path(), 1, MatcherParams::default()).unwrap_err();
    let text = err.to_string();
    assert!(text.contains("xfeat.onnx") && text.contains("--brief-matches"), "{text}");
}
