//! Hand-computed values of L_rgb, L_geom, L_sem and L_bd-rgb on tiny inputs, the defaults of
//! the loss configuration and the weighted total.

use burn::prelude::*;
use glam::{Quat, Vec3};
use inssplat_proto::{Camera, Intrinsics};
use inssplat_trainer::loss::{
    BoundaryTerm, LossConfig, LossError, LossTerms, SemanticForm, boundary_rgb_loss,
    boundary_weights, camera_loss, camera_targets, depth_loss, depth_weights, geometry_loss,
    median_depth, rgb_loss, semantic_loss,
};

fn tensor<const D: usize>(values: &[f32], shape: [usize; D]) -> Tensor<D> {
    Tensor::from_data(TensorData::new(values.to_vec(), shape), &Device::flex())
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

fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

#[test]
fn loss_config_defaults_are_the_papers() {
    let c = LossConfig::new();
    assert_eq!(
        [c.rgb_weight, c.geometry_weight, c.instance_weight, c.semantic_weight, c.boundary_weight],
        [1.0, 1.0, 0.01, 0.02, 0.02]
    );
    assert_eq!([c.pull_weight, c.push_weight, c.cross_weight], [2.0, 1.0, 2.0]);
    assert_eq!([c.eta_max, c.tau_sem], [3.0, 0.5]);
    assert_eq!(
        [c.boundary_threshold, c.boundary_temperature, c.charbonnier_eps],
        [0.15, 0.05, 1e-3]
    );
    let one = |v: f32| tensor(&[v], [1]);
    let terms = LossTerms {
        rgb: one(1.0),
        geometry: one(2.0),
        instance: one(3.0),
        semantic: one(4.0),
        boundary: one(5.0),
    };
    close(scalar(c.total(&terms)), 1.0 + 2.0 + 0.03 + 0.08 + 0.1, "total");
}

#[test]
fn loss_rgb_is_mse() {
    // Two pixels, three channels: differences 0.1, −0.2, 0.3, 0, 0.5, −0.4.
    let rendered = tensor(&[0.1, 0.0, 0.8, 0.5, 0.3, 0.1], [1, 3, 1, 2]);
    let target = tensor(&[0.0, 0.2, 0.5, 0.5, -0.2, 0.5], [1, 3, 1, 2]);
    let expected = (0.01 + 0.04 + 0.09 + 0.0 + 0.25 + 0.16) / 6.0;
    close(scalar(rgb_loss(rendered, target).unwrap()), expected, "L_rgb");
    assert!(matches!(
        rgb_loss(tensor(&[0.0; 3], [1, 3, 1, 1]), tensor(&[0.0; 6], [1, 3, 1, 2])),
        Err(LossError::Shape { .. })
    ));
}

#[test]
fn loss_depth_is_confidence_weighted_relative_error() {
    // Pixels: gt 2, 0 (no hit), 4, 3 → median of {2, 3, 4} is 3.
    let gt = [2.0, 0.0, 4.0, 3.0];
    let ids = [1, 1, 2, 1];
    assert_eq!(median_depth(&gt), Some(3.0));
    assert_eq!(median_depth(&[0.0, 0.0]), None);
    let e = std::f64::consts::E;
    let depth = tensor(&[2.3, 5.0, 3.6, 3.0], [1, 1, 2, 2]);
    let conf = tensor(&[2.0, 1.5, e as f32, 1.0], [1, 1, 2, 2]);
    let config = LossConfig::new();
    let alpha = 0.2;
    let expected =
        ((2.0 * 0.3 / 3.0 - alpha * 2f64.ln()) + (e * 0.4 / 3.0 - alpha * 1.0) + 0.0) / 3.0;
    close(
        scalar(depth_loss(depth.clone(), conf.clone(), &gt, &ids, 3.0, &config).unwrap()),
        expected,
        "L_depth",
    );

    // Instance balance β: instance 1 has the valid pixels 0 and 3, instance 2 pixel 2, so at
    // β = 1 pixel 2 weighs ½ and pixels 0 and 3 ¼ each; at β = ½ the mean of that and ⅓ each.
    assert_eq!(depth_weights(&gt, &ids, 1.0), vec![0.25, 0.0, 0.5, 0.25]);
    let half = depth_weights(&gt, &ids, 0.5);
    for (got, want) in half.iter().zip([
        (0.25 + 1.0 / 3.0) / 2.0,
        0.0,
        (0.5 + 1.0 / 3.0) / 2.0,
        (0.25 + 1.0 / 3.0) / 2.0,
    ]) {
        close(f64::from(*got), want, "β = ½ weight");
    }
    let per_pixel = [2.0 * 0.3 / 3.0 - alpha * 2f64.ln(), 0.0, e * 0.4 / 3.0 - alpha, 0.0];
    let balanced = config.clone().with_depth_instance_balance(Some(1.0));
    let expected = 0.25 * per_pixel[0] + 0.5 * per_pixel[2] + 0.25 * per_pixel[3];
    close(
        scalar(depth_loss(depth.clone(), conf.clone(), &gt, &ids, 3.0, &balanced).unwrap()),
        expected,
        "balanced L_depth",
    );
    // Ids of pixels without ground truth count nowhere, and one instance is uniform weighting.
    let one = depth_weights(&gt, &[7, 9, 7, 7], 1.0);
    assert_eq!(one, depth_weights(&gt, &ids, 0.0));
}

fn camera(rotation: Quat, translation: Vec3, fov_y: f32) -> Camera {
    Camera { intrinsics: Intrinsics::from_fov_y(64, 48, fov_y), rotation, translation }
}

#[test]
fn loss_camera_targets_are_relative_to_view_zero() {
    let r0 = Quat::from_euler(glam::EulerRot::YXZ, 0.3, -0.2, 0.1);
    let t0 = Vec3::new(0.5, -1.0, 2.0);
    // View 1 = a known motion (rotation about y by 0.4, then translation) after view 0.
    let rel_r = Quat::from_rotation_y(0.4);
    let rel_t = Vec3::new(0.2, 0.0, -0.3);
    let cams = [camera(r0, t0, 0.9), camera(rel_r * r0, rel_r * t0 + rel_t, 0.7)];
    let targets = camera_targets(&cams);
    let (fy0, fx0) = cams[0].intrinsics.fov();
    let identity = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, fy0, fx0];
    for (got, want) in targets[0].iter().zip(identity) {
        close(f64::from(*got), f64::from(want), "view 0 target");
    }
    let (fy1, fx1) = cams[1].intrinsics.fov();
    let sign = if targets[1][3] * rel_r.w >= 0.0 { 1.0 } else { -1.0 };
    let want = [
        rel_t.x,
        rel_t.y,
        rel_t.z,
        sign * rel_r.w,
        sign * rel_r.x,
        sign * rel_r.y,
        sign * rel_r.z,
        fy1,
        fx1,
    ];
    for (got, want) in targets[1].iter().zip(want) {
        assert!((got - want).abs() < 1e-5, "view 1 target {:?} vs {want:?}", targets[1]);
    }
}

#[test]
fn loss_camera_hand_values() {
    let targets = [
        [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.2],
        [1.0, 2.0, 3.0, 0.0, 1.0, 0.0, 0.0, 0.8, 1.0],
    ];
    // View 0: fov_y off by 0.1. View 1: x off by 0.3, rotation = −2·target (same rotation).
    let pred = tensor(
        &[
            0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.1, 1.2, 1.3, 2.0, 3.0, 0.0, -2.0, 0.0, 0.0, 0.8,
            1.0,
        ],
        [2, 9],
    );
    close(
        scalar(camera_loss(pred, &targets, 2.0).unwrap()),
        0.1 / 4.0 + 0.3 / 3.0 / 2.0,
        "L_cam, sign-invariant",
    );
    // Rotation by angle a about x against the identity: mean |(cos a/2 − 1, sin a/2, 0, 0)|.
    let a: f64 = 0.5;
    let (c, s) = ((a / 2.0).cos(), (a / 2.0).sin());
    let targets = [targets[0], [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.8, 1.0]];
    let pred = tensor(
        &[
            0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.2, 0.0, 0.0, 0.0, c as f32, s as f32, 0.0,
            0.0, 0.8, 1.0,
        ],
        [2, 9],
    );
    close(
        scalar(camera_loss(pred.clone(), &targets, 1.0).unwrap()),
        ((1.0 - c) + s) / 4.0,
        "L_cam rotation",
    );

    // L_geom = L_depth + L_cam with the scene's median depth as the scale.
    let gt = [2.0, 4.0];
    let depth = tensor(&[3.0, 4.0], [1, 1, 1, 2]);
    let conf = tensor(&[1.0, 1.0], [1, 1, 1, 2]);
    let geom =
        geometry_loss(depth, conf, &gt, &[3, 4], pred, &targets, &LossConfig::new()).unwrap();
    close(scalar(geom), (1.0 / 4.0) / 2.0 + ((1.0 - c) + s) / 4.0, "L_geom");
}

#[test]
fn loss_semantic_hand_values() {
    // 2×2 view, ids [0, 1, 2, 1]; features l = (5, 5), (1, 0), (0, 1), (1, 1);
    // Φ_sem(l) = W·l + b embeds 2-d features into 3-d: W = [[1, 0], [0, 1], [0, 0]].
    let ids = [0, 1, 2, 1];
    let semantic = tensor(&[5.0, 1.0, 0.0, 1.0, 5.0, 0.0, 1.0, 1.0], [1, 2, 2, 2]);
    let teacher = tensor(&[9.0, 9.0, 9.0, 1.0, 0.0, 0.0, 0.0, 0.0, 2.0], [3, 3]);
    let weight = tensor(&[1.0, 0.0, 0.0, 1.0, 0.0, 0.0], [3, 2]);
    let loss = |ids: &[u32], bias: [f32; 3]| {
        semantic_loss(
            semantic.clone(),
            ids,
            teacher.clone(),
            weight.clone(),
            tensor(&bias, [3]),
            SemanticForm::Cosine,
        )
    };
    // b = 0. Pixel 1: (1,0,0)·(1,0,0) → cos 1; pixel 2: (0,1,0)·(0,0,2) → 0; pixel 3:
    // (1,1,0)·(1,0,0) → 1/√2.
    let expected = (0.0 + 1.0 + (1.0 - 0.5f64.sqrt())) / 3.0;
    close(scalar(loss(&ids, [0.0; 3]).unwrap()), expected, "L_sem");
    // b = (0, 0, 1): (1,0,1) → 1/√2; (0,1,1) vs (0,0,2) → 1/√2; (1,1,1) vs (1,0,0) → 1/√3.
    let expected = ((1.0 - 0.5f64.sqrt()) * 2.0 + (1.0 - (1.0 / 3.0f64).sqrt())) / 3.0;
    close(scalar(loss(&ids, [0.0, 0.0, 1.0]).unwrap()), expected, "L_sem with bias");
    // Only background: zero. An id without a teacher row: error.
    close(scalar(loss(&[0; 4], [0.0; 3]).unwrap()), 0.0, "background");
    assert_eq!(
        loss(&[0, 1, 3, 1], [0.0; 3]).unwrap_err(),
        LossError::TeacherRow { id: 3, rows: 3 }
    );
}

/// The contrastive L_sem of a 1×5 view, and its value by hand. Ids [0, 1, 2, 3, 1]; ids 1 and 3
/// share a label (same teacher row), id
/// 2 has another: A = (1, 0, 0), B = (0, 2, 0) (unit (0, 1, 0)). The vocabulary holds B again
/// (one class) and C = (0, 0, 3), a label the view does not show: three classes, A (the
/// sample's own, beyond the vocabulary) last. Φ_sem embeds (l0, l1) as (l0, l1, 1) with
/// W = [[1, 0], [0, 1], [0, 0]] and b = (0, 0, 1).
fn contrastive_loss_and_hand_value() -> (f64, f64) {
    let ids = [0, 1, 2, 3, 1];
    let features: [(f32, f32); 5] = [(9.0, 9.0), (1.0, 0.0), (1.0, 1.0), (0.0, 2.0), (3.0, 1.0)];
    let planar: Vec<f32> =
        features.iter().map(|f| f.0).chain(features.iter().map(|f| f.1)).collect();
    let semantic = tensor(&planar, [1, 2, 1, 5]);
    let teacher = tensor(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 2.0, 0.0, 1.0, 0.0, 0.0], [4, 3]);
    let weight = tensor(&[1.0, 0.0, 0.0, 1.0, 0.0, 0.0], [3, 2]);
    let bias = tensor(&[0.0, 0.0, 1.0], [3]);
    let tau = 0.5;
    let vocabulary = [0.0, 2.0, 0.0, 0.0, 0.0, 3.0];
    let form = SemanticForm::Contrastive { temperature: tau, vocabulary: &vocabulary };
    let loss = semantic_loss(semantic, &ids, teacher, weight, bias, form).unwrap();
    // Pixel p (label pixels 1..5) has cos_A = l0/|y|, cos_B = l1/|y|, cos_C = 1/|y|,
    // |y| = sqrt(l0² + l1² + 1); CE of its own class; weights: instance 1 has 2 pixels,
    // instances 2 and 3 one each.
    let ce = |(l0, l1): (f32, f32), own_a: bool| {
        let (l0, l1) = (f64::from(l0), f64::from(l1));
        let n = (l0 * l0 + l1 * l1 + 1.0).sqrt();
        let (a, b, c) = (l0 / n / tau, l1 / n / tau, 1.0 / n / tau);
        let lse = (a.exp() + b.exp() + c.exp()).ln();
        lse - if own_a { a } else { b }
    };
    let expected = (ce(features[1], true) / 2.0 + ce(features[4], true) / 2.0)
        + ce(features[2], false)
        + ce(features[3], true);
    (scalar(loss), expected / 3.0)
}

#[test]
fn loss_semantic_contrastive_hand_values() {
    let (loss, expected) = contrastive_loss_and_hand_value();
    close(loss, expected, "contrastive L_sem");
}

/// A 1×9 strip (or its 9×1 transpose): pixels 0–1 embed as (1, 0), pixels 2–8 as (0.8, 0.6)
/// (scaled, to check the normalization), so r = 1 − 0.8 = 0.2 at pixels 1 and 2 only.
fn strip_embedding() -> Vec<f32> {
    let a: Vec<f32> = (0..9).map(|x| if x < 2 { 2.0 } else { 0.4 }).collect();
    let b: Vec<f32> = (0..9).map(|x| if x < 2 { 0.0 } else { 0.3 }).collect();
    [a, b].concat()
}

#[test]
fn loss_boundary_weights_hand_values() {
    let config = LossConfig::new();
    // The 5×5 max spreads r = 0.2 from pixels 1–2 to pixels 0–4; elsewhere r = 0.
    let near = sigmoid((0.2 - 0.15) / 0.05) as f32;
    let far = sigmoid(-0.15 / 0.05) as f32;
    let expected: Vec<f32> = (0..9).map(|x| if x <= 4 { near } else { far }).collect();
    for (h, w) in [(1, 9), (9, 1)] {
        let got = boundary_weights(&strip_embedding(), 1, h, w, &config);
        for (g, e) in got.iter().zip(&expected) {
            assert!((g - e).abs() < 1e-5, "{h}×{w}: {got:?} vs {expected:?}");
        }
    }
}

#[test]
fn loss_boundary_rgb_hand_values() {
    let config = LossConfig::new();
    let embedding = tensor(&strip_embedding(), [1, 2, 1, 9]);
    // Rendered = target + 0.1·x in every channel.
    let target: Vec<f32> = (0..27).map(|i| (i % 5) as f32 * 0.1).collect();
    let rendered: Vec<f32> =
        target.iter().enumerate().map(|(i, t)| t + 0.1 * (i % 9) as f32).collect();
    let eps = 1e-3f64;
    let (near, far) = (sigmoid(1.0), sigmoid(-3.0));
    let (mut num, mut den) = (0.0, 0.0);
    for x in 0..9u32 {
        let b = if x <= 4 { near } else { far };
        let d = 0.1 * f64::from(x);
        num += b * (d * d + eps * eps).sqrt();
        den += b;
    }
    let loss = boundary_rgb_loss(
        tensor(&rendered, [1, 3, 1, 9]),
        tensor(&target, [1, 3, 1, 9]),
        &embedding,
        &config,
    );
    close(scalar(loss.unwrap()), num / den, "L_bd-rgb");
    let off = config.with_boundary(BoundaryTerm::Off);
    let loss = boundary_rgb_loss(
        tensor(&rendered, [1, 3, 1, 9]),
        tensor(&target, [1, 3, 1, 9]),
        &embedding,
        &off,
    );
    close(scalar(loss.unwrap()), 0.0, "ablated");
}
