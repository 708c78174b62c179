//! The network behind the pipeline: the [`Backend`] trait (what a network is, [`Network`], and
//! one forward pass over a batch of views into planar arrays, [`ModelOutput`]). ONNX Runtime
//! ([`onnx`]) is the one backend today; a second runtime, or a test double that gives known
//! network outputs, is one impl of the trait.

pub mod onnx;

use std::path::PathBuf;

use inssplat_proto::shape::ShapeClassifier;
use inssplat_proto::signature;

pub use onnx::Model;

/// A network the pipeline runs.
pub trait Backend {
    /// What the network is: its input size, version and optional heads and inputs.
    fn network(&self) -> &Network;

    /// Runs the network on `views` images of `size` (height, width; one the network takes,
    /// [`Network::takes`]), `images` planar `[views][3][height][width]` in [0, 1], and their
    /// cameras' `rays` ([`RayInput`]), which a network with the `rays` input needs and one
    /// without refuses.
    fn run(
        &mut self,
        images: &[f32],
        views: usize,
        size: [usize; 2],
        rays: Option<&[f32]>,
    ) -> Result<ModelOutput, RuntimeError>;
}

/// What a loaded network is.
#[derive(Debug, Clone)]
pub struct Network {
    /// Side of the square input it was trained at, in pixels: the long side of every input.
    pub resolution: usize,
    /// What else it takes: inputs whose sides are multiples of this (no longer than
    /// `resolution`); `None`: the square only.
    pub size_multiple: Option<usize>,
    pub sem_dim: usize,
    pub model_version: String,
    /// The shape classifier stored with the network, if the file carries one.
    pub shapes: Option<ShapeClassifier>,
    /// The camera rays the network reads, when it has the optional `rays` input.
    pub rays: Option<RayInput>,
}

#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    #[error(
        "ONNX Runtime library not found: set ORT_DYLIB_PATH (unset or missing) or run scripts/setup, which puts it under {default}"
    )]
    LibraryMissing { default: String },
    #[error("cannot load ONNX Runtime from {path}: {message}")]
    Library { path: PathBuf, message: String },
    #[error("model file {path} not found")]
    ModelMissing { path: PathBuf },
    #[error(
        "keypoint matcher file {path} not found: pass --matcher DIR (a folder with xfeat.onnx and lighterglue.onnx, as models/matcher) or --brief-matches"
    )]
    MatcherMissing { path: PathBuf },
    #[error(
        "object detector file {path} not found: pass --detector DIR (a folder with nanodet_g_416.onnx and coco80.txt, as models/detector) or --no-detector"
    )]
    DetectorMissing { path: PathBuf },
    #[error("cannot load model {path}: {message}")]
    Load { path: PathBuf, message: String },
    #[error("model {path}: tensor `{tensor}`: {problem}")]
    Signature { path: PathBuf, tensor: String, problem: String },
    #[error("model {path}: metadata `{key}`: {problem}")]
    Metadata { path: PathBuf, key: &'static str, problem: String },
    #[error("inference failed: {0}")]
    Run(String),
}

/// The network's outputs for N views, each planar `[N][C][H][W]` (camera `[N][9]`).
#[derive(Debug, Clone)]
pub struct ModelOutput {
    pub views: usize,
    pub height: usize,
    pub width: usize,
    pub sem_dim: usize,
    pub camera: Vec<f32>,
    pub depth: Vec<f32>,
    pub depth_conf: Vec<f32>,
    pub gaussians: Vec<f32>,
    pub instance: Vec<f32>,
    pub semantic: Vec<f32>,
    /// Φ_sem, `[384][d_s]` row-major, and its bias `[384]`.
    pub sem_proj_weight: Vec<f32>,
    pub sem_proj_bias: Vec<f32>,
}

impl Network {
    /// Whether it takes an input of `size` (height, width).
    pub fn takes(&self, [h, w]: [usize; 2]) -> bool {
        let r = self.resolution;
        match self.size_multiple {
            None => h == r && w == r,
            Some(m) => [h, w].iter().all(|&s| s > 0 && s <= r && s.is_multiple_of(m)),
        }
    }
}

/// The optional `rays` input ([`signature::INPUT_RAYS`]): each patch of `patch` pixels a side
/// gets `k` × `k` rays ([`inssplat_proto::rays::patch_rays`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RayInput {
    pub patch: usize,
    pub k: usize,
}

impl RayInput {
    /// Of a `rays` input of `shape` `[N, T, 6·k²]`: the patch side is `patch` (the file's
    /// [`signature::META_PATCH`]) when it has one, else that of a square grid of T patches
    /// tiling the `resolution`² input.
    pub(crate) fn of_shape(
        path: &std::path::Path,
        shape: &[i64],
        resolution: usize,
        patch: Option<usize>,
    ) -> Result<Self, RuntimeError> {
        let err = |problem: String| RuntimeError::Signature {
            path: path.to_path_buf(),
            tensor: signature::INPUT_RAYS.name.into(),
            problem,
        };
        let [_, t, c] = *shape else {
            return Err(err(format!("shape {shape:?}, expected {}", signature::INPUT_RAYS.shape)));
        };
        let k = ((c.max(0) / 6) as f64).sqrt().round() as usize;
        let side = (t.max(0) as f64).sqrt().round() as usize;
        let patch = match patch {
            Some(p) if p > 0 && resolution.is_multiple_of(p) => Some(p),
            Some(_) => None,
            None if side > 0 && side * side == t as usize && resolution.is_multiple_of(side) => {
                Some(resolution / side)
            }
            None => None,
        };
        match patch {
            Some(patch) if k > 0 && inssplat_proto::rays::ray_channels(k) == c as usize => {
                Ok(Self { patch, k })
            }
            _ => Err(err(format!(
                "shape {shape:?}: expected [N, T, 6·K²] with T the patches that tile {resolution}² (or the file's `{}` patch side)",
                signature::META_PATCH
            ))),
        }
    }

    /// Values of the input for `views` views of `size` (height, width).
    pub fn values(&self, views: usize, [h, w]: [usize; 2]) -> usize {
        views * self.tokens([h, w]) * inssplat_proto::rays::ray_channels(self.k)
    }

    /// Patches of an input of `size` (height, width).
    pub fn tokens(&self, [h, w]: [usize; 2]) -> usize {
        (h / self.patch) * (w / self.patch)
    }
}

/// `threads`, else every core this process may use.
pub fn threads_or_all(threads: Option<usize>) -> usize {
    threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, usize::from))
}
