//! Parity of the exported ONNX graph with the trainer's own forward pass: a small network
//! with randomised weights (larger than the initial ones, so every activation leaves its
//! linear range) is exported, run through the real ONNX Runtime (`ORT_DYLIB_PATH`, set by
//! `.deps/env`) at 2 and at 5 views — the dynamic view axis — and every signature output is
//! compared with burn's, element by element (with the image encoder's skips, and without them
//! in the shipped model read back). Also checks the graph's declared I/O and metadata
//! against `inssplat_proto::signature`.

use burn::module::{Module, ModuleMapper, Param};
use burn::prelude::*;
use burn::tensor::Distribution;
use inssplat_proto::signature as sig;
use inssplat_trainer::export::{ExportMeta, export_onnx, to_model_proto};
use inssplat_trainer::model::{InsSplatNet, ModelConfig, ModelOutput};
use ort::session::Session;
use ort::value::Tensor as OrtTensor;

/// Absolute tolerance; values larger than 1 in magnitude are compared relative to themselves.
const TOL: f32 = 1e-3;

fn small_config() -> ModelConfig {
    ModelConfig::new()
        .with_image_size(32)
        .with_dim(32)
        .with_depth(2)
        .with_heads(2)
        .with_decoder_dim(32)
        .with_decoder_min_dim(16)
}

/// Adds N(0, std²) noise to every weight.
struct Perturb {
    std: f64,
}

impl ModuleMapper for Perturb {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let std = self.std;
        param.map(|t| {
            let noise = Tensor::random(t.shape(), Distribution::Normal(0.0, std), &t.device());
            t + noise
        })
    }
}

/// The small network with an image encoder, so that parity covers its skips too (the
/// shipped model, read back below, covers the decoder without them).
fn network(device: &Device) -> InsSplatNet {
    device.seed(7);
    small_config()
        .with_image_skips(Some(4))
        .init(device)
        .expect("valid config")
        .map(&mut Perturb { std: 0.15 })
}

fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec_as::<f32>().expect("f32 data")
}

/// ONNX Runtime allows one environment per process; the tests share it.
fn environment() -> &'static ort::environment::Environment {
    static ENV: std::sync::OnceLock<ort::environment::Environment> = std::sync::OnceLock::new();
    ENV.get_or_init(|| {
        let path = std::env::var("ORT_DYLIB_PATH")
            .expect("ORT_DYLIB_PATH is unset: source .deps/env (scripts/setup writes it)");
        ort::init_from(&path)
            .expect("load ONNX Runtime")
            .with_name("inssplat-parity")
            .build()
            .expect("environment")
    })
}

fn session_of(bytes: &[u8]) -> Session {
    let builder = Session::builder(environment()).expect("session builder");
    let mut builder = builder.with_intra_threads(2).expect("thread count");
    builder
        .commit_from_memory(bytes)
        .expect("ONNX Runtime accepts the exported graph")
}

fn compare(name: &str, ours: Vec<f32>, theirs: &[f32]) -> f32 {
    assert_eq!(ours.len(), theirs.len(), "{name}: element count");
    let mut worst = 0f32;
    for (i, (a, b)) in ours.iter().zip(theirs).enumerate() {
        assert!(
            a.is_finite() && b.is_finite(),
            "{name}[{i}]: non-finite burn {a} vs ORT {b}"
        );
        let diff = (a - b).abs();
        assert!(
            diff <= TOL * a.abs().max(1.0),
            "{name}[{i}]: burn {a} vs ORT {b} (diff {diff})"
        );
        worst = worst.max(diff);
    }
    worst
}

fn check_views(views: usize, net: &InsSplatNet, session: &mut Session, device: &Device) {
    let size = net.config().image_size;
    let images = Tensor::<4>::random(
        [views, 3, size, size],
        Distribution::Uniform(0.0, 1.0),
        device,
    );
    let input = OrtTensor::from_array(([views, 3, size, size], to_vec(images.clone())))
        .expect("input tensor");
    let ModelOutput {
        camera,
        depth,
        depth_conf,
        gaussians,
        instance,
        semantic,
        point_map,
        descriptors,
        ..
    } = net.forward(images).expect("forward");
    let (w, b) = net.sem_proj();
    let outputs = session
        .run(ort::inputs![sig::INPUT_IMAGES.name => input])
        .expect("ORT run");
    let point_map = point_map.map(|p| (sig::OUTPUT_POINT_MAP.name, p.dims().to_vec(), to_vec(p)));
    let descriptors = descriptors.map(|d| (sig::OUTPUT_DESCRIPTORS.name, d.dims().to_vec(), to_vec(d)));
    let ours = [
        (
            sig::OUTPUT_CAMERA.name,
            camera.dims().to_vec(),
            to_vec(camera),
        ),
        (sig::OUTPUT_DEPTH.name, depth.dims().to_vec(), to_vec(depth)),
        (
            sig::OUTPUT_DEPTH_CONF.name,
            depth_conf.dims().to_vec(),
            to_vec(depth_conf),
        ),
        (
            sig::OUTPUT_GAUSSIANS.name,
            gaussians.dims().to_vec(),
            to_vec(gaussians),
        ),
        (
            sig::OUTPUT_INSTANCE.name,
            instance.dims().to_vec(),
            to_vec(instance),
        ),
        (
            sig::OUTPUT_SEMANTIC.name,
            semantic.dims().to_vec(),
            to_vec(semantic),
        ),
        (
            sig::OUTPUT_SEM_PROJ_WEIGHT.name,
            w.dims().to_vec(),
            to_vec(w),
        ),
        (sig::OUTPUT_SEM_PROJ_BIAS.name, b.dims().to_vec(), to_vec(b)),
    ];
    for (name, dims, values) in ours.into_iter().chain(point_map).chain(descriptors) {
        let (shape, theirs) = outputs[name]
            .try_extract_tensor::<f32>()
            .expect("f32 output");
        let shape: Vec<usize> = shape.iter().map(|&d| d as usize).collect();
        assert_eq!(shape, dims, "{name}: shape");
        let worst = compare(name, values, theirs);
        eprintln!("{views} views, {name} {dims:?}: max |burn - ORT| = {worst:.2e}");
    }
}

#[test]
fn export_matches_burn_forward_at_2_and_5_views() {
    let device = Device::flex();
    let net = network(&device);
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("model.onnx");
    let meta = ExportMeta {
        model_version: "parity-test".into(),
        train_steps: 0,
    };
    export_onnx(&net, &path, &meta).expect("export");
    let bytes = std::fs::read(&path).expect("read back");
    let mut session = session_of(&bytes);
    for views in [2, 5] {
        check_views(views, &net, &mut session, &device);
    }
    let metadata = session.metadata().expect("metadata");
    assert_eq!(
        metadata.custom(sig::META_IO_VERSION).as_deref(),
        Some(sig::IO_VERSION)
    );
    assert_eq!(
        metadata.custom(sig::META_MODEL_VERSION).as_deref(),
        Some("parity-test")
    );
    assert_eq!(
        metadata.custom(sig::META_RESOLUTION).as_deref(),
        Some("32x32")
    );
    assert_eq!(metadata.custom(sig::META_SEM_DIM).as_deref(), Some("16"));
    assert_eq!(metadata.custom(sig::META_TRAIN_STEPS).as_deref(), Some("0"));
}

/// A network with an image encoder after three real training steps (synthesized scenes, every
/// loss), saved to a checkpoint and loaded back as `inssplat-train export` does.
#[test]
fn a_briefly_trained_checkpoint_exports_with_parity() {
    use inssplat_trainer::loss::LossConfig;
    use inssplat_trainer::synth::{Split, Structure};
    use inssplat_trainer::train::sample::DataSpec;
    use inssplat_trainer::train::{self, Session, TrainConfig, checkpoint};

    let run = tempfile::tempdir().expect("temp dir");
    let config = TrainConfig::new(small_config().with_image_skips(Some(4)), LossConfig::new()).with_steps(3).with_warmup(1).with_max_views(3);
    let data = DataSpec::Synth { split: Split::Train, furniture_dir: None, size: 32, structure: Structure::Instances };
    let session = Session { val_every: 0, progress: false, ..Session::default() };
    let summary = train::train(run.path(), config, data, &session).expect("train");
    let dir = summary.checkpoint.expect("a checkpoint at the end");
    let state = checkpoint::read_state(&dir).expect("state");
    let device = Device::flex();
    let net = checkpoint::load_model(&dir, &state, &device).expect("load");
    let meta = ExportMeta { model_version: "parity-trained".into(), train_steps: state.step };
    let bytes = inssplat_trainer::export::to_onnx_bytes(&net, &meta).expect("export");
    let mut session = session_of(&bytes);
    for views in [2, 5] {
        check_views(views, &net, &mut session, &device);
    }
    assert_eq!(session.metadata().expect("metadata").custom(sig::META_TRAIN_STEPS).as_deref(), Some("3"));
}

#[test]
fn export_declares_the_signature() {
    let net = small_config().init(&Device::flex()).expect("valid config");
    let model = to_model_proto(
        &net,
        &ExportMeta {
            model_version: "x".into(),
            train_steps: 3,
        },
    )
    .expect("export");
    assert!(
        model
            .opset_import
            .iter()
            .any(|o| o.version.unwrap_or(0) >= 17)
    );
    let graph = model.graph.expect("graph");
    let names = |v: &[inssplat_trainer::export::onnx_pb::ValueInfoProto]| -> Vec<String> {
        v.iter()
            .map(|i| i.name.clone().unwrap_or_default())
            .collect()
    };
    let want_in: Vec<String> = sig::INPUTS.iter().map(|t| t.name.to_string()).collect();
    let want_out: Vec<String> = sig::OUTPUTS.iter().map(|t| t.name.to_string()).collect();
    assert_eq!(names(&graph.input), want_in);
    assert_eq!(names(&graph.output), want_out);
    let allowed = [
        "Add",
        "Concat",
        "Conv",
        "ConvTranspose",
        "Div",
        "Erf",
        "Exp",
        "Expand",
        "Identity",
        "LayerNormalization",
        "MatMul",
        "Mul",
        "Reshape",
        "Shape",
        "Sigmoid",
        "Slice",
        "Softmax",
        "Softplus",
        "Split",
        "Squeeze",
        "Sub",
        "Transpose",
    ];
    for node in &graph.node {
        let op = node.op_type.as_deref().unwrap_or_default();
        assert!(allowed.contains(&op), "unexpected op {op}");
    }
}

fn shipped_model() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../models/inssplat-default.onnx")
}

/// The shipped model read back into a burn network computes what ONNX Runtime computes from
/// the file itself: training can go on from a release whose run folder is gone.
#[test]
fn the_shipped_model_reads_back_into_a_network_with_parity() {
    let device = Device::flex();
    let path = shipped_model();
    let (net, meta) = inssplat_trainer::export::import_onnx(&path, &device).expect("import the shipped model");
    let c = net.config();
    assert_eq!((c.image_size, c.dim, c.depth, c.heads, c.sem_dim), (128, 192, 6, 3, 16));
    assert!(meta.train_steps > 0, "the release records its steps");
    let mut session = session_of(&std::fs::read(&path).expect("read the shipped model"));
    check_views(2, &net, &mut session, &device);
}

/// A file with one weight taken out, and a file that is not ONNX, are refused with errors
/// naming the file and the weight.
#[test]
fn an_onnx_file_without_a_weight_or_not_onnx_is_refused_by_name() {
    use prost::Message;
    let dir = tempfile::tempdir().expect("temp dir");
    let net = network(&Device::flex());
    let mut model = to_model_proto(&net, &ExportMeta { model_version: "x".into(), train_steps: 3 }).expect("export");
    let graph = model.graph.as_mut().expect("graph");
    let before = graph.initializer.len();
    graph.initializer.retain(|t| !t.name.as_deref().unwrap_or_default().starts_with("blocks.1.fc1.weight_"));
    assert_eq!(graph.initializer.len(), before - 1);
    let path = dir.path().join("holed.onnx");
    std::fs::write(&path, model.encode_to_vec()).expect("write");
    let err = inssplat_trainer::export::import_onnx(&path, &Device::flex()).expect_err("a missing weight").to_string();
    assert!(err.contains("holed.onnx") && err.contains("blocks.1.fc1.weight"), "{err}");
    let junk = dir.path().join("junk.onnx");
    std::fs::write(&junk, b"not a model at all").expect("write");
    let err = inssplat_trainer::export::import_onnx(&junk, &Device::flex()).expect_err("not ONNX").to_string();
    assert!(err.contains("junk.onnx") && err.contains("not an ONNX model"), "{err}");
}

/// `--init-from model.onnx`: a fine-tune starts from an exported file's weights and records it.
#[test]
fn a_fine_tune_starts_from_an_exported_onnx_file() {
    use inssplat_trainer::loss::LossConfig;
    use inssplat_trainer::synth::{Split, Structure};
    use inssplat_trainer::train::sample::DataSpec;
    use inssplat_trainer::train::{self, Session, TrainConfig, checkpoint};

    let dir = tempfile::tempdir().expect("temp dir");
    let source = network(&Device::flex());
    let onnx = dir.path().join("start.onnx");
    export_onnx(&source, &onnx, &ExportMeta { model_version: "start".into(), train_steps: 41 }).expect("export");
    let config = TrainConfig::new(ModelConfig::new(), LossConfig::new()).with_steps(2).with_warmup(1).with_max_views(3).with_first_scene(5);
    let data = DataSpec::Synth { split: Split::Train, furniture_dir: None, size: 32, structure: Structure::Instances };
    let session = Session { val_every: 0, progress: false, ..Session::default() };
    let run = dir.path().join("run");
    let summary = train::fine_tune(&run, config, data, &onnx, &session).expect("fine-tune from ONNX");
    let state = checkpoint::read_state(&summary.checkpoint.expect("a checkpoint")).expect("state");
    let from = state.init_from.expect("init_from recorded");
    assert_eq!((from.checkpoint.as_path(), from.step, state.step), (onnx.as_path(), 41, 2));
    assert_eq!(state.config.model, *source.config(), "the file's shape, not the default one");
}

/// `--init-from M --image-skips K --point-map-weight W --descriptor-weight W` on a network
/// without an image encoder or either head: the grown network computes exactly what the source
/// did (the skips join through zero layers, each head has an output of its own), has the new
/// parts' weights besides, and exports (the point map and the descriptors as the optional
/// `point_map` and `descriptors` outputs) and reads back with parity.
#[test]
fn growing_an_image_encoder_and_the_point_and_descriptor_heads_keeps_the_output_and_exports_with_parity() {
    let device = Device::flex();
    device.seed(11);
    let source = small_config().init(&device).expect("valid config").map(&mut Perturb { std: 0.15 });
    let shape = source.config().clone().with_image_skips(Some(4)).with_point_head(Some(8)).with_descriptor_head(Some(6));
    let grown = inssplat_trainer::train::grow(&source, shape, 5, &device).expect("grow");
    let c = grown.config();
    assert_eq!((c.image_skips, c.point_head, c.descriptor_head), (Some(4), Some(8), Some(6)));
    assert!(grown.num_params() > source.num_params(), "the new parts add weights");
    let images = Tensor::<4>::random([3, 3, 32, 32], Distribution::Uniform(0.0, 1.0), &device);
    let (a, b) = (source.forward(images.clone()).expect("forward"), grown.forward(images).expect("forward"));
    assert!(a.point_map.is_none() && a.descriptors.is_none());
    assert_eq!(b.point_map.as_ref().map(|p| p.dims()), Some([3, 3, 32, 32]));
    assert_eq!(b.descriptors.as_ref().map(|p| p.dims()), Some([3, 6, 32, 32]));
    for (name, x, y) in [("depth", a.depth, b.depth), ("gaussians", a.gaussians, b.gaussians), ("instance", a.instance, b.instance), ("semantic", a.semantic, b.semantic)] {
        assert_eq!(to_vec(x), to_vec(y), "{name}: the grown network's output differs");
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("grown.onnx");
    export_onnx(&grown, &path, &ExportMeta { model_version: "grown".into(), train_steps: 1 }).expect("export");
    let (back, _) = inssplat_trainer::export::import_onnx(&path, &device).expect("read back");
    assert_eq!(back.config(), grown.config());
    let mut session = session_of(&std::fs::read(&path).expect("read"));
    check_views(2, &back, &mut session, &device);
}
