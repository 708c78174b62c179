//! One transformer layer of the backbone: pre-norm multi-head self-attention then a GELU MLP,
//! both residual. The same layer type serves frame attention (each view attends to its own
//! tokens, batch = views) and global attention (all views' tokens as one sequence, batch 1);
//! the caller chooses by how it shapes the token tensor. Query, key and value come from one
//! fused projection so the largest matmuls stay large.

use burn::nn::{LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::gelu;
use burn::tensor::module::attention;
use burn::tensor::ops::AttentionModuleOptions;

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
        self.forward_with_keys(x).0
    }

    /// [`Self::forward`], with the layer's queries and keys, `[batch, heads, seq, head_dim]`
    /// each (what a loss on the attention itself reads).
    pub fn forward_with_keys(&self, x: Tensor<3>) -> (Tensor<3>, Tensor<4>, Tensor<4>) {
        let [b, l, d] = x.dims();
        let hd = d / self.heads;
        let qkv = self
            .qkv
            .forward(self.norm1.forward(x.clone()))
            .reshape([b, l, 3, self.heads, hd])
            .permute([2, 0, 3, 1, 4]);
        let mut parts = qkv.chunk(3, 0).into_iter().map(|t| t.squeeze_dim::<4>(0));
        let (q, k, v) = (
            parts.next().unwrap(),
            parts.next().unwrap(),
            parts.next().unwrap(),
        );
        let options = AttentionModuleOptions {
            scale: Some(1.0 / (hd as f64).sqrt()),
            ..Default::default()
        };
        let ctx = attention(q.clone(), k.clone(), v, None, None, options)
            .swap_dims(1, 2)
            .reshape([b, l, d]);
        let x = x + self.proj.forward(ctx);
        let h = self
            .fc2
            .forward(gelu(self.fc1.forward(self.norm2.forward(x.clone()))));
        (x + h, q, k)
    }
}
