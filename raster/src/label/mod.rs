//! Naming instances. Each instance's semantic prototype is the mean, over its Gaussians, of
//! the L2-normalized text-space features Φ_sem(L) = W·L + b, normalized again; its label is
//! the vocabulary entry of highest cosine similarity. An open-vocabulary query compares one
//! text embedding with every prototype and returns the instances that score at least
//! [`QueryRule::min_score`] and lie within [`QueryRule::margin`] of the best score, so all
//! instances of the queried kind come back and near-misses of another kind do not. Text
//! embeddings come in as plain vectors: this crate does not know the text model. [`masks`]
//! renders per-Gaussian ids into per-view id maps.

pub mod masks;

use inssplat_proto::GaussianScene;
use inssplat_proto::gaussian::LengthMismatch;
use rayon::prelude::*;

/// Φ_sem: text-space feature = `weight`·L + `bias`; `weight` is `[text_dim][sem_dim]`
/// row-major (the model's `sem_proj_weight`), `bias` is `[text_dim]`.
#[derive(Debug, Clone, Copy)]
pub struct SemanticProjection<'a> {
    pub weight: &'a [f32],
    pub bias: &'a [f32],
}

impl SemanticProjection<'_> {
    pub fn text_dim(&self) -> usize {
        self.bias.len()
    }

    /// Writes W·l + b into `out` (`text_dim` entries).
    pub fn project(&self, l: &[f32], out: &mut [f32]) {
        for (r, o) in out.iter_mut().enumerate() {
            let row = &self.weight[r * l.len()..(r + 1) * l.len()];
            *o = self.bias[r] + row.iter().zip(l).map(|(w, x)| w * x).sum::<f32>();
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LabelError {
    #[error("invalid scene: {0}")]
    Scene(#[from] LengthMismatch),
    #[error("sem_proj_weight has {actual} values, expected {expected} ({text_dim}×{sem_dim})")]
    Projection { actual: usize, expected: usize, text_dim: usize, sem_dim: usize },
    #[error("text embedding {index} has {actual} dimensions, the prototypes have {expected}")]
    TextDim { index: usize, actual: usize, expected: usize },
}

/// The semantic prototype of one instance.
#[derive(Debug, Clone, PartialEq)]
pub struct InstancePrototype {
    pub id: u32,
    /// Unit vector in text space (zero if no member had a non-zero feature).
    pub embedding: Vec<f32>,
    pub gaussians: usize,
}

/// Prototypes of the ids 1..=max id present in `scene.instance_id`, in id order; ids with no
/// Gaussian are left out.
pub fn semantic_prototypes(
    scene: &GaussianScene,
    proj: &SemanticProjection<'_>,
) -> Result<Vec<InstancePrototype>, LabelError> {
    scene.validate()?;
    let (text_dim, sem_dim) = (proj.text_dim(), scene.sem_dim);
    if proj.weight.len() != text_dim * sem_dim {
        return Err(LabelError::Projection {
            actual: proj.weight.len(),
            expected: text_dim * sem_dim,
            text_dim,
            sem_dim,
        });
    }
    let k = scene.instance_id.iter().copied().max().unwrap_or(0) as usize;
    let (sums, counts) = (0..scene.len())
        .into_par_iter()
        .filter(|&i| scene.instance_id[i] > 0)
        .fold(
            || (vec![0.0f32; k * text_dim], vec![0usize; k], vec![0.0f32; text_dim]),
            |(mut sums, mut counts, mut t), i| {
                proj.project(scene.semantic_of(i), &mut t);
                let id = scene.instance_id[i] as usize - 1;
                counts[id] += 1;
                let n = t.iter().map(|x| x * x).sum::<f32>().sqrt();
                if n > 1e-12 {
                    sums[id * text_dim..(id + 1) * text_dim].iter_mut().zip(&t).for_each(|(s, x)| *s += x / n);
                }
                (sums, counts, t)
            },
        )
        .map(|(s, c, _)| (s, c))
        .reduce(
            || (vec![0.0; k * text_dim], vec![0; k]),
            |(mut s, mut c), (s2, c2)| {
                s.iter_mut().zip(s2).for_each(|(a, b)| *a += b);
                c.iter_mut().zip(c2).for_each(|(a, b)| *a += b);
                (s, c)
            },
        );
    Ok((0..k)
        .filter(|&id| counts[id] > 0)
        .map(|id| InstancePrototype {
            id: id as u32 + 1,
            embedding: normalized(&sums[id * text_dim..(id + 1) * text_dim]),
            gaussians: counts[id],
        })
        .collect())
}

/// A label (index into the vocabulary) and its cosine similarity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LabelMatch {
    pub label: usize,
    pub score: f32,
}

/// The best vocabulary entry per prototype (same order); `None` for an empty vocabulary or a
/// zero prototype. Vocabulary vectors need not be normalized.
pub fn assign_labels<V: AsRef<[f32]>>(
    prototypes: &[InstancePrototype],
    vocabulary: &[V],
) -> Result<Vec<Option<LabelMatch>>, LabelError> {
    let vocab = normalized_texts(prototypes, vocabulary)?;
    Ok(prototypes
        .iter()
        .map(|p| {
            if p.embedding.iter().all(|&x| x == 0.0) {
                return None;
            }
            vocab
                .iter()
                .enumerate()
                .map(|(label, t)| LabelMatch { label, score: dot(&p.embedding, t) })
                .max_by(|a, b| a.score.total_cmp(&b.score))
        })
        .collect())
}

fn normalized_texts<V: AsRef<[f32]>>(
    prototypes: &[InstancePrototype],
    texts: &[V],
) -> Result<Vec<Vec<f32>>, LabelError> {
    let dim = prototypes.first().map_or(0, |p| p.embedding.len());
    texts
        .iter()
        .enumerate()
        .map(|(index, t)| {
            let t = t.as_ref();
            if !prototypes.is_empty() && t.len() != dim {
                return Err(LabelError::TextDim { index, actual: t.len(), expected: dim });
            }
            Ok(normalized(t))
        })
        .collect()
}

/// Which instances a text query returns.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QueryRule {
    /// Cosine similarity an instance needs at least.
    pub min_score: f32,
    /// An instance must also score within this of the best-scoring instance.
    pub margin: f32,
    /// And within this of its own label's score: a text that another vocabulary label
    /// describes much better ("banana" for an instance labelled "chair") does not name it.
    pub label_margin: f32,
}

impl Default for QueryRule {
    fn default() -> Self {
        Self { min_score: 0.3, margin: 0.1, label_margin: 0.15 }
    }
}

/// An instance returned by a query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QueryHit {
    pub id: u32,
    pub score: f32,
}

/// Instances matching the query `text` under `rule`, best first. `label_scores[i]` is the
/// score of prototype i's own label (see [`assign_labels`]); an empty slice skips that test.
pub fn query(
    prototypes: &[InstancePrototype],
    text: &[f32],
    label_scores: &[f32],
    rule: &QueryRule,
) -> Result<Vec<QueryHit>, LabelError> {
    let t = normalized_texts(prototypes, &[text])?.remove(0);
    let mut hits: Vec<(QueryHit, f32)> = prototypes
        .iter()
        .enumerate()
        .map(|(i, p)| (QueryHit { id: p.id, score: dot(&p.embedding, &t) }, label_scores.get(i).copied().unwrap_or(f32::MIN)))
        .collect();
    hits.sort_by(|a, b| b.0.score.total_cmp(&a.0.score));
    let best = hits.first().map_or(f32::MIN, |h| h.0.score);
    hits.retain(|(h, own)| h.score >= rule.min_score && h.score >= best - rule.margin && h.score >= own - rule.label_margin);
    Ok(hits.into_iter().map(|(h, _)| h).collect())
}

fn dot(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn normalized(v: &[f32]) -> Vec<f32> {
    let n = dot(v, v).sqrt();
    if n > 1e-12 { v.iter().map(|x| x / n).collect() } else { vec![0.0; v.len()] }
}

#[cfg(test)]
mod tests;
