//! The InstanceSplat network, VGGT-style and sized to train on a small CPU: the images of N
//! views are cut into patches and embedded (or, with a pretrained image encoder, its
//! multi-scale features are: [`encoder`]); transformer layers alternate frame attention
//! (within one view) and global attention (across all views' tokens); a camera token per view
//! feeds the camera head, and a DPT-style dense decoder turns several layers' patch tokens
//! into full-resolution maps: depth and confidence, per-pixel Gaussian parameters, the compact
//! semantic feature L and the instance embedding S. The output activations produce exactly
//! the model I/O signature of `inssplat_proto::signature`, so the ONNX graph written by
//! [`crate::export`] (which walks these same modules) needs no post-processing.
//!
//! burn 0.22 tensors carry their backend in their [`Device`] (no backend type parameter):
//! the same model runs on `Device::flex()` for inference and export, on
//! `Device::flex().autodiff()` for training, or on a GPU device.

mod block;
mod decoder;
pub mod efficientnet;
pub mod encoder;
mod flops;
mod gelu;
use inssplat_proto::rays;

use burn::module::Param;
use burn::nn::{Initializer, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::module::interpolate;
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
use efficientnet::EfficientNetLite0;
use inssplat_proto::signature::TEXT_DIM;

pub use block::{Block, KeyPooling, LN_EPS};
pub use decoder::{
    CameraHead, DenseDecoder, DenseOutput, GAUSSIAN_AFFINE_CHANNELS, OUT_DEPTH, OUT_GAUSSIANS,
    OUT_INSTANCE, SH_C0, Skip, Stage, gaussian_affine,
};
pub use encoder::Encoder;
pub use gelu::gelu;

/// Shape and output-scaling hyper-parameters of the network. Configurations saved with the
/// heads of experiments since removed (`point_head`, `descriptor_head`; `null` in every file
/// shipped) read without them: unknown keys are ignored.
#[derive(Config, Debug, PartialEq)]
pub struct ModelConfig {
    /// Square input resolution in pixels (H = W); a multiple of `patch`.
    #[config(default = 128)]
    pub image_size: usize,
    /// Patch side in pixels; a power of two (the decoder upsamples by 2 per stage).
    #[config(default = 8)]
    pub patch: usize,
    /// Token width.
    #[config(default = 192)]
    pub dim: usize,
    /// Transformer layers, alternating frame then global attention; even.
    #[config(default = 6)]
    pub depth: usize,
    #[config(default = 3)]
    pub heads: usize,
    #[config(default = 4)]
    pub mlp_ratio: usize,
    /// Channels of the dense decoder at token resolution; halved per upsampling stage.
    #[config(default = 128)]
    pub decoder_dim: usize,
    /// Lower bound on decoder channels at the finer stages.
    #[config(default = 32)]
    pub decoder_min_dim: usize,
    /// Width d_s of the compact semantic feature L.
    #[config(default = 16)]
    pub sem_dim: usize,
    /// depth = depth_scale · softplus(raw), metres.
    #[config(default = 2.0)]
    pub depth_scale: f64,
    /// Gaussian offset xyz = offset_scale · raw, metres.
    #[config(default = 0.05)]
    pub offset_scale: f64,
    /// Added to the raw log-scales (≈ log of one pixel's footprint at room distance).
    #[config(default = -3.5)]
    pub log_scale_bias: f64,
    /// fov = 2 · fov_base · sigmoid(raw), radians: fov_base at raw = 0.
    #[config(default = 1.0)]
    pub fov_base: f64,
    /// Channels of the image encoder at full resolution (doubled at each halving, at most
    /// `decoder_dim`), whose features reach every decoder stage through a skip; `None`: no
    /// image encoder, the image enters the decoder only through one 1×1 layer at full
    /// resolution (the architecture of the 0.5 release and earlier, whose files lack the key).
    pub image_skips: Option<usize>,
    /// Side of the square of patch tokens whose keys and values the global layers average
    /// into one (the spatial-reduction attention of PVT, without its learned reduction):
    /// every token still asks its query, but of each view it reads the camera token and
    /// (grid / p)² pooled patch keys, so the global attention costs p² times less. The
    /// frame layers read every token. `None` (also what files saved before it existed read
    /// as): every token.
    pub global_kv_pool: Option<usize>,
    /// Rays a patch side of the cameras given as input ([`rays`]): k × k Plücker rays of
    /// each patch, in view 0's frame, added to its token through a layer without bias that
    /// starts at zero (so a network grown with it computes what it did, and zero rays
    /// always compute what it does without them). `None` (also what files saved
    /// before it existed read as): the network sees the images alone.
    pub camera_rays: Option<usize>,
    /// The pretrained image encoder the network is built around ([`encoder`]): the tokens
    /// embed its features on the stride-8 grid (so the patch is 8), and its stride-2 and
    /// stride-4 features join the decoder. Its weights come from its own file
    /// ([`InsSplatNet::with_pretrained_encoder`]). `None` (also what files saved before it
    /// existed read as): the tokens embed 8×8 pixel patches.
    pub encoder: Option<Encoder>,
}

impl ModelConfig {
    /// Patches per side.
    pub fn grid(&self) -> usize {
        self.image_size / self.patch
    }

    /// What the input's height and width must be multiples of: the patch, times the pooled
    /// square's side with [`ModelConfig::global_kv_pool`], and the encoder's deepest stride
    /// with [`ModelConfig::encoder`].
    pub fn size_multiple(&self) -> usize {
        let tokens = self.patch * self.global_kv_pool.unwrap_or(1);
        match self.encoder {
            Some(_) => least_common_multiple(tokens, encoder::SIZE_MULTIPLE),
            None => tokens,
        }
    }

    /// Channels of a token before its embedding: a patch's pixels, or the encoder's features.
    pub fn token_channels(&self) -> usize {
        match self.encoder {
            Some(_) => encoder::token_channels(),
            None => 3 * self.patch * self.patch,
        }
    }

    /// Upsampling stages of the decoder (log2 of the patch size).
    pub fn stages(&self) -> usize {
        self.patch.trailing_zeros() as usize
    }

    /// Decoder channels at stage `s` (0 = token resolution, `stages()` = full resolution).
    pub fn decoder_channels(&self, s: usize) -> usize {
        (self.decoder_dim >> s).max(self.decoder_min_dim)
    }

    /// Channels of the image encoder's features at `level` (0 = full resolution, each level
    /// half the last), `None` without an image encoder.
    pub fn skip_channels(&self, level: usize) -> Option<usize> {
        self.image_skips.map(|k| (k << level).min(self.decoder_dim))
    }

    /// Checks the constraints the architecture relies on.
    pub fn validate(&self) -> Result<(), ModelError> {
        let bad = |what: String| Err(ModelError::Config(what));
        if !self.patch.is_power_of_two() || self.patch < 2 {
            return bad(format!("patch {} must be a power of two ≥ 2", self.patch));
        }
        if self.image_size == 0 || !self.image_size.is_multiple_of(self.patch) {
            return bad(format!(
                "image_size {} must be a positive multiple of patch {}",
                self.image_size, self.patch
            ));
        }
        if self.depth == 0 || !self.depth.is_multiple_of(2) {
            return bad(format!(
                "depth {} must be even and positive (frame/global pairs)",
                self.depth
            ));
        }
        if self.heads == 0 || !self.dim.is_multiple_of(self.heads) {
            return bad(format!("dim {} must be a multiple of heads {}", self.dim, self.heads));
        }
        if self.sem_dim == 0
            || self.decoder_min_dim == 0
            || self.mlp_ratio == 0
            || self.image_skips == Some(0)
            || self.camera_rays == Some(0)
        {
            return bad(
                "sem_dim, decoder_min_dim, mlp_ratio, image_skips and camera_rays must be positive"
                    .into(),
            );
        }
        if self.encoder.is_some() {
            if self.patch != encoder::TOKEN_STRIDE || self.image_skips.is_some() {
                return bad(format!(
                    "an encoder makes the tokens on its stride-{} grid, with its own skips: patch must be {0}, and image_skips unset",
                    encoder::TOKEN_STRIDE
                ));
            }
            if !self.image_size.is_multiple_of(encoder::SIZE_MULTIPLE) {
                return bad(format!(
                    "image_size {} must be a multiple of the encoder's {}",
                    self.image_size,
                    encoder::SIZE_MULTIPLE
                ));
            }
        }
        if let Some(p) = self.global_kv_pool
            && (p < 2 || !self.grid().is_multiple_of(p))
        {
            return bad(format!(
                "global_kv_pool {p} must be ≥ 2 and divide the {} patches a side",
                self.grid()
            ));
        }
        Ok(())
    }

    /// Builds a freshly initialised network on `device`.
    pub fn init(&self, device: &Device) -> Result<InsSplatNet, ModelError> {
        self.validate()?;
        let tokens = self.grid() * self.grid();
        let small = Initializer::Normal { mean: 0.0, std: 0.02 };
        Ok(InsSplatNet {
            encoder: self.encoder.map(|_| EfficientNetLite0::folded(device)),
            patch_embed: LinearConfig::new(self.token_channels(), self.dim).init(device),
            pos_embed: small.init([tokens, self.dim], device),
            camera_tokens: small.init([2, self.dim], device),
            reference_embed: small.init([1, self.dim], device),
            blocks: (0..self.depth)
                .map(|_| Block::new(self.dim, self.heads, self.mlp_ratio, device))
                .collect(),
            camera_head: CameraHead::new(self.dim, device),
            decoder: DenseDecoder::new(self, device),
            sem_proj: LinearConfig::new(self.sem_dim, TEXT_DIM).init(device),
            ray_embed: self.camera_rays.map(|k| {
                // No bias: zero rays add nothing to a token however the layer trains, so the
                // pipeline's first pass (every ray zero) runs the network as it is without rays.
                LinearConfig::new(rays::ray_channels(k), self.dim)
                    .with_bias(false)
                    .with_initializer(Initializer::Zeros)
                    .init(device)
            }),
            config: self.clone(),
        })
    }
}

fn least_common_multiple(a: usize, b: usize) -> usize {
    let (mut x, mut y) = (a, b);
    while y != 0 {
        (x, y) = (y, x % y);
    }
    a / x * b
}

/// Errors of building or running the network.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("invalid model configuration: {0}")]
    Config(String),
    #[error(
        "images must be [N, 3, H, W] with N ≥ 1 and H, W positive multiples of {multiple}, got {got:?}"
    )]
    InputShape { multiple: usize, got: [usize; 4] },
    #[error("camera rays: {0}")]
    Rays(String),
}

/// The network. Fields are crate-visible so that [`crate::export`] can walk them.
#[derive(Module, Debug)]
pub struct InsSplatNet {
    /// The pretrained image encoder, folded ([`EfficientNetLite0::fold`]), with
    /// [`ModelConfig::encoder`].
    pub(crate) encoder: Option<EfficientNetLite0>,
    /// Patch embedding: a linear map of each flattened (channel, row, column) patch, or of
    /// the encoder's features at each token ([`encoder::tokens`]).
    pub(crate) patch_embed: Linear,
    /// Learned position embedding, `[tokens, dim]` of the square grid at `image_size`;
    /// interpolated to other grids ([`InsSplatNet::position_embedding`]).
    pub(crate) pos_embed: Param<Tensor<2>>,
    /// Camera token of the reference view (row 0) and of every other view (row 1).
    pub(crate) camera_tokens: Param<Tensor<2>>,
    /// Added to the reference view's patch tokens, `[1, dim]`.
    pub(crate) reference_embed: Param<Tensor<2>>,
    /// Even indices attend within a view, odd ones across views.
    pub(crate) blocks: Vec<Block>,
    pub(crate) camera_head: CameraHead,
    pub(crate) decoder: DenseDecoder,
    /// Φ_sem: compact semantic feature L (d_s) → text space (384).
    pub(crate) sem_proj: Linear,
    /// Camera rays → token, only with [`ModelConfig::camera_rays`].
    pub(crate) ray_embed: Option<Linear>,
    #[module(skip)]
    pub(crate) config: ModelConfig,
}

/// Everything one forward pass predicts, shaped as in the model I/O signature.
#[derive(Debug, Clone)]
pub struct ModelOutput {
    /// `[N, 9]`: translation (3), rotation w,x,y,z (4), fov_y, fov_x; view 0 is the identity.
    pub camera: Tensor<2>,
    /// `[N, 1, H, W]`, metres, > 0.
    pub depth: Tensor<4>,
    /// `[N, 1, H, W]`, > 1.
    pub depth_conf: Tensor<4>,
    /// `[N, 14, H, W]`: offset, log-scale, rotation, opacity logit, SH DC colour.
    pub gaussians: Tensor<4>,
    /// `[N, 8, H, W]`: instance embedding S.
    pub instance: Tensor<4>,
    /// `[N, d_s, H, W]`: compact semantic feature L.
    pub semantic: Tensor<4>,
}

impl InsSplatNet {
    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// The same weights with the global layers' keys and values pooled `pool` × `pool`
    /// ([`ModelConfig::global_kv_pool`]; `None`: every token).
    pub fn with_global_kv_pool(mut self, pool: Option<usize>) -> Result<Self, ModelError> {
        let config = self.config.clone().with_global_kv_pool(pool);
        config.validate()?;
        self.config = config;
        Ok(self)
    }

    /// Φ_sem as the signature lays it out: weight `[384, d_s]` and bias `[384]`
    /// (text-space feature = W·L + b).
    pub fn sem_proj(&self) -> (Tensor<2>, Tensor<1>) {
        let weight = self.sem_proj.weight.val().transpose();
        let bias = self.sem_proj.bias.as_ref().expect("Φ_sem has a bias").val();
        (weight, bias)
    }

    /// Maps compact semantic features `[.., d_s]` (channels last) to the text space.
    pub fn project_semantic<const D: usize>(&self, features: Tensor<D>) -> Tensor<D> {
        self.sem_proj.forward(features)
    }

    /// The position embedding of a `gh` × `gw` patch grid, `[gh·gw, dim]`: the learned one at
    /// its own square grid, else that one resampled bilinearly (half-pixel centres, as ONNX
    /// `Resize` in linear mode), as ViTs take other input sizes.
    pub fn position_embedding(&self, gh: usize, gw: usize) -> Tensor<2> {
        let (g, d) = (self.config.grid(), self.config.dim);
        let pos = self.pos_embed.val();
        if (gh, gw) == (g, g) {
            return pos;
        }
        let square = pos.reshape([1, g, g, d]).permute([0, 3, 1, 2]);
        let options = InterpolateOptions::new(InterpolateMode::Bilinear)
            .with_align_corners(false)
            .with_output_size([gh, gw]);
        interpolate(square, options).permute([0, 2, 3, 1]).reshape([gh * gw, d])
    }

    /// The same network with the encoder's weights read from its file (the PyTorch file of
    /// `scripts/setup`, `INSSPLAT_ENCODER_WEIGHTS`), folded.
    pub fn with_pretrained_encoder(mut self, path: &std::path::Path) -> anyhow::Result<Self> {
        anyhow::ensure!(self.encoder.is_some(), "this network has no image encoder");
        let device = self.patch_embed.weight.device();
        self.encoder = Some(EfficientNetLite0::load(path, &device)?.fold());
        Ok(self)
    }

    /// The image encoder, with [`ModelConfig::encoder`].
    pub fn encoder(&self) -> Option<&EfficientNetLite0> {
        self.encoder.as_ref()
    }

    /// The same network with the encoder's weights frozen (no gradient; a no-op without one).
    pub fn freeze_encoder(mut self) -> Self {
        self.encoder = self.encoder.map(Module::freeze);
        self
    }

    /// Token embedding: `[N, 3, H, W]` images in [0, 1], or the encoder's `features` of them
    /// (and the views' camera rays, with [`ModelConfig::camera_rays`]) → `[N, 1 + tokens,
    /// dim]`, camera token first, reference embedding on view 0.
    fn embed(
        &self,
        images: Tensor<4>,
        features: Option<&[Tensor<4>]>,
        rays: Option<Tensor<3>>,
    ) -> Tensor<3> {
        let p = self.config.patch;
        let [n, _, h, w] = images.dims();
        let (gh, gw) = (h / p, w / p);
        let patches = match features {
            Some(features) => encoder::tokens(features),
            None => (images - 0.5)
                .reshape([n, 3, gh, p, gw, p])
                .permute([0, 2, 4, 1, 3, 5])
                .reshape([n, gh * gw, 3 * p * p]),
        };
        let mut x =
            self.patch_embed.forward(patches) + self.position_embedding(gh, gw).unsqueeze_dim(0);
        if let (Some(embed), Some(rays)) = (&self.ray_embed, rays) {
            x = x + embed.forward(rays);
        }
        let cams = self.camera_tokens.val();
        let first = Tensor::cat(
            vec![
                cams.clone().narrow(0, 0, 1).unsqueeze_dim(0),
                x.clone().narrow(0, 0, 1) + self.reference_embed.val().unsqueeze_dim(0),
            ],
            1,
        );
        if n == 1 {
            return first;
        }
        let rest_cam = cams.narrow(0, 1, 1).unsqueeze_dim::<3>(0).repeat_dim(0, n - 1);
        let rest = Tensor::cat(vec![rest_cam, x.narrow(0, 1, n - 1)], 1);
        Tensor::cat(vec![first, rest], 0)
    }

    /// The forward pass. `images`: `[N, 3, H, W]`, RGB in [0, 1], N ≥ 1, H and W multiples of
    /// [`ModelConfig::size_multiple`] (trained at `image_size` square; other sizes read
    /// the position embedding resampled).
    pub fn forward(&self, images: Tensor<4>) -> Result<ModelOutput, ModelError> {
        self.forward_with_rays(images, None)
    }

    /// The forward pass of a network that also reads the cameras: `rays` `[N, tokens,
    /// 6·k²]` from [`rays::patch_rays`], required with [`ModelConfig::camera_rays`] and
    /// refused without it.
    pub fn forward_with_rays(
        &self,
        images: Tensor<4>,
        rays: Option<Tensor<3>>,
    ) -> Result<ModelOutput, ModelError> {
        let c = &self.config;
        let dims = images.dims();
        let m = c.size_multiple();
        let fits = |side: usize| side > 0 && side.is_multiple_of(m);
        if dims[0] == 0 || dims[1] != 3 || !fits(dims[2]) || !fits(dims[3]) {
            return Err(ModelError::InputShape { multiple: m, got: dims });
        }
        let n = dims[0];
        let grid = [dims[2] / c.patch, dims[3] / c.patch];
        let tokens = grid[0] * grid[1];
        let expected = c.camera_rays.map(|k| [n, tokens, rays::ray_channels(k)]);
        let got = rays.as_ref().map(|r| r.dims());
        if got != expected {
            return Err(ModelError::Rays(match expected {
                Some(shape) => format!(
                    "this network reads its cameras as rays {shape:?}, given {}",
                    got.map_or("none".into(), |g| format!("{g:?}"))
                ),
                None => "this network reads no camera rays, and some were given".into(),
            }));
        }
        let features = self.encoder.as_ref().map(|e| e.features(images.clone()));
        let mut x = self.embed(images.clone(), features.as_deref(), rays);
        let [_, s, d] = x.dims();
        let mut levels = Vec::with_capacity(c.depth / 2);
        let pooling = c.global_kv_pool.map(|pool| KeyPooling { views: n, grid, pool });
        for (i, block) in self.blocks.iter().enumerate() {
            if i % 2 == 0 {
                x = block.forward(x);
            } else {
                x = block.forward_pooled(x.reshape([1, n * s, d]), pooling).reshape([n, s, d]);
                levels.push(x.clone().slice([0..n, 1..s]));
            }
        }
        let camera = self.camera_head.forward(x.slice([0..n, 0..1]).reshape([n, d]), c);
        let skips = features.map(|mut f| {
            f.truncate(encoder::SKIP_LEVELS);
            f
        });
        let dense = self.decoder.forward(levels, images, skips.unwrap_or_default(), c);
        Ok(ModelOutput {
            camera,
            depth: dense.depth,
            depth_conf: dense.depth_conf,
            gaussians: dense.gaussians,
            instance: dense.instance,
            semantic: dense.semantic,
        })
    }

    /// Analytic FLOP count of one forward pass at `views` views (multiply-add = 2 FLOPs).
    pub fn forward_flops(&self, views: usize) -> u64 {
        flops::forward_flops(&self.config, views)
    }
}
