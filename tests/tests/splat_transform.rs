//! Our `scene.ply` read by a real 3DGS consumer: PlayCanvas' `splat-transform` CLI (npm,
//! installed by `scripts/setup` into `.deps/web`). It must take the file as Gaussians with
//! every Gaussian, no NaN or infinity in any column, the same extent of the centres as ours,
//! our extra columns kept, and convert it to SPZ (Niantic's compressed splat format) with
//! nothing lost in count.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::support::{s, web};
use inssplat_e2e::inssplat;
use inssplat_synth::{self as synth, Furniture, Split, SynthConfig};
use serde_json::Value;

/// Runs splat-transform (quiet) with `args`, checks it succeeded, and returns what it printed.
fn splat_transform(node: &Path, web_dir: &Path, args: &[&str]) -> String {
    let cli = web_dir.join("@playcanvas/splat-transform/bin/cli.mjs");
    let run = Command::new(node).arg(cli).arg("-q").args(args).output().unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout).into_owned();
    assert!(
        run.status.success(),
        "splat-transform {args:?}:\n{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    stdout
}

fn json(printed: &str) -> Value {
    serde_json::from_str(printed)
        .unwrap_or_else(|e| panic!("splat-transform printed no JSON ({e}):\n{printed}"))
}

#[test]
fn splat_transform_reads_and_converts_our_ply() {
    let (Some(node), Some(web_dir)) = (
        web::require(web::program("node")),
        web::require(web::npm_package("@playcanvas/splat-transform")),
    ) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth::generate_split(2, &SynthConfig::new(Split::Test, Furniture::Primitives))
        .unwrap()
        .write(&scene)
        .unwrap();
    let mut photos: Vec<PathBuf> =
        std::fs::read_dir(scene.join("images")).unwrap().map(|e| e.unwrap().path()).collect();
    photos.sort();
    let out = dir.path().join("out");
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/inssplat-default.onnx");
    let mut args = vec!["reconstruct", "-o", s(&out), "--model", s(&model)];
    args.extend(photos[..4].iter().map(|p| s(p)));
    let run = inssplat(&args);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let ply = out.join("scene.ply");
    let ours = inssplat_proto::ply::read_ply(&mut std::fs::File::open(&ply).unwrap()).unwrap();

    let stats = json(&splat_transform(&node, &web_dir, &[s(&ply), "--stats", "json", "null"]));
    assert_eq!(stats["format"], "ply");
    assert_eq!(stats["gaussian"], true, "read as Gaussians");
    assert_eq!(stats["numGaussians"].as_u64(), Some(ours.len() as u64));
    assert_eq!(stats["shBands"].as_u64(), Some(0));
    let extra: Vec<&str> = stats["extraColumns"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|c| c["name"].as_str())
        .collect();
    assert!(
        ["confidence", "instance_id", "ins_0", "sem_0"].iter().all(|c| extra.contains(c)),
        "{extra:?}"
    );
    let level = &stats["stats"][0];
    let columns: Vec<&str> =
        level["columns"].as_array().unwrap().iter().filter_map(Value::as_str).collect();
    let data = &level["data"];
    for key in ["nanCount", "infCount"] {
        assert!(data[key].as_array().unwrap().iter().all(|n| n == 0), "{key}: {}", data[key]);
    }
    for (axis, name) in ["x", "y", "z"].iter().enumerate() {
        let column = columns.iter().position(|c| c == name).unwrap();
        let lo = ours.means.iter().map(|m| m[axis]).fold(f32::INFINITY, f32::min);
        let hi = ours.means.iter().map(|m| m[axis]).fold(f32::NEG_INFINITY, f32::max);
        let (their_lo, their_hi) =
            (data["min"][column].as_f64().unwrap(), data["max"][column].as_f64().unwrap());
        assert!(
            (their_lo - f64::from(lo)).abs() < 1e-4 && (their_hi - f64::from(hi)).abs() < 1e-4,
            "{name}: ours {lo}..{hi}, theirs {their_lo}..{their_hi}"
        );
    }

    let spz = dir.path().join("scene.spz");
    splat_transform(&node, &web_dir, &[s(&ply), s(&spz)]);
    let info = json(&splat_transform(&node, &web_dir, &[s(&spz), "--info", "json", "null"]));
    assert_eq!(
        (info["format"].as_str(), info["numGaussians"].as_u64()),
        (Some("spz"), Some(ours.len() as u64))
    );
}
