//! The exported file read back, fine-tuned from, grown, quantized to int8 and rewritten with
//! pooled attention: each keeps the network and its parity with burn.

use super::*;

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
