//! L_pm, the point-map term of a network with a point-map head
//! ([`crate::model::ModelConfig::point_head`]), DUSt3R's regression target: every input pixel
//! with ground-truth depth is asked for its point in view 0's camera frame,
//! L_pm = (1/|Ω|) Σ_Ω ‖P̂_p − P_p‖ / s, the Euclidean distance over the valid pixels Ω of all
//! input views, s the scene's median depth as in L_depth. For view 0 the target is its own
//! depth along its rays; for every other view it is that view's surface carried by its pose
//! into view 0's frame, which a network meets only by matching the view against view 0. The
//! camera term asks the same of one token per view and has not taught the global attention
//! to match (a view's depth changes by 3% when 7 other views come with it); this term asks
//! it of every pixel. Added to L_geom with weight `point_map_weight`. With
//! `point_map_offsets` the target is each point's displacement instead, P_p − X_p with X_p the
//! pixel's true point in its own camera frame: zero for view 0, and for the others what the
//! pose does to the point, so a head that has learned no pose predicts the identity (the
//! view's points left where they are) rather than nothing at all.

use burn::prelude::*;
use inssplat_proto::Camera;

use super::{LossError, NORM_EPS, check_dims, check_len, constant, zero};

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

/// `[V][3][H][W]`: the true point of every pixel of the `cameras`' views in the camera frame
/// of `cameras[0]`, from the true `depth` (`[V][H][W]` metres, 0 = no hit, whose points are 0);
/// with `offsets`, that point minus the pixel's point in its own camera frame.
pub fn point_map_targets(
    cameras: &[Camera],
    depth: &[f32],
    h: usize,
    w: usize,
    offsets: bool,
) -> Result<Vec<f32>, LossError> {
    let hw = h * w;
    check_len("ground-truth depth of the point map", cameras.len() * hw, depth.len())?;
    let Some(reference) = cameras.first() else { return Ok(Vec::new()) };
    let rays = pixel_rays(cameras, h, w);
    let mut points = vec![0.0f32; cameras.len() * 3 * hw];
    for (v, cam) in cameras.iter().enumerate() {
        for p in 0..hw {
            let z = depth[v * hw + p];
            if z <= 0.0 {
                continue;
            }
            let ray = |c: usize| rays[(v * 3 + c) * hw + p];
            let own = glam::Vec3::new(ray(0), ray(1), 1.0) * z;
            let mut point = reference.world_to_camera(cam.camera_to_world(own));
            if offsets {
                point -= own;
            }
            for (c, x) in point.to_array().into_iter().enumerate() {
                points[(v * 3 + c) * hw + p] = x;
            }
        }
    }
    Ok(points)
}

/// L_pm of the predicted `points` `[V, 3, H, W]` against `target` (from [`point_map_targets`])
/// over the pixels with true `depth` (`[V][H][W]`), distances divided by `scale`. Zero when no
/// pixel is valid.
pub fn point_map_loss(
    points: Tensor<4>,
    target: &[f32],
    depth: &[f32],
    scale: f32,
) -> Result<Tensor<1>, LossError> {
    let [v, c, h, w] = points.dims();
    check_dims("point map", &[v, 3, h, w], &[v, c, h, w])?;
    check_len("ground-truth point map", v * 3 * h * w, target.len())?;
    check_len("ground-truth depth of the point map", v * h * w, depth.len())?;
    let device = points.device();
    let valid = depth.iter().filter(|&&d| d > 0.0).count();
    if valid == 0 {
        return Ok(zero(&device));
    }
    let weight = 1.0 / (valid as f32 * scale);
    let weights: Vec<f32> = depth.iter().map(|&d| if d > 0.0 { weight } else { 0.0 }).collect();
    let squared =
        (points - constant(target.to_vec(), [v, 3, h, w], &device)).powi_scalar(2).sum_dim(1);
    let distance = squared.add_scalar(NORM_EPS).sqrt();
    Ok((distance * constant(weights, [v, 1, h, w], &device)).sum())
}
