//! Instance clustering. inssplat clusters ONCE in 3D: HDBSCAN runs on a bounded, weighted
//! subsample of the voxelized Gaussians' L2-normalized instance embeddings S, each next to the
//! Gaussian's position (centred on the scene, divided by the scene's RMS spread, times
//! `position_weight`); each cluster becomes a prototype (the normalized mean of its members'
//! embeddings) with a centre (their mean position), and every Gaussian takes the id of the
//! prototype nearest in both when its cosine similarity to it reaches `min_cosine`, else 0.
//! The paper clusters the embeddings alone; the position separates two objects whose
//! embeddings the network has not told apart, which are then in different places. Ids then
//! live on the Gaussians, so every rendered view agrees by construction, and the cost is that
//! of a fixed-size HDBSCAN plus one linear assignment pass, whatever the number of views.
//! [`per_view`] holds the paper's own mode (HDBSCAN on each rendered 2D feature map) for
//! comparison.

pub mod per_view;
pub mod split;

use hdbscan::{Hdbscan, HdbscanError, HdbscanHyperParams};
use inssplat_proto::gaussian::{LengthMismatch, sigmoid, unit};
use inssplat_proto::{GaussianScene, INSTANCE_DIM};
use rayon::prelude::*;

/// Embedding as compared: L2-normalized S.
pub type Embedding = [f32; INSTANCE_DIM];

/// A point as HDBSCAN and the assignment see it: its embedding, then its weighted position.
type Feature = [f32; INSTANCE_DIM + 3];

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClusterParams {
    /// At most this many points go into HDBSCAN (weighted sampling without replacement).
    /// HDBSCAN's cost grows with the square of it and not with the views; the default, 1500,
    /// takes 12 ms on this machine's CPU (4000: 74 ms) and scored the test split as well
    /// (`inssplat-eval score --sweep`, see the model card).
    pub max_samples: usize,
    /// HDBSCAN: smallest cluster, as a share of the sampled points (at least 2 points); a share
    /// rather than a count keeps what an instance must cover the same whatever the sample size.
    /// The default, 0.5% (with `min_samples` 5 then), was chosen on 40 val-split scenes at 8 views
    /// (`synth --split val --eval-views`) with the 0.3 weights: with 1% and 10, small objects
    /// (a few dozen of the 1500 sampled points) never formed a cluster of their own; 0.5% and 5
    /// find about as many instances as there are (14.9 per scene for 9.5 true objects plus the
    /// room shell's parts) and score the context views' instance mIoU 22.9 against 15.8; 0.5%
    /// and 3 scored 25.1 but split scenes into 22 instances (see the model card). Re-swept with
    /// 0.8 (`inssplat-eval score --min-cluster-share S --min-samples M`): 0.3% lifts target-view
    /// instance mIoU by 0.3 ± 0.2 on 300 train rooms but costs query IoU 0.45 ± 0.17 and finds
    /// 21 instances where 0.5% finds 14 for 9.5 objects, so 0.5% stays.
    pub min_cluster_share: f32,
    /// HDBSCAN: neighbours that define a point's core distance. 3 since the embeddings are
    /// snapped to the photos' superpixels (`crate::superpixel`): on 120 val-split scenes at 8
    /// views, against 5, target-view instance mIoU +0.74 ± 0.28 and T-mIoU +0.98 ± 0.36 (paired
    /// per scene), for 30 instances found a scene instead of 22 (9.6 objects and the shell's
    /// parts); 10 scored lower on val40 (the model card's history).
    pub min_samples: usize,
    /// Weight of a point's position (centred, in units of the scene's RMS spread) next to its
    /// unit embedding; 0 clusters the embeddings alone (the paper). The default, 0.5, was
    /// chosen on 40 val-split scenes at 8 views with the 0.4 weights: target-view instance
    /// mIoU 16.5 at 0, 16.7 at 0.25, 17.4 at 0.35, 17.7 at 0.5, 17.6 at 0.7 and at 1 (see the
    /// model card).
    pub position_weight: f32,
    /// A point joins its nearest prototype only at this cosine similarity or more; else 0.
    pub min_cosine: f32,
    /// Seed of the subsample.
    pub seed: u64,
}

impl ClusterParams {
    /// HDBSCAN's smallest cluster for a sample of `sampled` points.
    pub fn min_cluster_size(&self, sampled: usize) -> usize {
        ((self.min_cluster_share * sampled as f32).ceil() as usize).max(2)
    }

    /// Names the first parameter out of its range.
    pub fn validate(&self) -> Result<(), ClusterError> {
        let bad = |name, reason| Err(ClusterError::Params { name, reason });
        if self.max_samples < 2 {
            return bad("max_samples", "must be at least 2");
        }
        if !(self.min_cluster_share > 0.0 && self.min_cluster_share < 1.0) {
            return bad("min_cluster_share", "must lie in (0, 1)");
        }
        if self.min_samples < 1 {
            return bad("min_samples", "must be at least 1");
        }
        if !(self.position_weight.is_finite() && self.position_weight >= 0.0) {
            return bad("position_weight", "must be a finite number ≥ 0");
        }
        if !(-1.0..=1.0).contains(&self.min_cosine) {
            return bad("min_cosine", "must lie in [-1, 1]");
        }
        Ok(())
    }
}

impl Default for ClusterParams {
    fn default() -> Self {
        Self {
            max_samples: 1500,
            min_cluster_share: 0.005,
            min_samples: 3,
            position_weight: 0.5,
            min_cosine: 0.5,
            seed: 0x1a5e,
        }
    }
}

#[derive(Debug, Clone, thiserror::Error)]
pub enum ClusterError {
    #[error("invalid scene: {0}")]
    Scene(#[from] LengthMismatch),
    #[error("HDBSCAN: {0}")]
    Hdbscan(#[from] HdbscanError),
    #[error(
        "feature map has {actual} values, expected {expected} ({channels} channels of {pixels} pixels)"
    )]
    Shape { actual: usize, expected: usize, channels: usize, pixels: usize },
    #[error("cluster parameter `{name}` is invalid: {reason}")]
    Params { name: &'static str, reason: &'static str },
}

/// Outcome of clustering a set of points.
#[derive(Debug, Clone, PartialEq)]
pub struct Clustering {
    /// Id per point: 1..=K, 0 = none.
    pub ids: Vec<u32>,
    /// Unit prototype of id k at index k−1; ids are ordered by sampled cluster size, largest first.
    pub prototypes: Vec<Embedding>,
    /// Points HDBSCAN saw, and how many of them it called noise.
    pub sampled: usize,
    pub sample_noise: usize,
}

/// Clusters the scene's instance embeddings once in 3D and writes an id per Gaussian into
/// `scene.instance_id`. Sampling is weighted by opacity alone, so the sample spreads over the
/// scene's surfaces as its Gaussians do. A merged Gaussian's confidence sums its members', and
/// weighting by it as well drew most of the sample from what many pixels saw (the near, large
/// surfaces): on 120 val-split scenes at 8 views, opacity alone scored T-mIoU +2.0 ± 0.6 and
/// target-view instance mIoU +0.35 ± 0.29 against opacity · confidence (paired per scene).
pub fn cluster_instances(
    scene: &mut GaussianScene,
    params: &ClusterParams,
) -> Result<Clustering, ClusterError> {
    scene.validate()?;
    let points: Vec<Embedding> = scene.instance_embedding.par_iter().map(|e| unit(*e)).collect();
    let weights: Vec<f32> = scene.logit_opacity.par_iter().map(|&o| sigmoid(o)).collect();
    let positions = normalized_positions(&scene.means);
    let clustering = cluster_points_at(&points, Some(&positions), &weights, params)?;
    scene.instance_id.clone_from(&clustering.ids);
    Ok(clustering)
}

/// Positions centred on their mean and divided by their RMS distance from it.
fn normalized_positions(means: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let n = means.len().max(1) as f32;
    let centre: [f32; 3] = std::array::from_fn(|k| means.iter().map(|p| p[k]).sum::<f32>() / n);
    let spread = (means
        .iter()
        .map(|p| (0..3).map(|k| (p[k] - centre[k]).powi(2)).sum::<f32>())
        .sum::<f32>()
        / n)
        .sqrt();
    let spread = if spread > 1e-12 { spread } else { 1.0 };
    means.iter().map(|p| std::array::from_fn(|k| (p[k] - centre[k]) / spread)).collect()
}

/// Clusters unit vectors: HDBSCAN on a weighted subsample, then nearest-prototype assignment
/// of every point. Zero vectors and points of weight ≤ 0 are never sampled; zero vectors get
/// id 0.
pub fn cluster_points(
    points: &[Embedding],
    weights: &[f32],
    params: &ClusterParams,
) -> Result<Clustering, ClusterError> {
    cluster_points_at(points, None, weights, params)
}

/// [`cluster_points`] with each point's (normalized) position beside its embedding, weighted by
/// [`ClusterParams::position_weight`]; `None` clusters the embeddings alone.
pub fn cluster_points_at(
    points: &[Embedding],
    positions: Option<&[[f32; 3]]>,
    weights: &[f32],
    params: &ClusterParams,
) -> Result<Clustering, ClusterError> {
    params.validate()?;
    let features: Vec<Feature> = points
        .iter()
        .enumerate()
        .map(|(i, e)| {
            let at = positions.map_or([0.0; 3], |p| p[i]);
            std::array::from_fn(|k| {
                if k < INSTANCE_DIM { e[k] } else { params.position_weight * at[k - INSTANCE_DIM] }
            })
        })
        .collect();
    let sample = weighted_sample(points, weights, params.max_samples, params.seed);
    let min_cluster_size = params.min_cluster_size(sample.len());
    if sample.len() < min_cluster_size || sample.len() <= params.min_samples {
        return Ok(Clustering {
            ids: vec![0; points.len()],
            prototypes: Vec::new(),
            sampled: sample.len(),
            sample_noise: 0,
        });
    }
    let data: Vec<Vec<f32>> = sample.iter().map(|&i| features[i].to_vec()).collect();
    let hp = HdbscanHyperParams::builder()
        .min_cluster_size(min_cluster_size)
        .min_samples(params.min_samples)
        .build();
    let labels = Hdbscan::new(&data, hp).cluster()?;

    let clusters =
        labels.iter().filter_map(|&l| usize::try_from(l).ok()).max().map_or(0, |m| m + 1);
    let mut sums = vec![([0.0f32; INSTANCE_DIM + 3], 0usize); clusters];
    for (&i, &l) in sample.iter().zip(&labels) {
        if let Ok(l) = usize::try_from(l) {
            let (sum, count) = &mut sums[l];
            sum.iter_mut().zip(&features[i]).for_each(|(s, p)| *s += p);
            *count += 1;
        }
    }
    sums.sort_by_key(|s| std::cmp::Reverse(s.1));
    // Each cluster: its unit mean embedding, then its mean (weighted) position.
    let centres: Vec<Feature> = sums
        .iter()
        .filter(|(_, n)| *n > 0)
        .map(|(s, n)| {
            let e: Embedding = unit(std::array::from_fn(|k| s[k]));
            std::array::from_fn(|k| if k < INSTANCE_DIM { e[k] } else { s[k] / *n as f32 })
        })
        .collect();
    let ids = assign(&features, &centres, params.min_cosine);
    let prototypes: Vec<Embedding> =
        centres.iter().map(|c| std::array::from_fn(|k| c[k])).collect();
    Ok(Clustering {
        ids,
        prototypes,
        sampled: sample.len(),
        sample_noise: labels.iter().filter(|&&l| l < 0).count(),
    })
}

/// The nearest cluster centre in embedding and weighted position (squared distance: 2 − 2·cosine
/// plus the positions' squared distance; with no positions, the most similar embedding), id
/// k+1, or 0 when its embedding's cosine similarity is below `min_cosine`, or for a zero
/// embedding.
fn assign(points: &[Feature], centres: &[Feature], min_cosine: f32) -> Vec<u32> {
    points
        .par_iter()
        .map(|p| {
            if p[..INSTANCE_DIM].iter().all(|&x| x == 0.0) {
                return 0;
            }
            let mut best = (0, f32::MAX, 0.0);
            for (k, q) in centres.iter().enumerate() {
                let cosine: f32 = p[..INSTANCE_DIM].iter().zip(q).map(|(a, b)| a * b).sum();
                let apart: f32 = p[INSTANCE_DIM..]
                    .iter()
                    .zip(&q[INSTANCE_DIM..])
                    .map(|(a, b)| (a - b).powi(2))
                    .sum();
                let distance = 2.0 - 2.0 * cosine + apart;
                if distance < best.1 {
                    best = (k as u32 + 1, distance, cosine);
                }
            }
            if best.2 >= min_cosine { best.0 } else { 0 }
        })
        .collect()
}

/// Indices of up to `m` points drawn without replacement with probability ∝ weight
/// (Efraimidis–Spirakis: the `m` largest keys ln(u)/w), in increasing index order. Only
/// points with a positive finite weight and a non-zero vector take part.
fn weighted_sample(points: &[Embedding], weights: &[f32], m: usize, seed: u64) -> Vec<usize> {
    let mut keyed: Vec<(f32, usize)> = (0..points.len())
        .filter(|&i| {
            weights[i].is_finite() && weights[i] > 0.0 && points[i].iter().any(|&x| x != 0.0)
        })
        .map(|i| (uniform(seed, i as u64).ln() / weights[i], i))
        .collect();
    if keyed.len() > m {
        keyed.select_nth_unstable_by(m - 1, |a, b| b.0.total_cmp(&a.0));
        keyed.truncate(m);
    }
    let mut idx: Vec<usize> = keyed.into_iter().map(|(_, i)| i).collect();
    idx.sort_unstable();
    idx
}

/// A uniform number in (0, 1) from (seed, index), by the SplitMix64 finalizer.
fn uniform(seed: u64, index: u64) -> f32 {
    let mut z = seed.wrapping_add(index.wrapping_add(1).wrapping_mul(0x9e37_79b9_7f4a_7c15));
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^= z >> 31;
    ((z >> 40) as f32 + 0.5) / (1u64 << 24) as f32
}

#[cfg(test)]
mod tests;
