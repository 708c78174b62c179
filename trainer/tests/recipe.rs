//! `inssplat-train train --config`: the shipped recipes are valid command lines of `train`, and
//! a bad recipe is refused naming its file and key.

use std::path::Path;
use std::process::Output;

use crate::train_loop::bin;

/// `train --config RECIPE --out unused --help`.
fn help_with(recipe: &Path) -> Output {
    bin()
        .args(["train", "--config"])
        .arg(recipe)
        .args(["--out", "unused", "--help"])
        .output()
        .unwrap()
}

/// Every flag of a recipe is parsed before `--help` is reached, so `--help` succeeds only
/// when each key is a flag of `train` with a valid value.
#[test]
fn the_shipped_recipes_are_train_command_lines() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("recipes");
    let mut recipes: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().path()).collect();
    recipes.sort();
    assert_eq!(recipes.len(), 2, "{recipes:?}");
    for recipe in recipes {
        let out = help_with(&recipe);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{}: {stderr}", recipe.display());
        assert!(String::from_utf8_lossy(&out.stdout).contains("--config <FILE>"));
    }
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
        let out = help_with(&path);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && stderr.contains(named), "{text}: {stderr}");
    }
}
