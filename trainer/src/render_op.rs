//! The project's CPU Gaussian rasterizer as a differentiable burn operation, so that the losses
//! on rendered images, depth and feature maps train the network through its Gaussians.
//!
//! burn 0.22 offers no closure-style custom backward on `Tensor`; custom operations go through
//! its backend-extension layer: the inputs are unwrapped to the `Autodiff<B, C>` primitive,
//! the output is registered in the autodiff graph with a hand-written [`Backward`] step, and
//! wrapped back into a `Tensor`. burn's autodiff nodes have one output, so the five
//! per-Gaussian inputs are concatenated (a differentiable `cat`) into one `[n, 11 + C]` tensor
//! (mean 3, log-scale 3, rotation w,x,y,z 4, opacity logit 1, features C) and the three
//! outputs leave as one `[C + 2, H, W]` tensor (features, depth, alpha) that is sliced apart;
//! burn routes the gradients of `cat` and `slice` itself.
//!
//! Forward reads the parameters to the host and runs `inssplat_raster::render::render_with`;
//! backward reads the output gradient to the host and runs
//! `inssplat_raster::render::render_backward` with the saved forward state. On a device
//! without autodiff the op just renders. Autodiff devices are supported on the Flex backend
//! (the CPU training backend) and, in builds with the `gpu` feature, on the wgpu backend
//! (`inssplat-train train --device gpu`), with or without gradient checkpointing. The
//! rasterizer is CPU code either way: on a GPU the op reads the parameters back and uploads
//! the image, so the network runs on the GPU and the render on the CPU cores.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::{
    BalancedCheckpointing, CheckpointStrategy, NoCheckpointing,
};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind, unary};
use burn::backend::{
    Autodiff, Backend, DispatchKindConversion, DispatchTensor, Flex, GradientCheckpointingStrategy,
    TensorMetadata,
};
use burn::prelude::*;
use inssplat_proto::Camera;
use inssplat_raster::render::{
    ForwardState, RenderError, RenderOptions, Splats, render_backward, render_with,
};

/// Columns of the packed parameter row before the features: mean 3, log-scale 3, rotation 4,
/// opacity logit 1.
const GEOMETRY_COLUMNS: usize = 11;

/// `n` Gaussians as tensors (any device).
#[derive(Debug, Clone)]
pub struct SplatTensors {
    /// `[n, 3]` world positions.
    pub means: Tensor<2>,
    /// `[n, 3]`.
    pub log_scales: Tensor<2>,
    /// `[n, 4]` quaternions w, x, y, z, not necessarily unit.
    pub rotations: Tensor<2>,
    /// `[n]`.
    pub logit_opacity: Tensor<1>,
    /// `[n, C]` features to composite (colour, instance embedding, semantic feature, ...).
    pub features: Tensor<2>,
}

/// One rendered view.
#[derive(Debug, Clone)]
pub struct Rendered {
    /// `[C, H, W]` composited features over the background.
    pub features: Tensor<3>,
    /// `[H, W]` expected depth.
    pub depth: Tensor<2>,
    /// `[H, W]` accumulated alpha.
    pub alpha: Tensor<2>,
}

/// Why a render could not run.
#[derive(Debug, thiserror::Error)]
pub enum RenderOpError {
    #[error("splat tensor `{field}` has shape {got:?}, expected {expected:?}")]
    Shape { field: &'static str, expected: Vec<usize>, got: Vec<usize> },
    #[error(transparent)]
    Render(#[from] RenderError),
    #[error("could not read the splat parameters back from the device: {0}")]
    Read(String),
    #[error("differentiable rendering is not available on this autodiff device: {0}")]
    UnsupportedBackend(String),
}

/// The Gaussians on the host, as the rasterizer takes them.
#[derive(Debug)]
struct HostSplats {
    means: Vec<[f32; 3]>,
    log_scales: Vec<[f32; 3]>,
    rotations: Vec<[f32; 4]>,
    logit_opacity: Vec<f32>,
    features: Vec<f32>,
    channels: usize,
}

impl HostSplats {
    /// Unpacks rows of `[n, 11 + channels]`.
    fn unpack(packed: &[f32], channels: usize) -> Self {
        let row = GEOMETRY_COLUMNS + channels;
        let n = packed.len() / row;
        let mut splats = Self {
            means: Vec::with_capacity(n),
            log_scales: Vec::with_capacity(n),
            rotations: Vec::with_capacity(n),
            logit_opacity: Vec::with_capacity(n),
            features: Vec::with_capacity(n * channels),
            channels,
        };
        for r in packed.chunks_exact(row) {
            splats.means.push([r[0], r[1], r[2]]);
            splats.log_scales.push([r[3], r[4], r[5]]);
            splats.rotations.push([r[6], r[7], r[8], r[9]]);
            splats.logit_opacity.push(r[10]);
            splats.features.extend_from_slice(&r[GEOMETRY_COLUMNS..]);
        }
        splats
    }

    fn splats(&self) -> Splats<'_> {
        Splats {
            means: &self.means,
            log_scales: &self.log_scales,
            rotations: &self.rotations,
            logit_opacity: &self.logit_opacity,
            features: &self.features,
            channels: self.channels,
        }
    }
}

/// What the backward step keeps from the forward.
#[derive(Debug)]
struct Saved {
    splats: HostSplats,
    camera: Camera,
    state: ForwardState,
    meter: Option<BackwardMeter>,
}

#[derive(Debug)]
struct RenderBackward;

/// Sums the time the CPU rasterizer's backward (`render_backward` alone: no read-back of the
/// output gradient, no upload) spends on the renders of [`render_metered`] that share it,
/// on whatever thread their backward runs; the training log's `render_backward_s`. Each
/// objective owns one, so trainings that run side by side in one process (tests, several
/// samples a step) never read each other's time.
#[derive(Debug, Clone, Default)]
pub struct BackwardMeter(Arc<AtomicU64>);

impl BackwardMeter {
    /// The time summed so far.
    pub fn elapsed(&self) -> Duration {
        Duration::from_nanos(self.0.load(Ordering::Relaxed))
    }

    fn add(&self, d: Duration) {
        self.0.fetch_add(d.as_nanos() as u64, Ordering::Relaxed);
    }
}

impl<B: Backend> Backward<B, 1> for RenderBackward
where
    DispatchTensor: DispatchKindConversion<B>,
{
    type State = Arc<Saved>;

    fn backward(
        self,
        ops: Ops<Self::State, 1>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let saved = ops.state;
        unary::<B, _>(ops.parents, ops.node, grads, |grad| {
            let device = grad.device();
            let [_, h, w] = grad.shape().dims::<3>();
            let grad = Tensor::<3>::from_primitive::<B>(grad)
                .into_data()
                .try_to_vec::<f32>()
                .expect("the gradient of a float32 render is float32");
            let pixels = h * w;
            let (d_features, rest) = grad.split_at(grad.len() - 2 * pixels);
            let (d_depth, d_alpha) = rest.split_at(pixels);
            let start = Instant::now();
            let g = render_backward(
                &saved.splats.splats(),
                &saved.camera,
                &saved.state,
                d_features,
                d_depth,
                d_alpha,
            );
            if let Some(meter) = &saved.meter {
                meter.add(start.elapsed());
            }
            let c = saved.splats.channels;
            let n = g.means.len();
            let mut packed = Vec::with_capacity(n * (GEOMETRY_COLUMNS + c));
            for i in 0..n {
                packed.extend_from_slice(&g.means[i]);
                packed.extend_from_slice(&g.log_scales[i]);
                packed.extend_from_slice(&g.rotations[i]);
                packed.push(g.logit_opacity[i]);
                packed.extend_from_slice(&g.features[i * c..(i + 1) * c]);
            }
            B::float_from_data(TensorData::new(packed, [n, GEOMETRY_COLUMNS + c]), &device)
        });
    }
}

/// Renders `splats` seen by `camera` over `background` (one value per channel, or empty for
/// zeros) with the CPU rasterizer; differentiable w.r.t. every splat tensor when they live on
/// an autodiff device. `options` selects the alpha cutoff (the default hard cutoff for
/// training; the smooth one only for finite-difference tests).
pub fn render(
    splats: SplatTensors,
    camera: &Camera,
    background: &[f32],
    options: &RenderOptions,
) -> Result<Rendered, RenderOpError> {
    render_with_meter(splats, camera, background, options, None)
}

/// [`render`], with the time its backward takes in the rasterizer added to `meter`.
pub fn render_metered(
    splats: SplatTensors,
    camera: &Camera,
    background: &[f32],
    options: &RenderOptions,
    meter: &BackwardMeter,
) -> Result<Rendered, RenderOpError> {
    render_with_meter(splats, camera, background, options, Some(meter.clone()))
}

fn render_with_meter(
    splats: SplatTensors,
    camera: &Camera,
    background: &[f32],
    options: &RenderOptions,
    meter: Option<BackwardMeter>,
) -> Result<Rendered, RenderOpError> {
    let [n, _] = splats.means.dims();
    let [_, c] = splats.features.dims();
    let shapes = [
        ("means", vec![n, 3], splats.means.dims().to_vec()),
        ("log_scales", vec![n, 3], splats.log_scales.dims().to_vec()),
        ("rotations", vec![n, 4], splats.rotations.dims().to_vec()),
        ("logit_opacity", vec![n], splats.logit_opacity.dims().to_vec()),
        ("features", vec![n, c], splats.features.dims().to_vec()),
    ];
    if let Some((field, expected, got)) = shapes.into_iter().find(|(_, e, g)| e != g) {
        return Err(RenderOpError::Shape { field, expected, got });
    }
    let packed = Tensor::cat(
        vec![
            splats.means,
            splats.log_scales,
            splats.rotations,
            splats.logit_opacity.reshape([n, 1]),
            splats.features,
        ],
        1,
    );
    let device = packed.device();
    let host =
        packed.to_data().try_to_vec::<f32>().map_err(|e| RenderOpError::Read(format!("{e:?}")))?;
    let host = HostSplats::unpack(&host, c);
    let (image, state) = render_with(&host.splats(), camera, background, options)?;
    let (h, w) = (image.height as usize, image.width as usize);
    let mut out = image.features;
    out.extend_from_slice(&image.depth);
    out.extend_from_slice(&image.alpha);
    let out = TensorData::new(out, [c + 2, h, w]);
    let saved = Saved { splats: host, camera: *camera, state, meter };
    let output = match device.gradient_checkpointing_strategy() {
        None => Tensor::from_data(out, &device),
        Some(strategy) => tracked_on_backend(packed, out, saved, strategy)?,
    };
    Ok(Rendered {
        features: output.clone().slice(s![0..c, .., ..]),
        depth: output.clone().slice(s![c..c + 1, .., ..]).reshape([h, w]),
        alpha: output.slice(s![c + 1..c + 2, .., ..]).reshape([h, w]),
    })
}

/// [`tracked`] on the backend `input` lives on (wgpu's in builds with the `gpu` feature, else
/// Flex) with the device's checkpointing strategy.
fn tracked_on_backend(
    input: Tensor<2>,
    output: TensorData,
    saved: Saved,
    strategy: GradientCheckpointingStrategy,
) -> Result<Tensor<3>, RenderOpError> {
    use GradientCheckpointingStrategy::{Balanced, Disabled};
    #[cfg(feature = "gpu")]
    if matches!(input.device().inner().as_dispatch(), burn::backend::DispatchDevice::Cube(_)) {
        use burn::backend::Cube;
        return match strategy {
            Disabled => tracked::<Cube, NoCheckpointing>(input, output, saved),
            Balanced => tracked::<Cube, BalancedCheckpointing>(input, output, saved),
        };
    }
    match strategy {
        Disabled => tracked::<Flex, NoCheckpointing>(input, output, saved),
        Balanced => tracked::<Flex, BalancedCheckpointing>(input, output, saved),
    }
}

/// Registers the render in the autodiff graph of `Autodiff<B, C>`, with `input` (the packed
/// parameters) as its only parent and `output` as its value.
fn tracked<B, C>(
    input: Tensor<2>,
    output: TensorData,
    saved: Saved,
) -> Result<Tensor<3>, RenderOpError>
where
    B: Backend,
    C: CheckpointStrategy,
    DispatchTensor: DispatchKindConversion<B> + DispatchKindConversion<Autodiff<B, C>>,
{
    let input = input
        .try_into_primitive::<Autodiff<B, C>>()
        .map_err(|e| RenderOpError::UnsupportedBackend(format!("{e:?}")))?;
    let output = B::float_from_data(output, &input.device());
    let result = match RenderBackward.prepare::<C>([input.node()]).compute_bound().stateful() {
        OpsKind::Tracked(prep) => prep.finish(Arc::new(saved), output),
        OpsKind::UnTracked(prep) => prep.finish(output),
    };
    Ok(Tensor::from_primitive::<Autodiff<B, C>>(result))
}
