//! The registration stage on synthesized test-split scenes (the evaluation's furniture and
//! 8-view context sets at 128×128) with their true depth, every camera starting at the
//! identity (as a camera head that learnt nothing) and their focal lengths as given or 15%
//! short (a wrong field of view): the stage must measure the focal length, the views that it
//! chains to view 0 must land on their true poses relative to view 0, most views must be
//! chained, and the views that no pair links must land closer to their poses than the
//! identity; so too with the keypoints found in 512² photos of the same scenes, as a user's
//! camera gives them. The predicted depth's effect is measured by `inssplat-eval score` (see the
//! model card).

use glam::Quat;
use inssplat_geometry::register::{
    KeypointImage, RegisterParams, RegisterView, brief_matches, register,
};
use inssplat_proto::Camera;
use inssplat_proto::dataset::Frame;
use inssplat_synth::{self as synth, Furniture, Split, SynthConfig};
use inssplat_trainer::train::sample::in_reference_frame;

const VIEWS: usize = 8;
const SIZE: u32 = 128;
/// Bounds on a chained view's error against the truth (relative to view 0): rotation in
/// degrees, camera centre in metres, and the mean rotation error. Pairwise errors of a few
/// tenths of a degree add up along a chain without a loop to close it: measured on these
/// scenes, the largest errors were 4.8° and 0.22 m (scene 3's last views), the mean 0.94°.
const MAX_ROTATION_DEG: f32 = 6.0;
const MAX_CENTRE_M: f32 = 0.3;
const MAX_MEAN_ROTATION_DEG: f32 = 1.5;
/// Share of all views that must be chained to view 0 (measured: 42 of 48).
const MIN_CHAINED: f64 = 0.75;
/// Views that no pair links to the others continue the motion of the views before them: their
/// mean rotation error must stay below this share of what the identity pose would leave
/// (measured: 34.9° against 94.7°, the six views of scene 2's second component).
const UNLINKED_GAIN: f32 = 0.5;

/// Largest error of the focal multiplier the stage estimates, relative to the true one, about
/// 2° of a 65° field of view (measured: −1.2% to +1.7% from the true intrinsics, −2.4% to
/// +0.9% from 0.85 of them; the camera head's field of view errs 12% on average).
const MAX_FOCAL_ERROR: f64 = 0.03;
/// The same with keypoints found in 512² photos (measured: −3.2% to +0.7%; scene 4's views,
/// whose focal length errs most, land at most 2.0° from their true rotations, against 3.2°
/// with the views' keypoints, which measure its focal length to 0.1%).
const MAX_FOCAL_ERROR_PHOTOS: f64 = 0.04;

/// The registration of `frames` from cameras at the identity whose focal lengths are
/// `focal_given` × the true ones, and the focal multiplier it estimated (`None`: not
/// measured).
fn registered(frames: &[&Frame], focal_given: f32) -> (Vec<Camera>, Vec<usize>, Option<f64>) {
    registered_with(frames, focal_given, None, &RegisterParams::default())
}

/// [`registered`] with keypoints found in `details` (one per frame) when given, under `params`.
fn registered_with(
    frames: &[&Frame],
    focal_given: f32,
    details: Option<&[KeypointImage]>,
    params: &RegisterParams,
) -> (Vec<Camera>, Vec<usize>, Option<f64>) {
    let rgb: Vec<Vec<f32>> = frames.iter().map(|f| f.planar_rgb()).collect();
    let blank: Vec<Camera> = frames
        .iter()
        .map(|f| {
            let mut intrinsics = f.camera.intrinsics;
            intrinsics.fx *= focal_given;
            intrinsics.fy *= focal_given;
            Camera { rotation: Quat::IDENTITY, translation: glam::Vec3::ZERO, intrinsics }
        })
        .collect();
    let views: Vec<RegisterView<'_>> = frames
        .iter()
        .zip(&rgb)
        .zip(&blank)
        .enumerate()
        .map(|(v, ((f, rgb), camera))| RegisterView {
            rgb,
            depth: f.depth.as_deref().expect("synthesized frames carry depth"),
            photo: [0, 0, SIZE, SIZE],
            camera,
            detail: details.map(|d| &d[v]),
        })
        .collect();
    let reg = register(&views, &brief_matches(&views, params).0, params);
    (reg.cameras, reg.component, reg.focal_scale)
}

#[test]
fn views_chained_to_the_first_land_on_their_true_poses() {
    chained_views_land_on_their_true_poses(1.0, 1, MAX_FOCAL_ERROR);
}

#[test]
fn keypoints_found_in_larger_photos_land_the_views_as_well() {
    // The same scenes photographed at 512² (the same seeds give the same rooms and cameras),
    // as a user's camera gives them: the keypoints are found there, their positions mapped
    // into the 128² views.
    chained_views_land_on_their_true_poses(1.0, 4, MAX_FOCAL_ERROR_PHOTOS);
}

#[test]
fn a_wrong_focal_length_is_measured_and_corrected() {
    // The camera head's field of view is a guess: 0.85 of the true focal length is a room
    // shot at 66° taken for 75°.
    chained_views_land_on_their_true_poses(0.85, 1, MAX_FOCAL_ERROR);
}

#[test]
fn two_photos_from_one_spot_keep_the_camera_heads_focal_length() {
    // A pair without motion cannot tell the focal length (every focal length lifts and
    // projects its matches back onto themselves): the head's guess must stay as it is, while
    // the same photo in an 8-view set is measured (the tests above).
    let cfg = SynthConfig::new(Split::Test, Furniture::from_env());
    let scene = synth::generate_split(0, &cfg).unwrap().scene;
    let frame = &scene.frames[0];
    let (cameras, component, focal) = registered(&[frame, frame], 0.85);
    assert_eq!(focal, None);
    assert_eq!(component, [0, 0], "the pair itself still registers");
    assert_eq!(cameras[1].intrinsics, cameras[0].intrinsics);
    assert!((cameras[1].intrinsics.fx / frame.camera.intrinsics.fx - 0.85).abs() < 1e-6);
}

/// The registration of each scene's 8-view context set, its keypoints found in photos
/// `photo_scale` times the views' size (1: in the views themselves), its focal multiplier
/// within `max_focal_error` of the truth.
fn chained_views_land_on_their_true_poses(
    focal_given: f32,
    photo_scale: u32,
    max_focal_error: f64,
) {
    let cfg = SynthConfig::new(Split::Test, Furniture::from_env());
    assert_eq!((cfg.width, cfg.height), (SIZE, SIZE));
    let mut large = cfg.clone();
    (large.width, large.height) = (photo_scale * SIZE, photo_scale * SIZE);
    let (mut chained, mut total, mut rotation_sum) = (0, 0, 0.0);
    // Views no pair links: their error as placed, and as left at the identity.
    let (mut unlinked, mut unlinked_sum, mut identity_sum) = (0, 0.0, 0.0);
    for index in 0..6 {
        let scene = synth::generate_split(index, &cfg).unwrap().scene;
        let context =
            scene.eval.as_ref().and_then(|e| e.context_for(VIEWS)).expect("an 8-view context set");
        let frames: Vec<&Frame> = context.iter().map(|&i| &scene.frames[i]).collect();
        let details: Option<Vec<KeypointImage>> = (photo_scale > 1).then(|| {
            let photos = synth::generate_split(index, &large).unwrap().scene;
            context
                .iter()
                .map(|&i| {
                    let f = &photos.frames[i];
                    assert_eq!(
                        f.camera.rotation, scene.frames[i].camera.rotation,
                        "the same camera"
                    );
                    let rgb =
                        image::RgbImage::from_raw(f.width(), f.height(), f.rgb.clone()).unwrap();
                    KeypointImage::of_photo(&rgb, photo_scale as f32, glam::Vec2::ZERO)
                })
                .collect()
        });
        let (cameras, component, focal) =
            registered_with(&frames, focal_given, details.as_deref(), &RegisterParams::default());
        let focal =
            focal.unwrap_or_else(|| panic!("scene {index}: the focal length was not measured"));
        let focal_error = (focal * focal_given as f64 - 1.0).abs();
        eprintln!("scene {index}: focal multiplier {focal:.4} (true {:.4})", 1.0 / focal_given);
        assert!(
            focal_error < max_focal_error,
            "scene {index}: focal multiplier {focal}, true {}",
            1.0 / focal_given
        );
        let truths = in_reference_frame(&frames.iter().map(|f| f.camera).collect::<Vec<_>>());
        let mut errors = Vec::new();
        let angle = |q: Quat| q.normalize().angle_between(Quat::IDENTITY).to_degrees();
        for ((cam, truth), c) in cameras.iter().zip(&truths).zip(&component) {
            total += 1;
            let rot = angle(cam.rotation * truth.rotation.conjugate());
            if *c != 0 {
                unlinked += 1;
                unlinked_sum += rot;
                identity_sum += angle(truth.rotation);
                continue;
            }
            chained += 1;
            let centre = (cam.center() - truth.center()).length();
            errors.push(format!("{rot:.2}°/{centre:.3} m"));
            assert!(
                rot < MAX_ROTATION_DEG && centre < MAX_CENTRE_M,
                "scene {index}: a chained view is off by {rot}° and {centre} m"
            );
            rotation_sum += rot;
        }
        eprintln!(
            "scene {index}: components {component:?}, chained views' errors {}",
            errors.join(", ")
        );
        assert_eq!(component[0], 0);
    }
    let share = chained as f64 / total as f64;
    let mean = rotation_sum / chained as f32;
    eprintln!("{chained} of {total} views chained to view 0, mean rotation error {mean:.2}°");
    assert!(mean < MAX_MEAN_ROTATION_DEG, "mean rotation error {mean}°");
    assert!(share >= MIN_CHAINED, "only {chained} of {total} views chained to view 0");
    let (placed, identity) = (unlinked_sum / unlinked as f32, identity_sum / unlinked as f32);
    eprintln!(
        "{unlinked} views linked by no pair: mean rotation error {placed:.1}° as placed, {identity:.1}° at the identity"
    );
    assert!(
        placed < UNLINKED_GAIN * identity,
        "unlinked views placed {placed}° off, {identity}° at the identity"
    );
}
