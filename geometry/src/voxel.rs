//! Confidence-aware voxelization (AnySplat style): per-pixel Gaussians from many views pile
//! up on the same surfaces, so they are binned in a world-space hash grid and every voxel's
//! Gaussians are merged into one, weighted by their depth confidence. The voxel size is a
//! fraction of the scene's robust extent (5–95 percentile box of the means), so it follows the
//! scene's unknown scale. Position, colour, the instance embedding S and the semantic
//! feature L are confidence-weighted means (S is L2-normalized per Gaussian first: only its
//! direction carries meaning; L is averaged raw because Φ_sem is affine); the covariance is
//! the weighted second moment Σ wᵢ (Σᵢ + (μᵢ−μ)(μᵢ−μ)ᵀ), turned back into scale and rotation
//! by eigen-decomposition; confidences add up. Opacity either is a weighted mean too, or keeps
//! the members' optical depth (see [`OpacityMerge`]). Binning is a parallel sort on the integer
//! voxel
//! key (an unbounded grid, no hash table to size), merging runs in parallel over runs of
//! equal keys, so the output order is deterministic.

use glam::{Mat3, Quat, Vec3};
use inssplat_proto::gaussian::{Gaussian, LengthMismatch, logit, sigmoid};
use inssplat_proto::{GaussianScene, INSTANCE_DIM};
use rayon::prelude::*;

use inssplat_proto::gaussian::unit;

/// Default voxel size as a fraction of the robust extent: 1/60. On the 128×128 views of the
/// test room this keeps ≤ 25% of the input pixels from 2 views up, 16 views keep ≤ 1.5× the
/// Gaussians of 8, and the ground-truth chain still recovers instances at mIoU ≥ 0.95
/// (`benches/post.rs`, `tests/post_pipeline.rs`). A voxel is then about 1.5 pixel footprints
/// at the scene's typical distance; much coarser voxels blur silhouettes, and close-up views
/// of moment-matched voxels show gaps between them. Swept for accuracy later (val40, 8 views):
/// 1/45 and 1/80 scored no better (instance mIoU −0.28 ± 0.57 and −0.68 ± 0.58, the model
/// card's history, "The voxel edge, swept for accuracy").
pub const DEFAULT_EXTENT_FRACTION: f32 = 1.0 / 60.0;

/// How a voxel's merged opacity follows from its members'.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OpacityMerge {
    /// The confidence-weighted mean of the members' opacities (the ablation: it makes a
    /// stack as see-through as each of its members).
    Mean,
    /// The members' optical depth, spread over the merged footprint: each member i adds
    /// −ln(1 − αᵢ)·aᵢ, aᵢ its face-on area (the product of its two largest scales), and the
    /// merged Gaussian of area a has α = 1 − exp(−Σ/a). k translucent members stacked on one
    /// spot (the same surface seen from k views) keep their composite 1 − Π(1 − αᵢ), and
    /// members side by side (neighbouring pixels of one view) keep their own α. The default:
    /// the network learns its opacities rendering every view's Gaussians unmerged.
    Coverage,
}

/// How a voxel's members are weighted by their confidence `c`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Weighting {
    /// wᵢ = cᵢ / Σ c.
    Normalized,
    /// wᵢ = softmax(cᵢ / temperature) within the voxel (AnySplat).
    Softmax { temperature: f32 },
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoxelParams {
    /// Voxel edge = this × the robust extent (largest 5–95 percentile range over x, y, z).
    pub extent_fraction: f32,
    pub weighting: Weighting,
    /// Gaussians less opaque than this add nothing and are dropped before merging.
    pub min_opacity: f32,
    pub opacity: OpacityMerge,
}

impl Default for VoxelParams {
    fn default() -> Self {
        Self {
            extent_fraction: DEFAULT_EXTENT_FRACTION,
            weighting: Weighting::Normalized,
            min_opacity: 0.005,
            opacity: OpacityMerge::Coverage,
        }
    }
}

/// [`voxelize`]'s result: the merged scene, what was done, and where every input went.
#[derive(Debug, Clone, PartialEq)]
pub struct Voxelized {
    pub scene: GaussianScene,
    pub report: VoxelReport,
    /// Index in `scene` of the Gaussian that each input Gaussian was merged into,
    /// [`DROPPED`] for one dropped before merging.
    pub voxel_of: Vec<u32>,
}

/// [`Voxelized::voxel_of`] of an input Gaussian that was dropped.
pub const DROPPED: u32 = u32::MAX;

impl Voxelized {
    /// Instance id of every input Gaussian: that of the Gaussian it was merged into, 0 for
    /// a dropped one. With per-pixel Gaussians in, this is each input view's instance map:
    /// every pixel takes the id of the surface its own depth put it on, exactly, with no
    /// rendering, and views agree because the ids live on the merged Gaussians.
    pub fn input_instance_ids(&self) -> Vec<u32> {
        self.voxel_of
            .par_iter()
            .map(|&v| if v == DROPPED { 0 } else { self.scene.instance_id[v as usize] })
            .collect()
    }

    /// The inverse of [`Voxelized::input_instance_ids`]: every merged Gaussian takes the id
    /// that most of its input Gaussians carry in `input_ids` (one per input Gaussian; a tie
    /// goes to the smaller id). Ids an input view's masks were corrected to (voted over the
    /// photo's superpixels) so reach the Gaussians, and through them the views rendered anew.
    pub fn adopt_member_majority(&mut self, input_ids: &[u32]) {
        assert_eq!(input_ids.len(), self.voxel_of.len(), "one id per input Gaussian");
        let mut pairs: Vec<(u32, u32)> = self
            .voxel_of
            .iter()
            .zip(input_ids)
            .filter(|(v, _)| **v != DROPPED)
            .map(|(&v, &id)| (v, id))
            .collect();
        pairs.par_sort_unstable();
        // Runs of one (merged Gaussian, id) pair, in order: the longest run of each Gaussian
        // wins, and of equal runs the first, the smaller id.
        let mut best: Vec<(u32, u32)> = vec![(0, 0); self.scene.len()];
        for run in pairs.chunk_by(|a, b| a == b) {
            let (v, id) = run[0];
            let slot = &mut best[v as usize];
            if run.len() as u32 > slot.0 {
                *slot = (run.len() as u32, id);
            }
        }
        for (id, &(count, winner)) in self.scene.instance_id.iter_mut().zip(&best) {
            if count > 0 {
                *id = winner;
            }
        }
    }
}

/// What voxelization did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoxelReport {
    pub gaussians_in: usize,
    pub gaussians_out: usize,
    /// Dropped before merging: below `min_opacity` or with a non-finite mean.
    pub dropped: usize,
    pub robust_extent: f32,
    pub voxel_size: f32,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VoxelError {
    #[error("invalid scene: {0}")]
    Scene(#[from] LengthMismatch),
    #[error("extent_fraction must be positive and finite, got {0}")]
    Fraction(f32),
    #[error("softmax temperature must be positive and finite, got {0}")]
    Temperature(f32),
}

impl VoxelParams {
    /// The voxel edge for Gaussians whose [`robust_extent`] is `extent`:
    /// [`VoxelParams::extent_fraction`] of it (1e-6 when it is 0).
    pub fn voxel_size(&self, extent: f32) -> f32 {
        if extent > 0.0 { extent * self.extent_fraction } else { 1e-6 }
    }
}

/// Largest 5–95 percentile range of the means over the three axes (0 for fewer than 2).
pub fn robust_extent(means: &[[f32; 3]]) -> f32 {
    if means.len() < 2 {
        return 0.0;
    }
    (0..3)
        .map(|axis| {
            let mut v: Vec<f32> = means.iter().map(|m| m[axis]).collect();
            let lo = percentile(&mut v, 0.05);
            let hi = percentile(&mut v, 0.95);
            hi - lo
        })
        .fold(0.0, f32::max)
}

fn percentile(v: &mut [f32], q: f32) -> f32 {
    let k = ((v.len() - 1) as f32 * q).round() as usize;
    *v.select_nth_unstable_by(k, f32::total_cmp).1
}

/// Merges the Gaussians of `scene` per voxel.
pub fn voxelize(scene: &GaussianScene, params: &VoxelParams) -> Result<Voxelized, VoxelError> {
    scene.validate()?;
    if !(params.extent_fraction.is_finite() && params.extent_fraction > 0.0) {
        return Err(VoxelError::Fraction(params.extent_fraction));
    }
    if let Weighting::Softmax { temperature } = params.weighting
        && !(temperature.is_finite() && temperature > 0.0)
    {
        return Err(VoxelError::Temperature(temperature));
    }
    let kept: Vec<u32> = (0..scene.len() as u32)
        .into_par_iter()
        .filter(|&i| {
            usable(scene, i as usize)
                && sigmoid(scene.logit_opacity[i as usize]) >= params.min_opacity
        })
        .collect();
    let kept_means: Vec<[f32; 3]> = kept.iter().map(|&i| scene.means[i as usize]).collect();
    let extent = robust_extent(&kept_means);
    let voxel_size = params.voxel_size(extent);
    let inv = 1.0 / voxel_size;
    let mut keyed: Vec<([i64; 3], u32)> = kept_means
        .par_iter()
        .zip(kept.par_iter())
        .map(|(m, &i)| ([0, 1, 2].map(|a| (m[a] * inv).floor() as i64), i))
        .collect();
    keyed.par_sort_unstable();
    let mut starts: Vec<usize> =
        (0..keyed.len()).filter(|&j| j == 0 || keyed[j].0 != keyed[j - 1].0).collect();
    starts.push(keyed.len());
    let members: Vec<u32> = keyed.into_iter().map(|(_, i)| i).collect();
    let voxels = starts.len() - 1;
    let mut voxel_of = vec![DROPPED; scene.len()];
    for (v, run) in starts.windows(2).enumerate() {
        for &i in &members[run[0]..run[1]] {
            voxel_of[i as usize] = v as u32;
        }
    }

    const VOXELS_PER_TASK: usize = 2048;
    let parts: Vec<GaussianScene> = (0..voxels.div_ceil(VOXELS_PER_TASK))
        .into_par_iter()
        .map(|task| {
            let range = task * VOXELS_PER_TASK..((task + 1) * VOXELS_PER_TASK).min(voxels);
            let mut out = GaussianScene::with_sem_dim(scene.sem_dim);
            out.reserve(range.len());
            let mut merger = Merger::new(scene.sem_dim);
            for v in range {
                merger.merge_into(scene, &members[starts[v]..starts[v + 1]], params, &mut out);
            }
            out
        })
        .collect();
    let mut out =
        GaussianScene { meta: scene.meta.clone(), ..GaussianScene::with_sem_dim(scene.sem_dim) };
    out.reserve(voxels);
    for part in parts {
        out.append(part);
    }
    let report = VoxelReport {
        gaussians_in: scene.len(),
        gaussians_out: out.len(),
        dropped: scene.len() - kept.len(),
        robust_extent: extent,
        voxel_size,
    };
    Ok(Voxelized { scene: out, report, voxel_of })
}

/// Largest log scale kept: e^(2·40) still fits an f32 variance.
const MAX_LOG_SCALE: f32 = 40.0;

/// A Gaussian with finite mean and opacity, finite bounded log scales and a non-zero finite
/// rotation; anything else would poison its voxel's merge.
fn usable(scene: &GaussianScene, i: usize) -> bool {
    let r = scene.rotations[i];
    scene.means[i].iter().all(|c| c.is_finite())
        && scene.logit_opacity[i].is_finite()
        && scene.log_scales[i].iter().all(|l| l.is_finite() && *l <= MAX_LOG_SCALE)
        && r.iter().all(|c| c.is_finite())
        && r.iter().any(|&c| c != 0.0)
}

/// Scratch space for merging one voxel.
struct Merger {
    weights: Vec<f32>,
    semantic: Vec<f32>,
}

impl Merger {
    fn new(sem_dim: usize) -> Self {
        Self { weights: Vec::new(), semantic: vec![0.0; sem_dim] }
    }

    fn merge_into(
        &mut self,
        scene: &GaussianScene,
        idx: &[u32],
        params: &VoxelParams,
        out: &mut GaussianScene,
    ) {
        if let [i] = idx {
            let i = *i as usize;
            out.push(Gaussian {
                mean: scene.means[i],
                log_scale: scene.log_scales[i],
                rotation: scene.rotations[i],
                logit_opacity: scene.logit_opacity[i],
                sh_dc: scene.sh_dc[i],
                confidence: scene.confidence[i],
                instance_embedding: unit(scene.instance_embedding[i]),
                semantic: scene.semantic_of(i),
                instance_id: scene.instance_id[i],
            });
            return;
        }
        let conf = |i: u32| {
            let c = scene.confidence[i as usize];
            if c.is_finite() { c.max(1e-6) } else { 1e-6 }
        };
        self.weights.clear();
        match params.weighting {
            Weighting::Normalized => self.weights.extend(idx.iter().map(|&i| conf(i))),
            Weighting::Softmax { temperature } => {
                let top = idx.iter().map(|&i| conf(i)).fold(f32::MIN, f32::max);
                self.weights.extend(idx.iter().map(|&i| ((conf(i) - top) / temperature).exp()));
            }
        }
        let total: f32 = self.weights.iter().sum();
        self.weights.iter_mut().for_each(|w| *w /= total);

        let mut mean = Vec3::ZERO;
        let mut sh = Vec3::ZERO;
        let mut opacity = 0.0;
        let mut embedding = [0.0; INSTANCE_DIM];
        self.semantic.fill(0.0);
        let (mut best, mut best_w) = (idx[0] as usize, f32::MIN);
        for (&i, &w) in idx.iter().zip(&self.weights) {
            let i = i as usize;
            mean += w * Vec3::from(scene.means[i]);
            sh += w * Vec3::from(scene.sh_dc[i]);
            opacity += w * sigmoid(scene.logit_opacity[i]);
            for (e, s) in embedding.iter_mut().zip(unit(scene.instance_embedding[i])) {
                *e += w * s;
            }
            for (a, s) in self.semantic.iter_mut().zip(scene.semantic_of(i)) {
                *a += w * s;
            }
            if w > best_w {
                (best, best_w) = (i, w);
            }
        }
        let mut cov = Mat3::ZERO;
        for (&i, &w) in idx.iter().zip(&self.weights) {
            let i = i as usize;
            let d = Vec3::from(scene.means[i]) - mean;
            cov += (covariance(scene.log_scales[i], scene.rotations[i]) + outer(d, d)) * w;
        }
        let (log_scale, rotation) =
            scale_rotation(cov).unwrap_or((scene.log_scales[best], scene.rotations[best]));
        if params.opacity == OpacityMerge::Coverage {
            let depth: f32 = idx
                .iter()
                .map(|&i| {
                    optical_depth(scene.logit_opacity[i as usize], scene.log_scales[i as usize])
                })
                .sum();
            opacity = (1.0 - (-depth / face_area(log_scale)).exp()).min(MAX_MERGED_OPACITY);
        }
        out.push(Gaussian {
            mean: mean.to_array(),
            log_scale,
            rotation,
            logit_opacity: logit(opacity),
            sh_dc: sh.to_array(),
            confidence: idx.iter().map(|&i| conf(i)).sum(),
            instance_embedding: embedding,
            semantic: &self.semantic,
            instance_id: scene.instance_id[best],
        });
    }
}

/// Opacities of members are capped here before their optical depth is taken, and merged
/// opacities after: a fully opaque member would have infinite depth.
const MAX_MERGED_OPACITY: f32 = 0.999;

/// Area a Gaussian of `log_scale` shows face on: the product of its two largest scales.
fn face_area(log_scale: [f32; 3]) -> f32 {
    let [a, b, c] = log_scale;
    (a + b + c - a.min(b).min(c)).exp()
}

/// −ln(1 − α)·area of one member (see [`OpacityMerge::Coverage`]).
fn optical_depth(logit_opacity: f32, log_scale: [f32; 3]) -> f32 {
    let alpha = sigmoid(logit_opacity).min(MAX_MERGED_OPACITY);
    -(1.0 - alpha).ln() * face_area(log_scale)
}

fn outer(a: Vec3, b: Vec3) -> Mat3 {
    Mat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// Σ = R diag(s²) Rᵀ from log scales and a w,x,y,z quaternion.
pub fn covariance(log_scale: [f32; 3], rotation: [f32; 4]) -> Mat3 {
    let [w, x, y, z] = rotation;
    let r = Mat3::from_quat(Quat::from_xyzw(x, y, z, w).normalize());
    let s2 = Vec3::from(log_scale.map(|l| (2.0 * l).exp()));
    r * Mat3::from_diagonal(s2) * r.transpose()
}

/// Log scales and a w,x,y,z unit quaternion whose covariance is `cov` (symmetric), by
/// eigen-decomposition; variances are floored at 1e-12 so flat Gaussians stay finite. `None`
/// when the decomposition does not converge or is not finite.
pub fn scale_rotation(cov: Mat3) -> Option<([f32; 3], [f32; 4])> {
    let m = nalgebra::Matrix3::from_fn(|r, c| cov.col(c)[r]);
    let eig = nalgebra::SymmetricEigen::try_new(m, f32::EPSILON, 256)?;
    if !eig.eigenvalues.iter().all(|v| v.is_finite()) {
        return None;
    }
    let col = |k: usize| {
        Vec3::new(eig.eigenvectors[(0, k)], eig.eigenvectors[(1, k)], eig.eigenvectors[(2, k)])
    };
    let (a, b) = (col(0).normalize(), col(1).normalize());
    // A right-handed frame: the third axis follows from the first two.
    let r = Mat3::from_cols(a, b, a.cross(b).normalize());
    let q = Quat::from_mat3(&r).normalize();
    let log_scale = [0, 1, 2].map(|k| 0.5 * eig.eigenvalues[k].max(1e-12).ln());
    let finite = log_scale.iter().chain(&[q.w, q.x, q.y, q.z]).all(|v| v.is_finite());
    finite.then_some((log_scale, [q.w, q.x, q.y, q.z]))
}

#[cfg(test)]
mod tests;
