//! The shape classifier on real synthesized rooms: descriptors measured from true depth stand
//! on the floor the code finds, an MLP fitted on some rooms names the objects of others better
//! than the most common label does (better again when it also reads the instances' semantic
//! prototypes), logit adjustment moves only its last bias, `attach` stores it in a real
//! exported model file, and `inssplat-train fit-shapes` names a bad flag and its value.

use burn::prelude::*;
use inssplat_proto::dataset::Scene;
use inssplat_proto::shape::{DESCRIPTOR, LabelledDescriptor, ShapeClassifier};
use inssplat_proto::signature as sig;
use inssplat_synth::{self as synth, Furniture, Split, Structure, SynthConfig};
use inssplat_text::LabelCache;
use inssplat_trainer::export::onnx_pb::ModelProto;
use inssplat_trainer::export::{ExportMeta, Weights, export_onnx};
use inssplat_trainer::model::ModelConfig;
use inssplat_trainer::shapes::{
    FitShapesConfig, accuracy, attach, draw_views, fit, scene_examples,
};
use inssplat_trainer::train::label_cache;
use prost::Message;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn room(split: Split, index: u64) -> Scene {
    let mut cfg = SynthConfig::new(split, Furniture::Primitives);
    (cfg.width, cfg.height, cfg.frames) = (48, 48, (12, 12));
    cfg.structure = Structure::Instances;
    synth::generate_split(index, &cfg).unwrap().scene
}

fn examples(split: Split, rooms: std::ops::Range<u64>) -> Vec<LabelledDescriptor> {
    rooms
        .flat_map(|i| {
            let scene = room(split, i);
            scene_examples(&scene, &draw_views(scene.frames.len(), i))
        })
        .collect()
}

/// The rooms the classifier tests fit on and score on, and their fit's knobs.
fn fit_and_held_out_rooms() -> (Vec<LabelledDescriptor>, Vec<LabelledDescriptor>, FitShapesConfig) {
    (
        examples(Split::Train, 0..40),
        examples(Split::Val, 0..12),
        FitShapesConfig { epochs: 300, ..FitShapesConfig::default() },
    )
}

#[test]
fn descriptors_of_a_room_stand_on_the_floor_found_in_it() {
    let scene = room(Split::Train, 3);
    let all: Vec<usize> = (0..scene.frames.len()).collect();
    let ex = scene_examples(&scene, &all);
    let labels: Vec<&str> = scene.instances.iter().map(|i| i.label.as_str()).collect();
    assert!(ex.iter().all(|e| labels.contains(&e.label.as_str())));
    let floor = ex.iter().find(|e| e.label == "floor").expect("the floor is an instance");
    // The floor is flat and at height 0 (descriptor: height extent, …, bottom, top).
    assert!(floor.descriptor[0] < 0.05 && floor.descriptor[3].abs() < 0.05, "{floor:?}");
    // Walls stand on the floor, upright and thin (the views see their lower part only).
    let walls: Vec<_> = ex.iter().filter(|e| e.label == "wall").collect();
    assert!(!walls.is_empty(), "{ex:?}");
    for w in &walls {
        assert!(
            w.descriptor[0] > 0.8 && w.descriptor[2] < 0.05 && w.descriptor[3].abs() < 0.1,
            "{w:?}"
        );
    }
    for e in ex.iter().filter(|e| !["floor", "wall", "ceiling"].contains(&e.label.as_str())) {
        assert!(e.descriptor[3] > -0.1 && e.descriptor[4] < 3.5, "{e:?}");
    }
}

#[test]
fn a_classifier_fitted_on_some_rooms_names_the_objects_of_others() {
    let (train, held_out, config) = fit_and_held_out_rooms();
    let (c, report) = fit(&train, &held_out, &config, None, &|_, _| {}).unwrap();
    let common = {
        let mut counts = std::collections::BTreeMap::<&str, usize>::new();
        train.iter().for_each(|e| *counts.entry(&e.label).or_default() += 1);
        let top = counts.into_iter().max_by_key(|(_, n)| *n).unwrap().0;
        held_out.iter().filter(|e| e.label == top).count() as f64 / held_out.len() as f64
    };
    let acc = report.held_out_accuracy.unwrap();
    assert!(
        acc > common + 0.2,
        "held-out accuracy {acc} against {common} for the most common label"
    );
    assert_eq!(Some(acc), accuracy(&c, &held_out, &[]).unwrap());
    assert!(report.train_accuracy >= acc);
    assert_eq!(ShapeClassifier::from_json(&c.to_json()).unwrap(), c);
}

#[test]
fn logit_adjustment_moves_only_the_last_bias_and_names_frequent_labels_less_often() {
    let (train, held_out, config) = fit_and_held_out_rooms();
    let (plain, _) = fit(&train, &held_out, &config, None, &|_, _| {}).unwrap();
    let (adjusted, _) =
        fit(&train, &held_out, &FitShapesConfig { logit_adjust: 1.0, ..config }, None, &|_, _| {})
            .unwrap();
    let (last, plain_last) = (adjusted.layers.last().unwrap(), plain.layers.last().unwrap());
    assert_eq!(adjusted.layers[..2], plain.layers[..2]);
    assert_eq!(last.weight, plain_last.weight);
    for (k, label) in plain.labels.iter().enumerate() {
        let share = train.iter().filter(|e| &e.label == label).count() as f32 / train.len() as f32;
        let shift = last.bias[k] - plain_last.bias[k];
        assert!((shift + share.ln()).abs() < 1e-4, "{label}: bias moved {shift}, share {share}");
    }
    // Every example's probability of the most frequent label falls (its share is the
    // largest, so its odds against every other label shrink), and it is named less often.
    let top = (0..plain.labels.len())
        .max_by_key(|&k| train.iter().filter(|e| e.label == plain.labels[k]).count())
        .unwrap();
    let argmax = |p: &[f32]| (0..p.len()).max_by(|&a, &b| p[a].total_cmp(&p[b])).unwrap();
    let (mut named_plain, mut named_adjusted) = (0, 0);
    for e in &held_out {
        let (p, a) =
            (plain.probabilities(&e.descriptor, &[]), adjusted.probabilities(&e.descriptor, &[]));
        assert!(
            a[top] <= p[top] + 1e-6,
            "{}: {} adjusted against {} plain",
            plain.labels[top],
            a[top],
            p[top]
        );
        named_plain += usize::from(argmax(&p) == top);
        named_adjusted += usize::from(argmax(&a) == top);
    }
    assert!(
        named_adjusted < named_plain,
        "{} named {named_adjusted} times adjusted, {named_plain} plain",
        plain.labels[top]
    );
}

/// `examples` with a prototype each: its label's text embedding plus as much noise again
/// (seeded), as a semantic head that knows the label but not well would give.
fn with_prototypes(
    mut ex: Vec<LabelledDescriptor>,
    cache: &LabelCache,
    seed: u64,
) -> Vec<LabelledDescriptor> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for e in &mut ex {
        let text = cache.embed(&[e.label.as_str()]).unwrap()[0];
        let noise: Vec<f32> = (0..text.len()).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let scale = text.iter().map(|x| x * x).sum::<f32>().sqrt()
            / noise.iter().map(|x| x * x).sum::<f32>().sqrt();
        e.prototype = text.iter().zip(&noise).map(|(t, n)| t + n * scale).collect();
    }
    ex
}

#[test]
fn a_semantic_classifier_also_reads_the_prototypes_and_needs_them() {
    let cache = label_cache().unwrap();
    let (train, held_out, config) = fit_and_held_out_rooms();
    let (train, held_out) =
        (with_prototypes(train, &cache, 1), with_prototypes(held_out, &cache, 2));
    let (plain, plain_report) = fit(&train, &held_out, &config, None, &|_, _| {}).unwrap();
    let (c, report) = fit(&train, &held_out, &config, Some(&cache), &|_, _| {}).unwrap();
    assert!(!plain.semantic && c.semantic);
    assert_eq!(c.input_width(), DESCRIPTOR.len() + c.labels.len());
    let (acc, plain_acc) =
        (report.held_out_accuracy.unwrap(), plain_report.held_out_accuracy.unwrap());
    assert!(acc > plain_acc + 0.1, "held out: {acc} with the prototypes, {plain_acc} without");
    assert_eq!(ShapeClassifier::from_json(&c.to_json()).unwrap(), c);
    // An example without its prototype is named.
    let mut bare = held_out.clone();
    bare[3].prototype.clear();
    let err = fit(&train, &bare, &config, Some(&cache), &|_, _| {}).unwrap_err();
    assert!(err.contains("example 3") && err.contains("no prototype"), "{err}");
}

#[test]
fn attach_stores_the_classifier_in_a_model_file_and_refuses_other_files() {
    let tmp = tempfile::tempdir().unwrap();
    let net = ModelConfig::new()
        .with_image_size(32)
        .with_dim(32)
        .with_depth(2)
        .with_heads(2)
        .with_decoder_dim(32);
    let net = net.init(&Device::flex()).unwrap();
    let plain = tmp.path().join("plain.onnx");
    export_onnx(
        &net,
        &plain,
        &ExportMeta { model_version: "v1".into(), train_steps: 3, weights: Weights::F32 },
    )
    .unwrap();
    let (c, _) = fit(
        &examples(Split::Train, 0..4),
        &[],
        &FitShapesConfig { epochs: 5, ..Default::default() },
        None,
        &|_, _| {},
    )
    .unwrap();
    let with = tmp.path().join("with.onnx");
    attach(&plain, &with, &c, Some("v2")).unwrap();
    // Attaching again replaces the entry instead of adding one.
    attach(&with, &with, &c, None).unwrap();
    let proto = ModelProto::decode(std::fs::read(&with).unwrap().as_slice()).unwrap();
    let get = |k: &str| -> Vec<String> {
        proto
            .metadata_props
            .iter()
            .filter(|p| p.key.as_deref() == Some(k))
            .filter_map(|p| p.value.clone())
            .collect()
    };
    assert_eq!(get(sig::META_MODEL_VERSION), ["v2"]);
    assert_eq!(get(sig::META_TRAIN_STEPS), ["3"]);
    let stored = get(sig::META_SHAPE_CLASSIFIER);
    assert_eq!(stored.len(), 1);
    assert_eq!(ShapeClassifier::from_json(&stored[0]).unwrap(), c);
    let before = ModelProto::decode(std::fs::read(&plain).unwrap().as_slice()).unwrap();
    assert_eq!(proto.graph, before.graph);
    let text = tmp.path().join("notes.txt");
    std::fs::write(&text, "not a model").unwrap();
    let err = attach(&text, &with, &c, None).unwrap_err().to_string();
    assert!(err.contains("notes.txt") && err.contains("not an ONNX model"), "{err}");
}

#[test]
fn fit_shapes_names_a_bad_logit_adjustment_and_a_missing_examples_file() {
    let tmp = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_inssplat-train"))
            .args(["fit-shapes", "--model", "missing.onnx", "--out"])
            .arg(tmp.path().join("out.onnx"))
            .args(args)
            .output()
            .unwrap();
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    for bad in ["-1", "NaN"] {
        let err = run(&[&format!("--logit-adjust={bad}"), "--primitives-only"]);
        assert!(err.contains("--logit-adjust") && err.contains("≥ 0"), "{err}");
    }
    let err = run(&["--examples", "/nonexistent/examples.json"]);
    assert!(err.contains("--examples") && err.contains("/nonexistent/examples.json"), "{err}");
    assert!(!tmp.path().join("out.onnx").exists());
}
