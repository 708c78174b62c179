//! ONNX export of the network: the single hand-off to the server. [`export_onnx`] walks the
//! model's modules (same structure and arithmetic as `InsSplatNet::forward`) into an ONNX
//! graph, opset 17, IR 8, with the view count, the image's height and width and the patch count
//! as the symbolic dimensions "N", "H", "W" and "T", the weights
//! as initializers, and the signature's metadata keys in `metadata_props`. With
//! [`Weights::Int8`] the linear layers' weights are stored as int8 ([`int8`]; `inssplat-train
//! quantize` writes such a file from any exported one).
//!
//! Why hand-written `prost` messages rather than onnx.proto compiled at build time or the
//! `onnx-protobuf` crate: compiling the schema needs protoc (absent from CI machines) or a
//! pure-Rust compiler (`protox`) plus `prost-build` as build dependencies, while the exporter
//! writes only a dozen message types; `onnx-protobuf` pulls in the older `rust-protobuf`
//! runtime under MPL-2.0 for the same few messages. The derived messages in [`onnx_pb`] carry
//! the official field numbers, and the parity test proves the bytes by loading them in ONNX
//! Runtime.

mod average;
mod graph;
mod import;
mod int8;
mod net;
pub mod onnx_pb;
mod rewrite;

use std::path::Path;

use inssplat_proto::signature as sig;
use prost::Message;

use crate::model::InsSplatNet;
pub use average::{AverageError, average_file, average_networks};
use graph::Graph;
pub use import::{ImportError, import_onnx};
pub use int8::quantize_file;
use onnx_pb::{
    DATA_TYPE_FLOAT, GraphProto, ModelProto, OperatorSetIdProto, StringStringEntryProto,
    TensorShapeProto, TypeProto, ValueInfoProto, tensor_shape_proto::Dimension,
    tensor_shape_proto::dimension, type_proto,
};
pub use rewrite::{RewriteError, export_keeping_metadata, pool_keys_file};

/// ONNX opset the graph is written against.
pub const OPSET: i64 = 17;
/// ONNX IR version matching [`OPSET`].
pub const IR_VERSION: i64 = 8;
/// Name of the symbolic view-count dimension.
pub const VIEWS_DIM: &str = "N";
/// Names of the symbolic image height and width, and of the patch count a view.
const HEIGHT_DIM: &str = "H";
const WIDTH_DIM: &str = "W";
const TOKENS_DIM: &str = "T";
/// Metadata key of the network's whole [`crate::model::ModelConfig`] as JSON, which
/// [`import_onnx`] reads back (the server does not need it).
pub const META_MODEL_CONFIG: &str = "inssplat.model_config";
/// Metadata key of the file's [`Weights`] ("f32" or "int8"; files without it are "f32").
pub const META_WEIGHTS: &str = "inssplat.weights";

/// How the linear layers' weights are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Weights {
    /// As trained.
    #[default]
    F32,
    /// Int8 with one scale a weight, run through ONNX Runtime's dynamic quantization
    /// (`inssplat-train quantize`; the pattern is [`int8`]'s).
    Int8,
}

impl Weights {
    pub fn as_str(self) -> &'static str {
        match self {
            Weights::F32 => "f32",
            Weights::Int8 => "int8",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        [Weights::F32, Weights::Int8].into_iter().find(|w| w.as_str() == s)
    }
}

/// What the exported file says about where it came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExportMeta {
    /// Free-form model version, e.g. "inssplat-0.1.0+run3".
    pub model_version: String,
    /// Optimizer steps the weights were trained for (0 for a fresh network).
    pub train_steps: u64,
    pub weights: Weights,
}

#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("reading a weight tensor: {0}")]
    Tensor(String),
    #[error("the exporter does not support {0}")]
    Unsupported(&'static str),
    #[error("writing {path}: {source}")]
    Io { path: String, source: std::io::Error },
}

/// Builds the ONNX model of `net` in memory.
pub fn to_model_proto(net: &InsSplatNet, meta: &ExportMeta) -> Result<ModelProto, ExportError> {
    let mut g = Graph::default();
    g.int8 = meta.weights == Weights::Int8;
    net::network(&mut g, net)?;
    let c = net.config();
    let ds = c.sem_dim as i64;
    let n = || Dim::Sym(VIEWS_DIM);
    let map = |channels: i64| vec![n(), F(channels), Dim::Sym(HEIGHT_DIM), Dim::Sym(WIDTH_DIM)];
    use Dim::Fixed as F;
    let outputs = [
        (sig::OUTPUT_CAMERA.name, vec![n(), F(sig::CAMERA_CHANNELS as i64)]),
        (sig::OUTPUT_DEPTH.name, map(1)),
        (sig::OUTPUT_DEPTH_CONF.name, map(1)),
        (sig::OUTPUT_GAUSSIANS.name, map(sig::GAUSSIAN_CHANNELS as i64)),
        (sig::OUTPUT_INSTANCE.name, map(crate::model::OUT_INSTANCE as i64)),
        (sig::OUTPUT_SEMANTIC.name, map(ds)),
        (sig::OUTPUT_SEM_PROJ_WEIGHT.name, vec![F(sig::TEXT_DIM as i64), F(ds)]),
        (sig::OUTPUT_SEM_PROJ_BIAS.name, vec![F(sig::TEXT_DIM as i64)]),
    ];
    debug_assert_eq!(outputs.len(), sig::OUTPUTS.len());
    let rays = c.camera_rays.map(|k| {
        (
            sig::INPUT_RAYS.name,
            vec![n(), Dim::Sym(TOKENS_DIM), F(inssplat_proto::rays::ray_channels(k) as i64)],
        )
    });
    let graph = GraphProto {
        node: g.nodes,
        name: Some("inssplat".into()),
        initializer: g.initializers,
        input: std::iter::once(value_info(sig::INPUT_IMAGES.name, &map(3)))
            .chain(rays.iter().map(|(name, dims)| value_info(name, dims)))
            .collect(),
        output: outputs.iter().map(|(name, dims)| value_info(name, dims)).collect(),
    };
    let resolution = format!("{}x{}", c.image_size, c.image_size);
    let props = [
        (sig::META_IO_VERSION, sig::IO_VERSION.to_string()),
        (sig::META_MODEL_VERSION, meta.model_version.clone()),
        (sig::META_RESOLUTION, resolution),
        (sig::META_SIZE_MULTIPLE, c.size_multiple().to_string()),
        (sig::META_PATCH, c.patch.to_string()),
        (sig::META_SEM_DIM, c.sem_dim.to_string()),
        (sig::META_TRAIN_STEPS, meta.train_steps.to_string()),
        (
            META_MODEL_CONFIG,
            serde_json::to_string(c).expect("a ModelConfig (numbers only) serializes"),
        ),
        (META_WEIGHTS, meta.weights.as_str().to_string()),
    ];
    Ok(ModelProto {
        ir_version: Some(IR_VERSION),
        opset_import: vec![OperatorSetIdProto {
            domain: Some(String::new()),
            version: Some(OPSET),
        }],
        producer_name: Some("inssplat-trainer".into()),
        producer_version: Some(env!("CARGO_PKG_VERSION").into()),
        doc_string: Some("InstanceSplat network; I/O as in inssplat_proto::signature".into()),
        graph: Some(graph),
        metadata_props: props
            .into_iter()
            .map(|(k, v)| StringStringEntryProto { key: Some(k.into()), value: Some(v) })
            .collect(),
    })
}

/// Serialises `net` to ONNX bytes.
pub fn to_onnx_bytes(net: &InsSplatNet, meta: &ExportMeta) -> Result<Vec<u8>, ExportError> {
    Ok(to_model_proto(net, meta)?.encode_to_vec())
}

/// Writes `net` as an ONNX file at `path`.
pub fn export_onnx(net: &InsSplatNet, path: &Path, meta: &ExportMeta) -> Result<(), ExportError> {
    let bytes = to_onnx_bytes(net, meta)?;
    std::fs::write(path, bytes)
        .map_err(|source| ExportError::Io { path: path.display().to_string(), source })
}

enum Dim {
    Fixed(i64),
    Sym(&'static str),
}

fn value_info(name: &str, dims: &[Dim]) -> ValueInfoProto {
    let dim = dims
        .iter()
        .map(|d| Dimension {
            value: Some(match d {
                Dim::Fixed(v) => dimension::Value::DimValue(*v),
                Dim::Sym(s) => dimension::Value::DimParam((*s).into()),
            }),
        })
        .collect();
    ValueInfoProto {
        name: Some(name.into()),
        r#type: Some(TypeProto {
            value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                elem_type: Some(DATA_TYPE_FLOAT),
                shape: Some(TensorShapeProto { dim }),
            })),
        }),
    }
}
