//! Reads an exported ONNX file back into a network, the inverse of [`super::export_onnx`]: a
//! shipped model is a starting point for more training even when the run that made it is gone.
//!
//! The shape comes from the file: the whole [`ModelConfig`] from its metadata
//! ([`super::META_MODEL_CONFIG`]); for files written before that key existed (the 0.4
//! release), resolution and d_s from the signature metadata, token width, patch, layers and
//! decoder width from the weights' shapes, everything else from the defaults. Each parameter
//! is read from the initializer the exporter named after its module path. The network is then
//! exported again and its graph compared with the file's, node for node and weight for
//! weight, so a file this trainer did not write, or one written for a shape the defaults miss
//! (heads, output scales), is refused rather than loaded wrong.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use burn::prelude::*;
use burn::store::ModuleSnapshot;
use burn::store::burn_pack::Tensor as PackTensor;
use burn::tensor::{Bytes, DType};
use inssplat_proto::signature as sig;
use prost::Message;

use super::onnx_pb::{DATA_TYPE_FLOAT, DATA_TYPE_INT8, GraphProto, ModelProto, TensorProto};
use super::{ExportMeta, META_WEIGHTS, Weights, to_model_proto};
use crate::model::{InsSplatNet, ModelConfig};

/// Why an ONNX file could not be read back into a network.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    #[error("{path}: {problem}")]
    Read { path: PathBuf, problem: String },
    #[error("{path}: not an inssplat network: {problem}")]
    Foreign { path: PathBuf, problem: String },
}

/// A float initializer: its shape and values.
struct Weight {
    dims: Vec<usize>,
    values: Vec<f32>,
}

/// The network stored in the ONNX file at `path`, on `device`, and what the file says about it.
pub fn import_onnx(path: &Path, device: &Device) -> Result<(InsSplatNet, ExportMeta), ImportError> {
    import_model(path, &read_model(path)?, device)
}

/// The ONNX file at `path`, decoded.
pub(super) fn read_model(path: &Path) -> Result<ModelProto, ImportError> {
    let bytes = std::fs::read(path)
        .map_err(|e| ImportError::Read { path: path.to_path_buf(), problem: e.to_string() })?;
    ModelProto::decode(bytes.as_slice()).map_err(|e| ImportError::Foreign {
        path: path.to_path_buf(),
        problem: format!("not an ONNX model: {e}"),
    })
}

/// [`import_onnx`] of a file already read from `path` (which errors name).
pub(super) fn import_model(
    path: &Path,
    model: &ModelProto,
    device: &Device,
) -> Result<(InsSplatNet, ExportMeta), ImportError> {
    let foreign = |problem: String| ImportError::Foreign { path: path.to_path_buf(), problem };
    let props: Props<'_> = model
        .metadata_props
        .iter()
        .filter_map(|p| Some((p.key.as_deref()?, p.value.as_deref()?)))
        .collect();
    let meta = metadata(&props).map_err(foreign)?;
    let graph = model.graph.as_ref().ok_or_else(|| foreign("the model has no graph".into()))?;
    let weights = weights(graph).map_err(foreign)?;
    let config = config(&props, &weights).map_err(foreign)?;
    let mut net = crate::train::seeded_init(&config, 0, device)
        .map_err(|e| foreign(format!("model shape {config:?}: {e}")))?;
    let tensors = parameters(&net, &weights).map_err(foreign)?;
    let result = net.apply(tensors, None, None, false);
    if !result.errors.is_empty() || !result.missing.is_empty() {
        return Err(foreign(format!(
            "weights missing {:?}, refused {:?}",
            result.missing, result.errors
        )));
    }
    let again = to_model_proto(&net, &meta).map_err(|e| foreign(e.to_string()))?;
    if let Some(difference) =
        first_difference(graph, again.graph.as_ref().expect("the exporter writes a graph"))
    {
        return Err(foreign(format!(
            "its graph is not the one this trainer exports for {config:?} (first difference: {difference})"
        )));
    }
    Ok((net, meta))
}

/// The file's metadata, key to value.
type Props<'a> = HashMap<&'a str, &'a str>;

fn metadata(props: &Props<'_>) -> Result<ExportMeta, String> {
    let get = |key: &str| props.get(key).copied().ok_or_else(|| format!("metadata has no {key}"));
    let io = get(sig::META_IO_VERSION)?;
    if io != sig::IO_VERSION {
        return Err(format!(
            "{} is {io}, this trainer writes {}",
            sig::META_IO_VERSION,
            sig::IO_VERSION
        ));
    }
    let steps = get(sig::META_TRAIN_STEPS)?;
    let weights = match props.get(META_WEIGHTS) {
        None => Weights::F32,
        Some(w) => Weights::parse(w)
            .ok_or_else(|| format!("{META_WEIGHTS} {w:?} is neither \"f32\" nor \"int8\""))?,
    };
    Ok(ExportMeta {
        model_version: get(sig::META_MODEL_VERSION)?.to_string(),
        train_steps: steps
            .parse()
            .map_err(|_| format!("{} {steps:?} is not a step count", sig::META_TRAIN_STEPS))?,
        weights,
    })
}

/// Float initializers by the module path the exporter named them after (`{path}_{counter}`),
/// and int8 weights dequantized with their `{path}.scale`.
fn weights(graph: &GraphProto) -> Result<HashMap<String, Weight>, String> {
    let hint = |t: &TensorProto| {
        let name = t.name.as_deref().unwrap_or_default();
        name.rsplit_once('_').map_or(name, |(hint, _)| hint).to_string()
    };
    fn err(t: &TensorProto) -> impl Fn(String) -> String + '_ {
        move |e| format!("initializer {}: {e}", t.name.as_deref().unwrap_or_default())
    }
    let mut out = HashMap::new();
    for t in graph.initializer.iter().filter(|t| t.data_type == Some(DATA_TYPE_FLOAT)) {
        out.insert(hint(t), weight(t).map_err(err(t))?);
    }
    for t in graph.initializer.iter().filter(|t| t.data_type == Some(DATA_TYPE_INT8)) {
        let hint = hint(t);
        let scale = match out.get(&format!("{hint}.scale")).map(|s| s.values.as_slice()) {
            Some(&[scale]) => scale,
            _ => return Err(err(t)(format!("an int8 weight without one float {hint}.scale"))),
        };
        let dims = dims(t, 1).map_err(err(t))?;
        let q: Vec<i8> =
            t.raw_data.as_deref().unwrap_or_default().iter().map(|&b| b as i8).collect();
        out.insert(hint, Weight { dims, values: super::int8::dequantize(&q, scale) });
    }
    Ok(out)
}

/// An initializer's shape, checked against its raw data of `bytes` a value.
fn dims(t: &TensorProto, bytes: usize) -> Result<Vec<usize>, String> {
    let raw = t.raw_data.as_deref().ok_or("no raw_data")?;
    let dims: Vec<usize> = t
        .dims
        .iter()
        .map(|&d| usize::try_from(d).map_err(|_| format!("dimension {d}")))
        .collect::<Result<_, _>>()?;
    if raw.len() != bytes * dims.iter().product::<usize>() {
        return Err(format!("{} bytes for shape {dims:?}", raw.len()));
    }
    Ok(dims)
}

fn weight(t: &TensorProto) -> Result<Weight, String> {
    let dims = dims(t, 4)?;
    let raw = t.raw_data.as_deref().unwrap_or_default();
    let values =
        raw.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    Ok(Weight { dims, values })
}

/// The network shape (checked afterwards by exporting again): the metadata's configuration,
/// or else resolution and d_s from the metadata, the rest from weight shapes and the defaults.
fn config(props: &Props<'_>, weights: &HashMap<String, Weight>) -> Result<ModelConfig, String> {
    let prop = |key: &str| props.get(key).copied();
    if let Some(json) = prop(super::META_MODEL_CONFIG) {
        return serde_json::from_str(json)
            .map_err(|e| format!("metadata {}: {e}", super::META_MODEL_CONFIG));
    }
    let dims = |name: &str| {
        weights.get(name).map(|w| w.dims.clone()).ok_or_else(|| format!("no weight {name}"))
    };
    let resolution = prop(sig::META_RESOLUTION)
        .ok_or_else(|| format!("metadata has no {}", sig::META_RESOLUTION))?;
    let image_size = resolution
        .split_once('x')
        .and_then(|(h, w)| (h == w).then(|| h.parse::<usize>().ok()).flatten())
        .ok_or_else(|| format!("{} {resolution:?} is not a square NxN", sig::META_RESOLUTION))?;
    let sem_dim = prop(sig::META_SEM_DIM)
        .and_then(|v| v.parse::<usize>().ok())
        .ok_or_else(|| format!("metadata has no numeric {}", sig::META_SEM_DIM))?;
    let [patch_in, dim] = dims("patch_embed.weight")?[..] else {
        return Err("patch_embed.weight is not a matrix".into());
    };
    let patch = ((patch_in / 3) as f64).sqrt().round() as usize;
    let [_, decoder_dim] = dims("decoder.fuse.weight")?[..] else {
        return Err("decoder.fuse.weight is not a matrix".into());
    };
    let depth =
        (0..).take_while(|i| weights.contains_key(&format!("blocks.{i}.qkv.weight"))).count();
    Ok(ModelConfig::new()
        .with_image_size(image_size)
        .with_patch(patch)
        .with_dim(dim)
        .with_depth(depth)
        .with_decoder_dim(decoder_dim)
        .with_sem_dim(sem_dim))
}

/// One tensor per parameter of `net`, by its module path, read from the file's weights. Two
/// parameters are stored differently: the camera tokens as two rows, and Φ_sem transposed.
fn parameters(
    net: &InsSplatNet,
    weights: &HashMap<String, Weight>,
) -> Result<Vec<PackTensor>, String> {
    let get = |name: &str| weights.get(name).ok_or_else(|| format!("no weight {name}"));
    net.collect(None, None, false)
        .into_iter()
        .map(|p| {
            let values = match p.name.as_str() {
                "camera_tokens" => [
                    get("camera_token.reference")?.values.as_slice(),
                    &get("camera_token.other")?.values,
                ]
                .concat(),
                "sem_proj.weight" => {
                    let w = get("sem_proj.weight")?;
                    let [rows, cols] = w.dims[..] else {
                        return Err("sem_proj.weight is not a matrix".into());
                    };
                    (0..cols).flat_map(|c| (0..rows).map(move |r| w.values[r * cols + c])).collect()
                }
                name => {
                    let w = get(name)?;
                    if w.dims != p.shape.as_slice() {
                        return Err(format!(
                            "{name}: shape {:?} in the file, {:?} in the network",
                            w.dims,
                            p.shape.as_slice()
                        ));
                    }
                    w.values.clone()
                }
            };
            if values.len() != p.shape.num_elements() {
                return Err(format!("{}: {} values for shape {:?}", p.name, values.len(), p.shape));
            }
            Ok(PackTensor::new(
                p.name.clone(),
                DType::F32,
                p.shape.clone(),
                None,
                Bytes::from_elems(values),
            ))
        })
        .collect()
}

/// Where graph `a` first differs from `b`, if it does.
fn first_difference(a: &GraphProto, b: &GraphProto) -> Option<String> {
    if let Some((i, (x, y))) = a.node.iter().zip(&b.node).enumerate().find(|(_, (x, y))| x != y) {
        return Some(format!(
            "node {i}: {:?} {:?} against {:?} {:?}",
            x.op_type, x.input, y.op_type, y.input
        ));
    }
    if let Some((x, _)) = a.initializer.iter().zip(&b.initializer).find(|(x, y)| x != y) {
        return Some(format!("initializer {}", x.name.as_deref().unwrap_or_default()));
    }
    (a.node.len() != b.node.len() || a.initializer.len() != b.initializer.len()).then(|| {
        format!(
            "{} nodes and {} initializers against {} and {}",
            a.node.len(),
            a.initializer.len(),
            b.node.len(),
            b.initializer.len()
        )
    })
}
