//! Analytic FLOP count of the network (a multiply-add counts 2), for throughput reports:
//! matmuls, attention products and convolutions (the image encoder's too); element-wise work,
//! norms and softmax are left out, so "effective GFLOP/s" understates the arithmetic done.

use super::efficientnet::{self, FEATURE_CHANNELS};
use super::{DenseDecoder, ModelConfig, encoder};

/// FLOPs of one forward pass at `n` views.
pub fn forward_flops(c: &ModelConfig, n: usize) -> u64 {
    let (n, d, g) = (n as u64, c.dim as u64, c.grid() as u64);
    let tokens = g * g;
    let s = tokens + 1;
    let mut f = 2 * n * tokens * c.token_channels() as u64 * d;
    if c.encoder.is_some() {
        let side = c.image_size;
        f += n * efficientnet::forward_flops(side, side);
        for (l, &ch) in FEATURE_CHANNELS.iter().take(encoder::SKIP_LEVELS).enumerate() {
            let r = (side >> (l + 1)) as u64;
            f += 2 * n * r * r * ch as u64 * c.decoder_channels(c.stages() - 1 - l) as u64;
        }
    }
    let mlp = c.mlp_ratio as u64;
    for i in 0..c.depth {
        f += 2 * n * s * d * d * (4 + 2 * mlp);
        f += if i % 2 == 0 {
            4 * n * s * s * d
        } else {
            let keys = c.global_kv_pool.map_or(s, |p| tokens / (p * p) as u64 + 1);
            4 * (n * s) * (n * keys) * d
        };
    }
    f += 2 * n * (d * d + d * 9);
    let levels = (c.depth / 2) as u64;
    f += 2 * n * tokens * levels * d * c.decoder_dim as u64;
    for st in 0..c.stages() {
        let r = g << st;
        let (ch, next) = (c.decoder_channels(st) as u64, c.decoder_channels(st + 1) as u64);
        f += 2 * n * r * r * ch * ch * 9 + 2 * n * r * r * ch * next * 4;
    }
    let mut input = 3;
    for level in 0..c.stages() {
        let Some(ch) = c.skip_channels(level) else { break };
        let r = (c.image_size >> level) as u64;
        let out = c.decoder_channels(c.stages() - level) as u64;
        f += 2 * n * r * r * (input * 9 + out) * ch as u64;
        input = ch as u64;
    }
    let hw = (c.image_size * c.image_size) as u64;
    let last = c.decoder_channels(c.stages()) as u64;
    f += 2 * n * hw * (last + 3) * last + 2 * n * hw * last * DenseDecoder::out_channels(c) as u64;
    if let Some(k) = c.camera_rays {
        f += 2 * n * tokens * inssplat_proto::rays::ray_channels(k) as u64 * d;
    }
    f
}
