//! Naming instances. Each instance's semantic prototype is the mean, over its Gaussians, of
//! the L2-normalized text-space features Φ_sem(L) = W·L + b, normalized again; its label is
//! the vocabulary entry of highest cosine similarity. An open-vocabulary query compares one
//! text embedding with every prototype and returns the instances that score at least
//! [`QueryRule::min_score`] and lie within [`QueryRule::margin`] of the best score, so all
//! instances of the queried kind come back and near-misses of another kind do not. Text
//! embeddings come in as plain vectors: this crate does not know the text model.

pub mod detections;
pub mod shape;

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

    /// W·l + β·b (`text_dim` entries).
    fn project(&self, l: &[f64], beta: f64) -> Vec<f32> {
        (0..self.text_dim())
            .map(|r| (beta * self.bias[r] as f64 + dot64(self.row(r, l.len()), l)) as f32)
            .collect()
    }

    /// Row `r` of W for features of `sem_dim` entries.
    fn row(&self, r: usize, sem_dim: usize) -> &[f32] {
        &self.weight[r * sem_dim..(r + 1) * sem_dim]
    }

    /// WᵀW (`[sem_dim][sem_dim]`) and Wᵀb, with which |W·l + b|² = lᵀ(WᵀW)l + 2(Wᵀb)·l + b·b
    /// costs sem_dim² per feature instead of text_dim × sem_dim.
    fn gram(&self, sem_dim: usize) -> (Vec<f64>, Vec<f64>) {
        let mut gram = vec![0.0f64; sem_dim * sem_dim];
        let mut wb = vec![0.0f64; sem_dim];
        for (r, &b) in self.bias.iter().enumerate() {
            let row = self.row(r, sem_dim);
            for (i, &wi) in row.iter().enumerate() {
                wb[i] += wi as f64 * b as f64;
                for (g, &wj) in gram[i * sem_dim..(i + 1) * sem_dim].iter_mut().zip(row) {
                    *g += wi as f64 * wj as f64;
                }
            }
        }
        (gram, wb)
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
    // Σ over an instance of t/|t| with t = W·l + b is W·(Σ l/|t|) + b·(Σ 1/|t|): per Gaussian
    // only |t| is needed (from the Gram matrix) and the sums stay in feature space; each
    // instance is projected once.
    let (gram, wb) = proj.gram(sem_dim);
    let bb: f64 = proj.bias.iter().map(|&b| b as f64 * b as f64).sum();
    let k = scene.instance_id.iter().copied().max().unwrap_or(0) as usize;
    // Per instance: Σ l/|t| (sem_dim values), then Σ 1/|t|.
    let stride = sem_dim + 1;
    let (sums, counts) = (0..scene.len())
        .into_par_iter()
        .filter(|&i| scene.instance_id[i] > 0)
        .fold(
            || (vec![0.0f64; k * stride], vec![0usize; k]),
            |(mut sums, mut counts), i| {
                let l = scene.semantic_of(i);
                let id = scene.instance_id[i] as usize - 1;
                counts[id] += 1;
                let quadratic: f64 = (0..sem_dim)
                    .map(|a| {
                        let row = &gram[a * sem_dim..(a + 1) * sem_dim];
                        l[a] as f64
                            * (row.iter().zip(l).map(|(&g, &x)| g * x as f64).sum::<f64>()
                                + 2.0 * wb[a])
                    })
                    .sum();
                let n = (quadratic + bb).max(0.0).sqrt();
                if n > 1e-12 {
                    let sum = &mut sums[id * stride..(id + 1) * stride];
                    sum.iter_mut().zip(l).for_each(|(s, &x)| *s += x as f64 / n);
                    sum[sem_dim] += 1.0 / n;
                }
                (sums, counts)
            },
        )
        .reduce(
            || (vec![0.0; k * stride], vec![0; k]),
            |(mut s, mut c), (s2, c2)| {
                s.iter_mut().zip(s2).for_each(|(a, b)| *a += b);
                c.iter_mut().zip(c2).for_each(|(a, b)| *a += b);
                (s, c)
            },
        );
    Ok((0..k)
        .filter(|&id| counts[id] > 0)
        .map(|id| {
            let sum = &sums[id * stride..(id + 1) * stride];
            InstancePrototype {
                id: id as u32 + 1,
                embedding: normalized(&proj.project(&sum[..sem_dim], sum[sem_dim])),
                gaussians: counts[id],
            }
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
        .map(|(i, p)| {
            (
                QueryHit { id: p.id, score: dot(&p.embedding, &t) },
                label_scores.get(i).copied().unwrap_or(f32::MIN),
            )
        })
        .collect();
    hits.sort_by(|a, b| b.0.score.total_cmp(&a.0.score));
    let best = hits.first().map_or(f32::MIN, |h| h.0.score);
    hits.retain(|(h, own)| {
        h.score >= rule.min_score
            && h.score >= best - rule.margin
            && h.score >= own - rule.label_margin
    });
    Ok(hits.into_iter().map(|(h, _)| h).collect())
}

fn dot(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// w·x with w in f32 and x in f64, summed in f64.
fn dot64(w: &[f32], x: &[f64]) -> f64 {
    w.iter().zip(x).map(|(&w, x)| w as f64 * x).sum()
}

/// Moves `p`'s embedding by `weight` × `dir` and normalizes it again.
fn add_direction(p: &mut InstancePrototype, dir: &[f32], weight: f32) {
    let sum: Vec<f32> = p.embedding.iter().zip(dir).map(|(e, d)| e + weight * d).collect();
    p.embedding = normalized(&sum);
}

fn normalized(v: &[f32]) -> Vec<f32> {
    let n = dot(v, v).sqrt();
    if n > 1e-12 { v.iter().map(|x| x / n).collect() } else { vec![0.0; v.len()] }
}

#[cfg(test)]
mod tests;
