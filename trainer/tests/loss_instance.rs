//! L_ins on hand-made pixels with values worked out by hand, its ablations, and
//! finite-difference checks of burn's gradients of L_ins, L_bd-rgb and L_depth with its
//! gradient term.

use burn::prelude::*;
use inssplat_trainer::loss::{
    CrossView, HardNegatives, LossConfig, boundary_rgb_loss, depth_loss, instance_loss,
};

fn tensor<const D: usize>(values: &[f32], shape: [usize; D], device: &Device) -> Tensor<D> {
    Tensor::from_data(TensorData::new(values.to_vec(), shape), device)
}

fn scalar(x: Tensor<1>) -> f64 {
    f64::from(x.into_scalar::<f32>())
}

fn close(got: f64, expected: f64, what: &str) {
    assert!(
        (got - expected).abs() <= 1e-5 + 1e-5 * expected.abs(),
        "{what}: got {got}, expected {expected}"
    );
}

fn unit(v: [f64; 2]) -> [f64; 2] {
    let n = v[0].hypot(v[1]);
    [v[0] / n, v[1] / n]
}

fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

#[test]
fn loss_instance_push_with_hard_negatives() {
    // One view, two pixels, two instances: f1 = (1, 0), f2 = unit(1.2, 1.6) = (0.6, 0.8).
    // Each instance is one pixel, so pull = 0; one view, so cross = 0.
    let device = Device::flex();
    let embedding = tensor(&[1.0, 1.2, 0.0, 1.6], [1, 2, 1, 2], &device);
    // Semantic prototypes (1, 0) and unit(1, 1): cos = 1/√2.
    let semantic = tensor(&[1.0, 1.0, 0.0, 1.0], [1, 2, 1, 2], &device);
    let config = LossConfig::new();
    let terms = instance_loss(embedding.clone(), &semantic, &[1, 2], &config).unwrap();
    // push = η·[cos − (1 − δ_push)]₊ / 1 pair, cos = 0.6, δ_push = 1;
    // η = 1 + (3 − 1)·(1/√2 − 0.5)/(1 − 0.5).
    let eta = 1.0 + 2.0 * (0.5f64.sqrt() - 0.5) / 0.5;
    close(scalar(terms.pull.clone()), 0.0, "pull");
    close(scalar(terms.cross.clone()), 0.0, "cross");
    close(scalar(terms.push.clone()), eta * 0.6, "push");
    close(scalar(terms.total(&config)), eta * 0.6, "L_ins");
    // Ablation: no hard negatives, η ≡ 1.
    let uniform = config.clone().with_hard_negatives(HardNegatives::Uniform);
    close(
        scalar(instance_loss(embedding.clone(), &semantic, &[1, 2], &uniform).unwrap().push),
        0.6,
        "η ≡ 1",
    );
    // Semantics below τ_sem: η = 1 as well.
    let apart = tensor(&[1.0, 0.0, 0.0, 1.0], [1, 2, 1, 2], &device);
    close(
        scalar(instance_loss(embedding, &apart, &[1, 2], &config).unwrap().push),
        0.6,
        "cos_sem < τ",
    );
}

#[test]
fn loss_instance_pull_push_cross_two_views() {
    // Two views of 1×2 pixels. View 0: ids [1, 1], f = (1, 0), (0.8, 0.6).
    // View 1: ids [1, 2], f = (0.6, 0.8), (0, 1). Instance 1 is seen in both views.
    let device = Device::flex();
    let embedding = tensor(&[1.0, 0.8, 0.0, 0.6, 0.6, 0.0, 0.8, 1.0], [2, 2, 1, 2], &device);
    // Every pixel's semantic feature is (1, 0): both instances mean the same thing.
    let semantic = tensor(&[1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0], [2, 2, 1, 2], &device);
    let ids = [1, 1, 1, 2];
    let config = LossConfig::new();
    let terms = instance_loss(embedding, &semantic, &ids, &config).unwrap();

    let f = [[1.0, 0.0], [0.8, 0.6], [0.6, 0.8], [0.0, 1.0]];
    let hinge = |cos: f64| (1.0 - cos - 0.1).max(0.0);
    // Prototypes: μ1 = unit(f0 + f1 + f2) = unit(2.4, 1.4), μ2 = (0, 1).
    let mu1 = unit([2.4, 1.4]);
    let mu2 = [0.0, 1.0];
    // pull = ½·(⅓ Σ_{p∈1} hinge + hinge(f3·μ2) = 0).
    let pull =
        0.5 * ((hinge(dot(f[0], mu1)) + hinge(dot(f[1], mu1)) + hinge(dot(f[2], mu1))) / 3.0);
    assert!(pull > 0.0, "the example has an active pull hinge");
    // Same semantics for both instances: η = η_max = 3; one pair; δ_push = 1.
    let push = 3.0 * dot(mu1, mu2).max(0.0);
    // Cross over (view 0, inst 1) → prototype of view 1 = f2; (view 1, inst 1) → unit(f0 + f1);
    // instance 2 is seen once and does not count.
    let other0 = f[2];
    let other1 = unit([1.8, 0.6]);
    let cross = 0.5
        * ((hinge(dot(f[0], other0)) + hinge(dot(f[1], other0))) / 2.0 + hinge(dot(f[2], other1)));
    close(scalar(terms.pull.clone()), pull, "pull");
    close(scalar(terms.push.clone()), push, "push");
    close(scalar(terms.cross.clone()), cross, "cross");
    close(scalar(terms.total(&config)), 2.0 * pull + push + 2.0 * cross, "L_ins");

    // Ablation: no cross-view term.
    let embedding = tensor(&[1.0, 0.8, 0.0, 0.6, 0.6, 0.0, 0.8, 1.0], [2, 2, 1, 2], &device);
    let no_cross = config.with_cross_view(CrossView::Off);
    close(
        scalar(instance_loss(embedding, &semantic, &ids, &no_cross).unwrap().cross),
        0.0,
        "no cross",
    );
}

/// Central differences of `loss` at `x` against the autodiff gradient of the same loss.
pub(crate) fn check_gradient(
    values: &[f32],
    shape: [usize; 4],
    loss: impl Fn(Tensor<4>) -> Tensor<1>,
) {
    let ad = Device::flex().autodiff();
    let x = tensor(values, shape, &ad).require_grad();
    let grads = loss(x.clone()).backward();
    let analytic = x.grad(&grads).unwrap().into_data().try_to_vec::<f32>().unwrap();
    let h = 1e-2f32;
    let plain = Device::flex();
    for i in 0..values.len() {
        let at = |delta: f32| {
            let mut v = values.to_vec();
            v[i] += delta;
            scalar(loss(tensor(&v, shape, &plain)))
        };
        let numeric = (at(h) - at(-h)) / (2.0 * f64::from(h));
        let got = f64::from(analytic[i]);
        assert!(
            (got - numeric).abs() <= 2e-3 + 2e-2 * numeric.abs(),
            "d/dx[{i}]: autodiff {got}, central difference {numeric}"
        );
    }
}

#[test]
fn loss_instance_gradient_matches_finite_differences() {
    // Margins chosen so that every hinge is active and smooth at this point: δ_pull = 0 (1 − cos
    // > 0 off the prototype) and δ_push = 1.5 (cos > −0.5 between the prototypes).
    let config = LossConfig::new().with_pull_margin(0.0).with_push_margin(1.5);
    let values = [
        0.9, 0.7, 0.2, -0.3, 0.5, 0.1, 0.3, 0.8, -0.2, 0.6, 0.4, 0.9, // view 0, E = 3, 2×2
        0.7, -0.1, 0.5, 0.2, 0.3, 0.6, 0.9, 0.1, 0.4, -0.5, 0.8, 0.3, // view 1
    ];
    let ids = [1, 1, 2, 0, 1, 2, 2, 0];
    let semantic = tensor(&[1.0, 0.9, 0.2, 0.1, 1.0, 0.8, 0.3, 0.0], [2, 1, 2, 2], &Device::flex());
    check_gradient(&values, [2, 3, 2, 2], |x| {
        let semantic = Tensor::from_data(semantic.to_data(), &x.device());
        instance_loss(x, &semantic, &ids, &config).unwrap().total(&config)
    });
}

#[test]
fn loss_boundary_gradient_matches_finite_differences() {
    let config = LossConfig::new();
    let plain = Device::flex();
    let embedding = tensor(
        &[1.0, 1.0, 0.2, 0.1, 0.0, 1.0, 0.0, 0.1, 0.9, 1.0, 0.0, 0.3, 1.0, 1.0, 0.0, 0.0, 1.0, 1.0],
        [1, 2, 3, 3],
        &plain,
    );
    let target: Vec<f32> = (0..27).map(|i| ((i * 7) % 10) as f32 * 0.1).collect();
    let rendered: Vec<f32> = (0..27).map(|i| ((i * 3) % 11) as f32 * 0.09).collect();
    check_gradient(&rendered, [1, 3, 3, 3], |x| {
        let device = x.device();
        let target = tensor(&target, [1, 3, 3, 3], &device);
        let embedding = Tensor::from_data(embedding.to_data(), &device);
        boundary_rgb_loss(x, target, &embedding, &config).unwrap()
    });
}

#[test]
fn loss_depth_gradient_matches_finite_differences() {
    // 2 views of 3×3, one pixel without ground truth; predictions kept ≥ 0.05 from the ground
    // truth, so ±h stays on one side of every |·|.
    let target =
        [2.0, 2.1, 0.0, 2.4, 2.5, 2.6, 1.0, 1.2, 3.0, 3.0, 2.9, 2.8, 1.5, 1.6, 2.7, 1.4, 1.5, 2.6];
    let depth =
        [2.3, 1.8, 2.0, 2.0, 2.9, 2.2, 1.4, 0.9, 3.5, 2.6, 3.4, 2.5, 1.9, 1.1, 3.1, 1.0, 2.0, 2.3];
    let conf: Vec<f32> = (0..18).map(|i| 1.0 + 0.1 * i as f32).collect();
    // Three instances of unequal size, weighed half uniformly, half per instance.
    let ids: Vec<u32> = (0..18).map(|i| [1, 1, 2, 3, 1, 1][i % 6]).collect();
    let config = LossConfig::new().with_depth_instance_balance(Some(0.5));
    check_gradient(&depth, [2, 1, 3, 3], |x| {
        let conf = tensor(&conf, [2, 1, 3, 3], &x.device());
        depth_loss(x, conf, &target, &ids, 2.5, &config).unwrap()
    });
}
