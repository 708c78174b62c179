//! L_pm, the point-map term: its value worked out by hand, its gradient against finite
//! differences, and its targets on a synthesized scene, where every view's true points land,
//! seen from view 0, on view 0's own true surface.

use burn::prelude::*;
use inssplat_proto::dataset::Scene;
use inssplat_synth::{self as synth, Furniture, Split, SynthConfig};
use inssplat_trainer::loss::{point_map_loss, point_map_targets};

use crate::loss_instance::check_gradient;

fn tensor(values: &[f32], shape: [usize; 4]) -> Tensor<4> {
    Tensor::from_data(TensorData::new(values.to_vec(), shape), &Device::flex())
}

#[test]
fn loss_point_map_is_the_mean_distance_over_valid_pixels_by_the_scale() {
    // One view of 1×3 pixels; the middle one has no ground truth and does not count.
    let predicted = [1.0, 5.0, 0.0, /* y */ 2.0, 5.0, 0.0, /* z */ 2.0, 5.0, 3.0];
    let target = [1.0, 0.0, 0.0, /* y */ 2.0, 0.0, 0.0, /* z */ 0.0, 0.0, -1.0];
    let depth = [2.0, 0.0, 1.0];
    let loss = point_map_loss(tensor(&predicted, [1, 3, 1, 3]), &target, &depth, 2.0).unwrap();
    // Distances 2 and 4 over the two valid pixels, divided by the scale 2.
    let got = f64::from(loss.into_scalar::<f32>());
    assert!((got - 1.5).abs() < 1e-5, "L_pm {got}, expected 1.5");
    let none = point_map_loss(tensor(&predicted, [1, 3, 1, 3]), &target, &[0.0; 3], 2.0).unwrap();
    assert_eq!(none.into_scalar::<f32>(), 0.0, "no valid pixel, no loss");
    let bad = point_map_loss(tensor(&predicted, [1, 3, 1, 3]), &target[..6], &depth, 2.0);
    assert!(bad.is_err(), "a target of the wrong length is refused");
}

#[test]
fn loss_point_map_gradient_matches_finite_differences() {
    let predicted = [
        0.3, 1.2, -0.4, 0.8, /* y */ 0.1, -0.6, 0.9, 0.2, /* z */ 2.1, 1.4, 2.6,
        0.7, // view 0, 2×2
        -0.2, 0.5, 1.1, 0.4, /* y */ 0.7, 0.3, -0.8, 0.6, /* z */ 1.9, 2.4, 0.9,
        1.6, // view 1
    ];
    let target: Vec<f32> = predicted
        .iter()
        .enumerate()
        .map(|(i, x)| x + 0.3 * ((i * 7 % 5) as f32 - 2.0) + 0.05)
        .collect();
    let depth = [2.0, 1.5, 0.0, 1.0, 1.8, 0.0, 2.2, 1.1];
    check_gradient(&predicted, [2, 3, 2, 2], |x| point_map_loss(x, &target, &depth, 1.7).unwrap());
}

/// Train scene `index` synthesized at `width`×`height` with `frames` frames along a path of
/// `overlap`, written and read back (the folder lives as long as the returned guard).
pub(crate) fn synthesized(
    index: u64,
    width: u32,
    height: u32,
    frames: usize,
    overlap: (f32, f32),
) -> (tempfile::TempDir, Scene) {
    let mut cfg = SynthConfig::new(Split::Train, Furniture::from_env());
    (cfg.width, cfg.height, cfg.frames, cfg.overlap) = (width, height, (frames, frames), overlap);
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("scene");
    synth::generate_split(index, &cfg).unwrap().write(&dir).unwrap();
    let scene = Scene::load(&dir).unwrap();
    (tmp, scene)
}

#[test]
fn point_map_targets_put_every_view_in_view_zeros_frame() {
    let (_dir, scene) = synthesized(7, 48, 40, 4, (0.7, 0.9));
    let (w, h) = (48usize, 40usize);
    let cameras: Vec<_> = scene.frames.iter().map(|f| f.camera).collect();
    let depth: Vec<f32> = scene.frames.iter().flat_map(|f| f.depth.clone().unwrap()).collect();
    let points = point_map_targets(&cameras, &depth, h, w, false).unwrap();
    let offsets = point_map_targets(&cameras, &depth, h, w, true).unwrap();
    let hw = h * w;
    let at = |v: usize, c: usize, p: usize| points[(v * 3 + c) * hw + p];
    // View 0's points are its depth along its own rays.
    let first = &scene.frames[0];
    for p in (0..hw).step_by(37) {
        let want = first.camera.unproject((p % w) as f32 + 0.5, (p / w) as f32 + 0.5, depth[p]);
        let got = glam::Vec3::new(at(0, 0, p), at(0, 1, p), at(0, 2, p));
        assert!((got - want).length() < 1e-4 * want.length(), "view 0 pixel {p}: {got} vs {want}");
    }
    // Another view's points, projected with view 0's intrinsics, meet view 0's surface; the
    // same points left in their own view's frame do not.
    let median_disagreement = |point_of: &dyn Fn(usize, usize) -> glam::Vec3| {
        let mut errors = Vec::new();
        for v in 1..cameras.len() {
            for p in 0..hw {
                let point = point_of(v, p);
                if point.z <= 0.05 {
                    continue;
                }
                let Some((x, y)) = first.camera.pixel_of(point) else { continue };
                let seen = depth[y * w + x];
                // Farther than what view 0 sees there: occluded from view 0, not compared.
                if point.z <= seen * 1.05 {
                    errors.push(((point.z - seen) / seen).abs());
                }
            }
        }
        assert!(errors.len() > hw / 2, "the views overlap: {} points compared", errors.len());
        errors.sort_by(f32::total_cmp);
        errors[errors.len() / 2]
    };
    // The offsets are the points less the pixels' own points: zero for view 0.
    for v in 0..cameras.len() {
        for p in (0..hw).step_by(29) {
            let own = scene.frames[v].camera.unproject(
                (p % w) as f32 + 0.5,
                (p / w) as f32 + 0.5,
                depth[v * hw + p],
            );
            let point = glam::Vec3::new(at(v, 0, p), at(v, 1, p), at(v, 2, p));
            let offset = glam::Vec3::from_array([0, 1, 2].map(|c| offsets[(v * 3 + c) * hw + p]));
            assert!(
                (offset - (point - own)).length() < 1e-4 * point.length().max(1.0),
                "view {v} pixel {p}: offset {offset}"
            );
        }
    }
    let moved = median_disagreement(&|v, p| glam::Vec3::new(at(v, 0, p), at(v, 1, p), at(v, 2, p)));
    let unmoved = median_disagreement(&|v, p| {
        scene.frames[v].camera.unproject(
            (p % w) as f32 + 0.5,
            (p / w) as f32 + 0.5,
            depth[v * hw + p],
        )
    });
    assert!(moved < 0.02, "median relative depth disagreement {moved}");
    assert!(
        unmoved > 5.0 * moved,
        "left in their own frames the points disagree by {unmoved}, carried by {moved}"
    );
}
