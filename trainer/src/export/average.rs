//! Weight averaging (Izmailov et al., 2018, "Averaging Weights Leads to Wider Optima and
//! Better Generalization"): the mean of several networks of one shape, parameter by
//! parameter, written as a model file. The networks are checkpoints of one run late in its
//! schedule, whose mean may sit nearer the middle of the region they wander in than any one
//! of them (for the shipped network's recipe it did not score better: the history's "Tighter
//! instance groups and weight averaging"). `inssplat-train average` writes it into a copy of
//! a base file, whose metadata (the shape classifier) it keeps.

use std::collections::HashMap;
use std::path::Path;

use burn::store::ModuleSnapshot;
use burn::store::burn_pack::Tensor as PackTensor;
use burn::tensor::{Bytes, DType};

use super::ExportMeta;
use super::rewrite::{RewriteError, rewrite_file};
use crate::model::InsSplatNet;

/// Why networks could not be averaged.
#[derive(Debug, thiserror::Error)]
pub enum AverageError {
    #[error("no networks to average")]
    Empty,
    #[error("{name} has another shape than the base file's network: {problem}")]
    Shape { name: String, problem: String },
}

/// A parameter's shape and values.
type Parameter = (Vec<usize>, Vec<f32>);

/// Every parameter of `net` by its module path: shape and values.
fn parameters(net: &InsSplatNet) -> Result<HashMap<String, Parameter>, String> {
    net.collect(None, None, false)
        .into_iter()
        .map(|t| {
            let (name, dtype, shape, _, bytes) = t.into_parts().map_err(|e| format!("{e:?}"))?;
            if dtype != DType::F32 {
                return Err(format!("{name} is {dtype:?}, not f32"));
            }
            let values = bytes
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            Ok((name, (shape.as_slice().to_vec(), values)))
        })
        .collect()
}

/// `base` with every parameter replaced by the mean of that parameter over `nets` (named
/// `names`, for errors), which must all have `base`'s configuration.
pub fn average_networks(
    mut base: InsSplatNet,
    nets: &[InsSplatNet],
    names: &[String],
) -> Result<InsSplatNet, AverageError> {
    let first = nets.first().ok_or(AverageError::Empty)?;
    let shape_err =
        |index: usize, problem: String| AverageError::Shape { name: names[index].clone(), problem };
    let mut sum = parameters(first).map_err(|p| shape_err(0, p))?;
    for (index, net) in nets.iter().enumerate() {
        if net.config() != base.config() {
            return Err(shape_err(
                index,
                format!("{:?} against {:?}", net.config(), base.config()),
            ));
        }
        if index == 0 {
            continue;
        }
        for (name, (shape, values)) in parameters(net).map_err(|p| shape_err(index, p))? {
            let (s, acc) = sum
                .get_mut(&name)
                .ok_or_else(|| shape_err(index, format!("a parameter {name} the first lacks")))?;
            if *s != shape {
                return Err(shape_err(index, format!("{name}: shape {shape:?} against {s:?}")));
            }
            acc.iter_mut().zip(values).for_each(|(a, v)| *a += v);
        }
    }
    let k = nets.len() as f32;
    let tensors: Vec<PackTensor> = sum
        .into_iter()
        .map(|(name, (shape, values))| {
            let mean: Vec<f32> = values.into_iter().map(|v| v / k).collect();
            PackTensor::new(name, DType::F32, shape, None, Bytes::from_elems(mean))
        })
        .collect();
    let result = base.apply(tensors, None, None, false);
    if !result.errors.is_empty() || !result.missing.is_empty() {
        return Err(shape_err(
            0,
            format!("parameters missing {:?}, refused {:?}", result.missing, result.errors),
        ));
    }
    Ok(base)
}

/// Writes `base_file` to `output` with its network's weights the mean of `nets`' (named
/// `names`), its other metadata kept, `version` as its model version and `train_steps` as
/// its step count. Returns what `output` says about itself.
pub fn average_file(
    base_file: &Path,
    output: &Path,
    nets: &[InsSplatNet],
    names: &[String],
    version: &str,
    train_steps: u64,
) -> Result<ExportMeta, RewriteError> {
    rewrite_file(base_file, output, |base, meta| {
        let net = average_networks(base, nets, names)?;
        Ok((net, ExportMeta { model_version: version.to_string(), train_steps, ..meta }))
    })
}
