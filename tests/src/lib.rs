//! inssplat-e2e: helpers for end-to-end tests that run the real `inssplat` and `inssplat-eval`
//! binaries. Each is found through `INSSPLAT_BIN` / `INSSPLAT_EVAL_BIN`, else in the
//! workspace's target folder, built there once if it is missing.

use std::path::PathBuf;
use std::process::{Command, Output};
use std::sync::OnceLock;

/// Path of the workspace binary `name`, found through the environment variable `var`, else
/// built once in the workspace's target folder.
fn workspace_bin(name: &str, var: &str, cell: &'static OnceLock<PathBuf>) -> PathBuf {
    cell.get_or_init(|| {
        if let Some(p) = std::env::var_os(var) {
            return PathBuf::from(p);
        }
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
    workspace_bin("inssplat", "INSSPLAT_BIN", &BIN)
}

/// Path of the `inssplat-eval` binary, building it if needed.
pub fn inssplat_eval_bin() -> PathBuf {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    workspace_bin("inssplat-eval", "INSSPLAT_EVAL_BIN", &BIN)
}

/// Runs `inssplat` with `args`, returning its output.
pub fn inssplat(args: &[&str]) -> Output {
    Command::new(inssplat_bin()).args(args).output().expect("start inssplat")
}

/// Runs `inssplat-eval` with `args`, returning its output.
pub fn inssplat_eval(args: &[&str]) -> Output {
    Command::new(inssplat_eval_bin()).args(args).output().expect("start inssplat-eval")
}
