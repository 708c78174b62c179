//! L_match, a loss on the attention itself: each patch token of a view after the first is
//! asked to attend, with the first head of the last global layer, to the patch token of view 0
//! that sees the same surface point. The target is found from the ground truth: the token's
//! centre pixel is lifted by its true depth into view 0's frame ([`super::point_map_targets`])
//! and projected into view 0; a point outside view 0, or behind what view 0 sees there
//! (occluded), has no target. L_match is the cross-entropy of the head's softmax over view 0's
//! patch tokens (q·k/√d, the layer's own attention logits), averaged over the tokens with a
//! target. The point-map head and the camera term leave it to the network to discover
//! matching; this term asks for it directly. Added to L_geom with weight
//! `attention_match_weight`.

use burn::prelude::*;
use burn::tensor::activation::log_softmax;
use inssplat_proto::Camera;

use super::{LossError, check_dims, check_len, constant, point_map_targets, zero};

/// Relative depth margin within which a projected point counts as the surface view 0 sees.
const VISIBLE: f32 = 0.03;

/// For every patch token of views 1.. (view-major, `[V − 1][grid²]`), the index of the patch
/// token of view 0 that sees its centre pixel's true point, or −1 for none; `patch` pixels a
/// token side, `depth` the true depth `[V][H][W]` (square views of `size`).
pub fn match_targets(
    cameras: &[Camera],
    depth: &[f32],
    size: usize,
    patch: usize,
) -> Result<Vec<i64>, LossError> {
    let (hw, grid) = (size * size, size / patch);
    let points = point_map_targets(cameras, depth, size, size, false)?;
    let Some(first) = cameras.first() else { return Ok(Vec::new()) };
    let view0 =
        Camera { intrinsics: first.intrinsics.scaled_to(size as u32, size as u32), ..*first };
    let mut targets = Vec::with_capacity(cameras.len().saturating_sub(1) * grid * grid);
    for v in 1..cameras.len() {
        for token in 0..grid * grid {
            let p = (token / grid * patch + patch / 2) * size + token % grid * patch + patch / 2;
            let at = |c: usize| points[(v * 3 + c) * hw + p];
            let point = glam::Vec3::new(at(0), at(1), at(2));
            let target = (depth[v * hw + p] > 0.0)
                .then(|| view0.pixel_of(point))
                .flatten()
                .filter(|&(x, y)| {
                    let seen = depth[y * size + x];
                    seen > 0.0 && point.z <= seen * (1.0 + VISIBLE)
                })
                .map_or(-1, |(x, y)| (y / patch * grid + x / patch) as i64);
            targets.push(target);
        }
    }
    Ok(targets)
}

/// L_match of `queries` and `keys` `[V, tokens, head_dim]` (the network's
/// `global_queries`/`global_keys`) against `targets` (from [`match_targets`]); zero when no
/// token has a target.
pub fn attention_match_loss(
    queries: Tensor<3>,
    keys: Tensor<3>,
    targets: &[i64],
) -> Result<Tensor<1>, LossError> {
    let device = queries.device();
    Ok(view_zero_logits(queries, keys, targets)?
        .map_or_else(|| zero(&device), |logits| cross_entropy(logits, targets)))
}

/// The attention logits q·k/√d of every patch token of views 1.. over view 0's patch tokens,
/// `[V − 1, tokens, tokens]`, after checking the shapes against `targets`; `None` when no
/// token has a target.
fn view_zero_logits(
    queries: Tensor<3>,
    keys: Tensor<3>,
    targets: &[i64],
) -> Result<Option<Tensor<3>>, LossError> {
    let [v, t, d] = queries.dims();
    check_dims("attention keys", &[v, t, d], &keys.dims())?;
    check_len("attention match targets", v.saturating_sub(1) * t, targets.len())?;
    if !targets.iter().any(|&i| i >= 0) {
        return Ok(None);
    }
    let reference = keys.narrow(0, 0, 1).swap_dims(1, 2).repeat_dim(0, v - 1); // [V − 1, d, T]
    Ok(Some(queries.narrow(0, 1, v - 1).matmul(reference).mul_scalar(1.0 / (d as f64).sqrt())))
}

/// The mean cross-entropy of `logits` `[V − 1, T, T]` at `targets`, over the tokens with one
/// (at least one has).
fn cross_entropy(logits: Tensor<3>, targets: &[i64]) -> Tensor<1> {
    let [rows, t, _] = logits.dims();
    let device = logits.device();
    let valid = targets.iter().filter(|&&i| i >= 0).count();
    let mut picks = vec![0.0f32; rows * t * t];
    for (row, &target) in targets.iter().enumerate() {
        if target >= 0 {
            picks[row * t + target as usize] = 1.0 / valid as f32;
        }
    }
    -(log_softmax(logits, 2) * constant(picks, [rows, t, t], &device)).sum()
}

/// How well an attention head matches the views, over the tokens with a target: the mean
/// cross-entropy (L_match; ln of the token count for a uniform head), and the shares whose
/// most-attended view-0 token is the target (chance: one over the token count) or within one
/// token of it in the grid.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MatchScores {
    pub tokens: usize,
    pub cross_entropy: f64,
    pub top1: f64,
    pub within_one: f64,
}

impl MatchScores {
    /// The scores of both token sets together.
    pub fn merge(self, o: MatchScores) -> MatchScores {
        let n = self.tokens + o.tokens;
        let mean = |a: f64, b: f64| {
            if n == 0 { 0.0 } else { (a * self.tokens as f64 + b * o.tokens as f64) / n as f64 }
        };
        MatchScores {
            tokens: n,
            cross_entropy: mean(self.cross_entropy, o.cross_entropy),
            top1: mean(self.top1, o.top1),
            within_one: mean(self.within_one, o.within_one),
        }
    }
}

/// [`MatchScores`] of `queries` and `keys` `[V, tokens, head_dim]` against `targets` (from
/// [`match_targets`]), the tokens on a square grid.
pub fn match_scores(
    queries: Tensor<3>,
    keys: Tensor<3>,
    targets: &[i64],
) -> Result<MatchScores, LossError> {
    let grid = (queries.dims()[1] as f64).sqrt().round() as i64;
    let Some(logits) = view_zero_logits(queries, keys, targets)? else {
        return Ok(MatchScores::default());
    };
    let tokens = targets.iter().filter(|&&i| i >= 0).count();
    let cross_entropy = f64::from(cross_entropy(logits.clone(), targets).into_scalar::<f32>());
    let best: Vec<i64> = logits.argmax(2).into_data().try_into_vec_as::<i64>().map_err(|e| {
        LossError::Read { what: "the most-attended tokens", message: format!("{e:?}") }
    })?;
    let (mut top1, mut within_one) = (0usize, 0usize);
    for (&b, &target) in best.iter().zip(targets).filter(|(_, t)| **t >= 0) {
        top1 += usize::from(b == target);
        within_one += usize::from(
            (b / grid - target / grid).abs() <= 1 && (b % grid - target % grid).abs() <= 1,
        );
    }
    Ok(MatchScores {
        tokens,
        cross_entropy,
        top1: top1 as f64 / tokens as f64,
        within_one: within_one as f64 / tokens as f64,
    })
}
