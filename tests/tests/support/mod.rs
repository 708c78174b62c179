//! Fixtures shared by the end-to-end tests: a tiny network exported by the trainer (random
//! weights from a fixed seed, so every run checks the same network: these tests check
//! plumbing, not accuracy) and procedural scenes.

pub use inssplat_e2e::http;
pub mod photo;
pub mod web;

use std::path::{Path, PathBuf};

use burn::prelude::Device;
use inssplat_trainer::export::{ExportMeta, Weights, export_onnx};
use inssplat_trainer::model::ModelConfig;
use inssplat_trainer::train::seeded_init;

/// Exports a tiny random 32×32 network (always the same weights) to `dir/tiny.onnx`.
pub fn tiny_model(dir: &Path) -> PathBuf {
    export_tiny(tiny_config(), &dir.join("tiny.onnx"))
}

/// [`tiny_model`] reading its cameras as 1 × 1 rays a patch (the optional `rays` input), at
/// `dir/tiny-rays.onnx`.
pub fn tiny_rays_model(dir: &Path) -> PathBuf {
    export_tiny(tiny_config().with_camera_rays(Some(1)), &dir.join("tiny-rays.onnx"))
}

fn tiny_config() -> ModelConfig {
    ModelConfig::new()
        .with_image_size(32)
        .with_dim(32)
        .with_depth(2)
        .with_heads(2)
        .with_decoder_dim(32)
        .with_decoder_min_dim(16)
}

fn export_tiny(config: ModelConfig, model: &Path) -> PathBuf {
    let net = seeded_init(&config, 7, &Device::flex()).unwrap();
    export_onnx(
        &net,
        model,
        &ExportMeta { model_version: "e2e-random".into(), train_steps: 0, weights: Weights::F32 },
    )
    .unwrap();
    model.to_path_buf()
}

/// Writes test-split scene `index` (32×32, primitives, 3–5 objects, eval context/target sets)
/// to `dir` and returns its folder.
pub fn test_scene(dir: &Path, index: u64) -> PathBuf {
    use inssplat_synth::{self as synth, Furniture, Split, SynthConfig};
    let mut cfg = SynthConfig::new(Split::Test, Furniture::Primitives);
    (cfg.width, cfg.height, cfg.objects) = (32, 32, (3, 5));
    let scene = dir.join(format!("scene_{index:06}"));
    synth::generate_split(index, &cfg).unwrap().write(&scene).unwrap();
    scene
}

/// [`tiny_model`] in `dir`, and a data folder `dir/test` holding test-split scene `index`
/// ([`test_scene`]): (model, data).
pub fn tiny_model_and_test_data(dir: &Path, index: u64) -> (PathBuf, PathBuf) {
    let data = dir.join("test");
    test_scene(&data, index);
    (tiny_model(dir), data)
}

/// `inssplat-eval score` of the scenes in `data` at `views` with `model`, then `extra`.
pub fn score(data: &Path, views: &str, model: &Path, extra: &[&str]) -> std::process::Output {
    inssplat_e2e::inssplat_eval(
        &[&["score", "--data", s(data), "--views", views, "--model", s(model)], extra].concat(),
    )
}

/// A path as `&str` for command lines.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}
