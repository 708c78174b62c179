//! The InstanceSplat training objective, L = w_rgb·L_rgb + w_geom·L_geom + w_ins·L_ins +
//! w_sem·L_sem + w_bd·L_bd-rgb with the paper's weights (1, 1, 0.01, 0.02, 0.02) as defaults of
//! [`LossConfig`], which also carries every margin and the ablation switches. Each term is a
//! function of `Tensor`s in the layouts the network and the differentiable rasterizer produce
//! (`[V, C, H, W]` per view) plus ground truth read from the dataset on the host (instance ids
//! `[V][H][W]` with 0 = background, metric depth with 0 = no hit, cameras). Everything that
//! only depends on ground truth or on detached predictions (pixel grouping, weights, the
//! boundary map, the hard-negative factors) is computed on the host and enters the graph as a
//! constant; everything else stays differentiable.
//!
//! - [`rgb_loss`]: L_rgb = mean over views, channels and pixels of (Î − I)².
//! - [`geometry`]: L_geom = confidence-weighted depth + camera pose and field of view.
//! - [`instance`]: L_ins = 2·pull + 1·push + 2·cross on rendered instance features.
//! - [`semantic`]: L_sem = 1 − cos(Φ_sem(rendered semantic feature), MiniLM label embedding),
//!   or a contrastive form over the label vocabulary.
//! - [`boundary`]: L_bd-rgb, Charbonnier RGB error weighted by instance boundaries.

pub mod boundary;
pub mod geometry;
pub mod instance;
pub mod semantic;

use std::collections::HashMap;

use burn::prelude::*;
use serde::{Deserialize, Serialize};

pub use boundary::{boundary_rgb_loss, boundary_weights};
pub use geometry::{
    CameraTarget, camera_loss, camera_targets, depth_loss, depth_weights, geometry_loss,
    median_depth,
};
pub use instance::{InstanceTerms, instance_loss};
pub use semantic::{SemanticForm, semantic_loss};

/// Added under square roots of squared norms, so that zero vectors normalize to zero with a
/// finite gradient.
pub(crate) const NORM_EPS: f64 = 1e-8;

/// How the push term of L_ins weighs pairs of instances.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum HardNegatives {
    /// η = 1 + (η_max − 1)·clamp((cos_sem − τ_sem)/(1 − τ_sem), 0, 1): semantically similar
    /// instances (two chairs) are pushed apart harder. The paper's setting.
    SemanticWeighted,
    /// η ≡ 1 (ablation "no hard negatives").
    Uniform,
}

/// Whether L_ins has its cross-view consistency term.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum CrossView {
    On,
    /// Ablation "no cross-view term": cross is zero.
    Off,
}

/// Whether L_bd-rgb is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum BoundaryTerm {
    On,
    /// Ablation "no boundary loss": L_bd-rgb is zero.
    Off,
}

/// Whether the Gaussian parameter heads train. Read by the training loop, not by the losses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum GaussianTraining {
    Trained,
    /// Ablation "frozen 3DGS": the geometry and Gaussian heads keep their weights and only the
    /// instance and semantic heads learn.
    Frozen,
}

/// Weights, margins and ablation switches of the training objective.
#[derive(Config, Debug, PartialEq)]
pub struct LossConfig {
    /// w_rgb.
    #[config(default = 1.0)]
    pub rgb_weight: f64,
    /// w_geom.
    #[config(default = 1.0)]
    pub geometry_weight: f64,
    /// w_ins.
    #[config(default = 0.01)]
    pub instance_weight: f64,
    /// w_sem.
    #[config(default = 0.02)]
    pub semantic_weight: f64,
    /// τ of the contrastive L_sem (cross-entropy of cos/τ over the label vocabulary, balanced
    /// per instance); `None` (also what configs saved before this form existed read as) is the
    /// paper's per-pixel cosine.
    pub semantic_temperature: Option<f64>,
    /// Weight, inside L_ins, of L_ins on the network's own per-pixel embeddings of the input
    /// views (the Gaussians' S that inference clusters) beside L_ins on the renders. The paper
    /// (and 0) supervises renders only; rendering averages neighbouring Gaussians, so pixel-
    /// scale noise in S costs nothing there but scatters the clustered embeddings. `None`
    /// (also what configs saved before this term existed read as) means 0.
    pub direct_instance_weight: Option<f64>,
    /// L_sem on the furniture alone: the pixels of the room's shell (instances labelled
    /// `wall`, `floor` or `ceiling`) are left out of it, as the evaluation's scenes leave the
    /// shell unlabelled, while L_ins still separates the shell's instances. `None` (also what
    /// configs saved before this switch existed read as) names the shell too.
    pub semantic_objects_only: Option<bool>,
    /// w_bd.
    #[config(default = 0.02)]
    pub boundary_weight: f64,
    /// α of the confidence term −α·log(conf) of the depth loss (VGGT's value).
    #[config(default = 0.2)]
    pub depth_conf_alpha: f64,
    /// β of L_depth's pixel weights: 0 (and `None`, also what configs saved before this switch
    /// existed read as) weighs every valid pixel alike, 1 every instance alike (see
    /// [`geometry`]).
    pub depth_instance_balance: Option<f64>,
    /// Weight of the camera term inside L_geom (depth has weight 1).
    #[config(default = 1.0)]
    pub camera_weight: f64,
    /// Weight of pull inside L_ins.
    #[config(default = 2.0)]
    pub pull_weight: f64,
    /// Weight of push inside L_ins.
    #[config(default = 1.0)]
    pub push_weight: f64,
    /// Weight of cross inside L_ins.
    #[config(default = 2.0)]
    pub cross_weight: f64,
    /// δ_pull: cosine distance to the prototype below which a pixel is not pulled (pull and
    /// cross), i.e. cos ≥ 1 − δ_pull is good enough.
    #[config(default = 0.1)]
    pub pull_margin: f64,
    /// δ_push: cosine distance between two prototypes below which they are pushed apart; 1.0
    /// pushes until the prototypes are orthogonal.
    #[config(default = 1.0)]
    pub push_margin: f64,
    /// η_max: push weight of two instances with identical semantics.
    #[config(default = 3.0)]
    pub eta_max: f64,
    /// τ_sem: semantic cosine above which a pair starts to count as a hard negative.
    #[config(default = 0.5)]
    pub tau_sem: f64,
    /// Cosine distance at which the boundary weight is ½.
    #[config(default = 0.15)]
    pub boundary_threshold: f64,
    /// Temperature of the boundary sigmoid.
    #[config(default = 0.05)]
    pub boundary_temperature: f64,
    /// ε of the Charbonnier penalty sqrt(x² + ε²).
    #[config(default = 1e-3)]
    pub charbonnier_eps: f64,
    #[config(default = "HardNegatives::SemanticWeighted")]
    pub hard_negatives: HardNegatives,
    #[config(default = "CrossView::On")]
    pub cross_view: CrossView,
    #[config(default = "BoundaryTerm::On")]
    pub boundary: BoundaryTerm,
    #[config(default = "GaussianTraining::Trained")]
    pub gaussians: GaussianTraining,
}

/// The five terms of one step, each a one-element tensor, unweighted.
#[derive(Debug, Clone)]
pub struct LossTerms {
    pub rgb: Tensor<1>,
    pub geometry: Tensor<1>,
    /// Already combined as pull_weight·pull + push_weight·push + cross_weight·cross, on the
    /// renders, plus direct_instance_weight times the same on the input views' own embeddings.
    pub instance: Tensor<1>,
    /// On the renders.
    pub semantic: Tensor<1>,
    pub boundary: Tensor<1>,
}

impl LossConfig {
    /// L = w_rgb·L_rgb + w_geom·L_geom + w_ins·L_ins + w_sem·L_sem + w_bd·L_bd-rgb.
    pub fn total(&self, terms: &LossTerms) -> Tensor<1> {
        terms.rgb.clone().mul_scalar(self.rgb_weight)
            + terms.geometry.clone().mul_scalar(self.geometry_weight)
            + terms.instance.clone().mul_scalar(self.instance_weight)
            + terms.semantic.clone().mul_scalar(self.semantic_weight)
            + terms.boundary.clone().mul_scalar(self.boundary_weight)
    }
}

/// Inputs that do not fit together.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LossError {
    #[error("{what}: expected shape {expected:?}, got {got:?}")]
    Shape { what: &'static str, expected: Vec<usize>, got: Vec<usize> },
    #[error("{what} has {got} values, expected {expected}")]
    Length { what: &'static str, expected: usize, got: usize },
    #[error("instance id {id} has no row in the teacher table of {rows} rows")]
    TeacherRow { id: u32, rows: usize },
    #[error("could not read {what} back from the device: {message}")]
    Read { what: &'static str, message: String },
}

/// L_rgb = mean((rendered − target)²) over every element; both `[V, 3, H, W]`.
pub fn rgb_loss(rendered: Tensor<4>, target: Tensor<4>) -> Result<Tensor<1>, LossError> {
    check_dims("rgb target", &target.dims(), &rendered.dims())?;
    let diff = rendered - target;
    Ok((diff.clone() * diff).mean())
}

/// `[V, C, H, W]` → `[V·H·W, C]`, pixels in `[V][H][W]` order, like the instance ids.
pub(crate) fn pixels_last(x: Tensor<4>) -> Tensor<2> {
    let [v, c, h, w] = x.dims();
    x.permute([0, 2, 3, 1]).reshape([v * h * w, c])
}

/// Rows of `x` scaled to unit L2 norm (zero rows stay zero).
pub(crate) fn normalize_rows(x: Tensor<2>) -> Tensor<2> {
    let norm = (x.clone() * x.clone()).sum_dim(1).add_scalar(NORM_EPS).sqrt();
    x / norm
}

/// Unit vectors, pixel-major `[pixel][channel]`, of one view's channel-planar features
/// `[channel][pixel]` (zero vectors stay zero).
pub(crate) fn unit_pixel_vectors(planar: &[f32], channels: usize) -> Vec<f32> {
    let plane = planar.len() / channels.max(1);
    let mut unit = vec![0.0f32; plane * channels];
    for p in 0..plane {
        let value = |c: usize| f64::from(planar[c * plane + p]);
        let norm = ((0..channels).map(|c| value(c).powi(2)).sum::<f64>() + NORM_EPS).sqrt();
        for c in 0..channels {
            unit[p * channels + c] = (value(c) / norm) as f32;
        }
    }
    unit
}

/// How many of `ids` (the instance id of each pixel that counts) each instance has: the
/// |Ω_i| of the losses balanced per instance (L_sem, L_depth), whose pixels weigh
/// 1/(|Ω_i|·instances) so that a chair counts as much as the floor.
pub(crate) fn pixels_per_instance(ids: impl IntoIterator<Item = u32>) -> HashMap<u32, usize> {
    let mut counts = HashMap::new();
    for id in ids {
        *counts.entry(id).or_default() += 1;
    }
    counts
}

/// A constant float tensor of `shape` from host values.
pub(crate) fn constant<const D: usize>(
    values: Vec<f32>,
    shape: [usize; D],
    device: &Device,
) -> Tensor<D> {
    Tensor::from_data(TensorData::new(values, shape), device)
}

/// A constant `[len]` index tensor from host values.
pub(crate) fn indices(values: Vec<i64>, device: &Device) -> Tensor<1, Int> {
    let len = values.len();
    Tensor::from_data(TensorData::new(values, [len]), device)
}

/// The values of a float tensor on the host.
pub(crate) fn host<const D: usize>(
    what: &'static str,
    x: &Tensor<D>,
) -> Result<Vec<f32>, LossError> {
    x.to_data().try_to_vec::<f32>().map_err(|e| LossError::Read { what, message: format!("{e:?}") })
}

pub(crate) fn check_dims(
    what: &'static str,
    expected: &[usize],
    got: &[usize],
) -> Result<(), LossError> {
    if expected == got {
        Ok(())
    } else {
        Err(LossError::Shape { what, expected: expected.to_vec(), got: got.to_vec() })
    }
}

pub(crate) fn check_len(what: &'static str, expected: usize, got: usize) -> Result<(), LossError> {
    if expected == got { Ok(()) } else { Err(LossError::Length { what, expected, got }) }
}

pub(crate) fn zero(device: &Device) -> Tensor<1> {
    Tensor::zeros([1], device)
}
