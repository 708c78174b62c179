//! The training loop on real synthesized scenes with the real MiniLM teacher: a small network
//! overfits one scene (the objective falls ≥ 10×), the direct term adds L_ins of the network's
//! own embeddings, samples carry the label vocabulary of the contrastive L_sem, L_sem on the
//! furniture alone is L_sem of the scene with its shell unlabelled, the prefetcher's data
//! threads hand out exactly the sampler's samples in order, and two samples on threads give the
//! mean gradient of one graph. Checkpoints and configurations are in `train_checkpoints`, runs
//! that stop and resume in `train_resume`.

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
    Session, TrainConfig, batch, checkpoint, label_cache, seeded_init, update,
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

/// Appends every float parameter a module visits.
pub(crate) struct Collect<'a>(pub(crate) &'a mut Vec<f32>);

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

pub(crate) fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_inssplat-train"))
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
