//! The rasterizer as a burn op: its forward equals `inssplat_raster::render::render_with`, and
//! burn's gradients through it (autodiff on Flex, with and without gradient checkpointing)
//! equal central finite differences of a scalar loss evaluated through the op's forward.
//!
//! The scene is a handful of overlapping semi-transparent Gaussians of a few pixels across the
//! tile borders of a 40×36 view, rendered with the smooth alpha cutoff (with the hard 1/255
//! cutoff a difference quotient can straddle a jump), alpha kept below the 0.999 clamp. The
//! loss is a fixed random linear functional of features, depth (where alpha > 0.1, the depth
//! average being ill-conditioned where coverage vanishes) and alpha, accumulated in f64.
//! Step h = 1e-3; bound per parameter: |autodiff − fd| ≤ 2e-2·|fd| + 2e-3·max|fd| over its kind.
//! A render's backward time goes to its own meter only, whichever thread runs it.

use std::time::Duration;

use burn::prelude::*;
use glam::Vec3;
use inssplat_proto::{Camera, Intrinsics};
use inssplat_raster::render::{AlphaCutoff, RenderOptions, Splats, render_with};
use inssplat_trainer::render_op::{
    BackwardMeter, RenderOpError, SplatTensors, render, render_metered,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const OPTIONS: RenderOptions = RenderOptions { cutoff: AlphaCutoff::Smooth };
const CHANNELS: usize = 3;
const BACKGROUND: [f32; CHANNELS] = [0.3, -0.2, 0.5];

fn camera() -> Camera {
    let k = Intrinsics::from_fov_y(40, 36, 0.9);
    Camera::look_at(k, Vec3::new(0.2, -0.3, -3.0), Vec3::ZERO, Vec3::Y)
}

/// Parameters per kind, flattened: means, log-scales, rotations, opacity logits, features.
#[derive(Clone)]
struct Params([Vec<f32>; 5]);

const KINDS: [&str; 5] = ["means", "log_scales", "rotations", "logit_opacity", "features"];

impl Params {
    fn scene(cam: &Camera) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let placed = [
            ([-0.2, -0.1, 3.0], [-1.6, -1.9, -2.2]),
            ([0.05, 0.0, 3.2], [-1.3, -2.0, -1.7]),
            ([0.15, 0.25, 2.8], [-1.8, -1.5, -2.0]),
            ([-0.1, 0.3, 3.6], [-1.2, -1.4, -1.9]),
            ([0.35, -0.3, 3.1], [-1.7, -2.1, -1.6]),
        ];
        let n = placed.len();
        Self([
            placed
                .iter()
                .flat_map(|(p, _)| cam.camera_to_world(Vec3::from(*p)).to_array())
                .collect(),
            placed.iter().flat_map(|(_, s)| *s).collect(),
            (0..4 * n).map(|_| rng.random_range(-1.5..1.5f32)).collect(),
            (0..n).map(|_| rng.random_range(-1.5..0.5f32)).collect(),
            (0..n * CHANNELS).map(|_| rng.random_range(-1.0..1.0f32)).collect(),
        ])
    }

    fn count(&self) -> usize {
        self.0[3].len()
    }

    fn tensors(&self, device: &Device) -> SplatTensors {
        let n = self.count();
        let t2 = |v: &Vec<f32>, w: usize| {
            Tensor::<2>::from_data(TensorData::new(v.clone(), [n, w]), device)
        };
        SplatTensors {
            means: t2(&self.0[0], 3),
            log_scales: t2(&self.0[1], 3),
            rotations: t2(&self.0[2], 4),
            logit_opacity: Tensor::from_data(TensorData::new(self.0[3].clone(), [n]), device),
            features: t2(&self.0[4], CHANNELS),
        }
    }
}

/// Weights of L = Σ wF·F + Σ wD·depth + Σ wA·alpha, as host vectors.
struct Weights {
    features: Vec<f32>,
    depth: Vec<f32>,
    alpha: Vec<f32>,
}

fn weights(params: &Params, cam: &Camera) -> Weights {
    let pixels = (cam.intrinsics.width * cam.intrinsics.height) as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut draw = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(-1.0..1.0)).collect() };
    let (features, mut depth, alpha) = (draw(pixels * CHANNELS), draw(pixels), draw(pixels));
    let rendered = render(params.tensors(&Device::flex()), cam, &BACKGROUND, &OPTIONS).unwrap();
    let coverage = rendered.alpha.into_data().try_to_vec::<f32>().unwrap();
    assert!(coverage.iter().all(|&a| a < 0.99), "the scene must stay below the alpha clamp");
    for (w, a) in depth.iter_mut().zip(coverage) {
        *w *= f32::from(u8::from(a > 0.1));
    }
    Weights { features, depth, alpha }
}

/// The loss through the op on a plain (non-autodiff) device, in f64.
fn host_loss(params: &Params, cam: &Camera, w: &Weights) -> f64 {
    let r = render(params.tensors(&Device::flex()), cam, &BACKGROUND, &OPTIONS).unwrap();
    let dot = |t: Vec<f32>, w: &[f32]| {
        t.iter().zip(w).map(|(&a, &b)| f64::from(a) * f64::from(b)).sum::<f64>()
    };
    let v = |t: TensorData| t.try_to_vec::<f32>().unwrap();
    dot(v(r.features.into_data()), &w.features)
        + dot(v(r.depth.into_data()), &w.depth)
        + dot(v(r.alpha.into_data()), &w.alpha)
}

/// burn's gradient of the same loss w.r.t. every parameter kind.
fn autodiff_grads(params: &Params, cam: &Camera, w: &Weights, device: &Device) -> [Vec<f32>; 5] {
    let s = params.tensors(device);
    let s = SplatTensors {
        means: s.means.require_grad(),
        log_scales: s.log_scales.require_grad(),
        rotations: s.rotations.require_grad(),
        logit_opacity: s.logit_opacity.require_grad(),
        features: s.features.require_grad(),
    };
    let r = render(s.clone(), cam, &BACKGROUND, &OPTIONS).unwrap();
    let [_, h, wd] = r.features.dims();
    let features =
        Tensor::<3>::from_data(TensorData::new(w.features.clone(), [CHANNELS, h, wd]), device);
    let plane = |v: &Vec<f32>| Tensor::<2>::from_data(TensorData::new(v.clone(), [h, wd]), device);
    let loss = (r.features * features).sum()
        + (r.depth * plane(&w.depth)).sum()
        + (r.alpha * plane(&w.alpha)).sum();
    let grads = loss.backward();
    let v =
        |t: Option<TensorData>| t.expect("every input has a gradient").try_to_vec::<f32>().unwrap();
    [
        v(s.means.grad(&grads).map(Tensor::into_data)),
        v(s.log_scales.grad(&grads).map(Tensor::into_data)),
        v(s.rotations.grad(&grads).map(Tensor::into_data)),
        v(s.logit_opacity.grad(&grads).map(Tensor::into_data)),
        v(s.features.grad(&grads).map(Tensor::into_data)),
    ]
}

fn check_against_finite_differences(device: &Device) {
    let cam = camera();
    let params = Params::scene(&cam);
    let w = weights(&params, &cam);
    let analytic = autodiff_grads(&params, &cam, &w, device);
    let h = 1e-3f32;
    let mut failures = Vec::new();
    for (kind, name) in KINDS.iter().enumerate() {
        let fd: Vec<f64> = (0..params.0[kind].len())
            .map(|i| {
                let (mut plus, mut minus) = (params.clone(), params.clone());
                plus.0[kind][i] += h;
                minus.0[kind][i] -= h;
                (host_loss(&plus, &cam, &w) - host_loss(&minus, &cam, &w)) / (2.0 * f64::from(h))
            })
            .collect();
        let scale = fd.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(scale > 1e-2, "{name}: the scene should give this kind a gradient");
        for (i, (&a, &f)) in analytic[kind].iter().zip(&fd).enumerate() {
            let tol = 2e-2 * f.abs() + 2e-3 * scale;
            if !a.is_finite() || (f64::from(a) - f).abs() > tol {
                failures.push(format!(
                    "{name}[{i}]: autodiff {a}, finite difference {f} (tolerance {tol:.2e})"
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{} gradients off:\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn render_op_gradients_match_finite_differences() {
    check_against_finite_differences(&Device::flex().autodiff());
}

#[test]
fn render_op_gradients_with_gradient_checkpointing() {
    check_against_finite_differences(&Device::flex().autodiff().gradient_checkpointing());
}

#[test]
fn render_op_forward_equals_the_rasterizer() {
    let cam = camera();
    let params = Params::scene(&cam);
    let [means, log_scales, rotations, logit_opacity, features] = &params.0;
    let pairs3 = |v: &Vec<f32>| v.chunks(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
    let (means, log_scales) = (pairs3(means), pairs3(log_scales));
    let rotations: Vec<[f32; 4]> = rotations.chunks(4).map(|c| [c[0], c[1], c[2], c[3]]).collect();
    let splats = Splats {
        means: &means,
        log_scales: &log_scales,
        rotations: &rotations,
        logit_opacity,
        features,
        channels: CHANNELS,
    };
    let (image, _) = render_with(&splats, &cam, &BACKGROUND, &OPTIONS).unwrap();
    for device in [Device::flex(), Device::flex().autodiff()] {
        let r = render(params.tensors(&device), &cam, &BACKGROUND, &OPTIONS).unwrap();
        assert_eq!(r.features.dims(), [CHANNELS, 36, 40]);
        assert_eq!(r.features.into_data().try_to_vec::<f32>().unwrap(), image.features);
        assert_eq!(r.depth.into_data().try_to_vec::<f32>().unwrap(), image.depth);
        assert_eq!(r.alpha.into_data().try_to_vec::<f32>().unwrap(), image.alpha);
    }
}

#[test]
fn a_renders_backward_time_goes_to_its_own_meter_only() {
    let cam = camera();
    let params = Params::scene(&cam);
    let device = Device::flex().autodiff();
    let (mine, other) = (BackwardMeter::default(), BackwardMeter::default());
    let loss = |meter: Option<&BackwardMeter>| {
        let s = params.tensors(&device);
        let s = SplatTensors { means: s.means.require_grad(), ..s };
        let r = match meter {
            Some(m) => render_metered(s, &cam, &BACKGROUND, &OPTIONS, m),
            None => render(s, &cam, &BACKGROUND, &OPTIONS),
        };
        r.unwrap().features.sum()
    };
    // A render of the other meter that is never differentiated, and two plain renders that
    // are (one on another thread), add nothing to either meter.
    let _forward_only = loss(Some(&other));
    loss(None).backward();
    std::thread::scope(|t| t.spawn(|| loss(None).backward()).join().unwrap());
    assert_eq!((mine.elapsed(), other.elapsed()), (Duration::ZERO, Duration::ZERO));
    loss(Some(&mine)).backward();
    let once = mine.elapsed();
    assert!(once > Duration::ZERO && other.elapsed() == Duration::ZERO);
    // A second render of the same meter, differentiated on another thread, adds to it.
    std::thread::scope(|t| t.spawn(|| loss(Some(&mine)).backward()).join().unwrap());
    assert!(mine.elapsed() > once && other.elapsed() == Duration::ZERO);
}

#[test]
fn render_op_rejects_mismatched_shapes() {
    let cam = camera();
    let mut s = Params::scene(&cam).tensors(&Device::flex());
    s.rotations = Tensor::zeros([5, 3], &Device::flex());
    match render(s, &cam, &BACKGROUND, &OPTIONS) {
        Err(RenderOpError::Shape { field: "rotations", expected, got }) => {
            assert_eq!((expected, got), (vec![5, 4], vec![5, 3]));
        }
        other => panic!("expected a shape error, got {other:?}"),
    }
}
