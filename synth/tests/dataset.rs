//! Synthesized scenes as the trainer and `inssplat-eval score` will read them: every written
//! scene passes `Scene::load`, the same seed gives a byte-identical folder, test scenes (and
//! val scenes when asked) carry a valid evaluation split, reserved furniture stays out of
//! train/val, and a missing
//! furniture folder is a clear error while primitives-only generation needs no files.

use std::collections::BTreeMap;
use std::path::Path;

use inssplat_proto::dataset::Scene;
use inssplat_synth::{
    self as synth, Furniture, Reserved, Split, Structure, SynthConfig, SynthError,
};

fn small(split: Split, furniture: Furniture) -> SynthConfig {
    let mut cfg = SynthConfig::new(split, furniture);
    cfg.width = 32;
    cfg.height = 24;
    cfg.frames = (4, 4);
    cfg
}

fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(
                    p.strip_prefix(dir).unwrap().display().to_string(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

#[test]
fn synth_written_scenes_load_and_the_same_seed_is_byte_identical() {
    let cfg = small(Split::Train, Furniture::from_env());
    let tmp = tempfile::tempdir().unwrap();
    for index in 0..3 {
        let (a, b) = (tmp.path().join(format!("a{index}")), tmp.path().join(format!("b{index}")));
        let s = synth::generate_split(index, &cfg).unwrap();
        s.write(&a).unwrap();
        synth::generate_split(index, &cfg).unwrap().write(&b).unwrap();
        let (fa, fb) = (files(&a), files(&b));
        assert!(
            fa.contains_key("transforms.json")
                && fa.contains_key("depth/003.png")
                && fa.contains_key("credits.json")
        );
        assert!(fa == fb, "scene {index}: two runs differ");
        let loaded = Scene::load(&a).unwrap_or_else(|e| panic!("scene {index}: {e}"));
        assert_eq!(loaded.instances, s.scene.instances);
        assert_eq!(loaded.frames.len(), 4);
        assert_eq!(loaded.frames[0].rgb, s.scene.frames[0].rgb);
        assert!(!loaded.instances.is_empty(), "scene {index} shows no object");
        assert!(loaded.eval.is_none(), "train scenes carry no evaluation split");
    }
    let other = synth::generate(Split::Train.seed(1).unwrap() + 7, &cfg).unwrap();
    assert_ne!(other.frames[0].rgb, synth::generate_split(1, &cfg).unwrap().scene.frames[0].rgb);
}

#[test]
fn synth_test_split_marks_context_and_target_views_and_may_show_the_shell() {
    let mut cfg = small(Split::Test, Furniture::from_env());
    cfg.width = 16;
    cfg.height = 16;
    cfg.frames = (24, 24);
    cfg.structure = Structure::Instances;
    let s = synth::generate_split(0, &cfg).unwrap().scene;
    let eval = s.eval.clone().expect("test scenes have an eval split");
    assert_eq!(eval.context_for(16).unwrap().len(), 16);
    assert_eq!(eval.context_for(2).unwrap().len(), 2);
    assert_eq!(eval.target.len(), 8);
    assert!(
        s.instances.iter().any(|i| i.label == "floor")
            && s.instances.iter().any(|i| i.label == "wall")
    );
    let tmp = tempfile::tempdir().unwrap();
    s.write(tmp.path()).unwrap();
    assert_eq!(Scene::load(tmp.path()).unwrap().eval, Some(eval));

    // Val scenes carry the same split only when asked (model selection with `inssplat-eval score`).
    let mut val = small(Split::Val, Furniture::from_env());
    val.frames = (24, 24);
    assert!(synth::generate_split(0, &val).unwrap().scene.eval.is_none());
    val.eval_views = true;
    let marked =
        synth::generate_split(0, &val).unwrap().scene.eval.expect("--eval-views marks val scenes");
    assert_eq!(marked.context_for(8).unwrap().len(), 8);
}

#[test]
fn synth_reserved_furniture_never_reaches_train_or_val() {
    for split in [Split::Train, Split::Val] {
        let mut cfg = small(split, Furniture::from_env());
        cfg.reserved = Reserved::Include;
        assert!(matches!(synth::generate_split(0, &cfg), Err(SynthError::Config(_))));
    }
    let dir = match Furniture::from_env() {
        Furniture::Catalog(d) => d,
        Furniture::Primitives => unreachable!(),
    };
    let catalog = synth::Catalog::open(&dir).unwrap();
    let reserved: Vec<&str> =
        catalog.entries.iter().filter(|e| e.reserved).map(|e| e.credit.id.as_str()).collect();
    assert!(reserved.len() > 40, "the reserved list matches catalog ids: {reserved:?}");
    let mut cfg = small(Split::Train, Furniture::from_env());
    cfg.mesh_share = 1.0;
    for index in 0..4 {
        for c in synth::generate_split(index, &cfg).unwrap().credits {
            assert!(!reserved.contains(&c.id.as_str()), "{} in train", c.id);
        }
    }
}

#[test]
fn synth_missing_furniture_folder_is_a_clear_error_and_primitives_need_none() {
    let cfg = small(Split::Train, Furniture::Catalog("/nonexistent/furniture".into()));
    let err = synth::generate_split(0, &cfg).unwrap_err().to_string();
    assert!(err.contains("/nonexistent/furniture"), "{err}");
    let cfg = small(Split::Val, Furniture::Primitives);
    let s = synth::generate_split(0, &cfg).unwrap();
    assert!(s.credits.is_empty() && !s.scene.instances.is_empty());
}
