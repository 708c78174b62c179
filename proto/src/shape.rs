//! The shape classifier: a small MLP from an instance's shape descriptor (its size, height
//! above the floor and colour, [`DESCRIPTOR`]) to a probability over the training labels;
//! a [`ShapeClassifier::semantic`] one also reads how close the instance's semantic
//! prototype lies to each label's text ([`label_cosines`]).
//! The trainer fits it on synthesized rooms and stores it in the model file as JSON under
//! [`crate::signature::META_SHAPE_CLASSIFIER`]; the server reads it back to name instances
//! by what they look like in 3D as well as by their semantic features. Only the contract and
//! the forward pass live here: computing descriptors is `inssplat_understand::label::shape`'s.

use serde::{Deserialize, Serialize};

/// The descriptor's entries, in order. The first [`LENGTHS`] are lengths in metres (they
/// scale with the scene); the rest are colours in [0, 1].
pub const DESCRIPTOR: [&str; 11] = [
    "height extent",
    "longer horizontal extent",
    "shorter horizontal extent",
    "bottom above floor",
    "top above floor",
    "mean red",
    "mean green",
    "mean blue",
    "red spread",
    "green spread",
    "blue spread",
];

/// Entries of [`DESCRIPTOR`] that are lengths.
pub const LENGTHS: usize = 5;

/// An instance's descriptor and the label it should get: what the classifier is fitted on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LabelledDescriptor {
    pub label: String,
    pub descriptor: [f32; DESCRIPTOR.len()],
    /// The instance's semantic prototype (text space) where it was recorded.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub prototype: Vec<f32>,
    /// The scene the instance was found in, where it was recorded (which instances share a
    /// room: examples can be split by room, not by instance).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub scene: String,
}

/// One fully connected layer: `y = W·x + b`, `W` row-major `[outputs][inputs]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Dense {
    pub inputs: usize,
    pub outputs: usize,
    pub weight: Vec<f32>,
    pub bias: Vec<f32>,
}

/// The classifier: standardize (`(x − mean) / std`), dense layers with ReLU between them,
/// softmax over `labels`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShapeClassifier {
    pub labels: Vec<String>,
    pub mean: Vec<f32>,
    pub std: Vec<f32>,
    pub layers: Vec<Dense>,
    /// How it was fitted (scenes, instances, held-out accuracy), for people.
    #[serde(default)]
    pub provenance: String,
    /// Whether the input goes on past the descriptor with the [`label_cosines`] of the
    /// instance's semantic prototype to `labels`' text embeddings.
    #[serde(default)]
    pub semantic: bool,
}

/// The cosine of `prototype` to each of `texts` (0 where either is zero): the semantic part
/// of a [`ShapeClassifier::semantic`] classifier's input.
pub fn label_cosines<T: AsRef<[f32]>>(prototype: &[f32], texts: &[T]) -> Vec<f32> {
    let norm = |v: &[f32]| v.iter().map(|x| x * x).sum::<f32>().sqrt();
    let p = norm(prototype);
    texts
        .iter()
        .map(|t| {
            let t = t.as_ref();
            let n = p * norm(t);
            if n > 0.0 { prototype.iter().zip(t).map(|(a, b)| a * b).sum::<f32>() / n } else { 0.0 }
        })
        .collect()
}

/// What is wrong with a stored classifier.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ShapeError {
    #[error("shape classifier: {0}")]
    Invalid(String),
    #[error("shape classifier: not valid JSON: {0}")]
    Json(String),
}

impl ShapeClassifier {
    /// Reads and checks the JSON form.
    pub fn from_json(text: &str) -> Result<Self, ShapeError> {
        let c: Self = serde_json::from_str(text).map_err(|e| ShapeError::Json(e.to_string()))?;
        c.validate()?;
        Ok(c)
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("numbers and strings serialize")
    }

    /// Entries of the input: the descriptor's, and with [`Self::semantic`] one cosine a label.
    pub fn input_width(&self) -> usize {
        DESCRIPTOR.len() + if self.semantic { self.labels.len() } else { 0 }
    }

    /// Shapes agree from the input through every layer to the labels, and every number
    /// is finite.
    pub fn validate(&self) -> Result<(), ShapeError> {
        let bad = |m: String| Err(ShapeError::Invalid(m));
        let d = self.input_width();
        if self.mean.len() != d || self.std.len() != d {
            return bad(format!(
                "mean/std have {}/{} entries, the input {d}",
                self.mean.len(),
                self.std.len()
            ));
        }
        if self.std.iter().any(|&s| !(s > 0.0 && s.is_finite())) {
            return bad("std has an entry that is not positive and finite".into());
        }
        let mut width = d;
        for (i, l) in self.layers.iter().enumerate() {
            if l.inputs != width
                || l.weight.len() != l.inputs * l.outputs
                || l.bias.len() != l.outputs
            {
                return bad(format!(
                    "layer {i}: {} inputs (expected {width}), {} weights and {} biases for {} outputs",
                    l.inputs,
                    l.weight.len(),
                    l.bias.len(),
                    l.outputs
                ));
            }
            if l.weight.iter().chain(&l.bias).any(|x| !x.is_finite()) {
                return bad(format!("layer {i} has a value that is not finite"));
            }
            width = l.outputs;
        }
        if self.layers.is_empty() || width != self.labels.len() {
            return bad(format!(
                "{} layers end in {width} outputs for {} labels",
                self.layers.len(),
                self.labels.len()
            ));
        }
        Ok(())
    }

    /// Probability of each label (in [`Self::labels`] order) for one descriptor and, for a
    /// [`Self::semantic`] classifier, the [`label_cosines`] of the instance's prototype to
    /// [`Self::labels`] (one a label; ignored otherwise).
    pub fn probabilities(&self, descriptor: &[f32; DESCRIPTOR.len()], cosines: &[f32]) -> Vec<f32> {
        let semantic: &[f32] = if self.semantic { cosines } else { &[] };
        assert_eq!(semantic.len() + DESCRIPTOR.len(), self.input_width(), "one cosine a label");
        let input = descriptor.iter().chain(semantic);
        let mut x: Vec<f32> =
            input.zip(&self.mean).zip(&self.std).map(|((v, m), s)| (v - m) / s).collect();
        for (i, l) in self.layers.iter().enumerate() {
            let relu = i + 1 < self.layers.len();
            x = l
                .weight
                .chunks_exact(l.inputs)
                .zip(&l.bias)
                .map(|(row, b)| {
                    let y = b + row.iter().zip(&x).map(|(w, v)| w * v).sum::<f32>();
                    if relu { y.max(0.0) } else { y }
                })
                .collect();
        }
        let top = x.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let exp: Vec<f32> = x.iter().map(|v| (v - top).exp()).collect();
        let sum: f32 = exp.iter().sum();
        exp.into_iter().map(|e| e / sum).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A one-layer classifier whose logits are the first two standardized entries.
    fn two_way() -> ShapeClassifier {
        let d = DESCRIPTOR.len();
        let mut weight = vec![0.0; 2 * d];
        weight[0] = 1.0;
        weight[d + 1] = 1.0;
        ShapeClassifier {
            labels: vec!["tall".into(), "long".into()],
            mean: vec![0.0; d],
            std: vec![1.0; d],
            layers: vec![Dense { inputs: d, outputs: 2, weight, bias: vec![0.0, 0.0] }],
            provenance: String::new(),
            semantic: false,
        }
    }

    #[test]
    fn probabilities_follow_the_logits_and_sum_to_one() {
        let c = two_way();
        let mut x = [0.0; DESCRIPTOR.len()];
        x[0] = 2.0;
        let p = c.probabilities(&x, &[]);
        assert!((p.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        assert!((p[0] - 1.0 / (1.0 + (-2.0f32).exp())).abs() < 1e-6, "{p:?}");
        let back = ShapeClassifier::from_json(&c.to_json()).unwrap();
        assert_eq!(back, c);
    }

    #[test]
    fn a_semantic_classifier_reads_the_prototypes_cosines_to_its_labels() {
        // Logits: the two cosines, the descriptor ignored.
        let d = DESCRIPTOR.len();
        let mut weight = vec![0.0; 2 * (d + 2)];
        weight[d] = 4.0;
        weight[(d + 2) + d + 1] = 4.0;
        let c = ShapeClassifier {
            mean: vec![0.0; d + 2],
            std: vec![1.0; d + 2],
            layers: vec![Dense { inputs: d + 2, outputs: 2, weight, bias: vec![0.0, 0.0] }],
            semantic: true,
            ..two_way()
        };
        c.validate().unwrap();
        let texts = [vec![1.0, 0.0], vec![0.0, 3.0]];
        let cos = label_cosines(&[0.2, 2.0], &texts);
        assert!(
            (cos[1] - 2.0 / 4.04f32.sqrt()).abs() < 1e-6
                && (cos[0] - 0.2 / 4.04f32.sqrt()).abs() < 1e-6,
            "{cos:?}"
        );
        let p = c.probabilities(&[0.0; DESCRIPTOR.len()], &cos);
        assert!(p[1] > 0.95, "{p:?}");
        assert_eq!(label_cosines(&[0.0, 0.0], &texts), [0.0, 0.0]);
        // Stored as a plain classifier's input width, it is refused.
        let plain = ShapeClassifier { semantic: false, ..c };
        assert!(plain.validate().unwrap_err().to_string().contains("the input 11"));
    }

    #[test]
    fn a_classifier_whose_shapes_disagree_is_refused_by_what_disagrees() {
        let mut c = two_way();
        c.labels.push("third".into());
        assert!(c.validate().unwrap_err().to_string().contains("2 outputs for 3 labels"));
        let mut c = two_way();
        c.layers[0].bias.pop();
        assert!(c.validate().unwrap_err().to_string().contains("layer 0"));
        let mut c = two_way();
        c.std[3] = 0.0;
        assert!(c.validate().unwrap_err().to_string().contains("std"));
        assert!(matches!(ShapeClassifier::from_json("{"), Err(ShapeError::Json(_))));
    }
}
