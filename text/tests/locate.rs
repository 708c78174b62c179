//! Finding the model folder: the environment variable, the default `.deps/all-minilm-l6-v2-*`
//! location, and the errors when neither holds a model (which must name both).

use std::fs;
use std::path::Path;

use inssplat_text::{DEFAULT_MODEL_GLOB, MODEL_ENV, TextEmbedder, TextError, locate_model_in};

/// A folder with the three files the locator checks for (empty: it checks, it does not load).
fn fake_model_dir(dir: &Path) {
    fs::create_dir_all(dir).unwrap();
    for f in ["model.safetensors", "tokenizer.json", "config.json"] {
        fs::write(dir.join(f), b"").unwrap();
    }
}

fn assert_names_env_and_default(err: &TextError) {
    let msg = err.to_string();
    assert!(matches!(err, TextError::ModelNotFound { .. }), "{err:?}");
    assert!(msg.contains(MODEL_ENV), "{msg}");
    assert!(msg.contains(DEFAULT_MODEL_GLOB), "{msg}");
}

#[test]
fn missing_env_folder_is_an_error_naming_the_variable_and_the_default() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("no-such-model");
    let err = locate_model_in(Some(&missing), &[]).unwrap_err();
    assert_names_env_and_default(&err);
    assert!(err.to_string().contains("no-such-model"), "{err}");
}

#[test]
fn env_folder_without_weights_is_an_error_naming_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    fs::write(tmp.path().join("tokenizer.json"), b"{}").unwrap();
    let err = locate_model_in(Some(tmp.path()), &[]).unwrap_err();
    assert_names_env_and_default(&err);
    assert!(err.to_string().contains("model.safetensors"), "{err}");
}

#[test]
fn no_env_and_no_default_folder_is_an_error_naming_both() {
    let tmp = tempfile::tempdir().unwrap();
    let err = locate_model_in(None, &[tmp.path().to_path_buf()]).unwrap_err();
    assert_names_env_and_default(&err);
    assert!(err.to_string().contains(&tmp.path().display().to_string()), "{err}");
}

#[test]
fn loading_a_missing_folder_is_an_error_naming_the_variable() {
    let tmp = tempfile::tempdir().unwrap();
    let err = TextEmbedder::load(&tmp.path().join("gone")).unwrap_err();
    assert_names_env_and_default(&err);
}

#[test]
fn default_location_is_found_above_a_root_newest_version_first() {
    let tmp = tempfile::tempdir().unwrap();
    let deps = tmp.path().join(".deps");
    fake_model_dir(&deps.join("all-minilm-l6-v2-0.9.0"));
    fake_model_dir(&deps.join("all-minilm-l6-v2-0.10.0"));
    // A newer version without weights does not count.
    fs::create_dir_all(deps.join("all-minilm-l6-v2-0.11.0")).unwrap();
    let nested = tmp.path().join("target/release/deps");
    fs::create_dir_all(&nested).unwrap();
    let found = locate_model_in(None, &[nested]).unwrap();
    assert_eq!(found, deps.join("all-minilm-l6-v2-0.10.0"));
}

#[test]
fn env_variable_wins_over_the_default_location() {
    let tmp = tempfile::tempdir().unwrap();
    fake_model_dir(&tmp.path().join(".deps/all-minilm-l6-v2-0.1.0"));
    let chosen = tmp.path().join("elsewhere");
    fake_model_dir(&chosen);
    let found = locate_model_in(Some(&chosen), &[tmp.path().to_path_buf()]).unwrap();
    assert_eq!(found, chosen);
}
