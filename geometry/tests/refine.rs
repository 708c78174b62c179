//! Test-time refinement of a scene against its input photos (`inssplat_geometry::refine`) on the
//! analytic room reconstructed from ideal outputs, with its Gaussians displaced, its colours
//! dimmed and one input camera turned: the input views' error falls, a view that no input saw
//! improves too, the turned camera turns back, and the reference camera stays where it was;
//! a photo shot brighter than the others gets a gain of its own.

use glam::{Quat, Vec3};
use inssplat_geometry::refine::{RefineParams, RefineView, refine_scene};
use inssplat_geometry::rotation::turn_deg;
use inssplat_proto::gaussian::{rgb_to_sh_dc, sh_dc_to_rgb};
use inssplat_proto::{Camera, Intrinsics};
use inssplat_raster::masks::render_colour;

use crate::ring_room::ring_reconstruction;
use inssplat_geometry::analytic_room::render_scene;

fn mse(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(x, y)| f64::from(x.clamp(0.0, 1.0) - y).powi(2)).sum::<f64>()
        / a.len() as f64
}

#[test]
fn refining_against_the_photos_mends_displaced_gaussians_and_a_turned_camera() {
    let size = 64;
    let (truth, room, exact) = ring_reconstruction(size, 0.05, 5);
    // Every Gaussian off its surface by up to 0.08 (the room is about 4 across) and 30% dimmer.
    let mut displaced = exact.clone();
    for (i, m) in displaced.means.iter_mut().enumerate() {
        let h = |k: usize| ((i * 7919 + k * 104_729) % 1000) as f32 / 1000.0 - 0.5;
        *m = [m[0] + 0.16 * h(0), m[1] + 0.16 * h(1), m[2] + 0.16 * h(2)];
    }
    for c in &mut displaced.sh_dc {
        *c = c.map(|v| rgb_to_sh_dc(0.7 * sh_dc_to_rgb(v)));
    }
    let mut scene = displaced.clone();
    let mut cameras = truth.clone();
    cameras[3].rotation =
        (Quat::from_axis_angle(Vec3::new(0.2, 1.0, 0.1).normalize(), 1.5f32.to_radians())
            * truth[3].rotation)
            .normalize();
    // A view between two ring cameras, lower down, that no input saw.
    let k = Intrinsics::from_fov_y(size, size, 34f32.to_radians());
    let novel = Camera::look_at(k, Vec3::new(6.0, 4.0, 4.0), Vec3::new(0.0, 0.5, 0.0), Vec3::Y);
    let novel_photo = render_scene(&[novel]).frames[0].planar_rgb();
    let novel_before = mse(&render_colour(&scene, &novel, false).unwrap(), &novel_photo);

    let photos: Vec<Vec<f32>> = room.frames.iter().map(|f| f.planar_rgb()).collect();
    let inputs: Vec<RefineView<'_>> =
        photos.iter().map(|p| RefineView { photo: p, rect: [0, 0, size, size] }).collect();
    let turned_before = turn_deg(&cameras[3], &truth[3]);
    let done =
        refine_scene(&mut scene, &mut cameras, &inputs, RefineParams { steps: 160, cameras: true })
            .unwrap();

    assert!(done.mse_after < 0.3 * done.mse_before, "input views {done:?}");
    assert_eq!(done.steps, 160);
    assert!(done.psnr()[1] > done.psnr()[0] + 5.0, "{:?}", done.psnr());
    let novel_after = mse(&render_colour(&scene, &novel, false).unwrap(), &novel_photo);
    assert!(novel_after < 0.6 * novel_before, "novel view {novel_before:.4} → {novel_after:.4}");
    let turned_after = turn_deg(&cameras[3], &truth[3]);
    assert!(
        turned_after < 0.75 * turned_before,
        "turned camera {turned_before:.2}° → {turned_after:.2}°"
    );
    assert_eq!(cameras[0], truth[0], "the reference camera moved");
    assert_eq!(scene.instance_id, exact.instance_id, "ids ride along unchanged");
    assert!(
        scene.rotations.iter().all(|q| (q.iter().map(|c| c * c).sum::<f32>() - 1.0).abs() < 1e-4),
        "quaternions come back unit"
    );

    // Cameras kept (as given ones are): only the Gaussians move.
    let (mut kept, mut fitted_scene) = (truth.clone(), displaced.clone());
    let fitted = refine_scene(
        &mut fitted_scene,
        &mut kept,
        &inputs,
        RefineParams { steps: 40, cameras: false },
    )
    .unwrap();
    assert_eq!(kept, truth, "cameras moved though kept");
    assert!(fitted.mse_after < 0.5 * fitted.mse_before, "{fitted:?}");
    // No steps: nothing changes. A photo of the wrong size is named, not a panic.
    let (before, cams) = (scene.clone(), cameras.clone());
    let same =
        refine_scene(&mut scene, &mut cameras, &inputs, RefineParams { steps: 0, cameras: true })
            .unwrap();
    assert_eq!(
        (same.steps, same.mse_before, &scene, &cameras),
        (0, same.mse_after, &before, &cams)
    );
    let short = [RefineView { photo: &photos[0][..50], rect: [0, 0, size, size] }];
    let err = refine_scene(
        &mut scene,
        &mut cameras[..1],
        &short,
        RefineParams { steps: 5, cameras: true },
    )
    .unwrap_err();
    assert!(err.to_string().contains("the photo has 50 values"), "{err}");
}

#[test]
fn a_photo_shot_brighter_gets_its_own_gain_and_the_others_stay_alike() {
    let size = 64;
    let (cameras, room, mut scene) = ring_reconstruction(size, 0.05, 5);
    // Photo 5 with 12% more light: its auto exposure chose differently.
    let mut photos: Vec<Vec<f32>> = room.frames.iter().map(|f| f.planar_rgb()).collect();
    photos[5].iter_mut().for_each(|v| *v = (*v * 1.12).min(1.0));
    let inputs: Vec<RefineView<'_>> =
        photos.iter().map(|p| RefineView { photo: p, rect: [0, 0, size, size] }).collect();
    let mut kept = cameras.clone();
    let done =
        refine_scene(&mut scene, &mut kept, &inputs, RefineParams { steps: 160, cameras: false })
            .unwrap();

    let others: Vec<f32> =
        done.gains.iter().enumerate().filter(|&(v, _)| v != 5).map(|(_, g)| *g).collect();
    let mean_other = others.iter().map(|g| g.ln()).sum::<f32>() / others.len() as f32;
    let relative = (done.gains[5].ln() - mean_other).exp();
    assert!(
        (1.08..1.16).contains(&relative),
        "photo 5's gain over the others' {relative:.3} ({:?})",
        done.gains
    );
    assert!(
        others.iter().all(|g| (g.ln() - mean_other).abs() < 0.02),
        "the alike photos' gains {:?}",
        done.gains
    );
    let log_mean = done.gains.iter().map(|g| g.ln()).sum::<f32>() / done.gains.len() as f32;
    assert!(log_mean.abs() < 1e-4, "the gains' logs average {log_mean}");
}
