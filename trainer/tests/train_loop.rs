//! The training loop on real synthesized scenes with the real MiniLM teacher: a small network
//! overfits one scene (the objective falls ≥ 10×), validating a checkpoint afterwards
//! reproduces the run's own validation loss, the direct term adds L_ins of the network's own
//! embeddings, samples carry the label vocabulary of the contrastive L_sem (older configs read
//! as without these, and configs with the fields of removed experiments read), ray dropout
//! trains a network that reads rays, L_sem on the furniture alone is
//! L_sem of the scene with its shell unlabelled, the prefetcher's data threads hand out
//! exactly the sampler's samples in order, and bad data folders and checkpoints are clear
//! errors that name the path. Runs that stop and resume are in `train_resume`.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use burn::module::Module;
use burn::optim::GradientsParams;
use burn::prelude::*;
use inssplat_synth::{Split, Structure};
use inssplat_trainer::loss::{LossConfig, instance_loss};
use inssplat_trainer::model::ModelConfig;
use inssplat_trainer::train::sample::{DataSpec, Prefetcher, Sample, Sampler, Source, ViewPlan};
use inssplat_trainer::train::step::objective;
use inssplat_trainer::train::{
    self, Session, TrainConfig, batch, checkpoint, label_cache, seeded_init, update,
};

pub(crate) fn tiny_model() -> ModelConfig {
    ModelConfig::new()
        .with_image_size(32)
        .with_patch(4)
        .with_dim(32)
        .with_depth(2)
        .with_heads(2)
        .with_decoder_dim(32)
        .with_sem_dim(8)
}

pub(crate) fn tiny_data() -> DataSpec {
    DataSpec::Synth {
        split: Split::Train,
        furniture_dir: None,
        size: 32,
        structure: Structure::Instances,
        antialias: 1,
    }
}

pub(crate) fn quiet_session() -> Session {
    Session {
        checkpoint_every: Duration::from_secs(3600),
        val_every: 0,
        progress: false,
        ..Session::default()
    }
}

/// Sample `index` of a sampler with seed `seed`: 3 input views and 1 target of a tiny scene.
fn three_view_sample(seed: u64, index: u64) -> Sample {
    let sampler = Sampler {
        source: Source::open(&tiny_data()).unwrap(),
        plan: ViewPlan {
            min_views: 3,
            max_views: 3,
            targets: 1,
            reuse: 1,
            first_scene: 0,
            window: None,
        },
        seed,
        labels: label_cache().unwrap(),
    };
    sampler.sample(index).unwrap()
}

/// The input views of `sample` as `[inputs, 3, size, size]`.
fn input_images(sample: &Sample, device: &Device) -> Tensor<4> {
    let (inputs, size) = (sample.inputs, sample.size);
    Tensor::from_data(
        TensorData::new(
            sample.images[..inputs * 3 * size * size].to_vec(),
            [inputs, 3, size, size],
        ),
        device,
    )
}

/// A direct term of weight 0.5 adds half of `own` (the term on the network's own outputs) to
/// the objective's `without` value, and weight 0 adds nothing.
fn assert_direct_term_adds_half(what: &str, own: f32, half: f32, without: f32, zero: f32) {
    assert!(own > 0.1, "{what} of a random network's own outputs: {own}");
    let added = half - without;
    assert!(
        (added - 0.5 * own).abs() <= 1e-4 * own.max(1.0),
        "{what}: added {added}, expected 0.5 × {own}"
    );
    assert_eq!(zero, without, "{what}: weight 0");
}

pub(crate) fn params(dir: &Path) -> Vec<f32> {
    let state = checkpoint::read_state(dir).unwrap();
    let net = checkpoint::load_model(dir, &state, &Device::flex()).unwrap();
    let mut out = Vec::new();
    net.visit(&mut Collect(&mut out));
    out
}

struct Collect<'a>(&'a mut Vec<f32>);

impl burn::module::ModuleVisitor for Collect<'_> {
    fn visit_float<const D: usize>(&mut self, param: &burn::module::Param<Tensor<D>>) {
        self.0.extend(param.val().into_data().try_to_vec::<f32>().unwrap());
    }
}

#[test]
fn a_small_network_overfits_one_scene() {
    // α = 0 drops the −α·log(conf) reward, so every term is ≥ 0 and "falls 10×" is meaningful.
    let loss = LossConfig::new().with_depth_conf_alpha(0.0);
    let config = TrainConfig::new(tiny_model(), loss.clone())
        .with_lr(3e-3)
        .with_weight_decay(0.0)
        .with_grad_clip(0.0);
    let sample = three_view_sample(1, 5);
    let device = Device::flex().autodiff();
    let mut net = seeded_init(&config.model, 3, &device).unwrap();
    let mut optim = burn::optim::AdamWConfig::new().with_weight_decay(0.0).init();
    let mut losses = Vec::new();
    for _ in 0..150 {
        let obj = objective(&net, &sample, &loss, &device).unwrap();
        losses.push(obj.values().total);
        let grads = GradientsParams::from_grads(obj.total.backward(), &net);
        net = update(net, &mut optim, grads, config.lr, &config);
    }
    let first = losses[0];
    let last = losses[losses.len() - 5..].iter().sum::<f32>() / 5.0;
    assert!(
        last * 10.0 <= first,
        "loss {first} -> {last} (every 10th: {:?})",
        losses.iter().step_by(10).collect::<Vec<_>>()
    );
}

#[test]
fn the_direct_instance_term_adds_l_ins_of_the_networks_own_embeddings() {
    let sample = three_view_sample(2, 0);
    let device = Device::flex();
    let net = seeded_init(&tiny_model(), 4, &device).unwrap();
    let paper = LossConfig::new();
    let direct = paper.clone().with_direct_instance_weight(Some(0.5));
    let instance =
        |config: &LossConfig| objective(&net, &sample, config, &device).unwrap().values().instance;

    let out = net.forward(input_images(&sample, &device)).unwrap();
    let own_ids = &sample.ids[..sample.inputs * sample.size * sample.size];
    let own = instance_loss(out.instance, &out.semantic, own_ids, &paper)
        .unwrap()
        .total(&paper)
        .into_scalar::<f32>();
    let zero = instance(&paper.clone().with_direct_instance_weight(Some(0.0)));
    assert_direct_term_adds_half("L_ins", own, instance(&direct), instance(&paper), zero);
}

#[test]
fn l_sem_on_the_furniture_alone_leaves_the_shells_pixels_out() {
    let sample = three_view_sample(4, 0);
    // The shell's ids are exactly the instances whose teacher row is wall, floor or ceiling.
    let shell_rows = label_cache().unwrap().embed(&["wall", "floor", "ceiling"]).unwrap();
    let shown: std::collections::BTreeSet<u32> =
        sample.ids.iter().copied().filter(|&i| i != 0).collect();
    for &id in &shown {
        let row = &sample.teacher[id as usize * 384..(id as usize + 1) * 384];
        let is_shell = shell_rows.iter().any(|r| r.as_slice() == row);
        assert_eq!(sample.shell.contains(&id), is_shell, "instance {id}");
    }
    assert!(
        !sample.shell.is_empty() && shown.iter().any(|id| !sample.shell.contains(id)),
        "{shown:?} {:?}",
        sample.shell
    );

    let device = Device::flex();
    let net = seeded_init(&tiny_model(), 9, &device).unwrap();
    let semantic = |s: &Sample, config: &LossConfig| {
        objective(&net, s, config, &device).unwrap().values().semantic
    };
    let all = LossConfig::new().with_semantic_temperature(Some(0.1));
    let objects = all.clone().with_semantic_objects_only(Some(true));
    // The same as the scene with its shell unlabelled: the render does not read the ids.
    let mut bare = sample.clone();
    bare.ids.iter_mut().filter(|id| sample.shell.contains(id)).for_each(|id| *id = 0);
    let (with_shell, without) = (semantic(&sample, &all), semantic(&sample, &objects));
    assert_eq!(without, semantic(&bare, &all));
    assert!(
        without.is_finite() && without > 0.0 && without != with_shell,
        "{without} vs {with_shell}"
    );
}

#[test]
fn a_sample_carries_the_whole_label_vocabulary_for_the_contrastive_l_sem() {
    let sample = three_view_sample(3, 0);
    let labels = inssplat_synth::all_labels();
    assert_eq!(sample.vocabulary.len(), labels.len() * 384);
    // Every label the scene shows is a vocabulary row.
    let rows: Vec<&[f32]> = sample.vocabulary.chunks_exact(384).collect();
    let shown: std::collections::BTreeSet<u32> =
        sample.ids.iter().copied().filter(|&i| i != 0).collect();
    assert!(shown.len() >= 2, "{shown:?}");
    for id in shown {
        let row = &sample.teacher[id as usize * 384..(id as usize + 1) * 384];
        assert!(rows.contains(&row), "instance {id}'s label is not in the vocabulary");
    }
    let device = Device::flex();
    let net = seeded_init(&tiny_model(), 5, &device).unwrap();
    let semantic =
        |config: &LossConfig| objective(&net, &sample, config, &device).unwrap().values().semantic;
    let contrastive = semantic(&LossConfig::new().with_semantic_temperature(Some(0.1)));
    let cosine = semantic(&LossConfig::new());
    assert!(
        contrastive.is_finite() && contrastive > 0.0 && contrastive != cosine,
        "{contrastive} vs cosine {cosine}"
    );
}

#[test]
fn the_prefetcher_hands_out_the_samplers_samples_in_order_from_several_threads() {
    // Scenes serve two samples each, so each of the three data threads makes every third
    // scene once and keeps it for its second sample.
    let sampler = Sampler {
        source: Source::open(&tiny_data()).unwrap(),
        plan: ViewPlan {
            min_views: 2,
            max_views: 4,
            targets: 1,
            reuse: 2,
            first_scene: 7,
            window: None,
        },
        seed: 11,
        labels: label_cache().unwrap(),
    };
    let prefetch = Prefetcher::start(sampler.clone(), 3, 13, 4, 3);
    let mut seen = Vec::new();
    for (index, sample) in prefetch {
        let (got, want) = (sample.unwrap(), sampler.sample(index).unwrap());
        assert_eq!(
            (&got.scene, got.inputs, &got.cameras),
            (&want.scene, want.inputs, &want.cameras),
            "sample {index}"
        );
        assert!(
            got.images == want.images && got.depth == want.depth && got.ids == want.ids,
            "sample {index}: other pixels"
        );
        seen.push(index);
    }
    assert_eq!(seen, (3..13).collect::<Vec<_>>());
    // Dropping it before the end stops its threads (the test would hang otherwise).
    let mut early = Prefetcher::start(sampler, 0, 1000, 4, 3);
    assert_eq!(early.next().map(|(i, _)| i), Some(0));
    drop(early);
}

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

pub(crate) fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_inssplat-train"))
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

#[test]
fn two_samples_on_threads_give_the_mean_gradient_of_one_graph() {
    let loss = LossConfig::new().with_instance_weight(0.1).with_semantic_weight(0.1);
    let device = Device::flex().autodiff();
    let net = seeded_init(&tiny_model(), 5, &device).unwrap();
    let samples = vec![three_view_sample(1, 5), three_view_sample(2, 9)];
    let parallel = batch::gradients(&net, &samples, &loss, &device).unwrap();
    let (a, b) = (
        objective(&net, &samples[0], &loss, &device).unwrap(),
        objective(&net, &samples[1], &loss, &device).unwrap(),
    );
    let mean_total = (a.values().total + b.values().total) / 2.0;
    assert!(
        (parallel.values.total - mean_total).abs() <= 1e-5 * mean_total.abs(),
        "{} vs {mean_total}",
        parallel.values.total
    );
    let reference =
        GradientsParams::from_grads((a.total + b.total).div_scalar(2.0).backward(), &net);
    let mut compare =
        Compare { a: &parallel.grads, b: &reference, tensors: 0, nonzero: 0, worst: 0.0 };
    net.visit(&mut compare);
    assert!(
        compare.nonzero > 10,
        "only {} of {} gradients are non-zero",
        compare.nonzero,
        compare.tensors
    );
    assert!(
        compare.worst <= 1e-4,
        "threaded and single-graph gradients differ by {} (relative)",
        compare.worst
    );
}

/// Compares two gradient sets parameter by parameter: worst relative difference per tensor.
struct Compare<'a> {
    a: &'a GradientsParams,
    b: &'a GradientsParams,
    tensors: usize,
    nonzero: usize,
    worst: f32,
}

impl burn::module::ModuleVisitor for Compare<'_> {
    fn visit_float<const D: usize>(&mut self, param: &burn::module::Param<Tensor<D>>) {
        let read = |g: &GradientsParams| {
            g.get::<D>(param.id).map(|t| t.into_data().try_to_vec::<f32>().unwrap())
        };
        let (a, b) = (read(self.a), read(self.b));
        assert_eq!(
            a.is_some(),
            b.is_some(),
            "parameter {} has a gradient on one side only",
            param.id
        );
        let (Some(a), Some(b)) = (a, b) else { return };
        self.tensors += 1;
        let scale = b.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        if scale > 0.0 {
            self.nonzero += 1;
            let diff = a.iter().zip(&b).fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
            self.worst = self.worst.max(diff / scale);
        }
    }
}
