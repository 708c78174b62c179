//! `inssplat-eval score` end to end: a tiny exported network (random weights), one procedural
//! test-split scene with context/target sets, the real binary and ONNX Runtime. Checks that
//! every metric of the protocol is reported within its range for each view count (and the
//! names each true label got), that the JSON and markdown files are written, that bad
//! arguments are named errors, and that a run whose stderr is no terminal logs a line per
//! finished run; `--shape-examples` records the prototypes as the features give
//! them, before the shipped shape classifier moves them, and the room each was found in;
//! `--known-names` names the instances by their true labels instead; `--photos` reconstructs
//! from larger photos of the same scene and refuses another's. Also
//! `inssplat-eval bench`: every stage timed per view count (the refine stage when asked for),
//! Gaussians in = views × pixels.

use std::path::Path;
use std::process::Output;

use crate::support::{self, s, score};

use inssplat_e2e::inssplat_eval;
use inssplat_proto::shape::LabelledDescriptor;
use inssplat_synth::{self as synth, Furniture, Split, SynthConfig};
use serde_json::Value;

/// `inssplat-eval bench` of the scene `scene` at `views` with `model`, then `extra`.
fn bench(scene: &Path, views: &str, model: &Path, extra: &[&str]) -> Output {
    inssplat_eval(
        &[&["bench", "--data", s(scene), "--views", views, "--model", s(model)], extra].concat(),
    )
}

/// A network that reads its cameras as rays runs twice by default (stage "rays", on the
/// registered cameras), once with `--no-ray-pass`, and with `--known-poses` once on the true
/// cameras' rays; the protocol line says which.
#[test]
fn a_network_that_reads_rays_runs_again_on_the_registered_cameras() {
    let dir = tempfile::tempdir().unwrap();
    let model = support::tiny_rays_model(dir.path());
    let data = dir.path().join("test");
    support::test_scene(&data, 0);
    let stages = |extra: &[&str]| {
        let out_dir = dir.path().join(format!("eval{}", extra.concat()));
        let out = score(&data, "2", &model, &[&["--out", s(&out_dir), "--json"], extra].concat());
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let report: Value = serde_json::from_slice(&out.stdout).unwrap();
        (
            report["scenes"][0]["stage_ms"].as_object().unwrap().clone(),
            report["protocol"].as_str().unwrap().to_string(),
        )
    };
    let (twice, protocol) = stages(&[]);
    assert!(twice["rays"].as_f64().unwrap() > 0.0);
    assert!(protocol.contains("again on the registered cameras' rays"), "{protocol}");
    let (once, protocol) = stages(&["--no-ray-pass"]);
    assert!(!once.contains_key("rays") && protocol.contains("--no-ray-pass"), "{protocol}");
    let (known, protocol) = stages(&["--known-poses"]);
    assert!(!known.contains_key("rays") && !known.contains_key("register"), "{known:?}");
    assert!(protocol.contains("true context cameras as rays"), "{protocol}");
}

#[test]
fn eval_reports_every_metric_per_view_count() {
    let dir = tempfile::tempdir().unwrap();
    let (model, data) = support::tiny_model_and_test_data(dir.path(), 0);
    let out_dir = dir.path().join("eval");
    let out = score(&data, "2,4", &model, &["--out", s(&out_dir), "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // Stderr is a pipe here, so progress comes as one line per finished run, the JSON alone
    // on stdout.
    let stderr = String::from_utf8_lossy(&out.stderr);
    let progress: Vec<&str> = stderr.lines().filter(|l| l.starts_with("eval ")).collect();
    assert_eq!(progress.len(), 2, "{stderr}");
    assert!(
        progress[0].starts_with("eval 1/2 after ")
            && progress[0].ends_with(&format!("2 views, {}", data.join("scene_000000").display())),
        "{stderr}"
    );
    assert!(
        progress[1].starts_with("eval 2/2 after ")
            && progress[1].contains(", about 0s left: 4 views, "),
        "{stderr}"
    );
    let report: Value = serde_json::from_slice(&out.stdout).unwrap();
    let summaries = report["summaries"].as_array().unwrap();
    assert_eq!(summaries.iter().map(|s| s["views"].as_u64().unwrap()).collect::<Vec<_>>(), [2, 4]);
    for summary in summaries {
        assert_eq!(summary["scenes"], 1);
        let m = &summary["metrics"];
        for unit in [
            "semantic_miou",
            "semantic_macc",
            "instance_miou",
            "instance_acc25",
            "instance_pq",
            "context_instance_miou",
            "context_ceiling_miou",
            "t_miou",
            "t_sr50",
        ] {
            let v = m[unit][0].as_f64().unwrap_or_else(|| panic!("{unit} missing: {m}"));
            assert!((0.0..=1.0).contains(&v), "{unit} = {v}");
        }
        // SSIM is a correlation: an image unlike the truth (this network's weights are
        // random) may score slightly below 0.
        let ssim = m["ssim"][0].as_f64().unwrap_or_else(|| panic!("ssim missing: {m}"));
        assert!((-1.0..=1.0).contains(&ssim), "ssim = {ssim}");
        for positive in [
            "psnr",
            "depth_abs_rel",
            "depth_abs_rel_objects",
            "depth_abs_rel_shell",
            "rotation_deg",
            "translation",
        ] {
            let v = m[positive][0].as_f64().unwrap_or_else(|| panic!("{positive} missing: {m}"));
            assert!(v.is_finite() && v >= 0.0, "{positive} = {v}");
        }
        // Every labelled target pixel is in one row; a label's right share is at most that
        // of its most common name.
        let labels = summary["labels"].as_array().unwrap();
        assert!(!labels.is_empty(), "{summary}");
        for row in labels {
            let (right, most) =
                (row["named_right"].as_f64().unwrap(), row["named_most_share"].as_f64().unwrap());
            assert!(
                row["pixels"].as_u64().unwrap() > 0
                    && (0.0..=1.0).contains(&most)
                    && right <= most + 1e-12,
                "{row}"
            );
        }
    }
    let scene = &report["scenes"][0];
    assert!(scene["gaussians_kept"].as_u64().unwrap() > 0);
    // Objects and shell split the pixels at one scale: the whole is a mean of the two parts.
    let depth = |scene: &Value, k: &str| {
        scene[k].as_f64().unwrap_or_else(|| panic!("{k} missing: {scene}"))
    };
    let (all, objects, shell) = (
        depth(scene, "depth_abs_rel"),
        depth(scene, "depth_abs_rel_objects"),
        depth(scene, "depth_abs_rel_shell"),
    );
    assert!(objects.min(shell) - 1e-9 <= all && all <= objects.max(shell) + 1e-9, "{scene}");
    assert!(scene["stage_ms"]["model"].as_f64().unwrap() > 0.0);
    assert!(
        scene.get("target_pose_turn_deg").is_none(),
        "no target pose refinement unless asked: {scene}"
    );
    assert!(
        scene.get("refine_context_psnr").is_none() && scene["stage_ms"].get("refine").is_none(),
        "no refinement unless asked: {scene}"
    );
    assert!(
        report["protocol"].as_str().unwrap().contains("no test-time optimization of the Gaussians")
    );
    assert!(
        report["protocol"].as_str().unwrap().contains("best of 36 headings"),
        "{}",
        report["protocol"]
    );
    assert!(
        report["protocol"].as_str().unwrap().contains("covers there filled from around it"),
        "{}",
        report["protocol"]
    );
    assert!(
        scene["stage_ms"]["heading"].as_f64().unwrap() >= 0.0,
        "the stage is timed whether or not it turns a view"
    );
    let table = std::fs::read_to_string(out_dir.join("eval.md")).unwrap();
    assert!(
        table.contains("| 2 |") && table.contains("| 4 |") && table.contains("inst mIoU"),
        "{table}"
    );
    assert!(table.contains("nearest true prototype (ceiling)"), "{table}");
    assert!(table.contains("Labels on the target views at 4 views"), "{table}");
    assert!(table.contains("| views | all pixels | objects | room shell |"), "{table}");
    assert!(out_dir.join("eval.json").is_file());
    assert_eq!(report["cluster"], "3d");

    // With the true context cameras the alignment is exact, with the true depth so is the
    // depth, and the report says so, as it says that the target cameras were refined and the
    // Gaussians fitted to the context photos (the given cameras kept) ...
    let out = score(
        &data,
        "4",
        &model,
        &[
            "--known-poses",
            "--known-depth",
            "--no-aggregation",
            "--target-pose-steps",
            "6",
            "--refine-steps",
            "12",
            "--no-fill",
            "--json",
        ],
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["known_poses"], true);
    assert_eq!(report["known_depth"], true);
    assert_eq!(report["no_fill"], true);
    assert!(
        report["protocol"].as_str().unwrap().contains("the RAW renders scored"),
        "{}",
        report["protocol"]
    );
    assert!(report["protocol"].as_str().unwrap().contains("TRUE context cameras and depth"));
    assert_eq!(report["target_pose_steps"], 6);
    assert!(
        report["protocol"]
            .as_str()
            .unwrap()
            .contains("TEST-TIME OPTIMIZATION of each target camera's pose")
    );
    assert_eq!(report["refine_steps"], 12);
    assert!(
        report["protocol"].as_str().unwrap().contains("TEST-TIME OPTIMIZATION of the Gaussians")
    );
    let scene = &report["scenes"][0];
    let fit = scene["refine_context_psnr"]
        .as_array()
        .unwrap_or_else(|| panic!("no refinement reported: {scene}"));
    assert!(
        fit[1].as_f64().unwrap() > fit[0].as_f64().unwrap(),
        "the context views fit worse after refining: {scene}"
    );
    assert!(scene["stage_ms"]["refine"].as_f64().unwrap() > 0.0, "{scene}");
    let turn = scene["target_pose_turn_deg"]
        .as_f64()
        .unwrap_or_else(|| panic!("no turn reported: {scene}"));
    assert!((0.0..10.0).contains(&turn), "{scene}");
    assert!(
        scene["rotation_deg"].as_f64().unwrap() < 1e-2
            && scene["translation"].as_f64().unwrap() < 1e-3,
        "{scene}"
    );
    assert!(
        depth(scene, "depth_abs_rel") < 1e-6 && depth(scene, "depth_abs_rel_objects") < 1e-6,
        "{scene}"
    );
    // ... and the labels come from every pixel's own semantic feature (still a valid score).
    assert_eq!(report["no_aggregation"], true);
    let sem = scene["semantic_macc"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&sem), "{scene}");

    // The paper's mode: per-view 2D clustering, same metrics, with the clustering asked for.
    let out = score(&data, "4", &model, &["--cluster", "2d", "--min-samples", "3", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["cluster"], "2d");
    assert_eq!(report["min_samples"], 3);
    let m = &report["summaries"][0]["metrics"];
    for unit in ["instance_miou", "t_miou", "semantic_miou"] {
        let v = m[unit][0].as_f64().unwrap_or_else(|| panic!("{unit} missing: {m}"));
        assert!((0.0..=1.0).contains(&v), "{unit} = {v}");
    }
    // The context-view diagnosis reads the 3D clustering's ids, which 2D mode does not use.
    assert!(m.get("context_ceiling_miou").is_none(), "{m}");
}

#[test]
fn shape_examples_record_the_unfused_prototypes_whatever_the_shape_weight() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("test");
    // At the shipped model's resolution.
    let mut cfg = SynthConfig::new(Split::Test, Furniture::Primitives);
    cfg.objects = (3, 5);
    synth::generate_split(0, &cfg).unwrap().write(&data.join("scene_000000")).unwrap();
    let model = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../models/inssplat-default.onnx");
    let examples = |weight: &str| -> Vec<LabelledDescriptor> {
        let file = dir.path().join(format!("examples_{weight}.json"));
        let out_dir = dir.path().join(format!("eval_{weight}"));
        let out = score(
            &data,
            "4",
            &model,
            &["--shape-weight", weight, "--shape-examples", s(&file), "--out", s(&out_dir)],
        );
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap()
    };
    let (plain, fused) = (examples("0"), examples("4"));
    assert!(!plain.is_empty());
    for e in &plain {
        assert_eq!(e.prototype.len(), 384, "{e:?}");
        assert_eq!(e.scene, "scene_000000", "each example names the room it was found in");
        let norm = e.prototype.iter().map(|x| x * x).sum::<f32>().sqrt();
        assert!((norm - 1.0).abs() < 1e-3, "{e:?}");
    }
    // The classifier at weight 4 names the instances differently, not what they record.
    assert_eq!(plain, fused);
    // Named with the true label most of their context pixels carry (`--known-names`; the rule
    // is unit-tested in `eval::scene`), the same instances name the target views otherwise than
    // the classifier did, and the report says how they were named. (Not necessarily better:
    // semantic mIoU averages over classes, and a mixed instance named for its larger part can
    // cost the smaller part's class more than it gains.)
    let semantic = |extra: &[&str]| -> (f64, Value) {
        let out = score(&data, "4", &model, &[&["--json"], extra].concat());
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let report: Value = serde_json::from_slice(&out.stdout).unwrap();
        (report["scenes"][0]["semantic_miou"].as_f64().unwrap(), report)
    };
    let ((named, _), (known, report)) = (semantic(&[]), semantic(&["--known-names"]));
    assert_ne!(known, named, "the true names changed nothing");
    assert_eq!(report["known_names"], true);
    assert!(
        report["protocol"].as_str().unwrap().contains("NAMED WITH THE TRUE LABEL"),
        "{}",
        report["protocol"]
    );
}

#[test]
fn eval_reconstructs_from_larger_photos_of_the_same_scene_and_refuses_another() {
    let dir = tempfile::tempdir().unwrap();
    let (model, data) = support::tiny_model_and_test_data(dir.path(), 0);
    // The same scene at 4× the size (the same seed gives the same room and cameras), and
    // another scene under its name.
    let mut cfg = SynthConfig::new(Split::Test, Furniture::Primitives);
    (cfg.width, cfg.height, cfg.objects) = (128, 128, (3, 5));
    let (photos, other) = (dir.path().join("photos"), dir.path().join("other"));
    synth::generate_split(0, &cfg).unwrap().write(&photos.join("scene_000000")).unwrap();
    synth::generate_split(1, &cfg).unwrap().write(&other.join("scene_000000")).unwrap();
    let eval = |extra: &[&str]| score(&data, "2", &model, &[&["--json"], extra].concat());
    let report = |out: Output| -> Value {
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_slice(&out.stdout).unwrap()
    };
    let own = report(eval(&[]));
    let large = report(eval(&["--photos", s(&photos)]));
    // The photos are what is reconstructed (the network sees them downscaled, registration
    // finds its keypoints in them), and the ground truth stays --data's.
    assert_ne!(own["scenes"][0]["psnr"], large["scenes"][0]["psnr"]);
    assert_eq!(own["scenes"][0]["instances_true"], large["scenes"][0]["instances_true"]);
    // The masks at the photos' resolution are scored against the larger scene's, upsampled
    // along the photos' edges and at the nearest model pixel.
    let scene = &large["scenes"][0];
    for k in [
        "photo_instance_miou",
        "photo_instance_miou_nearest",
        "photo_boundary_f",
        "photo_boundary_f_nearest",
    ] {
        assert!(scene[k].as_f64().is_some_and(|v| (0.0..=1.0).contains(&v)), "{k}: {scene}");
    }
    assert!(own["scenes"][0].get("photo_boundary_f").is_none(), "no photos, no photo masks");
    let out = eval(&["--photos", s(&other)]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success()
            && err.contains("transforms.json")
            && err.contains("not the same scene"),
        "{err}"
    );
    let missing = dir.path().join("missing");
    let out = eval(&["--photos", s(&missing)]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("--photos") && err.contains(s(&missing)),
        "{err}"
    );
}

#[test]
fn eval_names_bad_arguments() {
    let dir = tempfile::tempdir().unwrap();
    let out = inssplat_eval(&["score", "--data", s(dir.path()), "--model", "/nonexistent.onnx"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("--data") && err.contains("no scene folders"),
        "{err}"
    );
    let out = inssplat_eval(&["score", "--data", s(dir.path()), "--views", "1"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--views: 1"), "{err}");
    let out = inssplat_eval(&["score", "--data", s(dir.path()), "--min-cluster-share", "0"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("min_cluster_share") && err.contains("(0, 1)"),
        "{err}"
    );
    let out = inssplat_eval(&["score", "--data", s(dir.path()), "--superpixel-scale=-5"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--superpixel-scale: -5"), "{err}");
    let out =
        inssplat_eval(&["score", "--data", s(dir.path()), "--known-names", "--cluster", "2d"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("--known-names") && err.contains("--cluster 2d"),
        "{err}"
    );
    let out =
        inssplat_eval(&["score", "--data", s(dir.path()), "--known-names", "--no-aggregation"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("--known-names") && err.contains("--no-aggregation"),
        "{err}"
    );
}

#[test]
fn bench_times_every_stage_per_view_count() {
    let dir = tempfile::tempdir().unwrap();
    let model = support::tiny_model(dir.path());
    let scene = support::test_scene(dir.path(), 1);
    let out = bench(&scene, "2,4", &model, &["--runs", "2", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rows: Value = serde_json::from_slice(&out.stdout).unwrap();
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.iter().map(|r| r["views"].as_u64().unwrap()).collect::<Vec<_>>(), [2, 4]);
    for r in rows {
        let stages = r["stage_ms"].as_object().unwrap();
        for stage in [
            "decode",
            "model",
            "superpixels",
            "register",
            "heading",
            "backproject",
            "voxelize",
            "cluster",
            "vote",
            "label",
            "masks",
            "upsample",
        ] {
            assert!(stages[stage].as_f64().unwrap() >= 0.0, "{stage}");
        }
        assert!(r["render_cpu_ms"].as_f64().unwrap() > 0.0, "{r}");
        let sum: f64 = stages.values().map(|v| v.as_f64().unwrap()).sum();
        assert!(r["total_ms"].as_f64().unwrap() > 0.0 && sum > 0.0);
        assert_eq!(r["gaussians_in"].as_u64().unwrap(), r["views"].as_u64().unwrap() * 32 * 32);
        assert!(r["gaussians_kept"].as_u64().unwrap() <= r["gaussians_in"].as_u64().unwrap());
    }
    let table = bench(&scene, "8,16", &model, &["--runs", "1"]);
    let text = String::from_utf8_lossy(&table.stdout);
    assert!(
        table.status.success()
            && text.contains("| 16 |")
            && text.contains("Growth from 8 to 16 views"),
        "{text}"
    );
    assert!(!text.contains("refine"), "no refine stage unless asked: {text}");
    // With test-time refinement the stage is timed and gets its column.
    let table = bench(&scene, "2", &model, &["--runs", "1", "--refine-steps", "4"]);
    let text = String::from_utf8_lossy(&table.stdout);
    assert!(table.status.success() && text.contains("| label | refine | masks |"), "{text}");
}

/// `bench --against`: the tiny model and its int8 file (`inssplat-train quantize`'s
/// function) timed in turns; each row has both medians and the paired ratios, the table names
/// both models, and a missing second model is named.
#[test]
fn bench_against_times_two_models_in_turns() {
    let dir = tempfile::tempdir().unwrap();
    let model = support::tiny_model(dir.path());
    let int8 = dir.path().join("tiny-int8.onnx");
    inssplat_trainer::export::quantize_file(&model, &int8, None).unwrap();
    let scene = support::test_scene(dir.path(), 1);
    let out = bench(&scene, "2,4", &model, &["--runs", "3", "--against", s(&int8), "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rows: Value = serde_json::from_slice(&out.stdout).unwrap();
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.iter().map(|r| r["views"].as_u64().unwrap()).collect::<Vec<_>>(), [2, 4]);
    for r in rows {
        assert_eq!(r["runs"].as_u64(), Some(3));
        for key in ["model_ms", "total_ms"] {
            let [a, b] = [0, 1].map(|i| r[key][i].as_f64().unwrap());
            assert!(a > 0.0 && b > 0.0, "{r}");
        }
        for key in ["model_ratio", "total_ratio"] {
            let x = r[key].as_f64().unwrap();
            assert!(x.is_finite() && x > 0.0, "{r}");
        }
        assert!(
            r["model_ms"][0].as_f64() < r["total_ms"][0].as_f64(),
            "the network is one stage of the request: {r}"
        );
    }
    let table = bench(&scene, "2", &model, &["--runs", "1", "--against", s(&int8)]);
    let text = String::from_utf8_lossy(&table.stdout);
    assert!(
        table.status.success()
            && text.contains("A: e2e-random (")
            && text.contains("B: e2e-random+int8 ("),
        "{text}"
    );
    let missing = bench(&scene, "2", &model, &["--against", "/nonexistent/b.onnx"]);
    let err = String::from_utf8_lossy(&missing.stderr);
    assert!(!missing.status.success() && err.contains("/nonexistent/b.onnx"), "{err}");
}

#[test]
fn perturb_sweeps_strengths_and_reports_the_worst_scenes() {
    let dir = tempfile::tempdir().unwrap();
    let (model, data) = support::tiny_model_and_test_data(dir.path(), 2);
    let out_dir = dir.path().join("eval");
    let out = score(
        &data,
        "4",
        &model,
        &["--perturb", "noise,overlap,repeats", "--out", s(&out_dir), "--json"],
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: Value = serde_json::from_slice(&out.stdout).unwrap();
    let rows = report["robustness"].as_array().unwrap();
    let kinds: Vec<(&str, f64)> = rows
        .iter()
        .map(|r| (r["kind"].as_str().unwrap(), r["strength"].as_f64().unwrap()))
        .collect();
    assert_eq!(kinds.iter().filter(|k| k.0 == "noise").count(), 4, "{kinds:?}");
    assert_eq!(kinds.iter().filter(|k| k.0 == "overlap").count(), 3, "{kinds:?}");
    assert_eq!(
        kinds.iter().filter(|k| k.0 == "repeats").count(),
        1,
        "one scene: one repeats bucket"
    );
    // Noise of strength 0 is no perturbation: the same scores as the plain 4-view run.
    let plain = &report["summaries"][0]["metrics"]["instance_miou"][0];
    assert_eq!(&rows[0]["summary"]["metrics"]["instance_miou"][0], plain);
    let failure = &report["failures"][0];
    assert_eq!(failure["scene"], "scene_000002");
    assert!(std::path::Path::new(failure["preview"].as_str().unwrap()).is_file());
    let table = std::fs::read_to_string(out_dir.join("eval.md")).unwrap();
    assert!(table.contains("Robustness at 4 views") && table.contains("Worst scenes"), "{table}");
}

#[test]
fn sweep_draws_the_speed_accuracy_chart() {
    let dir = tempfile::tempdir().unwrap();
    let (model, data) = support::tiny_model_and_test_data(dir.path(), 3);
    let out_dir = dir.path().join("sweep");
    let out = score(&data, "2", &model, &["--sweep", "--out", s(&out_dir)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let points: Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("sweep.json")).unwrap())
            .unwrap();
    let points = points.as_array().unwrap();
    assert_eq!(points.len(), 6, "3 voxel sizes × 2 subsample sizes");
    assert!(
        points.iter().any(|p| p["pareto_instance"] == true)
            && points.iter().any(|p| p["pareto_psnr"] == true)
    );
    let png = image::open(out_dir.join("sweep.png")).unwrap();
    assert_eq!((png.width(), png.height()), (1200, 520));
    assert!(std::fs::read_to_string(out_dir.join("sweep.svg")).unwrap().contains("<svg"));
    // --sweep without --out is refused by the argument parser, naming the flag.
    let out = inssplat_eval(&["score", "--data", s(&data), "--sweep"]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("--out"));
}
