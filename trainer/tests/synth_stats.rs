//! Dataset statistics measured by library code on generated scenes: most scenes show two or
//! more instances of one category (neighbouring chairs, nightstands, bookcases), the
//! furniture spans at least twenty categories, and every scene shows several objects. The
//! label counts of the logit-adjusted L_sem: a layout's furniture is what its rendered scene
//! shows, and a folder counts what its scenes' `transforms.json` list.

use std::collections::BTreeSet;

use inssplat_synth::layout::{self, Source};
use inssplat_synth::room::Room;
use inssplat_synth::{
    self as synth, Catalog, DatasetStats, Furniture, Reserved, Split, SynthConfig,
};
use inssplat_trainer::train::sample::{DataSpec, Source as DataSource};
use rand::SeedableRng;

/// Train-split rooms at 32×32, six frames each: enough to render what a room shows, quickly.
fn small_train_rooms() -> SynthConfig {
    let mut cfg = SynthConfig::new(Split::Train, Furniture::from_env());
    cfg.width = 32;
    cfg.height = 32;
    cfg.frames = (6, 6);
    cfg
}

#[test]
fn synth_most_rendered_scenes_repeat_a_category() {
    let cfg = small_train_rooms();
    let mut stats = DatasetStats::default();
    for index in 0..20 {
        stats.add(&synth::generate_split(index, &cfg).unwrap().scene);
    }
    assert_eq!(stats.scenes, 20);
    assert!(stats.repeat_share() >= 0.6, "{stats}");
    assert!(stats.instances_per_scene.iter().all(|&n| n >= 2), "{stats}");
    assert!(stats.categories() >= 10, "{stats}");
    let background = stats.pixel_shares().into_iter().find(|(k, _)| k == "background").unwrap().1;
    assert!(background > 0.2 && background < 0.95, "{stats}");
}

#[test]
fn synth_layouts_span_twenty_categories_with_repeats() {
    let dir = match Furniture::from_env() {
        Furniture::Catalog(d) => d,
        Furniture::Primitives => unreachable!(),
    };
    let catalog = Catalog::open(&dir).unwrap();
    assert!(
        catalog.labels(Reserved::Exclude).len() >= 20,
        "{:?}",
        catalog.labels(Reserved::Exclude)
    );
    let cfg = SynthConfig::new(Split::Train, Furniture::Catalog(dir));
    let source = Source {
        catalog: Some(&catalog),
        reserved: Reserved::Exclude,
        mesh_share: 0.6,
        contrast: 1.0,
    };
    let mut labels = BTreeSet::new();
    let mut repeats = 0;
    let n = 60;
    for seed in 0..n {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let room = Room::random(&mut rng, 1.0);
        let l = layout::furnish(&room, &source, &cfg, &mut rng);
        let mut per: std::collections::BTreeMap<&str, usize> = Default::default();
        for o in &l.objects {
            labels.insert(o.model.label);
            *per.entry(o.model.label).or_default() += 1;
        }
        repeats += usize::from(per.iter().any(|(k, &c)| c >= 2 && *k != "rug"));
    }
    assert!(labels.len() >= 20, "{} categories: {labels:?}", labels.len());
    assert!(repeats as f64 >= 0.6 * n as f64, "{repeats} of {n}");
}

#[test]
fn synth_furniture_labels_are_the_layout_that_the_rendered_scene_shows() {
    let cfg = small_train_rooms();
    for index in 0..6 {
        let placed = synth::furniture_labels(index, &cfg).unwrap();
        assert_eq!(
            placed,
            synth::furniture_labels(index, &cfg).unwrap(),
            "scene {index}: the same layout each time"
        );
        // Every furniture instance the frames show is one the layout placed (as a multiset).
        let mut left: std::collections::BTreeMap<&str, i32> = Default::default();
        placed.iter().for_each(|l| *left.entry(l).or_default() += 1);
        let scene = synth::generate_split(index, &cfg).unwrap().scene;
        let shown: Vec<&str> = scene
            .instances
            .iter()
            .map(|i| i.label.as_str())
            .filter(|l| !synth::stats::SHELL_LABELS.contains(l))
            .collect();
        assert!(!shown.is_empty(), "scene {index} shows no furniture");
        for label in &shown {
            let n = left.get_mut(label).unwrap_or_else(|| {
                panic!("scene {index} shows a {label} its layout did not place: {placed:?}")
            });
            *n -= 1;
            assert!(
                *n >= 0,
                "scene {index} shows more of {label} than its layout placed: {placed:?}"
            );
        }
    }
}

#[test]
fn a_folder_of_scenes_counts_the_furniture_its_transforms_list() {
    let cfg = small_train_rooms();
    let tmp = tempfile::tempdir().unwrap();
    let mut want: std::collections::BTreeMap<String, u64> = Default::default();
    for index in 0..3 {
        let scene = synth::generate_split(index, &cfg).unwrap();
        scene.write(&tmp.path().join(format!("scene_{index}"))).unwrap();
        for inst in scene
            .scene
            .instances
            .iter()
            .filter(|i| !synth::stats::SHELL_LABELS.contains(&i.label.as_str()))
        {
            *want.entry(inst.label.clone()).or_default() += 1;
        }
    }
    let source = DataSource::open(&DataSpec::Folder(tmp.path().to_path_buf())).unwrap();
    assert_eq!(
        source.label_counts(0, 10).unwrap(),
        want,
        "each folder counted once, the shell left out"
    );
}
