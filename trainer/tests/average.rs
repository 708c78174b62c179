//! `inssplat-train average`: the mean of real checkpoints' weights, written into a copy of a
//! model file whose metadata it keeps; checkpoints of another shape, and a step filter that
//! leaves none, are refused by name; `export --metadata-from` keeps another file's metadata.

use burn::prelude::*;
use burn::store::ModuleSnapshot;
use inssplat_proto::signature as sig;
use inssplat_synth::{Split, Structure};
use inssplat_trainer::export::import_onnx;
use inssplat_trainer::loss::LossConfig;
use inssplat_trainer::model::InsSplatNet;
use inssplat_trainer::train::sample::DataSpec;
use inssplat_trainer::train::{self, Session, TrainConfig, checkpoint};

use crate::export_parity::{plain_file, session_of, small_config, trainer};

/// Every parameter of `net`, by name, as f32 values.
fn parameters(net: &InsSplatNet) -> Vec<(String, Vec<f32>)> {
    net.collect(None, None, false)
        .into_iter()
        .map(|t| {
            let (name, _, _, _, bytes) = t.into_parts().expect("resident tensor");
            (
                name,
                bytes
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                    .collect(),
            )
        })
        .collect()
}

/// A run of two real training steps on synthesized scenes from `first_scene`, in `dir`.
fn trained_run(dir: &std::path::Path, first_scene: u64) -> InsSplatNet {
    let config = TrainConfig::new(small_config().with_image_skips(Some(4)), LossConfig::new())
        .with_steps(2)
        .with_warmup(1)
        .with_max_views(3)
        .with_first_scene(first_scene);
    let data = DataSpec::Synth {
        split: Split::Train,
        furniture_dir: None,
        size: 32,
        structure: Structure::Instances,
        antialias: 1,
    };
    let session = Session { val_every: 0, progress: false, ..Session::default() };
    let summary = train::train(dir, config, data, &session).expect("train");
    let ckpt = summary.checkpoint.expect("a checkpoint at the end");
    checkpoint::load_model(&ckpt, &checkpoint::read_state(&ckpt).expect("state"), &Device::flex())
        .expect("load")
}

#[test]
fn average_writes_the_mean_of_the_checkpoints_into_the_base_file() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (run_a, run_b) = (dir.path().join("a"), dir.path().join("b"));
    let (a, b) = (trained_run(&run_a, 3), trained_run(&run_b, 40));
    let base = plain_file(&a, dir.path());
    let out = dir.path().join("mean.onnx");
    let run = |extra: &[&std::ffi::OsStr], out: &std::path::Path| {
        let mut args: Vec<&std::ffi::OsStr> = vec![
            "average".as_ref(),
            "--model".as_ref(),
            base.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ];
        args.extend(extra);
        trainer(&args)
    };
    let done = run(&[run_a.as_os_str(), run_b.as_os_str()], &out);
    assert!(done.status.success(), "{}", String::from_utf8_lossy(&done.stderr));

    let (mean, meta) = import_onnx(&out, &Device::flex())
        .expect("the mean reads back (its graph is the exporter's)");
    assert_eq!((meta.model_version.as_str(), meta.train_steps), ("inssplat-0.1.0+a.avg2-2", 2));
    let (pa, pb, pm) = (parameters(&a), parameters(&b), parameters(&mean));
    let mut differing = 0;
    for (((name, x), (_, y)), (_, m)) in pa.iter().zip(&pb).zip(&pm) {
        for ((x, y), m) in x.iter().zip(y).zip(m) {
            assert!(
                (m - 0.5 * (x + y)).abs() <= 1e-6 * (1.0 + m.abs()),
                "{name}: {m} is not the mean of {x} and {y}"
            );
            differing += usize::from(x != y);
        }
    }
    assert!(
        differing > 1000,
        "the two runs trained on different scenes differ ({differing} weights)"
    );
    let session = session_of(&std::fs::read(&out).expect("the file"));
    let metadata = session.metadata().expect("metadata");
    assert_eq!(
        metadata.custom("inssplat.extra").as_deref(),
        Some("kept"),
        "the base file's other metadata stays"
    );
    assert_eq!(metadata.custom(sig::META_TRAIN_STEPS).as_deref(), Some("2"));

    // A base file of another shape (no image encoder) is refused, naming the checkpoint.
    let other = small_config().init(&Device::flex()).expect("valid config");
    let other_dir = dir.path().join("other");
    std::fs::create_dir_all(&other_dir).expect("dir");
    let other_base = plain_file(&other, &other_dir);
    let refused = dir.path().join("refused.onnx");
    let args: Vec<&std::ffi::OsStr> = vec![
        "average".as_ref(),
        "--model".as_ref(),
        other_base.as_os_str(),
        "--out".as_ref(),
        refused.as_os_str(),
        run_a.as_os_str(),
    ];
    let out_err = trainer(&args);
    let err = String::from_utf8_lossy(&out_err.stderr);
    assert!(
        !out_err.status.success() && err.contains("another shape") && err.contains("step_00000002"),
        "{err}"
    );
    assert!(!refused.exists());

    // No checkpoint at or after --from-step, and a folder without checkpoints: errors by name.
    let late = run(&[run_a.as_os_str(), "--from-step".as_ref(), "5".as_ref()], &refused);
    assert!(
        !late.status.success()
            && String::from_utf8_lossy(&late.stderr).contains("no checkpoint of step 5 or later")
    );
    let empty = run(&[other_dir.as_os_str()], &refused);
    let err = String::from_utf8_lossy(&empty.stderr);
    assert!(
        !empty.status.success()
            && err.contains("neither a run with checkpoints nor a checkpoint")
            && err.contains("other"),
        "{err}"
    );
    assert!(!refused.exists());

    // What `average` refuses, `export --metadata-from` does: the checkpoint's own network
    // with the other file's metadata.
    let kept = dir.path().join("kept.onnx");
    let args: Vec<&std::ffi::OsStr> = vec![
        "export".as_ref(),
        "--checkpoint".as_ref(),
        run_a.as_os_str(),
        "--out".as_ref(),
        kept.as_os_str(),
        "--metadata-from".as_ref(),
        other_base.as_os_str(),
    ];
    let done = trainer(&args);
    assert!(done.status.success(), "{}", String::from_utf8_lossy(&done.stderr));
    let (net, _) = import_onnx(&kept, &Device::flex()).expect("reads back");
    assert_eq!(parameters(&net), pa, "the checkpoint's weights");
    let session = session_of(&std::fs::read(&kept).expect("the file"));
    assert_eq!(
        session.metadata().expect("metadata").custom("inssplat.extra").as_deref(),
        Some("kept")
    );
}
