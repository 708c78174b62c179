//! L_geom: depth and cameras supervised by the synthetic ground truth (the paper distils them
//! from VGGT; no VGGT can run here, and our ground truth is exact).
//!
//! Depth, over the valid pixels Ω (ground truth > 0) of all views, VGGT-style:
//! L_depth = (1/|Ω|) Σ_Ω [c_p·|d̂_p − d_p|/s − α·log c_p], with c_p > 1 the predicted confidence
//! and s the median ground-truth depth of the scene (all views). Dividing by s makes the error
//! relative, so rooms of any size weigh the same, while keeping a gradient that does not
//! explode near zero as log-depth would. With `depth_instance_balance` β > 0 the pixels are
//! not weighed alike: each pays (1 − β)/|Ω| + β/(n·|Ω_i|), |Ω_i| the valid pixels of its
//! instance i over all views and n the instances present, so that at β = 1 every instance
//! counts as much as every other, a chair as much as the floor (as the contrastive L_sem is
//! balanced). Uniform weights hand the room shell, about two thirds of the pixels, two thirds
//! of the gradient, and the network learns a smooth room in which the furniture sits at the
//! depth of the wall behind it. The L1 term itself has no scale alignment: the ground truth is
//! metric and the network predicts metric depth and translation, which the voxel size and
//! every metric at inference rely on.
//!
//! Cameras, in the frame of view 0 as the network predicts them (see [`camera_targets`]):
//! L_cam = (1/(N−1)) Σ_{i≥1} [mean_xyz |t̂_i − t_i|/s + mean_wxyz |unit(q̂_i) − σ_i·q_i|] +
//! (1/N) Σ_i mean(|fov̂_y − fov_y|, |fov̂_x − fov_x|), where σ_i = sign(unit(q̂_i)·q_i) (detached)
//! makes q and −q the same rotation. View 0's pose is the identity by construction of the
//! network and is left out of the pose term. L_geom = L_depth + camera_weight·L_cam.

use burn::prelude::*;
use inssplat_proto::Camera;
use inssplat_proto::signature::CAMERA_CHANNELS;

use super::{
    LossConfig, LossError, check_dims, check_len, constant, normalize_rows, pixels_per_instance,
    zero,
};

/// A ground-truth camera in the layout of the network's `camera` output: translation xyz,
/// rotation w,x,y,z (unit), fov_y, fov_x (radians); world = view 0's camera.
pub type CameraTarget = [f32; CAMERA_CHANNELS];

/// The network's camera targets for `cameras` (world→camera, any world frame): every pose
/// re-expressed with view 0's camera as the world, R_i' = R_i·R_0ᵀ, t_i' = t_i − R_i'·t_0.
pub fn camera_targets(cameras: &[Camera]) -> Vec<CameraTarget> {
    let Some(first) = cameras.first() else { return Vec::new() };
    let to_reference = first.rotation.normalize().conjugate();
    cameras
        .iter()
        .map(|cam| {
            let rotation = (cam.rotation.normalize() * to_reference).normalize();
            let t = cam.translation - rotation * first.translation;
            let (fov_y, fov_x) = cam.intrinsics.fov();
            [t.x, t.y, t.z, rotation.w, rotation.x, rotation.y, rotation.z, fov_y, fov_x]
        })
        .collect()
}

pub use inssplat_proto::rays::median_depth;

/// The weight of each pixel in L_depth: 0 without ground truth in `target`, else
/// (1 − `balance`)/|Ω| + `balance`/(n·|Ω_i|) for a pixel of instance `ids[p]` = i (id 0 counts
/// as one more group), |Ω_i| that instance's valid pixels and n the instances with any. The
/// weights sum to 1 over a sample with a valid pixel.
pub fn depth_weights(target: &[f32], ids: &[u32], balance: f64) -> Vec<f32> {
    let counts =
        pixels_per_instance(target.iter().zip(ids).filter(|(d, _)| **d > 0.0).map(|(_, &id)| id));
    let valid: usize = counts.values().sum();
    let groups = counts.len() as f64;
    target
        .iter()
        .zip(ids)
        .map(|(&d, id)| {
            if d > 0.0 {
                ((1.0 - balance) / valid as f64 + balance / (groups * counts[id] as f64)) as f32
            } else {
                0.0
            }
        })
        .collect()
}

/// L_depth of predicted `depth` and `conf` `[V, 1, H, W]` against ground truth `target`
/// (`[V][H][W]` metres, 0 = no hit) with scene scale `scale` (see [`median_depth`]); `ids`
/// (`[V][H][W]`, the instance ids) group the pixels for `depth_instance_balance`. Zero when no
/// pixel is valid.
pub fn depth_loss(
    depth: Tensor<4>,
    conf: Tensor<4>,
    target: &[f32],
    ids: &[u32],
    scale: f32,
    config: &LossConfig,
) -> Result<Tensor<1>, LossError> {
    let [v, one, h, w] = depth.dims();
    check_dims("depth", &[v, 1, h, w], &[v, one, h, w])?;
    check_dims("depth confidence", &depth.dims(), &conf.dims())?;
    check_len("ground-truth depth", v * h * w, target.len())?;
    check_len("instance ids of the depth", v * h * w, ids.len())?;
    let device = depth.device();
    if !target.iter().any(|d| *d > 0.0) {
        return Ok(zero(&device));
    }
    let weights = depth_weights(target, ids, config.depth_instance_balance.unwrap_or(0.0));
    let shape = [v, 1, h, w];
    let error = depth - constant(target.to_vec(), shape, &device);
    let per_pixel = error.abs().div_scalar(scale);
    let weights = constant(weights, shape, &device);
    let per_pixel = conf.clone() * per_pixel - conf.log().mul_scalar(config.depth_conf_alpha);
    Ok((per_pixel * weights).sum())
}

/// L_cam of the predicted `camera` `[N, 9]` against `targets` (from [`camera_targets`]),
/// translations divided by `scale`.
pub fn camera_loss(
    camera: Tensor<2>,
    targets: &[CameraTarget],
    scale: f32,
) -> Result<Tensor<1>, LossError> {
    let n = targets.len();
    check_dims("camera", &[n, CAMERA_CHANNELS], &camera.dims())?;
    let device = camera.device();
    if n == 0 {
        return Ok(zero(&device));
    }
    let target = constant(targets.concat(), [n, CAMERA_CHANNELS], &device);
    let fov =
        (camera.clone().slice(s![.., 7..9]) - target.clone().slice(s![.., 7..9])).abs().mean();
    if n == 1 {
        return Ok(fov);
    }
    let (camera, target) = (camera.slice(s![1.., ..]), target.slice(s![1.., ..]));
    let translation = (camera.clone().slice(s![.., 0..3]) - target.clone().slice(s![.., 0..3]))
        .abs()
        .mean()
        .div_scalar(scale);
    let q = normalize_rows(camera.slice(s![.., 3..7]));
    let q_target = target.slice(s![.., 3..7]);
    let sign = (q.clone() * q_target.clone()).sum_dim(1).detach().sign();
    let rotation = (q - q_target * sign).abs().mean();
    Ok(translation + rotation + fov)
}

/// L_geom = L_depth + camera_weight·L_cam, the scale s being the median of the ground-truth
/// depth (1 when no pixel has depth). `depth`, `conf` `[V, 1, H, W]`, `camera` `[V, 9]`;
/// `ids` the ground-truth instance ids of the depth's pixels.
pub fn geometry_loss(
    depth: Tensor<4>,
    conf: Tensor<4>,
    target_depth: &[f32],
    ids: &[u32],
    camera: Tensor<2>,
    target_cameras: &[CameraTarget],
    config: &LossConfig,
) -> Result<Tensor<1>, LossError> {
    let scale = median_depth(target_depth).unwrap_or(1.0);
    let depth = depth_loss(depth, conf, target_depth, ids, scale, config)?;
    let camera = camera_loss(camera, target_cameras, scale)?;
    Ok(depth + camera.mul_scalar(config.camera_weight))
}
