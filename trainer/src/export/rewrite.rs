//! Rewriting an exported file: its network is read back, changed in how it is stored or
//! run, and written again with every metadata entry of the input that the exporter does not
//! write itself (the shape classifier) kept. `inssplat-train quantize` ([`super::int8`]),
//! `inssplat-train pool-keys` ([`pool_keys_file`]) and `inssplat-train average`
//! ([`super::average`]) are such rewrites; `inssplat-train export --metadata-from`
//! ([`export_keeping_metadata`]) writes a new network with another file's entries.

use std::path::Path;

use burn::prelude::*;
use prost::Message;

use super::import::{import_model, read_model};
use super::{ExportError, ExportMeta, ImportError, onnx_pb, to_model_proto};
use crate::model::{InsSplatNet, ModelError};

/// Why a file could not be rewritten.
#[derive(Debug, thiserror::Error)]
pub enum RewriteError {
    #[error(transparent)]
    Import(#[from] ImportError),
    #[error(transparent)]
    Export(#[from] ExportError),
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Average(#[from] super::average::AverageError),
}

/// Reads the ONNX file `input`, lets `change` alter its network and what the file says about
/// itself, and writes the result to `output` with the input's other metadata. Returns what
/// `output` says about itself.
pub(super) fn rewrite_file(
    input: &Path,
    output: &Path,
    change: impl FnOnce(InsSplatNet, ExportMeta) -> Result<(InsSplatNet, ExportMeta), RewriteError>,
) -> Result<ExportMeta, RewriteError> {
    let original = read_model(input)?;
    let (net, meta) = import_model(input, &original, &Device::flex())?;
    let (net, meta) = change(net, meta)?;
    write_keeping(&net, &meta, original, output)?;
    Ok(meta)
}

/// Writes `net` to `output` as the exporter does, with every metadata entry of the ONNX file
/// `from` that the exporter does not write itself (its shape classifier).
pub fn export_keeping_metadata(
    net: &InsSplatNet,
    meta: &ExportMeta,
    from: &Path,
    output: &Path,
) -> Result<(), RewriteError> {
    write_keeping(net, meta, read_model(from)?, output)
}

fn write_keeping(
    net: &InsSplatNet,
    meta: &ExportMeta,
    original: onnx_pb::ModelProto,
    output: &Path,
) -> Result<(), RewriteError> {
    let mut model = to_model_proto(net, meta)?;
    let written: Vec<Option<String>> = model.metadata_props.iter().map(|p| p.key.clone()).collect();
    model
        .metadata_props
        .extend(original.metadata_props.into_iter().filter(|p| !written.contains(&p.key)));
    std::fs::write(output, model.encode_to_vec())
        .map_err(|source| ExportError::Io { path: output.display().to_string(), source })?;
    Ok(())
}

/// Writes the network of `input` to `output` with its global layers reading keys and values
/// pooled `pool` × `pool` (`crate::model::ModelConfig::global_kv_pool`; `None`: every
/// token), the same weights, and `version` as its model version (by default the input's with
/// `+kvP`).
pub fn pool_keys_file(
    input: &Path,
    output: &Path,
    pool: Option<usize>,
    version: Option<&str>,
) -> Result<ExportMeta, RewriteError> {
    rewrite_file(input, output, |net, meta| {
        let suffix = pool.map_or_else(|| "+kv1".to_string(), |p| format!("+kv{p}"));
        let model_version =
            version.map_or_else(|| format!("{}{suffix}", meta.model_version), str::to_string);
        Ok((net.with_global_kv_pool(pool)?, ExportMeta { model_version, ..meta }))
    })
}
