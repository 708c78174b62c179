//! The shipped default network (`models/inssplat-default.onnx`) end to end on a procedural
//! test scene it never saw, with the real binary, ONNX Runtime and MiniLM: the PLY reads
//! back, every mask has the model's size, a label the model names finds its instance in all
//! views, and a query for something absent says that nothing matches. (Whether the labels are
//! right is what `inssplat eval` and the model card measure; the shipped 0.1 network does not
//! yet name objects correctly, see `models/inssplat-default.md`.)

mod support;

use std::path::PathBuf;

use inssplat_e2e::inssplat;
use inssplat_proto::api::{QueryResponse, ReconstructResponse};
use inssplat_proto::dataset::Scene;
use inssplat_trainer::synth::{self, Furniture, Split, SynthConfig};
use support::s;

fn shipped_model() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../models/inssplat-default.onnx")
}

#[test]
fn shipped_model_reconstructs_and_answers_queries() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = SynthConfig::new(Split::Test, Furniture::from_env());
    let scene_dir = dir.path().join("scene");
    synth::generate_split(0, &cfg).unwrap().write(&scene_dir).unwrap();
    let scene = Scene::load(&scene_dir).unwrap();
    assert_eq!(scene.eval.as_ref().unwrap().context_for(16).map(<[usize]>::len), Some(16));

    let out = dir.path().join("out");
    let model = shipped_model();
    let run = inssplat(&["reconstruct", s(&scene_dir), "-o", s(&out), "--model", s(&model), "--json"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let r: ReconstructResponse = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(r.cameras.len(), 16);
    let ply = inssplat_proto::ply::read_ply(&mut std::fs::File::open(out.join("scene.ply")).unwrap()).unwrap();
    assert_eq!(ply.len(), r.gaussians_kept);

    for v in 0..16 {
        for kind in ["instances", "labels"] {
            let img = image::open(out.join(format!("{kind}/{v:03}.png"))).unwrap();
            assert_eq!((img.width(), img.height()), (128, 128), "{kind} {v}");
        }
    }
    assert!(!r.instances.is_empty());
    // A label the model names answers with masks in all 16 views.
    let named = &r.instances[0].label;
    let q = inssplat(&["query", s(&out), named, "--json"]);
    assert!(q.status.success(), "{}", String::from_utf8_lossy(&q.stderr));
    let answer: QueryResponse = serde_json::from_slice(&q.stdout).unwrap();
    assert!(answer.matches.iter().any(|m| m.label == *named), "{answer:?}");
    assert!(answer.matches.iter().all(|m| m.masks.len() == 16));
    let q = inssplat(&["query", s(&out), "banana", "--json"]);
    let answer: QueryResponse = serde_json::from_slice(&q.stdout).unwrap();
    assert!(answer.matches.is_empty() && answer.message.unwrap().contains("nothing in this scene matches"));
}
