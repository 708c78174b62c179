//! inssplat-e2e: helpers for end-to-end tests that run the real `inssplat` binary. The binary
//! is found through `INSSPLAT_BIN`, else in the workspace's target folder, built there once
//! if it is missing.

use std::path::PathBuf;
use std::process::{Command, Output};
use std::sync::OnceLock;

/// Path of the `inssplat` binary, building it if needed.
pub fn inssplat_bin() -> PathBuf {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| {
        if let Some(p) = std::env::var_os("INSSPLAT_BIN") {
            return PathBuf::from(p);
        }
        let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
        // `--workspace` builds with the features of nextest's own workspace build, so after it
        // this compiles nothing; `-p inssplat-server` would rebuild ~80 crates for its own set.
        let status = Command::new(env!("CARGO"))
            .args(["build", "-q", "--workspace", "--bin", "inssplat"])
            .current_dir(&root)
            .status()
            .expect("run cargo build");
        assert!(status.success(), "building inssplat failed");
        let target = std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or(root.join("target"));
        target.join("debug").join("inssplat")
    })
    .clone()
}

/// Runs `inssplat` with `args`, returning its output.
pub fn inssplat(args: &[&str]) -> Output {
    Command::new(inssplat_bin()).args(args).output().expect("start inssplat")
}
