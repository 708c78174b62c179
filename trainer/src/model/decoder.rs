//! The heads. [`CameraHead`] maps each view's final camera token to a pose and field of view,
//! forcing view 0 to the identity (the world frame). [`DenseDecoder`] is DPT-style: the patch
//! tokens of every global layer are normalised, concatenated and fused by one linear map
//! (a 1×1 convolution over the token grid), then each of log2(patch) stages refines with a
//! residual 3×3 convolution and doubles the resolution with a 2×2 stride-2 transposed
//! convolution. At full resolution the centred input image is concatenated (a skip that keeps
//! edges and colour sharp), a 1×1 layer mixes it in, and one fused 1×1 output layer feeds the
//! three dense heads: depth + confidence, Gaussians + semantic feature, instance embedding.
//! Sharing the trunk keeps the convolution count — the slow part on a CPU — small.
//!
//! With [`ModelConfig::image_skips`] a small convolutional image encoder (a 3×3 layer at full
//! resolution, then one 3×3 stride-2 layer per halving) adds its features to the decoder's
//! after every upsampling, U-Net style, through a 1×1 layer that starts at zero: the tokens
//! see 8×8 patches, and without local image features the maps cannot follow the edges inside
//! them. Starting at zero, a network grown from one without the encoder computes exactly what
//! it computed before.
//!
//! With [`ModelConfig::encoder`] the pretrained encoder's stride-4 and stride-2 features take
//! that role: each joins the decoder through a 1×1 layer after the stage that reaches its
//! resolution.

use burn::nn::conv::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig};
use burn::nn::{Initializer, LayerNorm, LayerNormConfig, Linear, LinearConfig, PaddingConfig2d};
use burn::prelude::*;
use burn::tensor::activation::{sigmoid, softplus};
use inssplat_proto::signature::{CAMERA_CHANNELS, GAUSSIAN_CHANNELS};

use super::efficientnet::FEATURE_CHANNELS;
use super::{LN_EPS, ModelConfig, encoder, gelu};

/// Raw output channels of the depth head (depth, confidence).
pub const OUT_DEPTH: usize = 2;
/// Raw output channels of the Gaussian head.
pub const OUT_GAUSSIANS: usize = GAUSSIAN_CHANNELS;
/// Output channels of the instance head (embedding S).
pub const OUT_INSTANCE: usize = 8;
/// SH degree-0 basis constant: colour = 0.5 + C0 · DC.
pub const SH_C0: f64 = 0.282_094_791_773_878_1;
/// Gaussian channels that get the per-channel affine (offset, log-scale, rotation, opacity);
/// the remaining three are the colour, which gets the image skip.
pub const GAUSSIAN_AFFINE_CHANNELS: usize = 11;

/// Per-view camera from the final camera token.
#[derive(Module, Debug)]
pub struct CameraHead {
    pub(crate) norm: LayerNorm,
    pub(crate) fc1: Linear,
    pub(crate) fc2: Linear,
}

impl CameraHead {
    pub fn new(dim: usize, device: &Device) -> Self {
        Self {
            norm: LayerNormConfig::new(dim).with_epsilon(LN_EPS).init(device),
            fc1: LinearConfig::new(dim, dim).init(device),
            fc2: LinearConfig::new(dim, CAMERA_CHANNELS).init(device),
        }
    }

    /// `tokens`: `[N, dim]` → `[N, 9]` = translation, rotation w,x,y,z (identity-biased),
    /// fov_y, fov_x. Row 0 is exactly translation 0 and rotation (1, 0, 0, 0).
    pub fn forward(&self, tokens: Tensor<2>, c: &ModelConfig) -> Tensor<2> {
        let n = tokens.dims()[0];
        let device = tokens.device();
        let raw = self.fc2.forward(gelu(self.fc1.forward(self.norm.forward(tokens))));
        let fov = sigmoid(raw.clone().slice([0..n, 7..9])) * (2.0 * c.fov_base);
        let identity = Tensor::<2>::from_floats([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]], &device);
        let pose = if n == 1 {
            identity
        } else {
            Tensor::cat(vec![identity.clone(), raw.slice([1..n, 0..7]) + identity], 0)
        };
        Tensor::cat(vec![pose, fov], 1)
    }
}

/// One decoder stage: residual 3×3 refinement at its resolution, then ×2 upsampling.
#[derive(Module, Debug)]
pub struct Stage {
    pub(crate) refine: Conv2d,
    pub(crate) up: ConvTranspose2d,
}

/// One level of the image encoder: its 3×3 layer (stride 1 at full resolution, 2 below) and
/// the 1×1 layer, zero at initialisation, that adds its features to the decoder's.
#[derive(Module, Debug)]
pub struct Skip {
    pub(crate) encode: Conv2d,
    pub(crate) inject: Conv2d,
}

/// The dense maps of one forward pass (everything but the camera).
#[derive(Debug, Clone)]
pub struct DenseOutput {
    pub depth: Tensor<4>,
    pub depth_conf: Tensor<4>,
    pub gaussians: Tensor<4>,
    pub instance: Tensor<4>,
    pub semantic: Tensor<4>,
}

/// DPT-style dense decoder shared by the depth, Gaussian/semantic and instance heads.
#[derive(Module, Debug)]
pub struct DenseDecoder {
    /// Normalises the concatenated tokens of all levels.
    pub(crate) norm: LayerNorm,
    /// Level fusion: `[levels·dim] → decoder_dim` per token.
    pub(crate) fuse: Linear,
    pub(crate) stages: Vec<Stage>,
    /// The image encoder, full resolution first; empty without [`ModelConfig::image_skips`].
    /// Level `l` joins the decoder after stage `stages − 1 − l` has upsampled.
    pub(crate) skips: Vec<Skip>,
    /// With [`ModelConfig::encoder`], its feature at stride 2^(l + 1) → decoder channels
    /// (1×1); joins after the stage that reaches that resolution. Empty without an encoder.
    pub(crate) encoder_skips: Vec<Conv2d>,
    /// Full resolution: decoder channels + 3 image channels → decoder channels (1×1).
    pub(crate) mix: Conv2d,
    /// Fused 1×1 output layer: depth (2) | Gaussians (14) | semantic (d_s) | instance (8).
    pub(crate) out: Conv2d,
}

impl DenseDecoder {
    pub fn new(c: &ModelConfig, device: &Device) -> Self {
        let levels = c.depth / 2;
        let stages = (0..c.stages())
            .map(|s| {
                let (ch, next) = (c.decoder_channels(s), c.decoder_channels(s + 1));
                Stage {
                    refine: Conv2dConfig::new([ch, ch], [3, 3])
                        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                        .init(device),
                    up: ConvTranspose2dConfig::new([ch, next], [2, 2])
                        .with_stride([2, 2])
                        .init(device),
                }
            })
            .collect();
        let skips = (0..c.stages())
            .map_while(|level| {
                let ch = c.skip_channels(level)?;
                let input = if level == 0 { 3 } else { c.skip_channels(level - 1)? };
                let stride = if level == 0 { 1 } else { 2 };
                Some(Skip {
                    encode: Conv2dConfig::new([input, ch], [3, 3])
                        .with_stride([stride, stride])
                        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                        .init(device),
                    inject: Conv2dConfig::new([ch, c.decoder_channels(c.stages() - level)], [1, 1])
                        .with_initializer(Initializer::Zeros)
                        .init(device),
                })
            })
            .collect();
        let encoder_skips = match c.encoder {
            Some(_) => (0..encoder::SKIP_LEVELS)
                .map(|l| {
                    let out = c.decoder_channels(c.stages() - 1 - l);
                    Conv2dConfig::new([FEATURE_CHANNELS[l], out], [1, 1]).init(device)
                })
                .collect(),
            None => Vec::new(),
        };
        let last = c.decoder_channels(c.stages());
        Self {
            norm: LayerNormConfig::new(levels * c.dim).with_epsilon(LN_EPS).init(device),
            fuse: LinearConfig::new(levels * c.dim, c.decoder_dim).init(device),
            stages,
            skips,
            encoder_skips,
            mix: Conv2dConfig::new([last + 3, last], [1, 1]).init(device),
            out: Conv2dConfig::new([last, Self::out_channels(c)], [1, 1]).init(device),
        }
    }

    /// Channels of the fused output layer.
    pub fn out_channels(c: &ModelConfig) -> usize {
        OUT_DEPTH + OUT_GAUSSIANS + c.sem_dim + OUT_INSTANCE
    }

    /// `levels`: patch tokens `[N, tokens, dim]` of each global layer; `images`: the input;
    /// `encoded`: the encoder's features at strides 2 and 4 (empty without one).
    pub fn forward(
        &self,
        levels: Vec<Tensor<3>>,
        images: Tensor<4>,
        encoded: Vec<Tensor<4>>,
        c: &ModelConfig,
    ) -> DenseOutput {
        let [n, _, h, w] = images.dims();
        let centred = images.clone() - 0.5;
        let mut features = Vec::with_capacity(self.skips.len());
        for skip in &self.skips {
            let input = features.last().cloned().unwrap_or_else(|| centred.clone());
            features.push(gelu(skip.encode.forward(input)));
        }
        let tokens = self.fuse.forward(self.norm.forward(Tensor::cat(levels, 2)));
        let mut x =
            tokens.reshape([n, h / c.patch, w / c.patch, c.decoder_dim]).permute([0, 3, 1, 2]);
        for (s, stage) in self.stages.iter().enumerate() {
            x = x.clone() + gelu(stage.refine.forward(x));
            x = stage.up.forward(x);
            let level = self.stages.len() - 1 - s;
            if let (Some(skip), Some(f)) = (self.skips.get(level), features.get(level)) {
                x = x + skip.inject.forward(f.clone());
            }
            let encoder_level = level.wrapping_sub(1);
            if let (Some(skip), Some(f)) =
                (self.encoder_skips.get(encoder_level), encoded.get(encoder_level))
            {
                x = x + skip.forward(f.clone());
            }
        }
        let x = gelu(self.mix.forward(Tensor::cat(vec![x, centred], 1)));
        let raw = self.out.forward(x);
        let mut parts = raw
            .split_with_sizes(vec![1, 1, GAUSSIAN_AFFINE_CHANNELS, 3, c.sem_dim, OUT_INSTANCE], 1)
            .into_iter();
        let mut next = || parts.next().expect("six output groups");
        let (depth, conf, affine, colour, semantic, instance) =
            (next(), next(), next(), next(), next(), next());
        let device = images.device();
        let (mul, add) = gaussian_affine(c);
        let mul = Tensor::<1>::from_floats(mul.as_slice(), &device).reshape([
            1,
            GAUSSIAN_AFFINE_CHANNELS,
            1,
            1,
        ]);
        let add = Tensor::<1>::from_floats(add.as_slice(), &device).reshape([
            1,
            GAUSSIAN_AFFINE_CHANNELS,
            1,
            1,
        ]);
        let colour = colour + (images - 0.5) * (1.0 / SH_C0);
        DenseOutput {
            depth: softplus(depth, 1.0) * c.depth_scale,
            depth_conf: conf.exp() + 1.0,
            gaussians: Tensor::cat(vec![affine * mul + add, colour], 1),
            instance,
            semantic,
        }
    }
}

/// Per-channel `raw · mul + add` of the first 11 Gaussian channels: offsets scaled to metres,
/// log-scales shifted to a pixel's footprint, rotations biased to the identity quaternion,
/// opacity logits as they are.
pub fn gaussian_affine(
    c: &ModelConfig,
) -> ([f32; GAUSSIAN_AFFINE_CHANNELS], [f32; GAUSSIAN_AFFINE_CHANNELS]) {
    let o = c.offset_scale as f32;
    let b = c.log_scale_bias as f32;
    (
        [o, o, o, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0],
        [0.0, 0.0, 0.0, b, b, b, 1.0, 0.0, 0.0, 0.0, 0.0],
    )
}
