//! inssplat-e2e: helpers for end-to-end tests that run the real `inssplat`, `inssplat-eval` and
//! `inssplat-train` binaries, found in the workspace's target folder and built there once if
//! they are missing.

pub mod http;
pub mod postgres;

use std::path::PathBuf;
use std::process::{Command, Output};
use std::sync::OnceLock;

/// Path of the workspace binary `name`, built once in the workspace's target folder.
fn workspace_bin(name: &str, cell: &'static OnceLock<PathBuf>) -> PathBuf {
    cell.get_or_init(|| {
        let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
        // `--workspace` builds with the features of nextest's own workspace build, so after it
        // this compiles nothing; `-p` of one crate would rebuild ~80 crates for its own set.
        let status = Command::new(env!("CARGO"))
            .args(["build", "-q", "--workspace", "--bin", name])
            .current_dir(&root)
            .status()
            .expect("run cargo build");
        assert!(status.success(), "building {name} failed");
        let target =
            std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or(root.join("target"));
        target.join("debug").join(name)
    })
    .clone()
}

/// Path of the `inssplat` binary, building it if needed.
pub fn inssplat_bin() -> PathBuf {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    workspace_bin("inssplat", &BIN)
}

/// Path of the `inssplat-eval` binary, building it if needed.
pub fn inssplat_eval_bin() -> PathBuf {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    workspace_bin("inssplat-eval", &BIN)
}

/// Path of the `inssplat-train` binary, building it if needed.
pub fn inssplat_train_bin() -> PathBuf {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    workspace_bin("inssplat-train", &BIN)
}

/// Runs `inssplat` with `args`, returning its output.
pub fn inssplat(args: &[&str]) -> Output {
    Command::new(inssplat_bin()).args(args).output().expect("start inssplat")
}

/// Runs `inssplat-eval` with `args`, returning its output.
pub fn inssplat_eval(args: &[&str]) -> Output {
    Command::new(inssplat_eval_bin()).args(args).output().expect("start inssplat-eval")
}

/// A tar archive (as `tar` writes it) of `entries` under `dir`, e.g. dataset scene folders
/// for a batch job.
pub fn tar_of(dir: &std::path::Path, entries: &[&str]) -> Vec<u8> {
    let out = Command::new("tar")
        .arg("-cf")
        .arg("-")
        .arg("-C")
        .arg(dir)
        .args(entries)
        .output()
        .expect("run tar");
    assert!(out.status.success(), "tar: {}", String::from_utf8_lossy(&out.stderr));
    out.stdout
}
