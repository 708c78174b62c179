//! The hand-written backward against central finite differences of the forward, for every
//! parameter kind (means, log-scales, quaternions, logit opacities, feature channels, and the
//! camera pose) and every output (features, expected depth, alpha), on tiny scenes that cross
//! tile borders.
//!
//! The forward runs with [`AlphaCutoff::Smooth`]: with the hard 1/255 cutoff the image jumps
//! where a pixel's alpha crosses the cutoff, and a difference quotient straddling such a jump
//! is meaningless. The smooth cutoff is exact above 1.5/255 and the backward differentiates
//! whichever cutoff the forward used. The scenes keep alpha below the 0.999 clamp and
//! transmittance above the 1e-4 stop, the other two kinks.
//!
//! Losses are random linear functionals of the outputs, evaluated in f64 on the f32 image;
//! steps h = 1e-3 (5e-3 for the depth-only loss).
//! Bound (stated): for each parameter, |analytic − fd| ≤ 2e-2·|fd| + 2e-3·max|fd over its
//! kind| — the absolute part covers the f32 rounding of the forward, divided by 2h.

use glam::{Quat, Vec3};
use inssplat_proto::{Camera, Intrinsics};
use inssplat_raster::render::{AlphaCutoff, RenderOptions, render_backward, render_with};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::support::Scene;

impl Scene {
    /// The parameter of `kind` number `i` (flattened), mutably.
    fn param(&mut self, kind: Kind, i: usize) -> &mut f32 {
        match kind {
            Kind::Mean => &mut self.means[i / 3][i % 3],
            Kind::LogScale => &mut self.log_scales[i / 3][i % 3],
            Kind::Rotation => &mut self.rotations[i / 4][i % 4],
            Kind::Opacity => &mut self.logits[i],
            Kind::Feature => &mut self.features[i],
        }
    }

    fn count(&self, kind: Kind) -> usize {
        match kind {
            Kind::Mean | Kind::LogScale => 3 * self.means.len(),
            Kind::Rotation => 4 * self.means.len(),
            Kind::Opacity => self.means.len(),
            Kind::Feature => self.features.len(),
        }
    }
}

#[derive(Debug, Clone, Copy)]
enum Kind {
    Mean,
    LogScale,
    Rotation,
    Opacity,
    Feature,
}

const KINDS: [Kind; 5] = [Kind::Mean, Kind::LogScale, Kind::Rotation, Kind::Opacity, Kind::Feature];

fn camera() -> Camera {
    // 40×36 pixels: 3×3 tiles, the last row and column partial.
    let k = Intrinsics::from_fov_y(40, 36, 0.9);
    Camera::look_at(k, Vec3::new(0.2, -0.3, -3.0), Vec3::new(0.0, 0.0, 0.0), Vec3::Y)
}

/// A handful of overlapping, semi-transparent Gaussians of a few pixels, placed across tile
/// borders, given in camera coordinates.
fn scene(cam: &Camera, channels: usize, extra: &[([f32; 3], [f32; 3])], seed: u64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let placed: Vec<([f32; 3], [f32; 3])> = [
        ([-0.2, -0.1, 3.0], [-1.6, -1.9, -2.2]),
        ([0.05, 0.0, 3.2], [-1.3, -2.0, -1.7]),
        ([0.15, 0.25, 2.8], [-1.8, -1.5, -2.0]),
        ([-0.1, 0.3, 3.6], [-1.2, -1.4, -1.9]),
        ([0.35, -0.3, 3.1], [-1.7, -2.1, -1.6]),
        ([0.0, -0.05, 2.5], [-2.2, -2.4, -2.0]),
    ]
    .into_iter()
    .chain(extra.iter().copied())
    .collect();
    let n = placed.len();
    Scene {
        means: placed.iter().map(|(p, _)| cam.camera_to_world(Vec3::from(*p)).to_array()).collect(),
        log_scales: placed.iter().map(|(_, s)| *s).collect(),
        rotations: (0..n).map(|_| [0; 4].map(|_| rng.random_range(-1.5..1.5f32))).collect(),
        logits: (0..n).map(|_| rng.random_range(-1.5..0.5)).collect(),
        features: (0..n * channels).map(|_| rng.random_range(-1.0..1.0)).collect(),
        channels,
    }
}

/// Weights of the linear loss L = Σ wF·F + Σ wD·depth + Σ wA·alpha.
struct Weights {
    features: Vec<f32>,
    depth: Vec<f32>,
    alpha: Vec<f32>,
}

#[derive(Clone, Copy)]
enum Outputs {
    All,
    FeaturesOnly,
    DepthOnly,
    AlphaOnly,
}

fn weights(pixels: usize, channels: usize, which: Outputs, seed: u64) -> Weights {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut draw = |n: usize, on: bool| -> Vec<f32> {
        (0..n).map(|_| if on { rng.random_range(-1.0..1.0) } else { 0.0 }).collect()
    };
    let (f, d, a) = match which {
        Outputs::All => (true, true, true),
        Outputs::FeaturesOnly => (true, false, false),
        Outputs::DepthOnly => (false, true, false),
        Outputs::AlphaOnly => (false, false, true),
    };
    Weights { features: draw(pixels * channels, f), depth: draw(pixels, d), alpha: draw(pixels, a) }
}

const OPTIONS: RenderOptions = RenderOptions { cutoff: AlphaCutoff::Smooth };

fn loss(scene: &Scene, cam: &Camera, background: &[f32], w: &Weights) -> f64 {
    let (image, _) = render_with(&scene.splats(), cam, background, &OPTIONS).unwrap();
    let dot =
        |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(&x, &y)| x as f64 * y as f64).sum::<f64>();
    dot(&image.features, &w.features) + dot(&image.depth, &w.depth) + dot(&image.alpha, &w.alpha)
}

/// Compares analytic gradients with central differences of step `h`.
fn check(scene: &Scene, cam: &Camera, background: &[f32], which: Outputs, seed: u64) {
    // Expected depth carries f32 rounding of ~1e-7 of the depth itself (~3 here) at every
    // pixel, with small gradients: a larger step keeps that noise below the bound.
    let h = if matches!(which, Outputs::DepthOnly) { 5e-3 } else { 1e-3 };
    let pixels = (cam.intrinsics.width * cam.intrinsics.height) as usize;
    let mut w = weights(pixels, scene.channels, which, seed);
    let (image, state) = render_with(&scene.splats(), cam, background, &OPTIONS).unwrap();
    // Expected depth Σw·z / Σw is ill-conditioned where Σw → 0 (a lone Gaussian entering the
    // smooth cutoff ramp changes the average at a rate ∝ 1/Σw): weigh depth only where the
    // pixel is reasonably covered, as a depth loss masked by alpha would.
    for (wd, &a) in w.depth.iter_mut().zip(&image.alpha) {
        *wd *= (a > 0.1) as u8 as f32;
    }
    assert!(
        image.alpha.iter().all(|&a| a < 0.99),
        "scene must stay away from the transmittance stop"
    );
    let grads = render_backward(&scene.splats(), cam, &state, &w.features, &w.depth, &w.alpha);
    let mut failures = Vec::new();
    for kind in KINDS {
        let analytic: Vec<f32> = match kind {
            Kind::Mean => grads.means.iter().flatten().copied().collect(),
            Kind::LogScale => grads.log_scales.iter().flatten().copied().collect(),
            Kind::Rotation => grads.rotations.iter().flatten().copied().collect(),
            Kind::Opacity => grads.logit_opacity.clone(),
            Kind::Feature => grads.features.clone(),
        };
        let fd: Vec<f64> = (0..scene.count(kind))
            .map(|i| {
                let mut plus = scene.clone();
                *plus.param(kind, i) += h;
                let mut minus = scene.clone();
                *minus.param(kind, i) -= h;
                (loss(&plus, cam, background, &w) - loss(&minus, cam, background, &w))
                    / (2.0 * h as f64)
            })
            .collect();
        let scale = fd.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if !matches!(kind, Kind::Feature) || matches!(which, Outputs::All | Outputs::FeaturesOnly) {
            assert!(
                scale > 1e-2,
                "{kind:?}: the scene should give this kind a gradient (max |fd| {scale})"
            );
        }
        for (i, (&a, &f)) in analytic.iter().zip(&fd).enumerate() {
            let tol = 2e-2 * f.abs() + 2e-3 * scale;
            if !a.is_finite() || (a as f64 - f).abs() > tol {
                failures.push(format!(
                    "{kind:?}[{i}]: analytic {a}, finite difference {f} (tolerance {tol:.2e})"
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{} gradients off:\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn gradients_of_all_outputs() {
    let cam = camera();
    check(&scene(&cam, 3, &[], 1), &cam, &[0.3, -0.2, 0.5], Outputs::All, 10);
}

#[test]
fn gradients_of_features_alone() {
    let cam = camera();
    check(&scene(&cam, 3, &[], 7), &cam, &[0.5, 0.1, -1.0], Outputs::FeaturesOnly, 15);
}

#[test]
fn gradients_of_depth_alone() {
    let cam = camera();
    check(&scene(&cam, 2, &[], 2), &cam, &[], Outputs::DepthOnly, 11);
}

#[test]
fn gradients_of_depth_without_feature_channels() {
    let cam = camera();
    check(&scene(&cam, 0, &[], 2), &cam, &[], Outputs::DepthOnly, 11);
}

#[test]
fn gradients_of_alpha_alone() {
    let cam = camera();
    check(&scene(&cam, 1, &[], 3), &cam, &[], Outputs::AlphaOnly, 12);
}

#[test]
fn gradients_with_many_channels() {
    // RGB + 8 instance channels + a small semantic feature, one pass; 17 channels, so the
    // backward's last group of four channels is padded.
    let cam = camera();
    check(&scene(&cam, 3 + 8 + 6, &[], 4), &cam, &[], Outputs::All, 13);
}

#[test]
fn gradients_through_the_clamped_jacobian() {
    // A wide Gaussian centred outside the clamped field of view whose tail reaches the image.
    let cam = camera();
    let extra = [([2.6, 0.2, 2.0], [-0.2, -0.6, -0.4])];
    check(&scene(&cam, 2, &extra, 5), &cam, &[], Outputs::All, 14);
}

#[test]
fn skipped_gaussians_get_zero_finite_gradients() {
    let cam = camera();
    let mut s = scene(&cam, 2, &[], 6);
    s.means.push(cam.camera_to_world(Vec3::new(0.0, 0.0, -1.0)).to_array()); // behind
    s.means.push([f32::NAN, 0.0, 0.0]);
    s.means.push(cam.camera_to_world(Vec3::new(0.0, 0.0, 3.0)).to_array());
    s.log_scales.extend([[-1.0; 3]; 3]);
    s.rotations.extend([[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0; 4]]); // zero quaternion
    s.logits.extend([2.0; 3]);
    s.features.extend([0.5; 6]);
    let pixels = (cam.intrinsics.width * cam.intrinsics.height) as usize;
    let w = weights(pixels, 2, Outputs::All, 7);
    let (_, state) = render_with(&s.splats(), &cam, &[], &RenderOptions::default()).unwrap();
    let g = render_backward(&s.splats(), &cam, &state, &w.features, &w.depth, &w.alpha);
    let n = s.means.len();
    for i in n - 3..n {
        assert_eq!(g.means[i], [0.0; 3]);
        assert_eq!(g.log_scales[i], [0.0; 3]);
        assert_eq!(g.rotations[i], [0.0; 4]);
        assert_eq!(g.logit_opacity[i], 0.0);
        assert_eq!(&g.features[2 * i..2 * i + 2], &[0.0, 0.0]);
    }
    let all = g
        .means
        .iter()
        .flatten()
        .chain(g.log_scales.iter().flatten())
        .chain(g.rotations.iter().flatten());
    assert!(all.chain(&g.logit_opacity).chain(&g.features).all(|v| v.is_finite()));
    assert!(g.means[..n - 3].iter().flatten().any(|&v| v != 0.0));
}

#[test]
fn camera_pose_gradients() {
    let cam = camera();
    let scene = scene(&cam, 3, &[], 8);
    let background = [0.1, 0.2, 0.3];
    let pixels = (cam.intrinsics.width * cam.intrinsics.height) as usize;
    let mut w = weights(pixels, 3, Outputs::All, 16);
    let (image, state) = render_with(&scene.splats(), &cam, &background, &OPTIONS).unwrap();
    for (wd, &a) in w.depth.iter_mut().zip(&image.alpha) {
        *wd *= (a > 0.1) as u8 as f32;
    }
    let grads = render_backward(&scene.splats(), &cam, &state, &w.features, &w.depth, &w.alpha);
    let h = 1e-3f32;
    // Camera parameter i: rotation w, x, y, z (the quaternion unnormalized), translation x, y, z.
    let perturbed = |i: usize, d: f32| {
        let mut c = cam;
        let q = cam.rotation;
        let mut wxyz = [q.w, q.x, q.y, q.z];
        match i {
            0..4 => wxyz[i] += d,
            _ => c.translation[i - 4] += d,
        }
        c.rotation = Quat::from_xyzw(wxyz[1], wxyz[2], wxyz[3], wxyz[0]);
        c
    };
    let fd: Vec<f64> = (0..7)
        .map(|i| {
            (loss(&scene, &perturbed(i, h), &background, &w)
                - loss(&scene, &perturbed(i, -h), &background, &w))
                / (2.0 * h as f64)
        })
        .collect();
    let analytic: Vec<f32> =
        grads.camera.rotation.iter().chain(&grads.camera.translation).copied().collect();
    let scale = fd.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(scale > 1e-2, "the camera should get a gradient");
    for (i, (&a, &f)) in analytic.iter().zip(&fd).enumerate() {
        let tol = 2e-2 * f.abs() + 2e-3 * scale;
        assert!(
            (a as f64 - f).abs() <= tol,
            "camera parameter {i}: analytic {a}, finite difference {f} (tolerance {tol:.2e})"
        );
    }
}
