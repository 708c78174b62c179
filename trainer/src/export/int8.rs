//! Int8 weights for the network's linear layers (`inssplat-train quantize`): ONNX Runtime's
//! dynamic quantization pattern, `DynamicQuantizeLinear` (the activations to uint8, one scale
//! and zero point per run) → `MatMulInteger` with the int8 weight → `Cast` → `Mul` by both
//! scales, which its CPU provider fuses into one kernel. Only the weights of [`super::net`]'s
//! `linear` layers are quantized (the blocks, the patch embedding, the camera head and the
//! decoder's fusion); attention products, convolutions and Φ_sem stay float.
//!
//! Each weight has one symmetric scale, max |w| / [`LEVELS`], moved to the fixed point of
//! dequantizing and quantizing again, so that a file read back by [`super::import_onnx`]
//! (which dequantizes) exports to the same bytes: its check that the graph is the one this
//! trainer writes holds for int8 files too. The weights use 7 of the 8 bits (ONNX Runtime's
//! `reduce_range`): CPUs without VNNI multiply uint8 by int8 in pairs summed into int16
//! (`vpmaddubsw`), which saturates when 255·|w| + 255·|w'| > 32767; at |w| ≤ 63 it cannot, so
//! the file computes the same on every x86 CPU.

use std::path::Path;

use burn::prelude::*;

use super::graph::{Graph, attr_int};
use super::onnx_pb::{DATA_TYPE_FLOAT, DATA_TYPE_INT8, TensorProto};
use super::rewrite::{RewriteError, rewrite_file};
use super::{ExportError, ExportMeta, Weights};

/// Writes the network of the ONNX file `input` to `output` with int8 linear weights, keeping
/// every metadata entry of `input` the exporter does not write itself (the shape classifier),
/// and `version` as its model version (by default the input's with `+int8`, so that reports
/// tell the two apart). Returns what `output` says about itself.
pub fn quantize_file(
    input: &Path,
    output: &Path,
    version: Option<&str>,
) -> Result<ExportMeta, RewriteError> {
    rewrite_file(input, output, |net, meta| {
        let model_version =
            version.map_or_else(|| format!("{}+int8", meta.model_version), str::to_string);
        Ok((net, ExportMeta { weights: Weights::Int8, model_version, ..meta }))
    })
}

/// Largest |quantized weight|.
pub const LEVELS: f32 = 63.0;

/// The symmetric per-tensor scale of `values` (1 for an all-zero tensor).
pub fn scale(values: &[f32]) -> f32 {
    let max = values.iter().fold(0f32, |m, v| m.max(v.abs()));
    if !(max > 0.0 && max.is_finite()) {
        return 1.0;
    }
    // `s` must survive a round trip: the largest dequantized value, LEVELS·s, gives s back.
    let mut s = max / LEVELS;
    for _ in 0..16 {
        let again = (s * LEVELS) / LEVELS;
        if again == s {
            break;
        }
        s = again;
    }
    s
}

pub fn quantize(values: &[f32], scale: f32) -> Vec<i8> {
    values.iter().map(|v| (v / scale).round().clamp(-LEVELS, LEVELS) as i8).collect()
}

pub fn dequantize(q: &[i8], scale: f32) -> Vec<f32> {
    q.iter().map(|&q| f32::from(q) * scale).collect()
}

impl Graph {
    /// `x · W` with `weight` (`[inputs, outputs]`) stored as int8 (hint `{hint}`, its scale
    /// as `{hint}.scale`), in the pattern ONNX Runtime fuses.
    pub fn int8_matmul<const D: usize>(
        &mut self,
        hint: &str,
        weight: Tensor<D>,
        x: &str,
    ) -> Result<String, ExportError> {
        let dims = weight.dims();
        let values = weight
            .into_data()
            .try_into_vec_as::<f32>()
            .map_err(|e| ExportError::Tensor(format!("{hint}: {e:?}")))?;
        let s = scale(&values);
        let name = self.fresh(hint);
        self.initializers.push(TensorProto {
            dims: dims.iter().map(|&d| d as i64).collect(),
            data_type: Some(DATA_TYPE_INT8),
            name: Some(name.clone()),
            raw_data: Some(quantize(&values, s).into_iter().map(|q| q as u8).collect()),
        });
        let w_scale = self.f32s(&format!("{hint}.scale"), &[], &[s]);
        let [xq, x_scale, x_zero] =
            <[String; 3]>::try_from(self.op_n("DynamicQuantizeLinear", &[x], 3, vec![]))
                .expect("three outputs");
        let product = self.op("MatMulInteger", &[&xq, &name, &x_zero], vec![]);
        let product =
            self.op("Cast", &[&product], vec![attr_int("to", i64::from(DATA_TYPE_FLOAT))]);
        let scales = self.op("Mul", &[&x_scale, &w_scale], vec![]);
        Ok(self.op("Mul", &[&product, &scales], vec![]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn quantizing_the_dequantized_weights_gives_the_same_scale_and_values() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for trial in 0..2000 {
            let magnitude = 10f32.powf(rng.random_range(-4.0..2.0));
            let values: Vec<f32> =
                (0..64).map(|_| rng.random_range(-1.0..1.0) * magnitude).collect();
            let s = scale(&values);
            let q = quantize(&values, s);
            assert!(
                q.iter().any(|&v| f32::from(v.unsigned_abs()) == LEVELS),
                "trial {trial}: the largest weight uses the whole range"
            );
            for (v, &k) in values.iter().zip(&q) {
                assert!(
                    (v - f32::from(k) * s).abs() <= 0.5 * s * 1.0001,
                    "trial {trial}: {v} → {k} at scale {s}"
                );
            }
            let back = dequantize(&q, s);
            assert_eq!(scale(&back), s, "trial {trial}: the scale moved");
            assert_eq!(quantize(&back, s), q, "trial {trial}: the values moved");
        }
        assert_eq!(scale(&[0.0; 4]), 1.0);
        assert_eq!(quantize(&[0.0; 4], 1.0), [0; 4]);
    }
}
