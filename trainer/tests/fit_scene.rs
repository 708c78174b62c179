//! The per-scene baseline on a real synthesized test scene: fitting Gaussians and instance
//! embeddings to its context views with the true cameras separates its instances on the
//! held-out target views, bad input is a named error, and a run stopped midway resumes from
//! its JSON.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use inssplat_proto::dataset::Scene;
use inssplat_synth::{self as synth, Furniture, Split, SynthConfig};
use inssplat_trainer::fit::{FitConfig, fit_scene};

/// Writes the small test-split scene of `seed` to `dir/name`.
fn write_scene(dir: &Path, seed: u64, name: &str) -> PathBuf {
    let mut cfg = SynthConfig::new(Split::Test, Furniture::Primitives);
    (cfg.width, cfg.height, cfg.objects) = (48, 48, (3, 4));
    let path = dir.join(name);
    synth::generate_split(seed, &cfg).unwrap().write(&path).unwrap();
    path
}

fn scene(dir: &Path) -> Scene {
    Scene::load(write_scene(dir, 2, "scene_000000")).unwrap()
}

#[test]
fn fitting_one_scene_separates_its_instances_on_target_views() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = scene(tmp.path());
    let config = FitConfig {
        views: 4,
        stride: 1,
        max_steps: 120,
        score_at: vec![20, 60],
        ..FitConfig::default()
    };
    let report = fit_scene(&scene, &config, &|_, _| {}).unwrap();
    assert!(report.final_loss * 5.0 < report.first_loss, "{report:?}");
    assert!(report.scores.instances_found >= 2, "{report:?}");
    let miou = report.scores.instance_miou.expect("target views show instances");
    assert!(miou >= 0.3, "instance mIoU {miou} ({report:?})");
    // Panoptic quality needs matches above IoU ½, which a separated object gives.
    let pq = report.scores.instance_pq.expect("target views show instances");
    assert!(pq > 0.0 && pq <= 1.0, "instance PQ {pq} ({report:?})");

    // Scored along the way: a point after each asked step count, its clock the optimization's
    // alone, and the fit after 20 steps separates less than the finished one.
    let steps: Vec<usize> = report.curve.iter().map(|p| p.steps).collect();
    assert_eq!(steps, [20, 60], "{report:?}");
    assert!(
        0.0 < report.curve[0].seconds
            && report.curve[0].seconds < report.curve[1].seconds
            && report.curve[1].seconds < report.seconds,
        "{report:?}"
    );
    assert!(report.curve[0].scores.instance_miou.unwrap() < miou, "{report:?}");
    // Scoring does not disturb the fit: a fit stopped at 60 steps scores what the point says.
    let stopped =
        fit_scene(&scene, &FitConfig { max_steps: 60, score_at: Vec::new(), ..config }, &|_, _| {})
            .unwrap();
    assert_eq!(stopped.steps, 60);
    assert_eq!(stopped.scores, report.curve[1].scores);
}

#[test]
fn a_scene_without_the_asked_context_set_is_a_named_error() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = scene(tmp.path());
    let err = fit_scene(&scene, &FitConfig { views: 5, ..FitConfig::default() }, &|_, _| {})
        .unwrap_err()
        .to_string();
    assert!(err.contains("scene_000000") && err.contains("no 5-view context set"), "{err}");
}

fn fit_cli(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_inssplat-train"))
        .arg("fit-scene")
        .args(args)
        .output()
        .expect("run inssplat-train")
}

fn reports(path: &Path) -> Vec<serde_json::Value> {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn a_stopped_fit_scene_run_resumes_from_its_json() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("scenes");
    write_scene(&data, 2, "scene_000000");
    write_scene(&data, 3, "scene_000001");
    let json = tmp.path().join("fit.json");
    let (data, json_arg) = (data.to_str().unwrap(), json.to_str().unwrap());
    let run = |extra: &[&str]| {
        fit_cli(
            &[&["--data", data, "--views", "4", "--score-at", "10", "--json", json_arg], extra]
                .concat(),
        )
    };
    let stderr = |out: &Output| String::from_utf8_lossy(&out.stderr).into_owned();

    // A run that stopped after its first scene left that scene in the JSON.
    let first = run(&["--max-steps", "20", "--max-scenes", "1"]);
    assert!(first.status.success(), "{}", stderr(&first));
    let one = reports(&json);
    assert_eq!(one.len(), 1, "{one:?}");

    // Resumed, it keeps that report as it was (the same wall time, so not fitted again) and
    // fits the other scene.
    let resumed = run(&["--max-steps", "20", "--resume"]);
    assert!(resumed.status.success(), "{}", stderr(&resumed));
    assert!(stderr(&resumed).contains("scene_000000: kept from --json"), "{}", stderr(&resumed));
    let both = reports(&json);
    assert_eq!(both.len(), 2, "{both:?}");
    assert_eq!(both[0], one[0]);
    assert_eq!(both[1]["scene"], "scene_000001");
    assert_eq!(both[1]["max_steps"], 20);
    assert_eq!(both[1]["curve"][0]["steps"], 10);
    assert!(
        String::from_utf8_lossy(&resumed.stdout).contains("| 10 | 2 of 2 |"),
        "the table along the way: {}",
        String::from_utf8_lossy(&resumed.stdout)
    );

    // Other settings would mix two baselines in one file: refused, naming the file and both.
    let other = run(&["--max-steps", "30", "--resume"]);
    let err = stderr(&other);
    assert!(
        !other.status.success()
            && err.contains("fit.json")
            && err.contains("max_steps 20")
            && err.contains("max_steps 30"),
        "{err}"
    );
    assert_eq!(reports(&json), both, "a refused resume leaves the file as it was");

    // A step count the fit can never reach is refused before any fitting, naming both.
    let beyond = run(&["--max-steps", "5", "--resume"]);
    let err = stderr(&beyond);
    assert!(
        !beyond.status.success() && err.contains("--score-at 10") && err.contains("(5)"),
        "{err}"
    );
    assert_eq!(reports(&json), both, "a refused run leaves the file as it was");
}
