//! L_ins, the instance-embedding loss on rendered instance features: pull every pixel toward
//! its instance's prototype, push prototypes of different instances apart (harder for
//! semantically similar pairs), and tie views together by pulling every pixel toward the
//! prototype its instance has in the other views.
//!
//! With f_p the rendered 8-d feature of pixel p scaled to unit length, k(p) its ground-truth
//! instance, v(p) its view, n_vk the pixels of instance k in view v and N_k = Σ_v n_vk:
//!
//! - prototypes μ̂_k = unit(Σ_{p: k(p)=k} f_p), per-view sums S_vk = Σ_{p∈(v,k)} f_p and
//!   leave-one-view-out prototypes μ̂_k^(−v) = unit(Σ_{v'≠v} S_v'k);
//! - pull = (1/K) Σ_k (1/N_k) Σ_{p∈k} [1 − f_p·μ̂_k − δ_pull]₊;
//! - push = (1/#pairs) Σ_{a<b} η_ab·[μ̂_a·μ̂_b − (1 − δ_push)]₊ over the K(K−1)/2 pairs, with
//!   η_ab = 1 + (η_max − 1)·clamp((c_ab − τ_sem)/(1 − τ_sem), 0, 1), c_ab the cosine between
//!   the instances' semantic prototypes unit(Σ_{p∈k} unit(sem_p)), computed on detached
//!   values (η ≡ 1 with [`HardNegatives::Uniform`]);
//! - cross = (1/|G|) Σ_{(v,k)∈G} (1/n_vk) Σ_{p∈(v,k)} [1 − f_p·μ̂_k^(−v) − δ_pull]₊ over the
//!   set G of (view, instance) pairs whose instance is also seen in another view (zero with
//!   [`CrossView::Off`], or when no instance is seen twice);
//! - L_ins = 2·pull + 1·push + 2·cross (weights from [`LossConfig`]).
//!
//! Background pixels (id 0: floor, walls, ceiling, nothing) take part as one more instance with
//! its own prototype: they are pulled together and every object is pushed away from them, so
//! that clustering at inference does not merge objects into the room. Averaging per instance
//! (not per pixel) keeps large regions such as the background from drowning small objects.

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;
use burn::tensor::activation::relu;

use super::{
    CrossView, HardNegatives, LossConfig, LossError, NORM_EPS, check_dims, check_len, constant,
    host, indices, normalize_rows, pixels_last, unit_pixel_vectors, zero,
};

/// The parts of L_ins, unweighted, each a one-element tensor.
#[derive(Debug, Clone)]
pub struct InstanceTerms {
    pub pull: Tensor<1>,
    pub push: Tensor<1>,
    pub cross: Tensor<1>,
}

impl InstanceTerms {
    /// pull_weight·pull + push_weight·push + cross_weight·cross.
    pub fn total(&self, config: &LossConfig) -> Tensor<1> {
        self.pull.clone().mul_scalar(config.pull_weight)
            + self.push.clone().mul_scalar(config.push_weight)
            + self.cross.clone().mul_scalar(config.cross_weight)
    }
}

/// Pixels grouped by instance, from the ground-truth id map alone.
struct Groups {
    views: usize,
    /// Distinct ids present, ascending; position = compact index k.
    instances: usize,
    /// Compact instance of every pixel.
    k_from_pixel: Vec<usize>,
    /// `[views][instances]` pixel counts.
    counts: Vec<usize>,
}

impl Groups {
    fn new(ids: &[u32], views: usize) -> Self {
        let mut distinct: Vec<u32> = ids.to_vec();
        distinct.sort_unstable();
        distinct.dedup();
        let k_from_pixel: Vec<usize> = ids
            .iter()
            .map(|id| distinct.binary_search(id).expect("every id is among the distinct ids"))
            .collect();
        let instances = distinct.len();
        let per_view = ids.len() / views.max(1);
        let mut counts = vec![0; views * instances];
        for (p, &k) in k_from_pixel.iter().enumerate() {
            counts[(p / per_view) * instances + k] += 1;
        }
        Self { views, instances, k_from_pixel, counts }
    }

    fn total(&self, k: usize) -> usize {
        (0..self.views).map(|v| self.counts[v * self.instances + k]).sum()
    }
}

/// L_ins of rendered instance features `embedding` `[V, E, H, W]` with ground-truth `ids`
/// (`[V][H][W]`, 0 = background); `semantic` `[V, D, H, W]` (any width D) gives the
/// hard-negative factors η and is only read, never differentiated.
pub fn instance_loss(
    embedding: Tensor<4>,
    semantic: &Tensor<4>,
    ids: &[u32],
    config: &LossConfig,
) -> Result<InstanceTerms, LossError> {
    let [views, _, height, width] = embedding.dims();
    let [sv, _, sh, sw] = semantic.dims();
    check_dims("semantic map (views, height, width)", &[views, height, width], &[sv, sh, sw])?;
    let pixels = views * height * width;
    check_len("instance ids", pixels, ids.len())?;
    let device = embedding.device();
    if pixels == 0 {
        return Ok(InstanceTerms {
            pull: zero(&device),
            push: zero(&device),
            cross: zero(&device),
        });
    }
    let groups = Groups::new(ids, views);
    let kk = groups.instances;

    let f = normalize_rows(pixels_last(embedding)); // [P, E]
    let e = f.dims()[1];
    let per_view = height * width;
    let group_of_pixel: Vec<i64> = groups
        .k_from_pixel
        .iter()
        .enumerate()
        .map(|(p, &k)| ((p / per_view) * kk + k) as i64)
        .collect();
    let group_index = indices(group_of_pixel, &device);
    let k_index = indices(groups.k_from_pixel.iter().map(|&k| k as i64).collect(), &device);
    // S_vk as rows v·K + k, and T_k = Σ_v S_vk.
    let view_sums = Tensor::<2>::zeros([views * kk, e], &device).select_assign(
        0,
        group_index.clone(),
        f.clone(),
        IndexingUpdateOp::Add,
    );
    let sums = view_sums.clone().reshape([views, kk, e]).sum_dim(0).reshape([kk, e]);
    let prototypes = normalize_rows(sums.clone()); // [K, E]

    let margin = 1.0 - config.pull_margin;
    // pull: per-pixel hinge, weighted 1/(K·N_k).
    let cos_own = (f.clone() * prototypes.clone().select(0, k_index)).sum_dim(1).reshape([pixels]);
    let pull_hinge = relu(cos_own.neg().add_scalar(margin));
    let pull_weights: Vec<f32> =
        groups.k_from_pixel.iter().map(|&k| 1.0 / (kk as f32 * groups.total(k) as f32)).collect();
    let pull = (pull_hinge * constant(pull_weights, [pixels], &device)).sum();

    let push = if kk < 2 {
        zero(&device)
    } else {
        let eta = match config.hard_negatives {
            HardNegatives::SemanticWeighted => {
                hard_negative_factors(&host("semantic map", semantic)?, &groups, config)
            }
            HardNegatives::Uniform => vec![1.0; kk * kk],
        };
        let pairs = (kk * (kk - 1) / 2) as f32;
        let pair_weights: Vec<f32> =
            (0..kk * kk).map(|i| if i / kk < i % kk { eta[i] / pairs } else { 0.0 }).collect();
        let cos = prototypes.clone().matmul(prototypes.transpose());
        (relu(cos.add_scalar(config.push_margin - 1.0)) * constant(pair_weights, [kk, kk], &device))
            .sum()
    };

    let cross = match config.cross_view {
        CrossView::Off => zero(&device),
        CrossView::On => {
            // Pixel weights 1/(|G|·n_vk) on groups seen in another view too, else 0.
            let seen_elsewhere = |g: usize| {
                let n = groups.counts[g];
                n > 0 && groups.total(g % kk) > n
            };
            let valid = (0..views * kk).filter(|&g| seen_elsewhere(g)).count();
            if valid == 0 {
                zero(&device)
            } else {
                let others =
                    sums.unsqueeze_dim::<3>(0).expand([views, kk, e]).reshape([views * kk, e])
                        - view_sums;
                let targets = normalize_rows(others).select(0, group_index);
                let cos_other = (f * targets).sum_dim(1).reshape([pixels]);
                let hinge = relu(cos_other.neg().add_scalar(margin));
                let weights: Vec<f32> = groups
                    .k_from_pixel
                    .iter()
                    .enumerate()
                    .map(|(p, &k)| {
                        let g = (p / per_view) * kk + k;
                        if seen_elsewhere(g) {
                            1.0 / (valid as f32 * groups.counts[g] as f32)
                        } else {
                            0.0
                        }
                    })
                    .collect();
                (hinge * constant(weights, [pixels], &device)).sum()
            }
        }
    };
    Ok(InstanceTerms { pull, push, cross })
}

/// η_ab for every ordered pair, `[K][K]` row-major, from the semantic map `[V][D][H][W]`.
fn hard_negative_factors(semantic: &[f32], groups: &Groups, config: &LossConfig) -> Vec<f32> {
    let (kk, pixels) = (groups.instances, groups.k_from_pixel.len());
    let d = semantic.len() / pixels;
    let per_view = pixels / groups.views;
    let mut prototypes = vec![0.0f64; kk * d];
    for (v, view) in semantic.chunks(d * per_view).enumerate() {
        let unit = unit_pixel_vectors(view, d);
        for (i, &k) in groups.k_from_pixel[v * per_view..(v + 1) * per_view].iter().enumerate() {
            for c in 0..d {
                prototypes[k * d + c] += f64::from(unit[i * d + c]);
            }
        }
    }
    for proto in prototypes.chunks_mut(d) {
        let norm = (proto.iter().map(|x| x * x).sum::<f64>() + NORM_EPS).sqrt();
        proto.iter_mut().for_each(|x| *x /= norm);
    }
    let (eta_max, tau) = (config.eta_max, config.tau_sem);
    (0..kk * kk)
        .map(|i| {
            let (a, b) = (i / kk, i % kk);
            let cos: f64 = (0..d).map(|c| prototypes[a * d + c] * prototypes[b * d + c]).sum();
            (1.0 + (eta_max - 1.0) * ((cos - tau) / (1.0 - tau)).clamp(0.0, 1.0)) as f32
        })
        .collect()
}
