//! Dataset statistics measured by library code on generated scenes: most scenes show two or
//! more instances of one category (neighbouring chairs, nightstands, bookcases), the
//! furniture spans at least twenty categories, and every scene shows several objects.

use std::collections::BTreeSet;

use inssplat_synth::layout::{self, Source};
use inssplat_synth::room::Room;
use inssplat_synth::{
    self as synth, Catalog, DatasetStats, Furniture, Reserved, Split, SynthConfig,
};
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
