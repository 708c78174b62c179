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
use inssplat_trainer::export::{ExportMeta, Weights, export_onnx, to_model_proto};
use inssplat_trainer::model::{InsSplatNet, ModelConfig, ModelOutput};
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

/// Runs `views` random images through `net` and the session, compares every output, and
/// returns each output's [`compare`] figure by name.
fn check_views(
    views: usize,
    net: &InsSplatNet,
    session: &mut Session,
    device: &Device,
    tol: Tol,
) -> Vec<(&'static str, f32)> {
    let size = net.config().image_size;
    let images =
        Tensor::<4>::random([views, 3, size, size], Distribution::Uniform(0.0, 1.0), device);
    let input = OrtTensor::from_array(([views, 3, size, size], to_vec(images.clone())))
        .expect("input tensor");
    // A network that reads camera rays gets random ones, the same on both sides.
    let rays = net.config().camera_rays.map(|k| {
        let grid = size / net.config().patch;
        Tensor::<3>::random(
            [views, grid * grid, inssplat_proto::rays::ray_channels(k)],
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
    assert_eq!(rays.dtype().tensor_shape().map(|s| s.to_vec()), Some(vec![-1, 16, 24]));
    for views in [2, 3] {
        check_views(views, &net, &mut session, &device, Tol::Exact);
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

/// A file with one weight taken out, and a file that is not ONNX, are refused with errors
/// naming the file and the weight.
#[test]
fn an_onnx_file_without_a_weight_or_not_onnx_is_refused_by_name() {
    use prost::Message;
    let dir = tempfile::tempdir().expect("temp dir");
    let net = network(&Device::flex());
    let mut model = to_model_proto(
        &net,
        &ExportMeta { model_version: "x".into(), train_steps: 3, weights: Weights::F32 },
    )
    .expect("export");
    let graph = model.graph.as_mut().expect("graph");
    let before = graph.initializer.len();
    graph
        .initializer
        .retain(|t| !t.name.as_deref().unwrap_or_default().starts_with("blocks.1.fc1.weight_"));
    assert_eq!(graph.initializer.len(), before - 1);
    let path = dir.path().join("holed.onnx");
    std::fs::write(&path, model.encode_to_vec()).expect("write");
    let err = inssplat_trainer::export::import_onnx(&path, &Device::flex())
        .expect_err("a missing weight")
        .to_string();
    assert!(err.contains("holed.onnx") && err.contains("blocks.1.fc1.weight"), "{err}");
    let junk = dir.path().join("junk.onnx");
    std::fs::write(&junk, b"not a model at all").expect("write");
    let err = inssplat_trainer::export::import_onnx(&junk, &Device::flex())
        .expect_err("not ONNX")
        .to_string();
    assert!(err.contains("junk.onnx") && err.contains("not an ONNX model"), "{err}");
}

/// `--init-from model.onnx --global-kv-pool 2`: a fine-tune starts from an exported file's
/// weights, records it, and trains them through the pooled global attention; from a file that
/// pools, the pooling stays unless `--global-kv-pool 1` asks for every token.
#[test]
fn a_fine_tune_starts_from_an_exported_onnx_file() {
    use inssplat_synth::{Split, Structure};
    use inssplat_trainer::loss::LossConfig;
    use inssplat_trainer::train::sample::DataSpec;
    use inssplat_trainer::train::{self, Session, TrainConfig, checkpoint};

    let dir = tempfile::tempdir().expect("temp dir");
    let source = network(&Device::flex());
    let onnx = dir.path().join("start.onnx");
    export_onnx(
        &source,
        &onnx,
        &ExportMeta { model_version: "start".into(), train_steps: 41, weights: Weights::F32 },
    )
    .expect("export");
    let config =
        TrainConfig::new(ModelConfig::new().with_global_kv_pool(Some(2)), LossConfig::new())
            .with_steps(2)
            .with_warmup(1)
            .with_max_views(3)
            .with_first_scene(5);
    let data = DataSpec::Synth {
        split: Split::Train,
        furniture_dir: None,
        size: 32,
        structure: Structure::Instances,
        antialias: 1,
    };
    let session = Session { val_every: 0, progress: false, ..Session::default() };
    let run = dir.path().join("run");
    let summary =
        train::fine_tune(&run, config, data.clone(), &onnx, &session).expect("fine-tune from ONNX");
    let state = checkpoint::read_state(&summary.checkpoint.expect("a checkpoint")).expect("state");
    let from = state.init_from.expect("init_from recorded");
    assert_eq!((from.checkpoint.as_path(), from.step, state.step), (onnx.as_path(), 41, 2));
    assert_eq!(
        state.config.model,
        source.config().clone().with_global_kv_pool(Some(2)),
        "the file's shape, not the default one, read through the pooling asked for"
    );

    // From a file that pools (as the shipped model does): left out, the pooling stays; 1 reads
    // every token again.
    let pooled = dir.path().join("pooled.onnx");
    let pooled_net = source.clone().with_global_kv_pool(Some(2)).expect("2 divides 4");
    export_onnx(
        &pooled_net,
        &pooled,
        &ExportMeta { model_version: "pooled".into(), train_steps: 7, weights: Weights::F32 },
    )
    .expect("export");
    for (asked, kept) in [(None, Some(2)), (Some(1), None)] {
        let config =
            TrainConfig::new(ModelConfig::new().with_global_kv_pool(asked), LossConfig::new())
                .with_steps(1)
                .with_warmup(1)
                .with_max_views(2)
                .with_first_scene(5);
        let run = dir.path().join(format!("run_{asked:?}"));
        let summary = train::fine_tune(&run, config, data.clone(), &pooled, &session)
            .expect("fine-tune from a pooled file");
        let state =
            checkpoint::read_state(&summary.checkpoint.expect("a checkpoint")).expect("state");
        assert_eq!(state.config.model.global_kv_pool, kept, "asked {asked:?}");
    }
}

/// `--init-from M --image-skips K --mlp-ratio R` on a network without an image encoder and
/// with narrower MLPs: the grown network computes exactly what the source did (the skips and
/// the new hidden units join through zeros), has the new parts' weights besides, and exports
/// and reads back with parity.
#[test]
fn growing_an_image_encoder_and_the_mlps_keeps_the_output_and_exports_with_parity() {
    let device = Device::flex();
    device.seed(11);
    let source =
        small_config().init(&device).expect("valid config").map(&mut Perturb { std: 0.15 });
    let shape = source.config().clone().with_image_skips(Some(4)).with_mlp_ratio(6);
    let grown = inssplat_trainer::train::grow(&source, shape, 5, &device).expect("grow");
    let c = grown.config();
    assert_eq!((c.image_skips, c.mlp_ratio), (Some(4), 6));
    assert!(grown.num_params() > source.num_params(), "the new parts add weights");
    let images = Tensor::<4>::random([3, 3, 32, 32], Distribution::Uniform(0.0, 1.0), &device);
    let (a, b) =
        (source.forward(images.clone()).expect("forward"), grown.forward(images).expect("forward"));
    for (name, x, y) in [
        ("depth", a.depth, b.depth),
        ("gaussians", a.gaussians, b.gaussians),
        ("instance", a.instance, b.instance),
        ("semantic", a.semantic, b.semantic),
    ] {
        assert_eq!(to_vec(x), to_vec(y), "{name}: the grown network's output differs");
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("grown.onnx");
    export_onnx(
        &grown,
        &path,
        &ExportMeta { model_version: "grown".into(), train_steps: 1, weights: Weights::F32 },
    )
    .expect("export");
    let (back, _) = inssplat_trainer::export::import_onnx(&path, &device).expect("read back");
    assert_eq!(back.config(), grown.config());
    let mut session = session_of(&std::fs::read(&path).expect("read"));
    check_views(2, &back, &mut session, &device, Tol::Exact);
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

/// `inssplat-train quantize`: the int8 file holds one `MatMulInteger` a linear layer and no
/// float weight for any of them, is smaller, keeps the input's other metadata, runs in ONNX
/// Runtime close to the network (but not exactly: it is quantized), and reads back into a
/// network whose weights lie within half a step of the originals and whose export is the
/// file again (`import_onnx` checks that).
#[test]
fn quantize_writes_int8_linear_weights_that_run_close_to_the_network_and_read_back() {
    use inssplat_trainer::export::onnx_pb::ModelProto;
    use prost::Message;
    let device = Device::flex();
    let net = network(&device);
    let dir = tempfile::tempdir().expect("temp dir");
    let plain = plain_file(&net, dir.path());
    let int8 = dir.path().join("int8.onnx");
    let out = trainer(&[
        "quantize".as_ref(),
        "--model".as_ref(),
        plain.as_os_str(),
        "--out".as_ref(),
        int8.as_os_str(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let bytes = std::fs::read(&int8).expect("the int8 file");
    assert!(
        bytes.len() < std::fs::metadata(&plain).expect("plain").len() as usize,
        "int8 weights take less space"
    );

    let proto = ModelProto::decode(bytes.as_slice()).expect("ONNX");
    let graph = proto.graph.as_ref().expect("graph");
    let count = |op: &str| graph.node.iter().filter(|n| n.op_type.as_deref() == Some(op)).count();
    let linear = 4 * net.config().depth + 4; // qkv, proj, fc1, fc2 a block; patch embedding, camera head ×2, decoder fusion
    assert_eq!((count("MatMulInteger"), count("DynamicQuantizeLinear")), (linear, linear));
    assert_eq!(count("MatMul"), 2 * net.config().depth, "only the attention products stay float");
    let meta = |key: &str| {
        proto
            .metadata_props
            .iter()
            .find(|p| p.key.as_deref() == Some(key))
            .and_then(|p| p.value.clone())
    };
    assert_eq!(meta("inssplat.extra").as_deref(), Some("kept"));
    assert_eq!(
        meta(sig::META_MODEL_VERSION).as_deref(),
        Some("plain+int8"),
        "the input's version, marked"
    );
    assert_eq!(meta(inssplat_trainer::export::META_WEIGHTS).as_deref(), Some("int8"));

    let mut session = session_of(&bytes);
    let figures = check_views(3, &net, &mut session, &device, Tol::Int8);
    let depth = figures.iter().find(|(n, _)| *n == sig::OUTPUT_DEPTH.name).expect("depth").1;
    assert!(depth > 0.0, "an int8 forward differs from the float one");

    let (back, back_meta) =
        inssplat_trainer::export::import_onnx(&int8, &device).expect("an int8 file reads back");
    assert_eq!((back_meta.weights, back_meta.train_steps), (Weights::Int8, 9));
    let weight = |n: &InsSplatNet| -> Vec<f32> {
        let m = to_model_proto(
            n,
            &ExportMeta { model_version: "w".into(), train_steps: 0, weights: Weights::F32 },
        )
        .expect("export");
        let t = m
            .graph
            .expect("graph")
            .initializer
            .into_iter()
            .find(|t| t.name.as_deref().is_some_and(|n| n.starts_with("blocks.0.fc1.weight_")))
            .expect("blocks.0.fc1.weight");
        t.raw_data
            .expect("raw")
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()
    };
    let (a, b) = (weight(&net), weight(&back));
    let step = a.iter().fold(0f32, |m, v| m.max(v.abs())) / 63.0;
    assert!(
        a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= 0.5 * step * 1.001),
        "dequantized within half a step"
    );
    assert!(a != b, "the read-back weights are the quantized ones");

    let never = dir.path().join("never.onnx");
    let missing = trainer(&[
        "quantize".as_ref(),
        "--model".as_ref(),
        "/nonexistent/m.onnx".as_ref(),
        "--out".as_ref(),
        never.as_os_str(),
    ]);
    let err = String::from_utf8_lossy(&missing.stderr);
    assert!(!missing.status.success() && err.contains("/nonexistent/m.onnx"), "{err}");
    assert!(!never.exists());
}

/// `inssplat-train pool-keys --pool 2`: the rewritten file keeps the weights and the input's
/// other metadata, records the pooling in its configuration, runs in ONNX Runtime exactly as
/// the pooled burn network does at 2 and 5 views (so the ReduceMean pooling of the export is
/// the trainer's), differs from the unpooled network, and reads back; `--pool 3`, which does
/// not divide the 4 patches a side, is refused by name.
#[test]
fn pool_keys_rewrites_a_file_whose_pooled_global_attention_matches_burn() {
    let device = Device::flex();
    let net = network(&device);
    let dir = tempfile::tempdir().expect("temp dir");
    let plain = plain_file(&net, dir.path());
    let run = |pool: &str, out: &std::path::Path| {
        trainer(&[
            "pool-keys".as_ref(),
            "--pool".as_ref(),
            pool.as_ref(),
            "--model".as_ref(),
            plain.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ])
    };
    let pooled_file = dir.path().join("kv2.onnx");
    let out = run("2", &pooled_file);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));

    let pooled = net.clone().with_global_kv_pool(Some(2)).expect("2 divides 4");
    let mut session = session_of(&std::fs::read(&pooled_file).expect("the pooled file"));
    for views in [2, 5] {
        check_views(views, &pooled, &mut session, &device, Tol::Exact);
    }
    let metadata = session.metadata().expect("metadata");
    assert_eq!(metadata.custom("inssplat.extra").as_deref(), Some("kept"));
    assert_eq!(metadata.custom(sig::META_MODEL_VERSION).as_deref(), Some("plain+kv2"));
    let images = Tensor::<4>::random([3, 3, 32, 32], Distribution::Uniform(0.0, 1.0), &device);
    let (a, b) =
        (net.forward(images.clone()).expect("forward"), pooled.forward(images).expect("forward"));
    assert_ne!(to_vec(a.depth), to_vec(b.depth), "pooling changes what the global layers read");
    let (back, meta) =
        inssplat_trainer::export::import_onnx(&pooled_file, &device).expect("read back");
    assert_eq!((back.config().global_kv_pool, meta.train_steps), (Some(2), 9));

    let refused = dir.path().join("kv3.onnx");
    let out = run("3", &refused);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("global_kv_pool 3") && err.contains("plain.onnx"),
        "{err}"
    );
    assert!(!refused.exists());
}
