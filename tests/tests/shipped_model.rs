//! The shipped default network (`models/inssplat-default.onnx`) end to end on a procedural
//! test scene it never saw (room shell as labelled instances, as in training), with the real
//! binary, ONNX Runtime and MiniLM: the PLY reads back, every mask has the model's size, at
//! least one instance carries a label that is right (its pixels are mostly that label in the
//! ground truth), a query for that label returns masks that overlap the label's true pixels
//! in all 16 views (IoU printed and bounded below), and a query for something absent says
//! that nothing matches. (The 0.5 model names the room shell, chairs and a few other pieces
//! of furniture, not yet most: see `models/inssplat-default.md`.) On eight test scenes at 8
//! views, every camera says how registration placed it, the views it registered are the
//! accurate ones, and the CLI's summary names the views placed otherwise.

use std::path::PathBuf;

use crate::support::s;
use glam::DMat3;
use inssplat_e2e::inssplat;
use inssplat_geometry::rotation::angle_deg;
use inssplat_proto::api::{FocalSource, Placement, QueryResponse, ReconstructResponse};
use inssplat_proto::dataset::Scene;
use inssplat_synth::{self as synth, Furniture, Split, Structure, SynthConfig};

fn shipped_model() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../models/inssplat-default.onnx")
}

#[test]
fn shipped_model_reconstructs_and_answers_queries() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = SynthConfig::new(Split::Test, Furniture::from_env());
    cfg.structure = Structure::Instances;
    let scene_dir = dir.path().join("scene");
    synth::generate_split(0, &cfg).unwrap().write(&scene_dir).unwrap();
    let scene = Scene::load(&scene_dir).unwrap();
    assert_eq!(scene.eval.as_ref().unwrap().context_for(16).map(<[usize]>::len), Some(16));

    let out = dir.path().join("out");
    let model = shipped_model();
    let run =
        inssplat(&["reconstruct", s(&scene_dir), "-o", s(&out), "--model", s(&model), "--json"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let r: ReconstructResponse = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(r.cameras.len(), 16);
    let ply =
        inssplat_proto::ply::read_ply(&mut std::fs::File::open(out.join("scene.ply")).unwrap())
            .unwrap();
    assert_eq!(ply.len(), r.gaussians_kept);

    for v in 0..16 {
        for kind in ["instances", "labels"] {
            let img = image::open(out.join(format!("{kind}/{v:03}.png"))).unwrap();
            assert_eq!((img.width(), img.height()), (128, 128), "{kind} {v}");
        }
    }
    assert!(!r.instances.is_empty());
    // Ground truth of the 16 context views: each pixel's label ("" for none).
    let context = scene.eval.as_ref().unwrap().context_for(16).unwrap().to_vec();
    let truth: Vec<&str> = context
        .iter()
        .flat_map(|&f| scene.frames[f].instances.as_ref().unwrap().iter())
        .map(|&id| scene.label_of(id).unwrap_or(""))
        .collect();
    // An instance is labelled right when most of its pixels carry that label in the truth.
    // Pixels of instances/NNN.png map back to ids through instances.json's colour table.
    let doc: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("instances.json")).unwrap()).unwrap();
    let colours: Vec<(u32, [u8; 3])> =
        serde_json::from_value(doc["instance_colours"].clone()).unwrap();
    let colour_of = |id: u32| colours.iter().find(|(i, _)| *i == id).map(|(_, c)| *c);
    let id_maps: Vec<u32> = (0..16)
        .flat_map(|v| {
            let img = image::open(out.join(format!("instances/{v:03}.png"))).unwrap().to_rgb8();
            img.pixels()
                .map(|p| {
                    r.instances.iter().find(|i| colour_of(i.id) == Some(p.0)).map_or(0, |i| i.id)
                })
                .collect::<Vec<_>>()
        })
        .collect();
    let right = r.instances.iter().find(|i| {
        let pixels: Vec<&str> =
            id_maps.iter().zip(&truth).filter(|(id, _)| **id == i.id).map(|(_, t)| *t).collect();
        !pixels.is_empty() && pixels.iter().filter(|t| **t == i.label).count() * 2 > pixels.len()
    });
    let right = right.unwrap_or_else(|| panic!("no instance is labelled right: {:?}", r.instances));
    // Its query answers in all 16 views and overlaps the label's true pixels.
    let q = inssplat(&["query", s(&out), &right.label, "--json"]);
    assert!(q.status.success(), "{}", String::from_utf8_lossy(&q.stderr));
    let answer: QueryResponse = serde_json::from_slice(&q.stdout).unwrap();
    assert!(answer.matches.iter().any(|m| m.label == right.label), "{answer:?}");
    assert!(answer.matches.iter().all(|m| m.masks.len() == 16));
    let mut got = vec![false; truth.len()];
    for m in &answer.matches {
        for mask in &m.masks {
            for (p, on) in mask.rle.decode().into_iter().enumerate() {
                got[mask.view * 128 * 128 + p] |= on;
            }
        }
    }
    let inter = got.iter().zip(&truth).filter(|(g, t)| **g && **t == right.label).count();
    let union = got.iter().zip(&truth).filter(|(g, t)| **g || **t == right.label).count();
    let iou = inter as f64 / union as f64;
    eprintln!("query {:?}: IoU {iou:.3} with its true pixels over 16 views", right.label);
    assert!(iou >= 0.3, "query {:?} IoU {iou}", right.label);
    let q = inssplat(&["query", s(&out), "banana", "--json"]);
    let answer: QueryResponse = serde_json::from_slice(&q.stdout).unwrap();
    assert!(
        answer.matches.is_empty()
            && answer.message.unwrap().contains("nothing in this scene matches")
    );
}

/// Rotation of a nerfstudio camera-to-world matrix (row-major).
fn rotation(m: &[[f64; 4]; 4]) -> DMat3 {
    DMat3::from_cols_array_2d(&[
        [m[0][0], m[0][1], m[0][2]],
        [m[1][0], m[1][1], m[1][2]],
        [m[2][0], m[2][1], m[2][2]],
    ])
    .transpose()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[test]
fn every_camera_says_how_it_was_placed_and_registered_ones_are_the_accurate_ones() {
    // Eight test scenes at 8 views with the shipped network: measured, the 50 registered views
    // err 2.0° (median) from their true rotation relative to view 0, and scene 2's six views
    // that no match links, placed by the camera's continued motion, 32.8°.
    let dir = tempfile::tempdir().unwrap();
    let cfg = SynthConfig::new(Split::Test, Furniture::from_env());
    let model = shipped_model();
    let (mut registered, mut continued, mut measured) = (Vec::new(), Vec::new(), 0);
    for index in 0..8 {
        let scene_dir = dir.path().join(format!("scene{index}"));
        synth::generate_split(index, &cfg).unwrap().write(&scene_dir).unwrap();
        let scene = Scene::load(&scene_dir).unwrap();
        let context = scene.eval.as_ref().and_then(|e| e.context_for(8)).unwrap().to_vec();
        let photos: Vec<String> = context
            .iter()
            .map(|&f| s(&scene_dir.join(format!("images/{f:03}.png"))).to_string())
            .collect();
        let out = dir.path().join(format!("out{index}"));
        let mut args = vec!["reconstruct"];
        args.extend(photos.iter().map(String::as_str));
        args.extend(["-o", s(&out), "--model", s(&model), "--json"]);
        let run = inssplat(&args);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        let r: ReconstructResponse = serde_json::from_slice(&run.stdout).unwrap();
        assert_eq!(r.cameras[0].placement, Some(Placement::Reference), "scene {index}");
        // Where the focal length came from, the same for every view of a scene.
        let focal = r.cameras[0].focal;
        assert!(
            matches!(focal, Some(FocalSource::Measured | FocalSource::CameraHead)),
            "scene {index}: {focal:?}"
        );
        assert!(r.cameras.iter().all(|c| c.focal == focal), "scene {index}");
        measured += usize::from(focal == Some(FocalSource::Measured));
        let truth: Vec<DMat3> =
            context.iter().map(|&f| rotation(&scene.frames[f].camera.to_nerfstudio())).collect();
        let predicted: Vec<DMat3> =
            r.cameras.iter().map(|c| rotation(&c.transform_matrix)).collect();
        for (v, camera) in r.cameras.iter().enumerate().skip(1) {
            let relative = |m: &[DMat3]| m[0].transpose() * m[v];
            let degrees = angle_deg(relative(&truth).transpose() * relative(&predicted));
            match camera.placement {
                Some(Placement::Registered) => registered.push(degrees),
                Some(Placement::Continued | Placement::CameraHead) => continued.push(degrees),
                other => panic!("scene {index} view {v}: placement {other:?}"),
            }
        }
        // The summary for people names the unlinked views (scene 2 has some, scene 0 none).
        if [0, 2].contains(&index) {
            let text = inssplat(&args[..args.len() - 1]);
            let said = format!(
                "{}{}",
                String::from_utf8_lossy(&text.stdout),
                String::from_utf8_lossy(&text.stderr)
            );
            let unlinked = r.cameras.iter().any(|c| c.placement == Some(Placement::Continued));
            assert_eq!(
                said.contains("placed by continuing the camera's motion"),
                unlinked,
                "scene {index}: {said}"
            );
        }
    }
    let (linked, others) = (registered.len(), continued.len());
    assert!(measured >= 6, "the focal length was measured in only {measured} of 8 scenes");
    assert!(linked >= 40, "only {linked} of 56 views registered");
    assert!(others > 0, "every view was registered: the test no longer sees the other placements");
    let (reg, cont) = (median(registered), median(continued));
    eprintln!(
        "{linked} registered views: median rotation error {reg:.1}°; {others} others: {cont:.1}°"
    );
    assert!(reg < 4.0, "registered views err {reg}° (median)");
    assert!(cont > 3.0 * reg, "views placed otherwise err {cont}°, registered ones {reg}°");
}

#[test]
fn two_copies_of_one_photo_keep_and_say_the_camera_heads_field_of_view() {
    // Matches between a photo and itself cannot tell the focal length: the response says the
    // field of view is the camera head's, and so does the summary for people.
    let dir = tempfile::tempdir().unwrap();
    let cfg = SynthConfig::new(Split::Test, Furniture::from_env());
    let scene_dir = dir.path().join("scene");
    synth::generate_split(0, &cfg).unwrap().write(&scene_dir).unwrap();
    let photo = scene_dir.join("images/000.png");
    let (model, out) = (shipped_model(), dir.path().join("out"));
    let args = ["reconstruct", s(&photo), s(&photo), "-o", s(&out), "--model", s(&model)];
    let run = inssplat(&[&args[..], &["--json"]].concat());
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let r: ReconstructResponse = serde_json::from_slice(&run.stdout).unwrap();
    assert!(r.cameras.iter().all(|c| c.focal == Some(FocalSource::CameraHead)), "{:?}", r.cameras);
    let text = inssplat(&args);
    let said = format!(
        "{}{}",
        String::from_utf8_lossy(&text.stdout),
        String::from_utf8_lossy(&text.stderr)
    );
    assert!(said.contains("the camera head's guess"), "{said}");
}
