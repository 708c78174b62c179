//! Test-time pose refinement of a target camera (`inssplat_geometry::target_pose`) on the
//! analytic room reconstructed from ideal outputs: a camera turned and moved off a view that
//! no context frame saw finds its way back toward the true pose, and the colour error falls.

use glam::{Quat, Vec3};
use inssplat_geometry::rotation::turn_deg;
use inssplat_geometry::target_pose::refine_pose;
use inssplat_proto::{Camera, Intrinsics};

use crate::ring_room::ring_reconstruction;
use inssplat_geometry::analytic_room::render_scene;

#[test]
fn a_displaced_target_camera_is_brought_back_by_its_photo() {
    let size = 96;
    let (_, _, scene) = ring_reconstruction(size, 0.1, 3);

    // A view between two ring cameras, lower down.
    let k = Intrinsics::from_fov_y(size, size, 34f32.to_radians());
    let truth = Camera::look_at(k, Vec3::new(6.0, 4.0, 4.0), Vec3::new(0.0, 0.5, 0.0), Vec3::Y);
    let photo = render_scene(&[truth]).frames[0].planar_rgb();
    let mut start = truth;
    start.rotation =
        (Quat::from_axis_angle(Vec3::new(0.3, 1.0, 0.2).normalize(), 3f32.to_radians())
            * truth.rotation)
            .normalize();
    start.translation += Vec3::new(0.15, -0.1, 0.1);

    let refined = refine_pose(&scene, &start, &photo, 90).unwrap();
    let (before, after) = (turn_deg(&start, &truth), turn_deg(&refined.camera, &truth));
    let (moved_before, moved_after) =
        (start.center().distance(truth.center()), refined.camera.center().distance(truth.center()));
    assert!(after < before / 3.0, "rotation error {before:.2}° → {after:.2}°");
    assert!(moved_after < moved_before, "centre off by {moved_before:.3} → {moved_after:.3}");
    assert!(refined.mse_after < 0.5 * refined.mse_before, "{refined:?}");
    // At the true pose there is nothing to gain: the pose stays close.
    let kept = refine_pose(&scene, &truth, &photo, 90).unwrap();
    assert!(turn_deg(&kept.camera, &truth) < 0.5, "{kept:?}");
    assert!(kept.mse_after <= kept.mse_before);
    // A photo of the wrong size is named, not a panic.
    let err = refine_pose(&scene, &truth, &photo[..100], 5).unwrap_err();
    assert!(err.to_string().contains("the photo has 100 values"), "{err}");
}
