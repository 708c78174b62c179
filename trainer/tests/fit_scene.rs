//! The per-scene baseline on a real synthesized test scene: fitting Gaussians and instance
//! embeddings to its context views with the true cameras separates its instances on the
//! held-out target views, and bad input is a named error.

use inssplat_proto::dataset::Scene;
use inssplat_trainer::fit::{FitConfig, fit_scene};
use inssplat_trainer::synth::{self, Furniture, Split, SynthConfig};

fn scene(dir: &std::path::Path) -> Scene {
    let mut cfg = SynthConfig::new(Split::Test, Furniture::Primitives);
    (cfg.width, cfg.height, cfg.objects) = (48, 48, (3, 4));
    let path = dir.join("scene_000000");
    synth::generate_split(2, &cfg).unwrap().write(&path).unwrap();
    Scene::load(&path).unwrap()
}

#[test]
fn fitting_one_scene_separates_its_instances_on_target_views() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = scene(tmp.path());
    let config = FitConfig { views: 4, stride: 1, max_steps: 120, ..FitConfig::default() };
    let report = fit_scene(&scene, &config, &|_, _| {}).unwrap();
    assert!(report.final_loss * 5.0 < report.first_loss, "{report:?}");
    assert!(report.instances_found >= 2, "{report:?}");
    let miou = report.instance_miou.expect("target views show instances");
    assert!(miou >= 0.3, "instance mIoU {miou} ({report:?})");
    // Panoptic quality needs matches above IoU ½, which a separated object gives.
    let pq = report.instance_pq.expect("target views show instances");
    assert!(pq > 0.0 && pq <= 1.0, "instance PQ {pq} ({report:?})");
}

#[test]
fn a_scene_without_the_asked_context_set_is_a_named_error() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = scene(tmp.path());
    let err = fit_scene(&scene, &FitConfig { views: 5, ..FitConfig::default() }, &|_, _| {}).unwrap_err().to_string();
    assert!(err.contains("scene_000000") && err.contains("no 5-view context set"), "{err}");
}
