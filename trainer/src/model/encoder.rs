//! The pretrained image encoder inside the network ([`ModelConfig::encoder`]): which one,
//! how its feature maps become the transformer's tokens, and which of them reach the decoder.
//! The tokens sit on the stride-8 grid: there the encoder's stride-8 map is concatenated with
//! its stride-16 and stride-32 maps, each repeated to that grid (nearest neighbour), so that
//! a token reads fine detail and the deeper layers' wider view, and one linear layer (the
//! network's `patch_embed`) embeds the 472 channels. The stride-2 and stride-4 maps join the
//! decoder after its upsampling stages reach those resolutions.
//!
//! [`ModelConfig::encoder`]: super::ModelConfig::encoder

use burn::prelude::*;
use burn::tensor::module::interpolate;
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
use serde::{Deserialize, Serialize};

use super::efficientnet::FEATURE_CHANNELS;

/// A pretrained image encoder the network can be built around.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Encoder {
    /// EfficientNet-Lite0 on ImageNet-1k ([`super::efficientnet`]).
    EfficientnetLite0,
}

/// The stride of the token grid, which is the network's patch.
pub const TOKEN_STRIDE: usize = 8;
/// What the input's sides must be multiples of: the encoder's deepest stride.
pub const SIZE_MULTIPLE: usize = 32;
/// Feature maps, by index into [`FEATURE_CHANNELS`] (strides 2 to 32), that make the tokens.
pub const TOKEN_LEVELS: [usize; 3] = [2, 3, 4];
/// Feature maps that join the decoder (strides 2 and 4).
pub const SKIP_LEVELS: usize = 2;

/// Channels of a token before its embedding.
pub fn token_channels() -> usize {
    TOKEN_LEVELS.iter().map(|&l| FEATURE_CHANNELS[l]).sum()
}

/// `features` (strides 2 to 32) → `[N, tokens, token_channels()]`, the stride-8 grid row by
/// row.
pub fn tokens(features: &[Tensor<4>]) -> Tensor<3> {
    let [n, _, gh, gw] = features[TOKEN_LEVELS[0]].dims();
    let maps = TOKEN_LEVELS
        .iter()
        .map(|&l| {
            let f = features[l].clone();
            if f.dims()[2..] == [gh, gw] {
                return f;
            }
            let options =
                InterpolateOptions::new(InterpolateMode::Nearest).with_output_size([gh, gw]);
            interpolate(f, options)
        })
        .collect();
    Tensor::cat(maps, 1).reshape([n, token_channels(), gh * gw]).swap_dims(1, 2)
}
