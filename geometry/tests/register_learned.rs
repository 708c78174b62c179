//! Registration on learned descriptors: the analytic room of `inssplat_geometry::analytic_room`
//! seen by eight
//! cameras on a ring (45° apart), with textureless photos (one flat grey: no keypoint
//! anywhere) and, per pixel, an ideal descriptor, a function of the world point the pixel
//! sees (16 random Fourier features: sin and cos of 8 random projections of it), as a
//! descriptor head trained to match would output. With the descriptors every view must be
//! chained to view 0 and land on its true pose; without them no pair links any two views.

use std::time::Instant;

use glam::{Quat, Vec3};
use inssplat_geometry::register::{Descriptors, RegisterParams, RegisterView, register};
use inssplat_proto::Camera;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use inssplat_geometry::analytic_room::{render_scene, ring_cameras};

const SIZE: u32 = 128;
const VIEWS: usize = 8;
/// Random projections of the world point; the descriptor is their sines and cosines.
const FREQUENCIES: usize = 8;
const DIM: usize = 2 * FREQUENCIES;
/// Bounds on a view's error against its true pose relative to view 0: rotation in degrees,
/// camera centre in metres (the cameras are 7.5–8.7 m from the room's centre).
const MAX_ROTATION_DEG: f32 = 1.0;
const MAX_CENTRE_M: f32 = 0.1;

/// Planar `[D][H][W]` descriptors of one view from its depth (0 = nothing seen: zero
/// descriptor): the random Fourier features of each pixel's world point, frequencies of
/// 1.5–10 rad/m in random directions.
fn ideal_descriptors(camera: &Camera, depth: &[f32], frequencies: &[(Vec3, f32)]) -> Vec<f32> {
    let (w, pixels) = (SIZE as usize, depth.len());
    let mut out = vec![0.0; DIM * pixels];
    for (p, &z) in depth.iter().enumerate().filter(|(_, z)| **z > 0.0) {
        let world =
            camera.camera_to_world(camera.unproject((p % w) as f32 + 0.5, (p / w) as f32 + 0.5, z));
        for (k, (omega, phase)) in frequencies.iter().enumerate() {
            let (s, c) = (omega.dot(world) + phase).sin_cos();
            out[2 * k * pixels + p] = s;
            out[(2 * k + 1) * pixels + p] = c;
        }
    }
    out
}

fn random_frequencies(seed: u64) -> Vec<(Vec3, f32)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..FREQUENCIES)
        .map(|_| {
            let dir = loop {
                let v = Vec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                );
                if (0.1..1.0).contains(&v.length_squared()) {
                    break v.normalize();
                }
            };
            let magnitude = (rng.random_range(1.5f32.ln()..10f32.ln())).exp();
            (dir * magnitude, rng.random_range(0.0..std::f32::consts::TAU))
        })
        .collect()
}

/// The ring room's eight views with flat grey photos, their true depth and ideal
/// descriptors, every camera starting at the identity with its true intrinsics; returns the
/// registration and the true cameras.
fn registered(params: &RegisterParams) -> (inssplat_geometry::register::Registration, Vec<Camera>) {
    let truths = ring_cameras(VIEWS, SIZE);
    let scene = render_scene(&truths);
    let frequencies = random_frequencies(3);
    let grey = vec![0.5f32; 3 * (SIZE * SIZE) as usize];
    let depths: Vec<&[f32]> =
        scene.frames.iter().map(|f| f.depth.as_deref().expect("rendered depth")).collect();
    let descriptors: Vec<Vec<f32>> =
        truths.iter().zip(&depths).map(|(c, d)| ideal_descriptors(c, d, &frequencies)).collect();
    let blank: Vec<Camera> = truths
        .iter()
        .map(|c| Camera {
            rotation: Quat::IDENTITY,
            translation: Vec3::ZERO,
            intrinsics: c.intrinsics,
        })
        .collect();
    let views: Vec<RegisterView<'_>> = (0..VIEWS)
        .map(|v| RegisterView {
            rgb: &grey,
            depth: depths[v],
            photo: [0, 0, SIZE, SIZE],
            camera: &blank[v],
            descriptors: Some(Descriptors { data: &descriptors[v], dim: DIM }),
            detail: None,
        })
        .collect();
    let start = Instant::now();
    let registration = register(&views, params);
    let used = if params.use_descriptors { "with" } else { "without" };
    eprintln!(
        "register: {VIEWS} views of {SIZE}², {used} descriptors (D = {DIM}): {:.1} ms",
        start.elapsed().as_secs_f64() * 1e3
    );
    (registration, truths)
}

#[test]
fn learned_descriptors_register_textureless_views() {
    let (reg, truths) = registered(&RegisterParams::default());
    assert_eq!(reg.component, vec![0; VIEWS], "every view chained to view 0");
    let reference = truths[0];
    for (v, (cam, truth)) in reg.cameras.iter().zip(&truths).enumerate() {
        // The true pose relative to view 0 (world = view 0's camera).
        let rotation = (truth.rotation * reference.rotation.conjugate()).normalize();
        let translation = truth.translation - rotation * reference.translation;
        let error = (cam.rotation * rotation.conjugate())
            .normalize()
            .angle_between(Quat::IDENTITY)
            .to_degrees();
        let centre = (cam.center() - -(rotation.conjugate() * translation)).length();
        eprintln!("view {v}: rotation off by {error:.3}°, centre by {centre:.4} m");
        assert!(error < MAX_ROTATION_DEG, "view {v}: rotation off by {error}°");
        assert!(centre < MAX_CENTRE_M, "view {v}: centre off by {centre} m");
    }
    if let Some(scale) = reg.focal_scale {
        assert!((scale - 1.0).abs() < 0.01, "focal multiplier {scale}, true 1");
    }
}

#[test]
fn without_descriptors_textureless_views_stay_unlinked() {
    let params = RegisterParams { use_descriptors: false, ..RegisterParams::default() };
    let (reg, _) = registered(&params);
    assert_eq!(reg.component, (0..VIEWS).collect::<Vec<_>>(), "no pair links two flat grey views");
    assert_eq!(reg.focal_scale, None);
}
