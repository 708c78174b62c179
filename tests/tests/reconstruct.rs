//! `inssplat reconstruct` end to end: a small network exported by the trainer (random
//! weights: this checks the plumbing, not accuracy), a procedural test scene, the real
//! binary and the real ONNX Runtime. Also the CLI's errors for bad input, each naming the
//! file at fault.

use std::path::PathBuf;
use std::sync::OnceLock;

use crate::support::{self, s};

use inssplat_e2e::{inssplat, inssplat_bin};
use inssplat_proto::api::ReconstructResponse;
use inssplat_proto::dataset::TransformsJson;
use inssplat_synth::{self as synth, Furniture, Split, SynthConfig};

/// A tiny exported network and a 4-view 32×32 scene, made once per test process.
fn fixtures() -> &'static (tempfile::TempDir, PathBuf, PathBuf) {
    static FIXTURES: OnceLock<(tempfile::TempDir, PathBuf, PathBuf)> = OnceLock::new();
    FIXTURES.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let model = support::tiny_model(dir.path());
        let mut cfg = SynthConfig::new(Split::Val, Furniture::Primitives);
        (cfg.width, cfg.height, cfg.frames, cfg.objects) = (32, 32, (4, 4), (3, 5));
        let scene = synth::generate(11, &cfg).unwrap();
        let scene_dir = dir.path().join("scene");
        scene.write(&scene_dir).unwrap();
        (dir, model, scene_dir)
    })
}

fn run(args: &[&str]) -> (bool, String, String) {
    let out = inssplat(args);
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

#[test]
fn reconstructs_a_scene_and_writes_every_artefact() {
    let (dir, model, scene) = fixtures();
    let out = dir.path().join("out");
    let (ok, stdout, stderr) =
        run(&["reconstruct", s(scene), "-o", s(&out), "--model", s(model), "--json"]);
    assert!(ok, "{stderr}");
    let r: ReconstructResponse = serde_json::from_str(&stdout).unwrap();
    assert_eq!(r.cameras.len(), 4);
    assert!(
        r.gaussians_kept > 0 && r.gaussians_kept <= r.gaussians_in && r.gaussians_in <= 4 * 32 * 32
    );
    let stages: Vec<&str> = r.timings.iter().map(|t| t.stage.as_str()).collect();
    assert_eq!(
        stages,
        [
            "decode",
            "detect",
            "model",
            "superpixels",
            "register",
            "heading",
            "backproject",
            "voxelize",
            "cluster",
            "vote",
            "masks",
            "label",
            "upsample"
        ]
    );

    let ply =
        inssplat_proto::ply::read_ply(&mut std::fs::File::open(out.join("scene.ply")).unwrap())
            .unwrap();
    assert_eq!(ply.len(), r.gaussians_kept);
    assert_eq!(ply.sem_dim, 16);
    assert_eq!(ply.meta.model_version.as_deref(), Some("e2e-random"));
    for v in 0..4 {
        for kind in ["instances", "labels", "ids"] {
            let img = image::open(out.join(format!("{kind}/{v:03}.png"))).unwrap();
            assert_eq!((img.width(), img.height()), (32, 32), "{kind} {v}");
        }
        // The ids are the instance table's, 16-bit.
        let ids = image::open(out.join(format!("ids/{v:03}.png"))).unwrap().into_luma16();
        assert!(
            ids.pixels().all(|p| p[0] == 0 || r.instances.iter().any(|i| i.id == u32::from(p[0])))
        );
    }
    let t: TransformsJson =
        serde_json::from_str(&std::fs::read_to_string(out.join("transforms.json")).unwrap())
            .unwrap();
    assert_eq!(t.frames.len(), 4);
    assert!(out.join("preview.png").is_file() && out.join("instances.json").is_file());
    // The folder is self-contained: each frame names its photo's copy relative to the json
    // (as nerfstudio-style loaders require), the copy is the input photo, and the folder loads
    // as a dataset scene with every photo at its frame's size.
    for (i, f) in t.frames.iter().enumerate() {
        assert_eq!(f.file_path, format!("images/{i:03}.png"));
    }
    let copy = image::open(out.join(&t.frames[1].file_path)).unwrap().into_rgb8();
    let given = inssplat_proto::dataset::Scene::load(scene).unwrap();
    let context: Vec<&[u8]> = given.frames.iter().map(|f| f.rgb.as_slice()).collect();
    assert!(context.contains(&copy.as_raw().as_slice()), "the copy is one of the input photos");
    let opened = inssplat_proto::dataset::Scene::load(&out).unwrap();
    assert_eq!(opened.frames.len(), 4);
    // Moved elsewhere, it still opens: nothing in it points outside.
    let moved = dir.path().join("moved");
    std::fs::rename(&out, &moved).unwrap();
    assert_eq!(inssplat_proto::dataset::Scene::load(&moved).unwrap().frames.len(), 4);
    std::fs::rename(&moved, &out).unwrap();
}

/// A network that reads its cameras as rays runs again on the registered cameras (stage
/// "rays", after the cameras are placed), and once with `--no-ray-pass` or its environment
/// variable.
#[test]
fn a_network_that_reads_rays_runs_twice_unless_told_not_to() {
    let (dir, _, scene) = fixtures();
    let model = support::tiny_rays_model(dir.path());
    let stages = |extra: &[&str], env: &[(&str, &str)]| -> Vec<String> {
        let out = dir.path().join(format!("rays-out{}{}", extra.concat(), env.len()));
        let args =
            [&["reconstruct", s(scene), "-o", s(&out), "--model", s(&model), "--json"], extra]
                .concat();
        let output = std::process::Command::new(inssplat_bin())
            .args(&args)
            .envs(env.iter().copied())
            .output()
            .unwrap();
        assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
        let r: ReconstructResponse = serde_json::from_slice(&output.stdout).unwrap();
        r.timings.into_iter().map(|t| t.stage).collect()
    };
    let twice = stages(&[], &[]);
    assert_eq!(
        twice.iter().position(|t| t == "rays"),
        twice.iter().position(|t| t == "heading").map(|h| h + 1),
        "{twice:?}"
    );
    let once = stages(&["--no-ray-pass"], &[]);
    assert_eq!(once, twice.iter().filter(|t| *t != "rays").cloned().collect::<Vec<_>>());
    assert_eq!(stages(&[], &[("INSSPLAT_NO_RAY_PASS", "true")]), once);
}

#[test]
fn refuses_a_single_view() {
    let (dir, model, scene) = fixtures();
    let (ok, _, stderr) = run(&[
        "reconstruct",
        s(&scene.join("images/000.png")),
        "-o",
        s(&dir.path().join("o1")),
        "--model",
        s(model),
    ]);
    assert!(!ok);
    assert!(stderr.contains("1 images given"), "{stderr}");
}

#[test]
fn names_a_corrupt_and_an_empty_image() {
    let (dir, model, scene) = fixtures();
    let bad = dir.path().join("corrupt.png");
    std::fs::write(&bad, b"\x89PNG\r\n\x1a\n garbage").unwrap();
    let empty = dir.path().join("empty.jpg");
    std::fs::write(&empty, b"").unwrap();
    let good = scene.join("images/001.png");
    for file in [&bad, &empty] {
        let (ok, _, stderr) = run(&[
            "reconstruct",
            s(file),
            s(&good),
            "-o",
            s(&dir.path().join("o2")),
            "--model",
            s(model),
        ]);
        assert!(!ok);
        assert!(stderr.contains(s(file)), "error names {}: {stderr}", file.display());
    }
}

#[test]
fn names_a_missing_and_an_incompatible_model() {
    let (dir, _, scene) = fixtures();
    let missing = dir.path().join("nope.onnx");
    let (ok, _, stderr) =
        run(&["reconstruct", s(scene), "-o", s(&dir.path().join("o3")), "--model", s(&missing)]);
    assert!(!ok && stderr.contains("nope.onnx") && stderr.contains("not found"), "{stderr}");
    let not_a_model = dir.path().join("garbage.onnx");
    std::fs::write(&not_a_model, b"definitely not protobuf").unwrap();
    let (ok, _, stderr) = run(&[
        "reconstruct",
        s(scene),
        "-o",
        s(&dir.path().join("o4")),
        "--model",
        s(&not_a_model),
    ]);
    assert!(!ok && stderr.contains("garbage.onnx"), "{stderr}");
}

#[test]
fn queries_a_saved_reconstruction() {
    let (dir, model, scene) = fixtures();
    let out = dir.path().join("oq");
    let (ok, stdout, stderr) =
        run(&["reconstruct", s(scene), "-o", s(&out), "--model", s(model), "--json"]);
    assert!(ok, "{stderr}");
    let r: ReconstructResponse = serde_json::from_str(&stdout).unwrap();
    let label = r.instances.first().map_or("chair", |i| i.label.as_str());
    let (ok, stdout, stderr) = run(&["query", s(&out), label, "--json"]);
    assert!(ok, "{stderr}");
    let answer: inssplat_proto::api::QueryResponse = serde_json::from_str(&stdout).unwrap();
    assert_eq!(answer.text, label);
    // Random weights may or may not clear the score threshold; either answer must be complete.
    match answer.message {
        Some(msg) => assert!(
            answer.matches.is_empty() && msg.contains("nothing in this scene matches"),
            "{msg}"
        ),
        None => {
            assert!(!answer.matches.is_empty());
            for m in &answer.matches {
                assert!(r.instances.iter().any(|i| i.id == m.instance_id && i.label == m.label));
                assert_eq!(m.masks.len(), 4);
                for v in &m.masks {
                    assert_eq!((v.rle.width, v.rle.height, v.rle.decode().len()), (32, 32, 1024));
                    assert_eq!(image::open(&v.png_url).unwrap().width(), 32);
                }
            }
        }
    }
    let (ok, _, stderr) = run(&["query", s(&out), "  "]);
    assert!(!ok && stderr.contains("query text is empty"), "{stderr}");
    let (ok, _, stderr) = run(&["query", s(dir.path()), "lamp"]);
    assert!(!ok && stderr.contains("scene.ply"), "{stderr}");
}

#[test]
fn renders_a_saved_reconstruction_from_new_cameras() {
    let (dir, model, scene) = fixtures();
    let out = dir.path().join("or");
    let (ok, _, stderr) = run(&["reconstruct", s(scene), "-o", s(&out), "--model", s(model)]);
    assert!(ok, "{stderr}");
    let (ok, stdout, stderr) = run(&["render", s(&out), "--camera", "interp:0,3,0.5"]);
    assert!(ok && stdout.contains("3 images from 1 camera"), "{stdout}{stderr}");
    for kind in ["rgb", "instances", "labels"] {
        let img = image::open(out.join(format!("render/{kind}_000.png"))).unwrap();
        assert_eq!((img.width(), img.height()), (32, 32));
    }
    // The input cameras themselves, from the reconstruction's own transforms.json.
    let again = dir.path().join("or_again");
    let (ok, stdout, stderr) =
        run(&["render", s(&out), "--camera", s(&out.join("transforms.json")), "-o", s(&again)]);
    assert!(ok && stdout.contains("12 images from 4 camera"), "{stdout}{stderr}");
    // The first camera turned 30° about its own up axis (half its field of view) sees past
    // what the photos saw: raw,
    // those pixels carry no instance; filled, every pixel takes the nearest one's, and the
    // covered pixels keep theirs.
    let mut transforms: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("transforms.json")).unwrap())
            .unwrap();
    let frame = transforms["frames"][0].clone();
    let m: Vec<Vec<f64>> = serde_json::from_value(frame["transform_matrix"].clone()).unwrap();
    let (c, sn) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
    let turn = [[c, 0.0, sn], [0.0, 1.0, 0.0], [-sn, 0.0, c]];
    let mut turned = m.clone();
    for (r, row) in turned.iter_mut().enumerate().take(3) {
        for (k, v) in row.iter_mut().enumerate().take(3) {
            *v = (0..3).map(|j| m[r][j] * turn[j][k]).sum();
        }
    }
    let mut frame = frame;
    frame["transform_matrix"] = serde_json::to_value(&turned).unwrap();
    transforms["frames"] = serde_json::Value::Array(vec![frame]);
    let turned_path = dir.path().join("turned.json");
    std::fs::write(&turned_path, transforms.to_string()).unwrap();
    let instances = |extra: &[&str], to: &str| -> image::RgbImage {
        let to = dir.path().join(to);
        let mut args = vec!["render", s(&out), "--camera", s(&turned_path), "-o", s(&to)];
        args.extend_from_slice(extra);
        let (ok, _, stderr) = run(&args);
        assert!(ok, "{stderr}");
        image::open(to.join("instances_000.png")).unwrap().to_rgb8()
    };
    let (raw, filled) = (instances(&["--no-fill"], "turned_raw"), instances(&[], "turned_filled"));
    let black = |img: &image::RgbImage| img.pixels().filter(|p| p.0 == [0, 0, 0]).count();
    assert!(black(&raw) > 0, "the turned camera should see past the reconstruction");
    assert_eq!(black(&filled), 0, "every pixel filled");
    assert!(
        raw.pixels().zip(filled.pixels()).all(|(r, f)| r.0 == [0, 0, 0] || r == f),
        "a covered pixel changed"
    );
    let (ok, _, stderr) = run(&["render", s(&out), "--camera", "interp:0,9,0.5"]);
    assert!(!ok && stderr.contains("view 9 does not exist"), "{stderr}");
    let (ok, _, stderr) = run(&["render", s(&out), "--camera", "interp:0,1,2"]);
    assert!(!ok && stderr.contains("outside 0-1"), "{stderr}");
    // A camera file, and the reconstruction's own transforms.json, are named by the field that
    // breaks them.
    transforms["frames"][0]["transform_matrix"] = serde_json::json!("identity");
    std::fs::write(&turned_path, transforms.to_string()).unwrap();
    let (ok, _, stderr) = run(&["render", s(&out), "--camera", s(&turned_path)]);
    assert!(!ok && stderr.contains("turned.json: frames[0].transform_matrix"), "{stderr}");
    std::fs::write(out.join("transforms.json"), transforms.to_string()).unwrap();
    let (ok, _, stderr) = run(&["render", s(&out), "--camera", "interp:0,1,0.5"]);
    assert!(!ok && stderr.contains("or/transforms.json: frames[0].transform_matrix"), "{stderr}");
}

#[test]
fn renders_novel_view_masks_on_the_gpu_when_asked_and_says_so() {
    // `scripts/setup` installs Mesa's lavapipe, so a Vulkan adapter exists here and in CI.
    let (dir, model, scene) = fixtures();
    let out = dir.path().join("o_render");
    let (ok, _, stderr) =
        run(&["reconstruct", s(scene), "-o", s(&out), "--model", s(model), "--json"]);
    assert!(ok, "{stderr}");
    let backend = |choice: &str| -> (String, image::RgbImage) {
        let to = dir.path().join(format!("render_{choice}"));
        let (ok, stdout, stderr) = run(&[
            "render",
            s(&out),
            "--camera",
            "interp:0,1,0.5",
            "-o",
            s(&to),
            "--render",
            choice,
        ]);
        assert!(ok, "{stderr}");
        (stdout, image::open(to.join("instances_000.png")).unwrap().to_rgb8())
    };
    let (cpu, cpu_mask) = backend("cpu");
    let (gpu, gpu_mask) = backend("gpu");
    assert!(
        cpu.contains("masks rendered on cpu") && gpu.contains("masks rendered on wgpu"),
        "{cpu}\n{gpu}"
    );
    // The same instance in (nearly) every pixel: the two rasterizers agree within tolerance,
    // so only pixels where two instances nearly tie may differ.
    let same = cpu_mask.pixels().zip(gpu_mask.pixels()).filter(|(a, b)| a == b).count();
    assert!(same as f64 >= 0.95 * (32.0 * 32.0), "{same} of 1024 pixels agree");
}

/// The tiny model with a shape classifier whose one label is "lamp" (every descriptor gets
/// probability 1), or with `json` stored as the classifier verbatim.
fn with_classifier(name: &str, json: Option<&str>) -> PathBuf {
    use inssplat_proto::shape::{DESCRIPTOR, Dense, ShapeClassifier};
    let (dir, model, _) = fixtures();
    let d = DESCRIPTOR.len();
    let lamp = ShapeClassifier {
        labels: vec!["lamp".into()],
        mean: vec![0.0; d],
        std: vec![1.0; d],
        layers: vec![Dense { inputs: d, outputs: 1, weight: vec![0.0; d], bias: vec![0.0] }],
        provenance: "hand-made".into(),
        semantic: false,
    };
    let path = dir.path().join(name);
    inssplat_trainer::shapes::attach(model, &path, &lamp, None).unwrap();
    if let Some(json) = json {
        // Replace the stored JSON (attach only writes valid classifiers).
        use inssplat_trainer::export::onnx_pb::ModelProto;
        use prost::Message;
        let mut proto = ModelProto::decode(std::fs::read(&path).unwrap().as_slice()).unwrap();
        for p in &mut proto.metadata_props {
            if p.key.as_deref() == Some(inssplat_proto::signature::META_SHAPE_CLASSIFIER) {
                p.value = Some(json.into());
            }
        }
        std::fs::write(&path, proto.encode_to_vec()).unwrap();
    }
    path
}

#[test]
fn the_shape_classifier_in_a_model_file_names_the_instances_by_its_weight() {
    let (dir, _, scene) = fixtures();
    let model = with_classifier("lamp.onnx", None);
    let labels_at = |weight: &str| -> Vec<String> {
        let out = dir.path().join(format!("shape-{weight}"));
        let (ok, stdout, stderr) = run(&[
            "reconstruct",
            s(scene),
            "-o",
            s(&out),
            "--model",
            s(&model),
            "--shape-weight",
            weight,
            "--json",
        ]);
        assert!(ok, "{stderr}");
        let r: ReconstructResponse = serde_json::from_str(&stdout).unwrap();
        assert!(!r.instances.is_empty());
        r.instances.into_iter().map(|i| i.label).collect()
    };
    let strong = labels_at("1000");
    assert!(strong.iter().all(|l| l == "lamp"), "{strong:?}");
    let none = labels_at("0");
    assert!(
        none.iter().any(|l| l != "lamp"),
        "without the classifier the random network names: {none:?}"
    );
}

#[test]
fn a_model_file_with_a_broken_shape_classifier_is_refused_by_key() {
    let (dir, _, scene) = fixtures();
    let model = with_classifier(
        "broken.onnx",
        Some(r#"{"labels": ["lamp"], "mean": [0], "std": [1], "layers": []}"#),
    );
    let out = dir.path().join("broken-out");
    let (ok, _, stderr) = run(&["reconstruct", s(scene), "-o", s(&out), "--model", s(&model)]);
    assert!(!ok);
    assert!(
        stderr.contains("broken.onnx")
            && stderr.contains("inssplat.shape_classifier")
            && stderr.contains("mean/std"),
        "{stderr}"
    );
}
