//! A small ONNX graph builder: appends nodes in topological order (the order the exporter
//! walks the network in), names intermediate values uniquely, and stores weights and
//! constants as initializers with little-endian raw data.

use burn::prelude::*;

use super::ExportError;
use super::onnx_pb::{
    AttributeProto, DATA_TYPE_FLOAT, DATA_TYPE_INT64, NodeProto, TensorProto, attribute_type,
};

/// Nodes and initializers of the graph being built.
#[derive(Default)]
pub struct Graph {
    pub nodes: Vec<NodeProto>,
    pub initializers: Vec<TensorProto>,
    counter: usize,
    /// Whether linear layers store their weights as int8 ([`super::int8`]).
    pub int8: bool,
}

/// Attribute constructors.
pub fn attr_int(name: &str, i: i64) -> AttributeProto {
    AttributeProto {
        name: Some(name.into()),
        i: Some(i),
        r#type: Some(attribute_type::INT),
        ..Default::default()
    }
}

pub fn attr_ints(name: &str, ints: &[i64]) -> AttributeProto {
    AttributeProto {
        name: Some(name.into()),
        ints: ints.to_vec(),
        r#type: Some(attribute_type::INTS),
        ..Default::default()
    }
}

pub fn attr_string(name: &str, value: &str) -> AttributeProto {
    AttributeProto {
        name: Some(name.into()),
        s: Some(value.as_bytes().to_vec()),
        r#type: Some(attribute_type::STRING),
        ..Default::default()
    }
}

pub fn attr_float(name: &str, f: f32) -> AttributeProto {
    AttributeProto {
        name: Some(name.into()),
        f: Some(f),
        r#type: Some(attribute_type::FLOAT),
        ..Default::default()
    }
}

impl Graph {
    pub(super) fn fresh(&mut self, hint: &str) -> String {
        self.counter += 1;
        format!("{hint}_{}", self.counter)
    }

    /// Appends a node with the given output names.
    pub fn op_into(
        &mut self,
        op: &str,
        inputs: &[&str],
        outputs: &[&str],
        attrs: Vec<AttributeProto>,
    ) {
        let name = self.fresh(op);
        self.nodes.push(NodeProto {
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: outputs.iter().map(|s| s.to_string()).collect(),
            name: Some(name),
            op_type: Some(op.into()),
            attribute: attrs,
        });
    }

    /// Appends a node with `n` fresh outputs and returns their names.
    pub fn op_n(
        &mut self,
        op: &str,
        inputs: &[&str],
        n: usize,
        attrs: Vec<AttributeProto>,
    ) -> Vec<String> {
        let outputs: Vec<String> = (0..n).map(|_| self.fresh(&op.to_lowercase())).collect();
        let refs: Vec<&str> = outputs.iter().map(String::as_str).collect();
        self.op_into(op, inputs, &refs, attrs);
        outputs
    }

    /// Appends a single-output node and returns the output's name.
    pub fn op(&mut self, op: &str, inputs: &[&str], attrs: Vec<AttributeProto>) -> String {
        self.op_n(op, inputs, 1, attrs).pop().expect("one output")
    }

    /// Adds a float initializer.
    pub fn f32s(&mut self, hint: &str, dims: &[usize], values: &[f32]) -> String {
        assert_eq!(
            dims.iter().product::<usize>(),
            values.len(),
            "initializer {hint}: shape and data disagree"
        );
        let name = self.fresh(hint);
        let raw = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.initializers.push(TensorProto {
            dims: dims.iter().map(|&d| d as i64).collect(),
            data_type: Some(DATA_TYPE_FLOAT),
            name: Some(name.clone()),
            raw_data: Some(raw),
        });
        name
    }

    /// Adds a scalar float constant (shape `[]`, broadcasts against anything).
    pub fn scalar(&mut self, value: f32) -> String {
        self.f32s("c", &[], &[value])
    }

    /// Adds a 1-D int64 constant (shapes, axes, slice bounds, split sizes).
    pub fn i64s(&mut self, values: &[i64]) -> String {
        let name = self.fresh("i");
        let raw = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.initializers.push(TensorProto {
            dims: vec![values.len() as i64],
            data_type: Some(DATA_TYPE_INT64),
            name: Some(name.clone()),
            raw_data: Some(raw),
        });
        name
    }

    /// Adds a tensor's current value as a float initializer, reshaped to `dims`
    /// (which must hold the same number of elements).
    pub fn weight<const D: usize>(
        &mut self,
        hint: &str,
        tensor: Tensor<D>,
        dims: &[usize],
    ) -> Result<String, ExportError> {
        let values = tensor
            .into_data()
            .try_into_vec_as::<f32>()
            .map_err(|e| ExportError::Tensor(format!("{hint}: {e:?}")))?;
        Ok(self.f32s(hint, dims, &values))
    }

    /// A tensor's value as an initializer of its own shape.
    pub fn param<const D: usize>(
        &mut self,
        hint: &str,
        tensor: Tensor<D>,
    ) -> Result<String, ExportError> {
        let dims = tensor.dims();
        self.weight(hint, tensor, &dims)
    }

    /// `Slice(x, starts, ends, axes)` with constant bounds.
    pub fn slice(&mut self, x: &str, starts: &[i64], ends: &[i64], axes: &[i64]) -> String {
        let (s, e, a) = (self.i64s(starts), self.i64s(ends), self.i64s(axes));
        self.op("Slice", &[x, &s, &e, &a], vec![])
    }

    /// `Reshape(x, shape)` with a constant target (0 copies a dimension, -1 infers one).
    pub fn reshape(&mut self, x: &str, shape: &[i64]) -> String {
        let s = self.i64s(shape);
        self.op("Reshape", &[x, &s], vec![])
    }

    /// `Reshape(x, shape)` with a target built at run time from constants and 1-D int64
    /// tensors of one element each ([`Dim`]).
    pub fn reshape_to(&mut self, x: &str, shape: &[Dim<'_>]) -> String {
        let s = self.shape_of(shape);
        self.op("Reshape", &[x, &s], vec![])
    }

    /// A 1-D int64 shape tensor of `dims`, consecutive constants in one initializer.
    pub fn shape_of(&mut self, dims: &[Dim<'_>]) -> String {
        let mut parts: Vec<String> = Vec::new();
        let mut constants: Vec<i64> = Vec::new();
        for d in dims {
            match d {
                Dim::Const(v) => constants.push(*v),
                Dim::Tensor(t) => {
                    if !constants.is_empty() {
                        parts.push(self.i64s(&std::mem::take(&mut constants)));
                    }
                    parts.push((*t).to_string());
                }
            }
        }
        if !constants.is_empty() {
            parts.push(self.i64s(&constants));
        }
        let refs: Vec<&str> = parts.iter().map(String::as_str).collect();
        self.op("Concat", &refs, vec![attr_int("axis", 0)])
    }

    pub fn transpose(&mut self, x: &str, perm: &[i64]) -> String {
        self.op("Transpose", &[x], vec![attr_ints("perm", perm)])
    }

    /// Exact GELU, `x · ½ · (1 + erf(x / √2))`, in the pattern ONNX Runtime fuses to one kernel.
    pub fn gelu(&mut self, x: &str) -> String {
        let sqrt2 = self.scalar(std::f32::consts::SQRT_2);
        let one = self.scalar(1.0);
        let half = self.scalar(0.5);
        let d = self.op("Div", &[x, &sqrt2], vec![]);
        let e = self.op("Erf", &[&d], vec![]);
        let a = self.op("Add", &[&e, &one], vec![]);
        let m = self.op("Mul", &[x, &a], vec![]);
        self.op("Mul", &[&m, &half], vec![])
    }
}

/// One dimension of a shape computed at run time.
#[derive(Debug, Clone, Copy)]
pub enum Dim<'a> {
    /// A constant (0 copies the input's dimension, -1 infers it).
    Const(i64),
    /// A 1-D int64 tensor of one element, by name.
    Tensor(&'a str),
}
