//! The network's forward pass against the model I/O signature: output shapes at several view
//! counts, view 0 as the world frame (identity pose), positive depth, confidence above one,
//! the Φ_sem layout, configuration validation, and a backward pass on the autodiff device
//! that reaches the patch embedding (the whole graph is differentiable); a network built around
//! the image encoder, trained or frozen.

use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;
use burn::tensor::Distribution;
use burn::tensor::Gradients;
use inssplat_proto::signature as sig;
use inssplat_trainer::model::{
    Encoder, InsSplatNet, ModelConfig, ModelError, ModelOutput, efficientnet,
};

fn small() -> ModelConfig {
    ModelConfig::new()
        .with_image_size(32)
        .with_dim(32)
        .with_depth(2)
        .with_heads(2)
        .with_decoder_dim(32)
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec_as::<f32>().expect("f32")
}

#[test]
fn model_outputs_follow_the_signature() {
    let device = Device::flex();
    device.seed(1);
    let config = small().with_sem_dim(12);
    let net = config.init(&device).expect("config");
    for views in [1usize, 3] {
        let images =
            Tensor::<4>::random([views, 3, 32, 32], Distribution::Uniform(0.0, 1.0), &device);
        let out = net.forward(images).expect("forward");
        assert_eq!(out.camera.dims(), [views, sig::CAMERA_CHANNELS]);
        assert_eq!(out.depth.dims(), [views, 1, 32, 32]);
        assert_eq!(out.depth_conf.dims(), [views, 1, 32, 32]);
        assert_eq!(out.gaussians.dims(), [views, sig::GAUSSIAN_CHANNELS, 32, 32]);
        assert_eq!(out.instance.dims(), [views, 8, 32, 32]);
        assert_eq!(out.semantic.dims(), [views, 12, 32, 32]);
        let camera = values(out.camera);
        assert_eq!(&camera[..7], &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], "view 0 is the world frame");
        assert!(
            camera
                .chunks(9)
                .all(|row| row[7] > 0.0 && row[8] > 0.0 && row[7] < 2.0 * config.fov_base as f32)
        );
        assert!(values(out.depth).iter().all(|&d| d > 0.0));
        assert!(values(out.depth_conf).iter().all(|&c| c > 1.0));
    }
    let (w, b) = net.sem_proj();
    assert_eq!(w.dims(), [sig::TEXT_DIM, 12]);
    assert_eq!(b.dims(), [sig::TEXT_DIM]);
}

#[test]
fn model_rejects_bad_configs_and_inputs() {
    assert!(matches!(small().with_patch(6).validate(), Err(ModelError::Config(_))));
    assert!(matches!(small().with_image_size(36).validate(), Err(ModelError::Config(_))));
    assert!(matches!(small().with_depth(3).validate(), Err(ModelError::Config(_))));
    assert!(matches!(small().with_heads(5).validate(), Err(ModelError::Config(_))));
    let device = Device::flex();
    let net = small().init(&device).expect("config");
    for wrong in [[2, 3, 12, 16], [2, 3, 32, 20], [0, 3, 32, 32], [2, 1, 32, 32]] {
        let images = Tensor::<4>::zeros(wrong, &device);
        assert!(matches!(net.forward(images), Err(ModelError::InputShape { .. })), "{wrong:?}");
    }
}

/// A wide input (the photo's aspect rather than the trained square) runs on its own patch grid:
/// maps of its size, the position embedding resampled to the grid (4×4 → 2×4: each row the
/// mean of two of the square's, the columns as they are).
#[test]
fn model_runs_on_the_grid_of_a_wide_input() {
    let device = Device::flex();
    device.seed(2);
    let net = small().with_global_kv_pool(Some(2)).init(&device).expect("config");
    let images = Tensor::<4>::random([2, 3, 16, 32], Distribution::Uniform(0.0, 1.0), &device);
    let out = net.forward(images).expect("a 16×32 input");
    assert_eq!(out.depth.dims(), [2, 1, 16, 32]);
    assert_eq!(out.instance.dims(), [2, 8, 16, 32]);
    let square = values(net.position_embedding(4, 4));
    let wide = values(net.position_embedding(2, 4));
    assert_eq!(wide.len(), 2 * 4 * 32);
    let at = |grid: &[f32], columns: usize, r: usize, c: usize, k: usize| {
        grid[(r * columns + c) * 32 + k]
    };
    for (r, c, k) in (0..2).flat_map(|r| (0..4).flat_map(move |c| (0..32).map(move |k| (r, c, k))))
    {
        let mean = (at(&square, 4, 2 * r, c, k) + at(&square, 4, 2 * r + 1, c, k)) / 2.0;
        assert!((at(&wide, 4, r, c, k) - mean).abs() < 1e-6, "row {r} column {c} channel {k}");
    }
}

#[test]
fn model_default_size_and_gradients() {
    let config = ModelConfig::new();
    let params = config.init(&Device::flex()).expect("config").num_params();
    assert!((2_000_000..6_000_000).contains(&params), "default network has {params} parameters");

    let device = Device::flex().autodiff();
    let net = small().init(&device).expect("config");
    let images = Tensor::<4>::random([2, 3, 32, 32], Distribution::Uniform(0.0, 1.0), &device);
    let out = net.forward(images).expect("forward");
    let loss = out.camera.sum()
        + out.depth.mean()
        + out.gaussians.mean()
        + out.instance.mean()
        + out.semantic.mean();
    let grads = loss.backward();
    let mut visitor = GradCheck { grads: &grads, with: 0, without: 0 };
    net.visit(&mut visitor);
    // Φ_sem (weight and bias) is used by the losses, not by the forward pass.
    assert_eq!(visitor.without, 2, "every tensor but Φ_sem's receives a finite gradient");
    assert!(visitor.with > 20);
    assert!(net.forward_flops(4) > 0);
}

/// The parameters of `net` that get no non-zero finite gradient from its output `out` (every
/// head's maps and the cameras summed).
fn tensors_without_gradient(net: &InsSplatNet, out: ModelOutput) -> usize {
    let grads = (out.camera.sum()
        + out.depth.mean()
        + out.gaussians.mean()
        + out.instance.mean()
        + out.semantic.mean())
    .backward();
    let mut visitor = GradCheck { grads: &grads, with: 0, without: 0 };
    net.visit(&mut visitor);
    visitor.without
}

/// Counts parameters with and without a non-zero finite gradient.
struct GradCheck<'a> {
    grads: &'a Gradients,
    with: usize,
    without: usize,
}

impl ModuleVisitor for GradCheck<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let ok = param.val().grad(self.grads).is_some_and(|g| {
            let s = values(g.abs().sum())[0];
            s > 0.0 && s.is_finite()
        });
        if ok { self.with += 1 } else { self.without += 1 }
    }
}

/// A network built around the image encoder: it needs patch 8, no pixel skips and sizes in
/// multiples of 32; every one of its tensors gets a gradient, and none of the encoder's once
/// frozen; its FLOPs count the encoder's.
#[test]
fn a_network_on_the_encoder_checks_its_shape_and_trains_or_freezes_it() {
    let config = small().with_encoder(Some(Encoder::EfficientnetLite0));
    assert!(matches!(config.clone().with_patch(4).validate(), Err(ModelError::Config(_))));
    assert!(matches!(
        config.clone().with_image_skips(Some(4)).validate(),
        Err(ModelError::Config(_))
    ));
    assert!(matches!(config.clone().with_image_size(48).validate(), Err(ModelError::Config(_))));
    assert_eq!(config.size_multiple(), 32);
    assert_eq!(config.clone().with_global_kv_pool(Some(3)).size_multiple(), 96);
    let device = Device::flex().autodiff();
    device.seed(3);
    let net = config.init(&device).expect("config");
    let wrong = Tensor::<4>::zeros([1, 3, 32, 48], &device);
    assert!(matches!(net.forward(wrong), Err(ModelError::InputShape { multiple: 32, .. })));
    let images = || Tensor::<4>::random([2, 3, 64, 32], Distribution::Uniform(0.0, 1.0), &device);
    let out = net.forward(images()).expect("a 64×32 input");
    assert_eq!(out.semantic.dims(), [2, 16, 64, 32]);
    let encoder = net.encoder().expect("an encoder").num_params();
    assert!(encoder > 2_500_000, "the encoder has {encoder} parameters");
    assert_eq!(tensors_without_gradient(&net, out), 2, "all but Φ_sem's");
    let net = net.freeze_encoder();
    let out = net.forward(images()).expect("forward");
    let mut frozen = Tensors(0);
    net.encoder().expect("an encoder").visit(&mut frozen);
    // Weight and bias of the stem and of 3 layers in each of 16 blocks (the first has 2).
    assert_eq!(frozen.0, 2 + 2 * (2 + 15 * 3));
    assert_eq!(tensors_without_gradient(&net, out), 2 + frozen.0, "none reach the frozen encoder");
    // PyTorch's FlopCounterMode on the reference script's `forward` at 224² counts 770,375,104
    // FLOPs, 42,700,800 of them in the head and classifier, which the network leaves out.
    assert_eq!(efficientnet::forward_flops(224, 224), 770_375_104 - 42_700_800);
    let flops = |c: &ModelConfig| c.init(&Device::flex()).unwrap().forward_flops(4);
    assert!(flops(&config) > flops(&small()) + 4 * efficientnet::forward_flops(32, 32));
}

/// Counts the float tensors a module visits.
struct Tensors(usize);

impl ModuleVisitor for Tensors {
    fn visit_float<const D: usize>(&mut self, _: &Param<Tensor<D>>) {
        self.0 += 1;
    }
}

/// `--camera-rays` grown onto a network: with the rays of real cameras it computes exactly
/// what the source did (they join through a layer at zero), that layer still receives a
/// gradient (so training moves it), rays are required by it and refused by a network without
/// it.
#[test]
fn camera_rays_join_at_zero_learn_and_are_checked() {
    use glam::Vec3;
    use inssplat_proto::rays::{patch_rays, ray_channels};
    use inssplat_proto::{Camera, Intrinsics};
    let device = Device::flex().autodiff();
    device.seed(3);
    let source = small().init(&device).expect("config");
    let grown =
        inssplat_trainer::train::grow(&source, small().with_camera_rays(Some(2)), 9, &device)
            .expect("grow");
    let k = Intrinsics::from_fov_y(32, 32, 1.1);
    let cameras: Vec<Camera> = (0..3)
        .map(|i| {
            Camera::look_at(
                k,
                Vec3::new(0.4 * i as f32, 0.1, 0.0),
                Vec3::new(0.0, 0.0, 3.0),
                Vec3::NEG_Y,
            )
        })
        .collect();
    let rays = Tensor::<3>::from_data(
        TensorData::new(patch_rays(&cameras, [32, 32], 8, 2, 2.5), [3, 16, ray_channels(2)]),
        &device,
    );
    let images = Tensor::<4>::random([3, 3, 32, 32], Distribution::Uniform(0.0, 1.0), &device);
    let plain = source.forward(images.clone()).expect("forward");
    let with =
        grown.forward_with_rays(images.clone(), Some(rays.clone())).expect("forward with rays");
    assert_eq!(values(plain.depth), values(with.depth.clone()));
    assert_eq!(values(plain.instance), values(with.instance.clone()));
    assert_eq!(
        tensors_without_gradient(&grown, with),
        2,
        "the ray layer's weight receives a gradient like every tensor but Φ_sem's two"
    );
    assert!(matches!(grown.forward(images.clone()), Err(ModelError::Rays(_))));
    assert!(matches!(source.forward_with_rays(images, Some(rays)), Err(ModelError::Rays(_))));
}

/// `--mlp-ratio` widened on a network: it computes exactly what the source did (the new
/// hidden units write through zeros), has the wider blocks' weights, and every tensor, the
/// widened ones included, receives a gradient (so training moves the new units' zeros);
/// narrowing is refused.
#[test]
fn a_wider_mlp_starts_where_the_source_was_and_learns() {
    let device = Device::flex().autodiff();
    device.seed(4);
    let source = small().init(&device).expect("config");
    let grown = inssplat_trainer::train::grow(&source, small().with_mlp_ratio(6), 9, &device)
        .expect("grow");
    assert_eq!(grown.config().mlp_ratio, 6);
    assert_eq!(
        grown.num_params() - source.num_params(),
        2 * (64 * 32 + 64 + 64 * 32),
        "two blocks, each 64 more hidden units: their reads, biases and writes"
    );
    let images = Tensor::<4>::random([3, 3, 32, 32], Distribution::Uniform(0.0, 1.0), &device);
    let (a, b) =
        (source.forward(images.clone()).expect("forward"), grown.forward(images).expect("forward"));
    assert_eq!(values(a.camera), values(b.camera.clone()));
    assert_eq!(values(a.depth), values(b.depth.clone()));
    assert_eq!(values(a.instance), values(b.instance.clone()));
    assert_eq!(
        tensors_without_gradient(&grown, b),
        2,
        "every tensor but Φ_sem's two receives a gradient"
    );
    let err = inssplat_trainer::train::grow(&grown, small().with_mlp_ratio(2), 9, &device)
        .expect_err("narrowing is refused");
    assert!(err.to_string().contains("cannot narrow"), "{err}");
}

/// `--sem-dim` widened on a network: its first channels are the source's, Φ_sem's text-space
/// feature is exactly the source's (the new channels are read through zeros), the other outputs
/// are unchanged, every tensor receives a gradient, and narrowing is refused.
#[test]
fn a_wider_semantic_feature_starts_where_the_source_was_and_learns() {
    let device = Device::flex().autodiff();
    device.seed(5);
    let source = small().init(&device).expect("config");
    let d_s = source.config().sem_dim;
    let grown = inssplat_trainer::train::grow(&source, small().with_sem_dim(d_s + 4), 9, &device)
        .expect("grow");
    assert_eq!(grown.config().sem_dim, d_s + 4);
    let last = small().decoder_channels(small().stages());
    assert_eq!(
        grown.num_params() - source.num_params(),
        4 * (last + 1) + 4 * 384,
        "four output rows (weights and biases) and four rows of Φ_sem"
    );
    let images = Tensor::<4>::random([3, 3, 32, 32], Distribution::Uniform(0.0, 1.0), &device);
    let (a, b) =
        (source.forward(images.clone()).expect("forward"), grown.forward(images).expect("forward"));
    assert_eq!(values(a.depth), values(b.depth.clone()));
    assert_eq!(values(a.gaussians), values(b.gaussians.clone()));
    assert_eq!(values(a.instance), values(b.instance.clone()));
    assert_eq!(values(a.semantic.clone()), values(b.semantic.clone().narrow(1, 0, d_s)));
    let new = values(b.semantic.clone().narrow(1, d_s, 4));
    assert!(new.iter().any(|v| v.abs() > 1e-3), "the new channels carry features of their own");
    let text =
        |net: &InsSplatNet, s: Tensor<4>| values(net.project_semantic(s.permute([0, 2, 3, 1])));
    let (ta, tb) = (text(&source, a.semantic), text(&grown, b.semantic.clone()));
    assert!(
        ta.iter().zip(&tb).all(|(x, y)| (x - y).abs() <= 1e-5 * (1.0 + x.abs())),
        "Φ_sem reads the new channels through zeros"
    );
    assert_eq!(
        tensors_without_gradient(&grown, b),
        2,
        "every tensor but Φ_sem's two receives a gradient"
    );
    let err = inssplat_trainer::train::grow(&grown, small().with_sem_dim(d_s), 9, &device)
        .expect_err("narrowing is refused");
    assert!(err.to_string().contains("cannot narrow"), "{err}");
}
