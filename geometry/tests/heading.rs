//! Placing an unlinked view by its heading (`inssplat_geometry::heading`) on the analytic room
//! reconstructed from its ideal outputs: a ring camera turned off its true heading is turned
//! back by its photo, and a photo that shows nothing of the room moves nothing.

use glam::{Quat, Vec3};
use inssplat_geometry::heading::{HeadingParams, place_by_heading};
use inssplat_geometry::rotation::turn_deg;
use inssplat_proto::Camera;

use crate::ring_room::ring_reconstruction;
use inssplat_geometry::analytic_room::render_scene;

#[test]
fn a_view_turned_off_its_heading_is_turned_back_by_its_photo() {
    let size = 96;
    let (ring, _, linked) = ring_reconstruction(size, 0.1, 5);
    let truth = ring[3];
    let room = render_scene(&[truth]);
    let photo = room.frames[0].planar_rgb();
    let depth = room.frames[0].depth.clone().unwrap();
    // Registration's continued pose: the right place, 40° off about the world's up axis.
    let turn = Quat::from_axis_angle(Vec3::Y, 40f32.to_radians());
    let mut off = truth;
    off.rotation = (truth.rotation * turn.conjugate()).normalize();
    off.translation = -(off.rotation * truth.center());
    let grey = vec![0.5; photo.len()];
    let ring_gaussians = |_: &[Camera], views: &[usize]| {
        assert_eq!(views, [0, 1], "only the linked views are asked for");
        linked.clone()
    };
    let flat = vec![1.0; depth.len()];

    let mut cameras = vec![ring[0], ring[1], off];
    let photos: Vec<&[f32]> = vec![&grey, &grey, &photo];
    let depths: Vec<&[f32]> = vec![&flat, &flat, &depth];
    let params = HeadingParams::default();
    let choices =
        place_by_heading(&mut cameras, &[0, 0, 2], &photos, &depths, &params, &ring_gaussians)
            .unwrap();
    assert_eq!(choices.len(), 1, "{choices:?}");
    let choice = choices[0];
    assert_eq!(choice.root, 2);
    let (before, after) = (turn_deg(&off, &truth), turn_deg(&cameras[2], &truth));
    assert!(before > 39.0 && after < 3.0, "rotation error {before:.2}° → {after:.2}° ({choice:?})");
    assert!(
        cameras[2].center().distance(truth.center()) < 1e-3,
        "the camera turned in place: {:?}",
        cameras[2].center()
    );
    assert!(params.score(&choice.best) < params.score(&choice.continued), "{choice:?}");
    assert_eq!((cameras[0], cameras[1]), (ring[0], ring[1]), "the linked views stay");

    // A photo of a colour the room does not have matches no heading clearly better.
    let magenta: Vec<f32> =
        (0..photo.len()).map(|i| if i / depth.len() == 1 { 0.0 } else { 1.0 }).collect();
    let mut cameras = vec![ring[0], ring[1], off];
    let photos: Vec<&[f32]> = vec![&grey, &grey, &magenta];
    let choices =
        place_by_heading(&mut cameras, &[0, 0, 2], &photos, &depths, &params, &ring_gaussians)
            .unwrap();
    assert_eq!(choices[0].turn_deg, 0.0, "{choices:?}");
    assert_eq!(cameras[2], off);

    // Every view linked: nothing to place.
    let mut cameras = vec![ring[0], ring[1], off];
    assert!(
        place_by_heading(&mut cameras, &[0, 0, 0], &photos, &depths, &params, &ring_gaussians)
            .unwrap()
            .is_empty()
    );
}
