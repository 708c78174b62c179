//! L_sem: the rendered compact semantic feature, mapped to the 384-d text space by the
//! network's Φ_sem (y = W·l + b), should point where the MiniLM sentence embedding of the
//! pixel's ground-truth label points. The teacher is given as a table with one row per instance
//! id (the embedding of that instance's label) and looked up per pixel; background pixels
//! (id 0) have no label and are left out. Two forms:
//!
//! - the paper's cosine, L_sem = (1/|Ω|) Σ_{p∈Ω} [1 − cos(y_p, t_{id(p)})], Ω = pixels with
//!   id ≠ 0;
//! - contrastive with temperature τ: the classes are a label vocabulary (every label the
//!   synthesizer can produce) plus any label of the sample outside it, each pixel's logits are
//!   cos(y_p, t_k)/τ, and L_sem is the cross-entropy of its own label, averaged per instance
//!   and then over instances, so the walls and floor that cover most pixels count as much as
//!   any chair. With label embeddings (not per-pixel image features) as the teacher the
//!   cosine form is satisfied by a direction between all labels, and with shell pixels
//!   dominating the mean, 0.3 named every object pixel `wall` or `floor`. Contrasting only
//!   the sample's own labels named every object `chair` or `stool` (labels a bed never met in
//!   its own scene cost it nothing, while inference picks from the whole vocabulary).
//!
//! Both are zero when Ω is empty. The 384-d projections are never formed per pixel (at 4 views
//! of 128×128 they cost about a second a step on two cores): with t̂ a unit teacher row,
//! y·t̂ = l·(Wᵀt̂) + b·t̂ and |y|² = lᵀ(WᵀW)l + 2·l·(Wᵀb) + |b|², so every per-pixel quantity
//! lives in d_s dimensions (or d_s plus one column per class).

use std::collections::HashMap;

use burn::prelude::*;
use burn::tensor::activation::log_softmax;

use super::{
    LossError, NORM_EPS, check_dims, check_len, constant, host, indices, normalize_rows,
    pixels_last, pixels_per_instance, zero,
};

/// L_sem of the rendered semantic features `semantic` `[V, d_s, H, W]` with ground-truth `ids`
/// (`[V][H][W]`, 0 = background); `teacher` `[rows, 384]` holds the label embedding of instance
/// id `i` in row `i` (row 0 is never read); Φ_sem is `weight` `[384, d_s]` and `bias` `[384]`,
/// as the network's `sem_proj` returns them.
pub fn semantic_loss(
    semantic: Tensor<4>,
    ids: &[u32],
    teacher: Tensor<2>,
    weight: Tensor<2>,
    bias: Tensor<1>,
    form: SemanticForm<'_>,
) -> Result<Tensor<1>, LossError> {
    let [v, ds, h, w] = semantic.dims();
    check_len("instance ids", v * h * w, ids.len())?;
    let [rows, text] = teacher.dims();
    check_dims("Φ_sem weight", &[text, ds], &weight.dims())?;
    check_dims("Φ_sem bias", &[text], &bias.dims())?;
    if let Some(&id) = ids.iter().find(|&&id| id as usize >= rows) {
        return Err(LossError::TeacherRow { id, rows });
    }
    let device = semantic.device();
    let (pixels, labels): (Vec<i64>, Vec<u32>) =
        ids.iter().enumerate().filter(|(_, id)| **id != 0).map(|(p, &id)| (p as i64, id)).unzip();
    if pixels.is_empty() {
        return Ok(zero(&device));
    }
    let l = pixels_last(semantic).select(0, indices(pixels, &device)); // [Q, d_s]
    let norm = projected_norm(l.clone(), weight.clone(), bias.clone());
    match form {
        SemanticForm::Cosine => {
            let q = labels.len();
            let rows = indices(labels.iter().map(|&id| i64::from(id)).collect(), &device);
            let (along, offset) =
                along_targets(normalize_rows(teacher).select(0, rows), weight, bias); // [Q, d_s], [Q, 1]
            let cos = ((l * along).sum_dim(1) + offset) / norm;
            Ok(cos.neg().add_scalar(1.0).sum().div_scalar(q as f64))
        }
        SemanticForm::Contrastive { temperature: tau, vocabulary } => {
            check_len("label vocabulary", vocabulary.len() / text * text, vocabulary.len())?;
            let classes =
                Classes::of(&host("semantic teacher", &teacher)?, vocabulary, text, &labels);
            let q = labels.len();
            let k = classes.table.len() / text;
            let table = normalize_rows(constant(classes.table, [k, text], &device)); // [K, 384]
            let (along, offset) = along_targets(table, weight, bias); // [K, d_s], [K, 1]
            let cos = (l.matmul(along.transpose()) + offset.transpose()) / norm; // [Q, K]
            let log_p = log_softmax(cos.div_scalar(tau), 1);
            let own = log_p.gather(1, indices(classes.of_pixel, &device).reshape([q, 1]));
            Ok((own * constant(classes.pixel_weight, [q, 1], &device)).sum().neg())
        }
    }
}

/// |W·l + b| per row of `l` `[Q, d_s]`, as `[Q, 1]`.
fn projected_norm(l: Tensor<2>, weight: Tensor<2>, bias: Tensor<1>) -> Tensor<2> {
    let text = bias.dims()[0];
    let bias_row = bias.reshape([1, text]);
    let gram = weight.clone().transpose().matmul(weight.clone()); // [d_s, d_s]
    let wb = bias_row.clone().matmul(weight); // [1, d_s]
    let bb = (bias_row.clone() * bias_row).sum(); // [1]
    let norm2 = (l.clone().matmul(gram) * l.clone()).sum_dim(1)
        + (l * wb).sum_dim(1).mul_scalar(2.0)
        + bb.reshape([1, 1]);
    norm2.clamp_min(0.0).add_scalar(NORM_EPS).sqrt()
}

/// For unit text vectors `targets` `[K, 384]`: Wᵀt̂ `[K, d_s]` and b·t̂ `[K, 1]`, so that
/// (W·l + b)·t̂ = l·(Wᵀt̂) + b·t̂.
fn along_targets(targets: Tensor<2>, weight: Tensor<2>, bias: Tensor<1>) -> (Tensor<2>, Tensor<2>) {
    let text = bias.dims()[0];
    (targets.clone().matmul(weight), targets.matmul(bias.reshape([text, 1])))
}

/// What L_sem compares the projected features with.
#[derive(Debug, Clone, Copy)]
pub enum SemanticForm<'a> {
    /// The paper's per-pixel 1 − cos to the pixel's own label.
    Cosine,
    /// Cross-entropy of cos/`temperature` over `vocabulary` (`[K][384]` label embeddings, row
    /// major) and the sample's own labels, balanced per instance.
    Contrastive { temperature: f64, vocabulary: &'a [f32] },
}

/// The classes of the contrastive form: the distinct label embeddings of the vocabulary and
/// of the labelled pixels' ids (instances with the same label share a class), on the host.
#[derive(Debug, PartialEq)]
struct Classes {
    /// `[K][text]` one embedding per class.
    table: Vec<f32>,
    /// Per labelled pixel, its class.
    of_pixel: Vec<i64>,
    /// Per labelled pixel, 1 / (pixels of its instance · instances present).
    pixel_weight: Vec<f32>,
}

impl Classes {
    /// `teacher` is the `[rows][text]` table, `vocabulary` `[K][text]` more labels, `labels`
    /// the instance id of each labelled pixel.
    fn of(teacher: &[f32], vocabulary: &[f32], text: usize, labels: &[u32]) -> Self {
        let pixels_of = pixels_per_instance(labels.iter().copied());
        let mut table = Vec::new();
        let mut class_of_row: HashMap<Vec<u32>, i64> = HashMap::new();
        let mut class_of = |row: &[f32]| {
            let key: Vec<u32> = row.iter().map(|x| x.to_bits()).collect();
            *class_of_row.entry(key).or_insert_with(|| {
                table.extend_from_slice(row);
                (table.len() / text) as i64 - 1
            })
        };
        vocabulary.chunks_exact(text).for_each(|row| {
            class_of(row);
        });
        let mut ids: Vec<u32> = pixels_of.keys().copied().collect();
        ids.sort_unstable();
        let class_of_id: HashMap<u32, i64> = ids
            .into_iter()
            .map(|id| (id, class_of(&teacher[id as usize * text..(id as usize + 1) * text])))
            .collect();
        let instances = pixels_of.len() as f32;
        Classes {
            table,
            of_pixel: labels.iter().map(|id| class_of_id[id]).collect(),
            pixel_weight: labels
                .iter()
                .map(|id| 1.0 / (pixels_of[id] as f32 * instances))
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn instances_with_one_label_share_a_class_and_every_instance_weighs_the_same() {
        // Rows: 0 unused, 1 and 3 the same label, 2 another. The vocabulary has label 2's
        // embedding and one the sample does not show; label 1's comes after them.
        let teacher = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0];
        let vocabulary = [0.0, 1.0, 0.5, 0.5];
        let labels = [3, 1, 1, 2, 1, 3];
        let c = Classes::of(&teacher, &vocabulary, 2, &labels);
        assert_eq!(c.table, [0.0, 1.0, 0.5, 0.5, 1.0, 0.0]);
        assert_eq!(c.of_pixel, [2, 2, 2, 0, 2, 2]);
        let third = 1.0 / 3.0;
        let want = [third / 2.0, third / 3.0, third / 3.0, third, third / 3.0, third / 2.0];
        for (g, w) in c.pixel_weight.iter().zip(want) {
            assert!((g - w).abs() < 1e-7, "{:?}", c.pixel_weight);
        }
    }
}
