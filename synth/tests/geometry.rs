//! Cameras, depth and instance masks agree: depth re-projected from one view into another
//! matches that view's own depth where the point is visible (median relative error < 1 %),
//! and the instance ids at matching pixels agree. Read back from disk, so the 16-bit depth
//! quantization and the nerfstudio camera convention are part of what is checked.

use glam::Vec3;
use inssplat_proto::dataset::Scene;
use inssplat_synth::{self as synth, Furniture, Split, SynthConfig};

#[test]
fn synth_depth_reprojects_consistently_between_views() {
    let mut cfg = SynthConfig::new(Split::Train, Furniture::from_env());
    cfg.width = 48;
    cfg.height = 40;
    cfg.frames = (5, 5);
    cfg.overlap = (0.7, 0.9);
    let tmp = tempfile::tempdir().unwrap();
    let mut errors = Vec::new();
    let (mut same_id, mut compared_ids) = (0usize, 0usize);
    for index in 0..3 {
        let dir = tmp.path().join(format!("s{index}"));
        synth::generate_split(index, &cfg).unwrap().write(&dir).unwrap();
        let scene = Scene::load(&dir).unwrap();
        for (a, b) in [(0, 1), (1, 3), (4, 2)] {
            let (fa, fb) = (&scene.frames[a], &scene.frames[b]);
            let (da, db) = (fa.depth.as_ref().unwrap(), fb.depth.as_ref().unwrap());
            let (ia, ib) = (fa.instances.as_ref().unwrap(), fb.instances.as_ref().unwrap());
            let (w, h) = (fa.width() as usize, fa.height() as usize);
            for y in 0..h {
                for x in 0..w {
                    let z = da[y * w + x];
                    assert!(z > 0.0, "every ray hits the room");
                    let world = fa.camera.camera_to_world(fa.camera.unproject(
                        x as f32 + 0.5,
                        y as f32 + 0.5,
                        z,
                    ));
                    let pb: Vec3 = fb.camera.world_to_camera(world);
                    if pb.z <= 0.05 {
                        continue;
                    }
                    let Some((bx, by)) = fb.camera.pixel_of(pb) else { continue };
                    let k = by * w + bx;
                    let rel = (db[k] - pb.z).abs() / pb.z;
                    errors.push(rel);
                    if rel < 0.01 {
                        compared_ids += 1;
                        same_id += usize::from(ia[y * w + x] == ib[k]);
                    }
                }
            }
        }
    }
    assert!(errors.len() > 1000, "views overlap: {} re-projected pixels", errors.len());
    errors.sort_by(f32::total_cmp);
    let median = errors[errors.len() / 2];
    assert!(median < 0.01, "median relative depth error {median}");
    let agree = same_id as f64 / compared_ids as f64;
    assert!(agree > 0.95, "instance ids agree at {:.1}% of matching pixels", 100.0 * agree);
}
