//! One training objective evaluation: the network's forward pass on a sample's input views,
//! its per-pixel Gaussians placed in the world with the ground-truth cameras, rendered by the
//! differentiable rasterizer into every view of the sample (inputs and held-out targets), and
//! the five InstanceSplat terms on the renders (and, if asked, L_ins on the input views' own
//! per-pixel embeddings too).
//!
//! Gaussians are placed with the ground-truth cameras (in view 0's frame, as the network
//! predicts them) rather than the predicted ones: the camera head is supervised directly by
//! L_geom, and rendering through a still-wrong predicted pose early in training would only
//! blur the image losses. At inference the predicted cameras place them (see `raster`'s
//! back-projection, which this mirrors: pixel centre lifted to its depth, camera-frame offset
//! added, camera-frame rotation turned into the world frame).

use std::borrow::Cow;
use std::time::{Duration, Instant};

use burn::prelude::*;
use glam::Quat;
use inssplat_proto::Camera;
use inssplat_proto::rays;
use inssplat_proto::signature::TEXT_DIM;
use inssplat_raster::render::RenderOptions;

use super::sample::{RayCameras, Sample};
use crate::loss::{
    GaussianTraining, LossConfig, LossError, LossTerms, SemanticForm, boundary_rgb_loss,
    camera_targets, geometry_loss, instance_loss, median_depth, rgb_loss, semantic_loss,
};
use crate::model::{InsSplatNet, ModelError, ModelOutput, SH_C0};
use crate::render_op::{BackwardMeter, RenderOpError, SplatTensors, render_metered};

/// Why a step could not be evaluated.
#[derive(Debug, thiserror::Error)]
pub enum StepError {
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Loss(#[from] LossError),
    #[error(transparent)]
    Render(#[from] RenderOpError),
}

/// The objective of one sample, with where its time went.
#[derive(Debug, Clone)]
pub struct Objective {
    /// The weighted total (what backward differentiates).
    pub total: Tensor<1>,
    /// The unweighted terms.
    pub terms: LossTerms,
    pub forward_time: Duration,
    pub render_time: Duration,
    pub loss_time: Duration,
    /// The time the rasterizer's backward takes on this objective's renders, once
    /// `total.backward()` has run.
    pub render_backward: BackwardMeter,
}

/// The five terms and the total as numbers, for logs.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LossValues {
    pub total: f32,
    pub rgb: f32,
    pub geometry: f32,
    pub instance: f32,
    pub semantic: f32,
    pub boundary: f32,
}

impl std::ops::Add for LossValues {
    type Output = Self;

    fn add(self, o: Self) -> Self {
        LossValues {
            total: self.total + o.total,
            rgb: self.rgb + o.rgb,
            geometry: self.geometry + o.geometry,
            instance: self.instance + o.instance,
            semantic: self.semantic + o.semantic,
            boundary: self.boundary + o.boundary,
        }
    }
}

impl std::ops::Mul<f32> for LossValues {
    type Output = Self;

    fn mul(self, s: f32) -> Self {
        LossValues {
            total: self.total * s,
            rgb: self.rgb * s,
            geometry: self.geometry * s,
            instance: self.instance * s,
            semantic: self.semantic * s,
            boundary: self.boundary * s,
        }
    }
}

impl Objective {
    /// Reads the total and the terms back to the host.
    pub fn values(&self) -> LossValues {
        let read = |t: &Tensor<1>| t.clone().into_scalar::<f32>();
        LossValues {
            total: read(&self.total),
            rgb: read(&self.terms.rgb),
            geometry: read(&self.terms.geometry),
            instance: read(&self.terms.instance),
            semantic: read(&self.terms.semantic),
            boundary: read(&self.terms.boundary),
        }
    }
}

/// The input views' cameras as rays, `[inputs, tokens, 6·k²]`, for a network that reads
/// them ([`crate::model::ModelConfig::camera_rays`]): [`Sample::ray_cameras`] (by default the
/// true ones; zero where dropped) with their centres over the inputs' median true depth, the
/// scale every geometry term divides by.
pub fn input_rays(net: &InsSplatNet, sample: &Sample, device: &Device) -> Option<Tensor<3>> {
    let k = net.config().camera_rays?;
    let (inputs, size, patch) = (sample.inputs, sample.size, net.config().patch);
    let shape = [inputs, (size / patch) * (size / patch), rays::ray_channels(k)];
    if sample.ray_cameras == RayCameras::Dropped {
        return Some(Tensor::zeros(shape, device));
    }
    let scale = median_depth(&sample.depth[..inputs * size * size]).unwrap_or(1.0);
    Some(Tensor::from_data(
        TensorData::new(
            rays::patch_rays(&sample.cameras[..inputs], [size, size], patch, k, scale),
            shape,
        ),
        device,
    ))
}

/// Evaluates the objective of `sample` for `net` on `device` (an autodiff device to train).
pub fn objective(
    net: &InsSplatNet,
    sample: &Sample,
    config: &LossConfig,
    device: &Device,
) -> Result<Objective, StepError> {
    let (views, inputs, size) = (sample.views(), sample.inputs, sample.size);
    let pixels = size * size;
    let t0 = Instant::now();
    let images: Tensor<4> =
        Tensor::from_data(TensorData::new(sample.images.clone(), [views, 3, size, size]), device);
    let input_images = images.clone().narrow(0, 0, inputs);
    let mut out = net.forward_with_rays(input_images.clone(), input_rays(net, sample, device))?;
    if config.gaussians == GaussianTraining::Frozen {
        out.depth = out.depth.detach();
        out.depth_conf = out.depth_conf.detach();
        out.gaussians = out.gaussians.detach();
        out.camera = out.camera.detach();
    }
    let forward_time = t0.elapsed();

    let t1 = Instant::now();
    let input_cameras = &sample.cameras[..inputs];
    let splats = splats_from_outputs(&out, input_cameras);
    let channels = splats.features.dims()[1];
    let meter = BackwardMeter::default();
    let renders = sample
        .cameras
        .iter()
        .map(|camera| {
            render_metered(splats.clone(), camera, &[], &RenderOptions::default(), &meter)
                .map(|r| r.features)
        })
        .collect::<Result<Vec<_>, _>>()?;
    let rendered = Tensor::stack::<4>(renders, 0); // [V, C, H, W]
    let render_time = t1.elapsed();

    let t2 = Instant::now();
    let sem_dim = net.config().sem_dim;
    let rgb = rendered.clone().narrow(1, 0, 3);
    let instance = rendered.clone().narrow(1, 3, 8);
    let semantic = rendered.narrow(1, 11, sem_dim);
    debug_assert_eq!(channels, 11 + sem_dim);
    let targets = camera_targets(input_cameras);
    let geometry = geometry_loss(
        out.depth.clone(),
        out.depth_conf.clone(),
        &sample.depth[..inputs * pixels],
        &sample.ids[..inputs * pixels],
        out.camera.clone(),
        &targets,
        config,
    )?;
    let teacher = Tensor::from_data(
        TensorData::new(sample.teacher.clone(), [sample.teacher_rows(), TEXT_DIM]),
        device,
    );
    let (weight, bias) = net.sem_proj();
    let semantic_form = match config.semantic_temperature {
        Some(temperature) => {
            SemanticForm::Contrastive { temperature, vocabulary: &sample.vocabulary }
        }
        None => SemanticForm::Cosine,
    };
    let own_ids = &sample.ids[..inputs * pixels];
    let mut instance =
        instance_loss(instance, &semantic.clone().detach(), &sample.ids, config)?.total(config);
    if let Some(weight) = config.direct_instance_weight.filter(|&w| w > 0.0) {
        let own =
            instance_loss(out.instance.clone(), &out.semantic.clone().detach(), own_ids, config)?;
        instance = instance + own.total(config).mul_scalar(weight);
    }
    let semantic_ids: Cow<[u32]> = match config.semantic_objects_only {
        Some(true) => {
            sample.ids.iter().map(|id| if sample.shell.contains(id) { 0 } else { *id }).collect()
        }
        _ => Cow::Borrowed(&sample.ids),
    };
    let semantic = semantic_loss(semantic, &semantic_ids, teacher, weight, bias, semantic_form)?;
    let terms = LossTerms {
        rgb: rgb_loss(rgb.clone(), images)?,
        geometry,
        instance,
        semantic,
        boundary: boundary_rgb_loss(rgb.narrow(0, 0, inputs), input_images, &out.instance, config)?,
    };
    let total = match config.gaussians {
        GaussianTraining::Trained => config.total(&terms),
        GaussianTraining::Frozen => {
            terms.instance.clone().mul_scalar(config.instance_weight)
                + terms.semantic.clone().mul_scalar(config.semantic_weight)
        }
    };
    Ok(Objective {
        total,
        terms,
        forward_time,
        render_time,
        loss_time: t2.elapsed(),
        render_backward: meter,
    })
}

/// `[V][3][H][W]`: per pixel centre the camera-frame ray with z = 1, ((u − cx)/fx, (v − cy)/fy, 1),
/// of each camera's intrinsics scaled to `w`×`h`.
pub fn pixel_rays(cameras: &[Camera], h: usize, w: usize) -> Vec<f32> {
    let mut rays = Vec::with_capacity(cameras.len() * 3 * h * w);
    for cam in cameras {
        let k = cam.intrinsics.scaled_to(w as u32, h as u32);
        rays.extend((0..h * w).map(|p| ((p % w) as f32 + 0.5 - k.cx) / k.fx));
        rays.extend((0..h * w).map(|p| ((p / w) as f32 + 0.5 - k.cy) / k.fy));
        rays.extend(std::iter::repeat_n(1.0, h * w));
    }
    rays
}

/// The per-pixel Gaussians of every input view in the world frame of `cameras` (one per
/// input view), with features colour (3) | instance embedding (8) | semantic feature (d_s).
pub fn splats_from_outputs(out: &ModelOutput, cameras: &[Camera]) -> SplatTensors {
    let [v, _, h, w] = out.depth.dims();
    let device = out.depth.device();
    let hw = h * w;
    let g = out.gaussians.clone();
    let pixels_last = |x: Tensor<4>| {
        let c = x.dims()[1];
        x.reshape([v, c, hw]).swap_dims(1, 2) // [V, HW, C]
    };
    let rays =
        Tensor::<4>::from_data(TensorData::new(pixel_rays(cameras, h, w), [v, 3, h, w]), &device);
    let camera_points = rays * out.depth.clone() + g.clone().narrow(1, 0, 3);
    // World = Rᵀ(p − t); with points as rows: (p − t)ᵀ·R.
    let (mut rotations, mut translations, mut quats) = (Vec::new(), Vec::new(), Vec::new());
    for cam in cameras {
        let r = glam::Mat3::from_quat(cam.rotation.normalize());
        // Row-major R: row i = (R[i][0], R[i][1], R[i][2]); glam is column-major.
        for i in 0..3 {
            rotations.extend([r.col(0)[i], r.col(1)[i], r.col(2)[i]]);
        }
        translations.extend(cam.translation.to_array());
        quats.extend(left_product_matrix(cam.rotation.normalize().conjugate()));
    }
    let rotations = Tensor::<3>::from_data(TensorData::new(rotations, [v, 3, 3]), &device);
    let translations = Tensor::<3>::from_data(TensorData::new(translations, [v, 1, 3]), &device);
    let quats = Tensor::<3>::from_data(TensorData::new(quats, [v, 4, 4]), &device);
    let means = (pixels_last(camera_points) - translations).matmul(rotations).reshape([v * hw, 3]);
    let world_rotations = pixels_last(g.clone().narrow(1, 6, 4)).matmul(quats).reshape([v * hw, 4]);
    let colour = g.clone().narrow(1, 11, 3).mul_scalar(SH_C0).add_scalar(0.5);
    let features = Tensor::cat(vec![colour, out.instance.clone(), out.semantic.clone()], 1);
    let c = features.dims()[1];
    SplatTensors {
        means,
        log_scales: pixels_last(g.clone().narrow(1, 3, 3)).reshape([v * hw, 3]),
        rotations: world_rotations,
        logit_opacity: pixels_last(g.narrow(1, 10, 1)).reshape([v * hw]),
        features: pixels_last(features).reshape([v * hw, c]),
    }
}

/// The 4×4 matrix M with (a ⊗ b) = b·M for quaternions as rows (w, x, y, z), row-major.
fn left_product_matrix(a: Quat) -> [f32; 16] {
    let (w, x, y, z) = (a.w, a.x, a.y, a.z);
    // Columns of M are the output components w, x, y, z; rows the components of b.
    [
        w, x, y, z, //
        -x, w, z, -y, //
        -y, -z, w, x, //
        -z, y, -x, w,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn left_product_matrix_matches_quaternion_product() {
        let a = Quat::from_xyzw(0.1, -0.4, 0.3, 0.85).normalize();
        let b = Quat::from_xyzw(-0.6, 0.2, 0.5, 0.3);
        let m = left_product_matrix(a);
        let row = [b.w, b.x, b.y, b.z];
        let got: Vec<f32> = (0..4).map(|j| (0..4).map(|i| row[i] * m[i * 4 + j]).sum()).collect();
        let want = a * b;
        for (g, w) in got.iter().zip([want.w, want.x, want.y, want.z]) {
            assert!((g - w).abs() < 1e-6, "{got:?} vs {want:?}");
        }
    }
}
