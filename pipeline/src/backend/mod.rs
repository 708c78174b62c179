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

    /// Runs the network on `views` images, `images` planar `[views][3][res][res]` in [0, 1],
    /// and their cameras' `rays` ([`RayInput`]), which a network with the `rays` input needs
    /// and one without refuses.
    fn run(
        &mut self,
        images: &[f32],
        views: usize,
        rays: Option<&[f32]>,
    ) -> Result<ModelOutput, RuntimeError>;
}

/// What a loaded network is.
#[derive(Debug, Clone)]
pub struct Network {
    /// Input size (square) in pixels.
    pub resolution: usize,
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

/// The optional `rays` input ([`signature::INPUT_RAYS`]): each view's `tokens` patches get
/// `k` × `k` rays ([`inssplat_proto::rays::patch_rays`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RayInput {
    pub tokens: usize,
    pub k: usize,
}

impl RayInput {
    /// Of a `rays` input of `shape` `[N, T, 6·k²]` for a square grid of T patches.
    pub(crate) fn of_shape(
        path: &std::path::Path,
        shape: &[i64],
        resolution: usize,
    ) -> Result<Self, RuntimeError> {
        let err = |problem: String| RuntimeError::Signature {
            path: path.to_path_buf(),
            tensor: signature::INPUT_RAYS.name.into(),
            problem,
        };
        let [_, t, c] = *shape else {
            return Err(err(format!("shape {shape:?}, expected {}", signature::INPUT_RAYS.shape)));
        };
        let side = (t.max(0) as f64).sqrt().round() as usize;
        let k = ((c.max(0) / 6) as f64).sqrt().round() as usize;
        if side == 0
            || side * side != t as usize
            || !resolution.is_multiple_of(side)
            || k == 0
            || inssplat_proto::rays::ray_channels(k) != c as usize
        {
            return Err(err(format!(
                "shape {shape:?}: expected [N, T, 6·K²] with T a square number of patches that tile {resolution}²"
            )));
        }
        Ok(Self { tokens: t as usize, k })
    }

    /// Pixels on a side of one patch at `resolution`.
    pub fn patch(&self, resolution: usize) -> usize {
        resolution / (self.tokens as f64).sqrt().round() as usize
    }

    /// Values of the input for `views` views.
    pub fn values(&self, views: usize) -> usize {
        views * self.tokens * inssplat_proto::rays::ray_channels(self.k)
    }
}

/// `threads`, else every core this process may use.
pub fn threads_or_all(threads: Option<usize>) -> usize {
    threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, usize::from))
}
