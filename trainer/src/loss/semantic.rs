//! L_sem: the rendered compact semantic feature, mapped to the 384-d text space by the
//! network's Φ_sem (y = W·l + b), should point where the MiniLM sentence embedding of the
//! pixel's ground-truth label points. The teacher is given as a table with one row per instance
//! id (the embedding of that instance's label) and looked up per pixel; background pixels
//! (id 0) have no label and are left out.
//!
//! L_sem = (1/|Ω|) Σ_{p∈Ω} [1 − cos(W·l_p + b, t_{id(p)})], Ω = pixels with id ≠ 0; zero when Ω
//! is empty.
//!
//! The 384-d projections are never formed per pixel (at 4 views of 128×128 they cost about a
//! second a step on two cores): with t̂ the unit teacher row, y·t̂ = l·(Wᵀt̂) + b·t̂ and
//! |y|² = lᵀ(WᵀW)l + 2·l·(Wᵀb) + |b|², so every per-pixel quantity lives in d_s dimensions.

use burn::prelude::*;

use super::{LossError, NORM_EPS, check_dims, check_len, indices, normalize_rows, pixels_last, zero};

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
    let (pixels, labels): (Vec<i64>, Vec<i64>) =
        ids.iter().enumerate().filter(|(_, id)| **id != 0).map(|(p, &id)| (p as i64, i64::from(id))).unzip();
    if pixels.is_empty() {
        return Ok(zero(&device));
    }
    let q = pixels.len();
    let l = pixels_last(semantic).select(0, indices(pixels, &device)); // [Q, d_s]
    let labels = indices(labels, &device);
    let t = normalize_rows(teacher); // [rows, 384]
    let bias_row = bias.reshape([1, text]);
    // Per teacher row: Wᵀt̂ [rows, d_s] and b·t̂ [rows, 1], gathered per pixel.
    let along = t.clone().matmul(weight.clone()).select(0, labels.clone());
    let offset = (t * bias_row.clone()).sum_dim(1).select(0, labels);
    let dot = (l.clone() * along).sum_dim(1) + offset; // [Q, 1]
    let gram = weight.clone().transpose().matmul(weight.clone()); // [d_s, d_s]
    let wb = bias_row.clone().matmul(weight); // [1, d_s]
    let bb = (bias_row.clone() * bias_row).sum(); // [1]
    let norm2 =
        (l.clone().matmul(gram) * l.clone()).sum_dim(1) + (l * wb).sum_dim(1).mul_scalar(2.0) + bb.reshape([1, 1]);
    let cos = dot / norm2.clamp_min(0.0).add_scalar(NORM_EPS).sqrt();
    Ok(cos.neg().add_scalar(1.0).sum().div_scalar(q as f64))
}
