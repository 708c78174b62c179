//! `inssplat-train train --config`: the shipped recipe is a valid command line of `train`, and
//! a bad recipe is refused naming its file and key.

use crate::train_loop::bin;

/// Every flag of a recipe is parsed before `--help` is reached, so `--help` succeeds only
/// when each key is a flag of `train` with a valid value.
#[test]
fn the_shipped_recipe_is_a_train_command_line() {
    let recipe = concat!(env!("CARGO_MANIFEST_DIR"), "/recipes/inssplat-default-0.13.toml");
    let out =
        bin().args(["train", "--config", recipe, "--out", "unused", "--help"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("--config <FILE>"));
}

#[test]
fn a_recipe_with_an_unknown_or_bad_flag_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("run.toml");
    for (text, named) in [
        ("lr = \"fast\"\n", "--lr"),
        ("no-such-flag = 1\n", "--no-such-flag"),
        ("lr = [\n", "run.toml"),
    ] {
        std::fs::write(&path, text).unwrap();
        let out = bin()
            .args(["train", "--config"])
            .arg(&path)
            .args(["--out", "unused", "--help"])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && stderr.contains(named), "{text}: {stderr}");
    }
}
