//! The `inssplat-train synth` command as a person runs it: scenes, previews, credits and the
//! statistics report; a bad furniture folder names the flag and the path.

use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_inssplat-train"))
}

#[test]
fn synth_cli_writes_scenes_previews_and_statistics() {
    let tmp = tempfile::tempdir().unwrap();
    let out = bin()
        .args([
            "synth",
            "--split",
            "val",
            "--count",
            "2",
            "--size",
            "24",
            "--frames",
            "3",
            "--preview",
        ])
        .arg("--out")
        .arg(tmp.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(
        stdout.contains("scenes/s") && stdout.contains("share of pixels per class"),
        "{stdout}"
    );
    assert!(stdout.contains("instances of one category"), "{stdout}");
    for f in [
        "scene_000000/transforms.json",
        "scene_000001/images/002.png",
        "preview/scene_000000.png",
        "credits.json",
    ] {
        assert!(tmp.path().join(f).is_file(), "{f} missing");
    }
    assert!(
        !tmp.path().join("preview/scene_000001.png").exists(),
        "--preview alone previews one scene"
    );
}

#[test]
fn synth_cli_names_the_bad_flag() {
    let tmp = tempfile::tempdir().unwrap();
    let out = bin()
        .args(["synth", "--split", "train", "--count", "1", "--furniture-dir", "/nonexistent/sh3d"])
        .arg("--out")
        .arg(tmp.path())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("--furniture-dir") && stderr.contains("/nonexistent/sh3d"), "{stderr}");
    let out = bin()
        .args([
            "synth",
            "--split",
            "train",
            "--count",
            "1",
            "--primitives-only",
            "--reserved",
            "include",
        ])
        .arg("--out")
        .arg(tmp.path())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("reserved"), "{stderr}");
}
