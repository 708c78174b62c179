//! One transformer layer of the backbone: pre-norm multi-head self-attention then a GELU MLP,
//! both residual. The same layer type serves frame attention (each view attends to its own
//! tokens, batch = views) and global attention (all views' tokens as one sequence, batch 1);
//! the caller chooses by how it shapes the token tensor. Query, key and value come from one
//! fused projection so the largest matmuls stay large. A global layer may read its keys and
//! values pooled over the patch grid ([`KeyPooling`]).

use burn::nn::{LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::module::attention;
use burn::tensor::ops::AttentionModuleOptions;

use super::gelu;

/// Epsilon of every layer norm in the network (ONNX LayerNormalization gets the same).
pub const LN_EPS: f64 = 1e-5;

/// A pre-norm transformer layer.
#[derive(Module, Debug)]
pub struct Block {
    pub(crate) norm1: LayerNorm,
    /// Fused query/key/value projection, `[dim, 3·dim]`, output laid out as (q|k|v, head, channel).
    pub(crate) qkv: Linear,
    pub(crate) proj: Linear,
    pub(crate) norm2: LayerNorm,
    pub(crate) fc1: Linear,
    pub(crate) fc2: Linear,
    pub(crate) heads: usize,
}

impl Block {
    pub fn new(dim: usize, heads: usize, mlp_ratio: usize, device: &Device) -> Self {
        assert!(
            dim.is_multiple_of(heads),
            "width {dim} is not a multiple of the head count {heads}"
        );
        Self {
            norm1: LayerNormConfig::new(dim).with_epsilon(LN_EPS).init(device),
            qkv: LinearConfig::new(dim, 3 * dim).init(device),
            proj: LinearConfig::new(dim, dim).init(device),
            norm2: LayerNormConfig::new(dim).with_epsilon(LN_EPS).init(device),
            fc1: LinearConfig::new(dim, mlp_ratio * dim).init(device),
            fc2: LinearConfig::new(mlp_ratio * dim, dim).init(device),
            heads,
        }
    }

    /// `x`: `[batch, seq, dim]` → same shape; attention runs within each batch entry.
    pub fn forward(&self, x: Tensor<3>) -> Tensor<3> {
        self.forward_pooled(x, None)
    }

    /// [`Self::forward`], reading the keys and values through `pooling` when given.
    pub fn forward_pooled(&self, x: Tensor<3>, pooling: Option<KeyPooling>) -> Tensor<3> {
        let [b, l, d] = x.dims();
        let hd = d / self.heads;
        let qkv = self
            .qkv
            .forward(self.norm1.forward(x.clone()))
            .reshape([b, l, 3, self.heads, hd])
            .permute([2, 0, 3, 1, 4]);
        let mut parts = qkv.chunk(3, 0).into_iter().map(|t| t.squeeze_dim::<4>(0));
        let (q, k, v) = (parts.next().unwrap(), parts.next().unwrap(), parts.next().unwrap());
        let options =
            AttentionModuleOptions { scale: Some(1.0 / (hd as f64).sqrt()), ..Default::default() };
        let (keys, values) = match pooling {
            Some(p) => (p.apply(k), p.apply(v)),
            None => (k, v),
        };
        let ctx =
            attention(q, keys, values, None, None, options).swap_dims(1, 2).reshape([b, l, d]);
        let x = x + self.proj.forward(ctx);
        let h = self.fc2.forward(gelu(self.fc1.forward(self.norm2.forward(x.clone()))));
        x + h
    }
}

/// How a global layer pools its keys and values: the sequence holds `views` views of one
/// camera token and a `grid` (rows, columns) of patch tokens each (row-major); each view keeps
/// its camera token and averages its patches' keys (and values) over `pool` × `pool` squares.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KeyPooling {
    pub views: usize,
    pub grid: [usize; 2],
    pub pool: usize,
}

impl KeyPooling {
    /// `[1, heads, views·(1 + rows·columns), head_dim]` → `[1, heads, views·(1 + rows·columns
    /// / pool²), head_dim]`.
    pub fn apply(&self, t: Tensor<4>) -> Tensor<4> {
        let [_, heads, _, hd] = t.dims();
        let ([gh, gw], n, p) = (self.grid, self.views, self.pool);
        let (qh, qw) = (gh / p, gw / p);
        let t = t.reshape([heads, n, 1 + gh * gw, hd]);
        let camera = t.clone().narrow(2, 0, 1);
        let pooled = t
            .narrow(2, 1, gh * gw)
            .reshape([heads * n, qh, p, qw, p, hd])
            .mean_dim(2)
            .mean_dim(4)
            .reshape([heads, n, qh * qw, hd]);
        Tensor::cat(vec![camera, pooled], 2).reshape([1, heads, n * (1 + qh * qw), hd])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two views of a camera token and a 4×4 grid, one head of width 1 holding each token's
    /// index: pooled 2×2, each view keeps its camera token and the means of its four squares.
    #[test]
    fn key_pooling_keeps_camera_tokens_and_averages_squares() {
        let device = Device::flex();
        let values: Vec<f32> = (0..34).map(|i| i as f32).collect();
        let t = Tensor::<1>::from_floats(values.as_slice(), &device).reshape([1, 1, 34, 1]);
        let pooled = KeyPooling { views: 2, grid: [4, 4], pool: 2 }.apply(t);
        assert_eq!(pooled.dims(), [1, 1, 10, 1]);
        let got = pooled.into_data().try_to_vec::<f32>().expect("f32");
        // View 0: camera 0, patches 1..=16 row-major; its top-left square is 1, 2, 5, 6.
        let square = |first: f32| (4.0 * first + 1.0 + 4.0 + 5.0) / 4.0;
        let view = |cam: f32| {
            vec![cam, square(cam + 1.0), square(cam + 3.0), square(cam + 9.0), square(cam + 11.0)]
        };
        assert_eq!(got, [view(0.0), view(17.0)].concat());
    }
}
