//! The web page in a real browser: `inssplat serve` with the shipped network on loopback, and
//! Debian's Chromium driven by playwright-core (`tests/web/page.mjs`). The photos of a
//! procedural room go in through the page's file input; the 3D view must draw the Gaussians
//! (most of the canvas off the background), and a label the reconstruction reports, typed into
//! the query box, must light its instance up (highlight-coloured pixels in the canvas go from
//! next to none to many) and mask it on every input photo. The same photos sent as a batch job
//! from `/jobs` must be followed there to the end, with a link to the result. Nothing may be
//! requested from anywhere but the service. The screenshots stay in `target/tmp/web_page/`.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::support::http::Server;
use crate::support::s;
use crate::support::web;
use inssplat_synth::{self as synth, Furniture, Split, SynthConfig};
use serde_json::Value;

const VIEWS: usize = 4;

#[test]
fn page_reconstructs_draws_and_highlights_a_queried_label() {
    let (Some(node), Some(web_dir), Some(chromium)) = (
        web::require(web::program("node")),
        web::require(web::npm_package("playwright-core")),
        web::require(web::program("chromium")),
    ) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth::generate_split(1, &SynthConfig::new(Split::Test, Furniture::Primitives))
        .unwrap()
        .write(&scene)
        .unwrap();
    let mut photos: Vec<PathBuf> =
        std::fs::read_dir(scene.join("images")).unwrap().map(|e| e.unwrap().path()).collect();
    photos.sort();
    photos.truncate(VIEWS);

    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/inssplat-default.onnx");
    let server = Server::start(&model, &dir.path().join("data"), &["--web-dir", s(&web_dir)]);
    for page in ["/", "/jobs", "/docs"] {
        let html = server.get(page).text();
        assert!(
            !html.contains("http://") && !html.contains("https://"),
            "{page} names another host:\n{html}"
        );
        assert!(!html.contains("cannot work"), "{page} says its packages are missing:\n{html}");
    }

    let artefacts = Path::new(env!("CARGO_TARGET_TMPDIR")).join("web_page");
    std::fs::create_dir_all(&artefacts).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("web/page.mjs");
    let run = Command::new(node)
        .arg(script)
        .arg(format!("http://{}/", server.addr))
        .arg(&artefacts)
        .args(&photos)
        .env("INSSPLAT_WEB_DIR", &web_dir)
        .env("CHROMIUM", chromium)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(
        run.status.success(),
        "page.mjs failed:\n{stderr}\nservice log:\n{}",
        server.log_text()
    );
    let stdout = String::from_utf8_lossy(&run.stdout);
    let m: Value = serde_json::from_str(stdout.lines().last().unwrap_or_default())
        .unwrap_or_else(|e| panic!("{e}: {stdout}\n{stderr}"));
    eprintln!("{m:#}\nscreenshots in {}", artefacts.display());

    assert_eq!(m["errors"], Value::Array(vec![]), "the page reported errors");
    assert_eq!(m["foreign"], Value::Array(vec![]), "the page fetched from another host");
    let (scene_px, query_px) = (&m["scene"], &m["query"]);
    let pixels = scene_px["pixels"].as_u64().unwrap();
    assert!(
        scene_px["drawn"].as_u64().unwrap() > pixels / 5,
        "the 3D view is mostly background: {scene_px}"
    );
    let labels: Vec<&str> =
        m["labels"].as_array().unwrap().iter().filter_map(Value::as_str).collect();
    assert!(
        labels.contains(&m["label"].as_str().unwrap()),
        "the queried label is listed: {labels:?}"
    );
    assert!(m["matches"].as_u64().unwrap() >= 1, "a listed label matches: {m}");
    let (before, after) =
        (scene_px["highlight"].as_u64().unwrap(), query_px["highlight"].as_u64().unwrap());
    assert!(
        after > before + pixels / 50,
        "highlighted pixels rose only from {before} to {after} of {pixels}"
    );
    assert_eq!(m["masked"].as_u64(), Some(VIEWS as u64), "one masked photo per view");
    assert_eq!(
        m["job"]["state"], "done · 1/1",
        "the batch job submitted on /jobs ran: {}",
        m["job"]
    );
    assert_eq!(m["job"]["plyLinks"], 1, "the finished job links its scene.ply");
    for shot in ["scene.png", "query.png", "page.png"] {
        image::open(artefacts.join(shot)).unwrap_or_else(|e| panic!("{shot}: {e}"));
    }
}
