//! Runs that stop and go on (`train_loop`'s tiny network and scenes): a run interrupted
//! after every step and resumed ends with exactly the weights and log of an uninterrupted
//! one, `--resume` keeps the checkpoints the run kept, and the real binary stopped by SIGTERM
//! checkpoints the step it was on and resumes from it.

use std::path::Path;
use std::time::Duration;

use inssplat_trainer::loss::LossConfig;
use inssplat_trainer::train::{self, Session, TrainConfig, checkpoint};

use super::train_loop::{bin, params, quiet_session, tiny_data, tiny_model};

#[test]
fn an_interrupted_run_resumes_exactly() {
    interrupted_run_resumes_exactly(None);
}

#[test]
fn an_interrupted_run_of_two_samples_per_step_resumes_exactly() {
    interrupted_run_resumes_exactly(Some(2));
}

fn interrupted_run_resumes_exactly(samples_per_step: Option<usize>) {
    let config = || {
        TrainConfig::new(tiny_model(), LossConfig::new())
            .with_steps(4)
            .with_warmup(2)
            .with_max_views(3)
            .with_seed(9)
            .with_samples_per_step(samples_per_step)
    };
    let straight = tempfile::tempdir().unwrap();
    let s = train::train(straight.path(), config(), tiny_data(), &quiet_session()).unwrap();
    assert_eq!(s.steps, 4);

    // Stop after every step (time limit 0) and resume, three times.
    let pieces = tempfile::tempdir().unwrap();
    let stop_each_step = Session { time_limit: Some(Duration::ZERO), ..quiet_session() };
    let s = train::train(pieces.path(), config(), tiny_data(), &stop_each_step).unwrap();
    assert_eq!(s.steps, 1);
    for expected in 2..=4 {
        let s = train::resume(pieces.path(), None, &stop_each_step).unwrap();
        assert_eq!((s.first_step, s.steps), (expected - 1, expected));
    }
    let a = params(&checkpoint::latest(straight.path()).unwrap().unwrap());
    let b = params(&checkpoint::latest(pieces.path()).unwrap().unwrap());
    assert_eq!(a.len(), b.len());
    let max_diff = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
    assert!(max_diff <= 1e-6, "resumed weights differ by {max_diff}");
    // The logs agree step by step on the losses (timings differ).
    let losses = |dir: &Path| -> Vec<String> {
        std::fs::read_to_string(dir.join("train_log.csv"))
            .unwrap()
            .lines()
            .map(|l| l.split(',').take(8).collect::<Vec<_>>().join(","))
            .collect()
    };
    assert_eq!(losses(straight.path()).len(), 5, "header + 4 steps");
    assert_eq!(losses(straight.path()), losses(pieces.path()));
    // Every step logs the CPU rasterizer's share of its backward (summed over the sample threads).
    let log = std::fs::read_to_string(straight.path().join("train_log.csv")).unwrap();
    let header: Vec<&str> = log.lines().next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|c| *c == name).unwrap();
    let (backward, raster) = (col("backward_s"), col("render_backward_s"));
    let rows: Vec<Vec<f64>> =
        log.lines().skip(1).map(|l| l.split(',').map(|c| c.parse().unwrap()).collect()).collect();
    for r in &rows {
        assert!(
            r[raster] >= 0.0
                && (samples_per_step.is_some_and(|k| k > 1) || r[raster] <= r[backward]),
            "{r:?}"
        );
    }
    assert!(rows.iter().map(|r| r[raster]).sum::<f64>() > 0.0, "{log}");
    assert!(pieces.path().join("loss.png").is_file());
    // Only the newest `keep` checkpoints stay.
    let kept = std::fs::read_dir(checkpoint::checkpoints_dir(pieces.path()))
        .unwrap()
        .filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().starts_with("step_"));
    assert_eq!(kept.count(), 2);
    // A second start in the same folder refuses to overwrite the run.
    let again = train::train(pieces.path(), config(), tiny_data(), &quiet_session()).unwrap_err();
    assert!(again.to_string().contains("--resume"), "{again}");
}

/// `--resume` without `--keep` keeps as many checkpoints as the session that wrote the newest
/// one: a run told to keep 10 is not pruned to the default 2 by the session that resumes
/// it; `--keep 1` still prunes when asked.
#[test]
fn resuming_keeps_the_checkpoints_the_run_kept() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let every_step =
        Session { checkpoint_every: Duration::ZERO, keep: Some(10), ..quiet_session() };
    train::train(
        &run,
        TrainConfig::new(tiny_model(), LossConfig::new()).with_steps(4).with_max_views(2),
        tiny_data(),
        &every_step,
    )
    .unwrap();
    let steps = || {
        checkpoint::all(&run)
            .iter()
            .map(|d| checkpoint::read_state(d).unwrap().step)
            .collect::<Vec<_>>()
    };
    assert_eq!(steps(), [1, 2, 3, 4], "a checkpoint after every step");
    let resume = |steps: &str, extra: &[&str]| {
        let out = bin()
            .args([
                "train",
                "--quiet",
                "--resume",
                "--steps",
                steps,
                "--checkpoint-minutes",
                "0",
                "--out",
            ])
            .arg(&run)
            .args(extra)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    };
    resume("6", &[]);
    assert_eq!(steps(), [1, 2, 3, 4, 5, 6], "nothing the run kept is deleted");
    resume("7", &["--keep", "1"]);
    assert_eq!(steps(), [7], "an explicit --keep prunes");
}

#[test]
fn a_terminated_run_checkpoints_its_last_step_and_resumes_from_it() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let tiny = [
        "--primitives-only",
        "--image-size",
        "32",
        "--dim",
        "32",
        "--depth",
        "2",
        "--heads",
        "2",
        "--val-every",
        "0",
        "--quiet",
    ];
    let child = bin()
        .args(["train", "--steps", "1000", "--checkpoint-minutes", "60", "--out"])
        .arg(&run)
        .args(tiny)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let logged = || {
        std::fs::read_to_string(run.join("train_log.csv"))
            .map_or(0, |t| t.lines().count().saturating_sub(1))
    };
    let start = std::time::Instant::now();
    while logged() < 3 {
        assert!(start.elapsed() < Duration::from_secs(120), "no 3 steps logged in 2 minutes");
        std::thread::sleep(Duration::from_millis(50));
    }
    // SAFETY: kill(2) on the pid of a child this test spawned and has not yet waited for.
    assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) }, 0);
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(128 + libc::SIGTERM), "{err}");
    // The step in progress finished and was checkpointed: nothing logged is lost.
    let steps = logged();
    let dir = checkpoint::latest(&run).unwrap().expect("a checkpoint written on SIGTERM");
    assert_eq!(checkpoint::read_state(&dir).unwrap().step as usize, steps);
    assert!(
        err.contains(&format!("stopped by signal {} after step {steps}", libc::SIGTERM))
            && err.contains("--resume"),
        "{err}"
    );
    // --resume goes on from there.
    let out = bin()
        .args(["train", "--resume", "--quiet", "--steps"])
        .arg((steps + 1).to_string())
        .arg("--out")
        .arg(&run)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(
        String::from_utf8_lossy(&out.stdout).contains(&format!("steps {steps}..{}", steps + 1)),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    assert_eq!(logged(), steps + 1);
}
