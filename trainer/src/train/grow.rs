//! Growing a trained network into a larger shape that starts by computing exactly what it
//! did: an image encoder and ray layers joined at zero, wider MLPs
//! whose new hidden units write through zeros, and a wider semantic feature whose new channels
//! Φ_sem reads through zeros. `--init-from` fine-tunes start from here.

use burn::module::Param;
use burn::prelude::*;
use burn::store::ModuleSnapshot;

use inssplat_proto::signature::TEXT_DIM;

use super::{TrainError, seeded_init};
use crate::model::{InsSplatNet, ModelConfig, OUT_DEPTH, OUT_GAUSSIANS};

/// `net` grown to `shape`, which may add an image encoder
/// ([`crate::model::ModelConfig::image_skips`]) or camera rays
/// ([`crate::model::ModelConfig::camera_rays`]) that `net` lacks: every weight of `net` is
/// kept and the new parts are drawn from `seed`. The image encoder and the rays join through
/// layers that start at zero, so the grown network computes exactly what `net` did. A larger
/// [`crate::model::ModelConfig::mlp_ratio`] widens
/// every block's MLP the same way (Net2Net's function-preserving widening, with zeros in
/// place of its split weights): the new hidden units read the tokens through fresh weights
/// and write nothing until training moves their output weights, which start at zero. A larger
/// [`crate::model::ModelConfig::sem_dim`] adds semantic channels the same way: the output
/// layer's new rows are drawn from `seed` and Φ_sem reads them through zeros, so the text-space
/// feature, which every loss and the pipeline's names read, is what it was.
pub fn grow(
    net: &InsSplatNet,
    shape: ModelConfig,
    seed: u64,
    device: &Device,
) -> Result<InsSplatNet, TrainError> {
    let mut widened = None;
    if shape.mlp_ratio != net.config().mlp_ratio {
        widened = Some(widen_mlps(net, shape.mlp_ratio, seed, device)?);
    }
    if shape.sem_dim != net.config().sem_dim {
        widened =
            Some(widen_semantic(widened.as_ref().unwrap_or(net), shape.sem_dim, seed, device)?);
    }
    let net = widened.as_ref().unwrap_or(net);
    let old = net.config();
    let mut new_parts = Vec::new();
    if old.image_skips.is_none() && shape.image_skips.is_some() {
        new_parts.push("decoder.skips.");
    }
    if old.camera_rays.is_none() && shape.camera_rays.is_some() {
        new_parts.push("ray_embed.");
    }
    let mut grown =
        seeded_init(&shape, seed, device).map_err(|e| TrainError::Config(e.to_string()))?;
    let result = grown.apply(net.collect(None, None, false), None, None, false);
    let kept_all =
        result.missing.iter().all(|(path, _)| new_parts.iter().any(|part| path.starts_with(part)))
            && result.unused.is_empty();
    if !result.errors.is_empty() || !kept_all {
        return Err(TrainError::Config(format!(
            "growing {old:?} to {shape:?}: tensors missing {:?}, unused {:?}, errors {:?}",
            result.missing, result.unused, result.errors
        )));
    }
    Ok(grown)
}

/// `net` with every block's MLP `ratio` times the token width: the old hidden units keep their
/// weights, the new ones read through weights drawn from `seed` and write through zeros.
fn widen_mlps(
    net: &InsSplatNet,
    ratio: usize,
    seed: u64,
    device: &Device,
) -> Result<InsSplatNet, TrainError> {
    let old = net.config();
    if ratio < old.mlp_ratio {
        return Err(TrainError::Config(format!(
            "the MLP of {} × the width cannot narrow to {ratio} ×",
            old.mlp_ratio
        )));
    }
    let shape = old.clone().with_mlp_ratio(ratio);
    let fresh = seeded_init(&shape, seed, device).map_err(|e| TrainError::Config(e.to_string()))?;
    let (dim, hidden, added) =
        (old.dim, old.mlp_ratio * old.dim, (ratio - old.mlp_ratio) * old.dim);
    let mut grown = net.clone();
    for (block, new) in grown.blocks.iter_mut().zip(&fresh.blocks) {
        let reads = new.fc1.weight.val().narrow(1, hidden, added);
        block.fc1.weight =
            Param::from_tensor(Tensor::cat(vec![block.fc1.weight.val(), reads], 1).detach());
        if let (Some(bias), Some(new_bias)) = (&block.fc1.bias, &new.fc1.bias) {
            let extra = new_bias.val().narrow(0, hidden, added);
            block.fc1.bias =
                Some(Param::from_tensor(Tensor::cat(vec![bias.val(), extra], 0).detach()));
        }
        let writes = Tensor::zeros([added, dim], device);
        block.fc2.weight =
            Param::from_tensor(Tensor::cat(vec![block.fc2.weight.val(), writes], 0).detach());
    }
    grown.config = shape;
    Ok(grown)
}

/// `net` with a semantic feature of `sem_dim` channels: the fused output layer gains rows drawn
/// from `seed` after the old semantic ones, and Φ_sem reads them through zeros.
fn widen_semantic(
    net: &InsSplatNet,
    sem_dim: usize,
    seed: u64,
    device: &Device,
) -> Result<InsSplatNet, TrainError> {
    let old = net.config();
    if sem_dim < old.sem_dim {
        return Err(TrainError::Config(format!(
            "the semantic feature of {} channels cannot narrow to {sem_dim}",
            old.sem_dim
        )));
    }
    let shape = old.clone().with_sem_dim(sem_dim);
    let fresh = seeded_init(&shape, seed, device).map_err(|e| TrainError::Config(e.to_string()))?;
    let (at, added) = (OUT_DEPTH + OUT_GAUSSIANS + old.sem_dim, sem_dim - old.sem_dim);
    let mut grown = net.clone();
    let out = &mut grown.decoder.out;
    out.weight = Param::from_tensor(insert_rows(
        out.weight.val(),
        fresh.decoder.out.weight.val(),
        at,
        added,
    ));
    if let (Some(bias), Some(new_bias)) = (&out.bias, &fresh.decoder.out.bias) {
        out.bias = Some(Param::from_tensor(insert_rows(bias.val(), new_bias.val(), at, added)));
    }
    let reads = Tensor::zeros([added, TEXT_DIM], device);
    grown.sem_proj.weight =
        Param::from_tensor(Tensor::cat(vec![grown.sem_proj.weight.val(), reads], 0).detach());
    grown.config = shape;
    Ok(grown)
}

/// `old` with rows `at..at + added` of `new` inserted before its row `at`.
fn insert_rows<const D: usize>(
    old: Tensor<D>,
    new: Tensor<D>,
    at: usize,
    added: usize,
) -> Tensor<D> {
    let rest = old.dims()[0] - at;
    Tensor::cat(
        vec![old.clone().narrow(0, 0, at), new.narrow(0, at, added), old.narrow(0, at, rest)],
        0,
    )
    .detach()
}
