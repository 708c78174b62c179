//! L_bd-rgb: the colour error near instance boundaries, where a blurry rendering merges
//! neighbouring objects. The boundary map comes from the network's own pixel-aligned instance
//! embedding S (not the rendered one), detached, and only weighs the RGB error.
//!
//! Per view, with ŝ_p = unit(S_p):
//! r_p = max over the in-image 4-neighbours q of (1 − ŝ_p·ŝ_q); r'_p = max of r over the 5×5
//! window around p (clipped to the image); b_p = sigmoid((r'_p − 0.15)/0.05);
//! D_p = (1/3) Σ_c sqrt((Î_cp − I_cp)² + ε²), ε = 1e-3 (Charbonnier);
//! L_bd-rgb = Σ_p b_p·D_p / Σ_p b_p over all views' pixels (zero with [`BoundaryTerm::Off`]).

use burn::prelude::*;

use super::{
    BoundaryTerm, LossConfig, LossError, check_dims, constant, host, unit_pixel_vectors, zero,
};

/// Half the side of the max filter (5×5).
const DILATE: usize = 2;

/// The boundary weights b `[V][H][W]` of an instance embedding `embedding` laid out
/// `[V][E][H][W]`; empty when there are no pixels or no channels.
pub fn boundary_weights(
    embedding: &[f32],
    views: usize,
    height: usize,
    width: usize,
    config: &LossConfig,
) -> Vec<f32> {
    let plane = height * width;
    let e = embedding.len() / (views * plane).max(1);
    if plane == 0 || e == 0 {
        return Vec::new();
    }
    let mut weights = Vec::with_capacity(views * plane);
    for view in embedding.chunks(e * plane).take(views) {
        let unit = unit_pixel_vectors(view, e);
        let distance = |p: usize, q: usize| {
            1.0 - (0..e).map(|c| unit[p * e + c] * unit[q * e + c]).sum::<f32>()
        };
        let mut r = vec![0.0f32; plane];
        for y in 0..height {
            for x in 0..width {
                let p = y * width + x;
                let mut best = f32::NEG_INFINITY;
                if x > 0 {
                    best = best.max(distance(p, p - 1));
                }
                if x + 1 < width {
                    best = best.max(distance(p, p + 1));
                }
                if y > 0 {
                    best = best.max(distance(p, p - width));
                }
                if y + 1 < height {
                    best = best.max(distance(p, p + width));
                }
                // A 1×1 image has no neighbours: no boundary.
                r[p] = if best.is_finite() { best } else { 0.0 };
            }
        }
        // Separable 5×5 max: rows, then columns.
        let mut rows = vec![0.0f32; plane];
        for y in 0..height {
            for x in 0..width {
                let (lo, hi) = (x.saturating_sub(DILATE), (x + DILATE).min(width - 1));
                rows[y * width + x] = r[y * width + lo..=y * width + hi]
                    .iter()
                    .copied()
                    .fold(f32::NEG_INFINITY, f32::max);
            }
        }
        for y in 0..height {
            for x in 0..width {
                let (lo, hi) = (y.saturating_sub(DILATE), (y + DILATE).min(height - 1));
                let dilated =
                    (lo..=hi).map(|yy| rows[yy * width + x]).fold(f32::NEG_INFINITY, f32::max);
                let z =
                    (f64::from(dilated) - config.boundary_threshold) / config.boundary_temperature;
                weights.push((1.0 / (1.0 + (-z).exp())) as f32);
            }
        }
    }
    weights
}

/// L_bd-rgb of the rendered image `rendered` against `target` (both `[V, 3, H, W]`), with the
/// boundary map of the network's pixel-aligned instance embedding `embedding` `[V, E, H, W]`
/// (read, never differentiated).
pub fn boundary_rgb_loss(
    rendered: Tensor<4>,
    target: Tensor<4>,
    embedding: &Tensor<4>,
    config: &LossConfig,
) -> Result<Tensor<1>, LossError> {
    check_dims("rgb target", &rendered.dims(), &target.dims())?;
    let [v, c, h, w] = rendered.dims();
    let [ev, e, eh, ew] = embedding.dims();
    check_dims("instance embedding (views, height, width)", &[v, h, w], &[ev, eh, ew])?;
    if e == 0 {
        return Err(LossError::Shape {
            what: "instance embedding",
            expected: vec![v, 1, h, w],
            got: vec![v, 0, h, w],
        });
    }
    let device = rendered.device();
    if config.boundary == BoundaryTerm::Off || v * h * w == 0 {
        return Ok(zero(&device));
    }
    let b = boundary_weights(&host("instance embedding", embedding)?, v, h, w, config);
    let total: f32 = b.iter().sum();
    let b = constant(b, [v, 1, h, w], &device).div_scalar(total);
    let eps2 = config.charbonnier_eps * config.charbonnier_eps;
    let diff = rendered - target;
    let charbonnier = (diff.clone() * diff).add_scalar(eps2).sqrt().sum_dim(1).div_scalar(c as f64);
    Ok((charbonnier * b).sum())
}
