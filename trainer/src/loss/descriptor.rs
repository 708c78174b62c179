//! L_desc, the term of a network with a descriptor head
//! ([`crate::model::ModelConfig::descriptor_head`]): registration matches the views on these
//! descriptors where keypoints find too few matches, so the pixels of two views that see the
//! same point must have the most alike descriptors. For every pair of input views (a, b),
//! [`descriptor_matches`] samples pixels of a whose true point b sees (inside b, and not behind
//! what b sees there) and finds the pixel of b that sees it. [`descriptor_loss`] is InfoNCE
//! with in-batch negatives: each sample's L2-normalized descriptor in a is asked to be nearer
//! its own match in b than the pair's other samples' matches (the cross-entropy of cos/τ), and
//! each match in b the same of the samples in a. Two samples within [`NEAR`] pixels of each
//! other (in a or in b) are not each other's negatives: their descriptors should be alike.
//! [`descriptor_grid_loss`] asks what registration asks instead: each sample's descriptor is
//! compared with every point of the other view's [`registration_grid`], and the grid points
//! within a stride of its match must win (the cross-entropy of cos/τ over the grid, the
//! positives' probabilities summed), both ways. Added to L_geom with weight
//! `descriptor_weight`.

use burn::prelude::*;
use burn::tensor::activation::log_softmax;
use inssplat_proto::Camera;

use super::{LossError, check_len, constant, indices, normalize_rows, pixels_last, zero};

/// Relative depth margin within which a projected point counts as the surface b sees.
const VISIBLE: f32 = 0.03;
/// Samples closer than this (pixels, in either view) are not each other's negatives.
pub const NEAR: f32 = 2.0;
/// τ of the cross-entropy of cos/τ.
pub const TEMPERATURE: f64 = 0.07;
/// Samples per pair of views when the config names none.
pub const DEFAULT_SAMPLES: usize = 256;
/// Added to the logit of a pair of samples that are not each other's negatives.
const MASKED: f32 = -1.0e4;

/// The sampled matches of the pairs of input views: for pair `k`, samples
/// `offsets[k]..offsets[k + 1]` of `a` and `b`, flat pixel indices `view · H·W + y · W + x`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DescriptorMatches {
    pub a: Vec<usize>,
    pub b: Vec<usize>,
    pub offsets: Vec<usize>,
}

impl DescriptorMatches {
    pub fn pairs(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    pub fn len(&self) -> usize {
        self.a.len()
    }

    pub fn is_empty(&self) -> bool {
        self.a.is_empty()
    }

    /// The samples of pair `k`.
    pub fn pair(&self, k: usize) -> std::ops::Range<usize> {
        self.offsets[k]..self.offsets[k + 1]
    }

    /// The same matches but those of the pairs of `cameras` (in [`descriptor_matches`]' order)
    /// whose views turn by less than `min_angle` radians from one to the other: such pairs are
    /// left without samples, so that the loss weighs the wide baselines registration fails on.
    pub fn turned_at_least(&self, cameras: &[Camera], min_angle: f32) -> DescriptorMatches {
        let mut out = DescriptorMatches { offsets: vec![0], ..Default::default() };
        for (k, (a, b)) in view_pairs(cameras.len()).enumerate().take(self.pairs()) {
            if cameras[a].rotation.angle_between(cameras[b].rotation) >= min_angle {
                out.a.extend_from_slice(&self.a[self.pair(k)]);
                out.b.extend_from_slice(&self.b[self.pair(k)]);
            }
            out.offsets.push(out.a.len());
        }
        out
    }
}

/// The pairs (a, b) of `views` views, a < b, in the order of [`DescriptorMatches`]' pairs.
pub fn view_pairs(views: usize) -> impl Iterator<Item = (usize, usize)> {
    (0..views).flat_map(move |a| (a + 1..views).map(move |b| (a, b)))
}

/// For every pair of the `cameras`' views a < b (square views of `size`, true `depth`
/// `[V][H][W]` metres, 0 = no hit), up to `per_pair` pixels of a whose true point b sees, spread
/// evenly over those pixels in scan order, and the pixel of b that sees each. Pairs that share
/// no pixel have no samples.
pub fn descriptor_matches(
    cameras: &[Camera],
    depth: &[f32],
    size: usize,
    per_pair: usize,
) -> Result<DescriptorMatches, LossError> {
    let hw = size * size;
    check_len("ground-truth depth of the descriptor matches", cameras.len() * hw, depth.len())?;
    let cameras: Vec<Camera> = cameras
        .iter()
        .map(|c| Camera { intrinsics: c.intrinsics.scaled_to(size as u32, size as u32), ..*c })
        .collect();
    let mut matches = DescriptorMatches { offsets: vec![0], ..Default::default() };
    for (a, b) in view_pairs(cameras.len()) {
        let seen: Vec<(usize, usize)> = (0..hw)
            .filter_map(|p| {
                let z = depth[a * hw + p];
                if z <= 0.0 {
                    return None;
                }
                let own = cameras[a].unproject((p % size) as f32 + 0.5, (p / size) as f32 + 0.5, z);
                let point = cameras[b].world_to_camera(cameras[a].camera_to_world(own));
                let (x, y) = cameras[b].pixel_of(point)?;
                let there = depth[b * hw + y * size + x];
                ((point.z - there).abs() <= VISIBLE * there)
                    .then_some((a * hw + p, b * hw + y * size + x))
            })
            .collect();
        let take = seen.len().min(per_pair);
        for i in 0..take {
            let (pa, pb) = seen[i * seen.len() / take];
            matches.a.push(pa);
            matches.b.push(pb);
        }
        matches.offsets.push(matches.a.len());
    }
    Ok(matches)
}

/// L_desc of `descriptors` `[V, D, H, W]` (raw; normalized here) on `matches` (from
/// [`descriptor_matches`] at the same size); zero when there are none.
pub fn descriptor_loss(
    descriptors: Tensor<4>,
    matches: &DescriptorMatches,
) -> Result<Tensor<1>, LossError> {
    let [v, d, h, w] = descriptors.dims();
    check_len("descriptor matches", matches.a.len(), matches.b.len())?;
    let device = descriptors.device();
    let total = matches.len();
    if total == 0 {
        return Ok(zero(&device));
    }
    check_matches_inside(matches, [v, d, h, w])?;
    let pairs = matches.pairs();
    let k = (0..pairs).map(|p| matches.pair(p).len()).max().unwrap_or(0);
    // Every pair padded to k samples; a padded sample points at pixel 0 and is masked out.
    let mut index_a = vec![0i64; pairs * k];
    let mut index_b = vec![0i64; pairs * k];
    let mut bias = vec![MASKED; pairs * k * k];
    let mut diagonal = vec![0.0f32; pairs * k * k];
    let pixel = |i: usize| ((i % w) as f32, ((i / w) % h) as f32);
    let near = |x: usize, y: usize| {
        let ((ax, ay), (bx, by)) = (pixel(x), pixel(y));
        (ax - bx).abs() <= NEAR && (ay - by).abs() <= NEAR
    };
    let weight = 0.5 / total as f32;
    for p in 0..pairs {
        let range = matches.pair(p);
        for (i, s) in range.clone().enumerate() {
            index_a[p * k + i] = matches.a[s] as i64;
            index_b[p * k + i] = matches.b[s] as i64;
            diagonal[(p * k + i) * k + i] = weight;
            for (j, t) in range.clone().enumerate() {
                let negative = i != j
                    && (near(matches.a[s], matches.a[t]) || near(matches.b[s], matches.b[t]));
                if !negative {
                    bias[(p * k + i) * k + j] = 0.0;
                }
            }
        }
    }
    let rows = normalize_rows(pixels_last(descriptors));
    let gather =
        |index: Vec<i64>| rows.clone().select(0, indices(index, &device)).reshape([pairs, k, d]);
    let (a, b) = (gather(index_a), gather(index_b));
    let logits = a.matmul(b.swap_dims(1, 2)).mul_scalar(1.0 / TEMPERATURE)
        + constant(bias, [pairs, k, k], &device);
    let picks = constant(diagonal, [pairs, k, k], &device);
    let both = log_softmax(logits.clone(), 2) + log_softmax(logits, 1);
    Ok((both * picks).sum().neg())
}

/// Flat pixel indices `y · W + x` of the grid registration compares descriptors on: every
/// `stride`-th pixel of an `h`×`w` view in both directions, starting half a stride in.
pub fn registration_grid(h: usize, w: usize, stride: usize) -> Vec<usize> {
    let stride = stride.max(1);
    (stride / 2..h)
        .step_by(stride)
        .flat_map(|y| (stride / 2..w).step_by(stride).map(move |x| y * w + x))
        .collect()
}

/// L_desc with the grid's negatives: for every sample of `matches` (from [`descriptor_matches`]
/// at the size of `descriptors` `[V, D, H, W]`), −log of the probability, under the softmax of
/// cos/τ between its descriptor in a and every point of b's [`registration_grid`] of `stride`,
/// of the grid points within `stride` pixels (in x and in y) of its match; the same from b to
/// a's grid; averaged over the samples and both ways. Zero when there are none.
pub fn descriptor_grid_loss(
    descriptors: Tensor<4>,
    matches: &DescriptorMatches,
    stride: usize,
) -> Result<Tensor<1>, LossError> {
    let [v, d, h, w] = descriptors.dims();
    check_len("descriptor matches", matches.a.len(), matches.b.len())?;
    let device = descriptors.device();
    let hw = h * w;
    check_matches_inside(matches, [v, d, h, w])?;
    let pairs: Vec<usize> = (0..matches.pairs()).filter(|&p| !matches.pair(p).is_empty()).collect();
    if pairs.is_empty() {
        return Ok(zero(&device));
    }
    let grid = registration_grid(h, w, stride);
    let g = grid.len();
    if g == 0 {
        return Err(LossError::Shape {
            what: "descriptor map holding a registration grid point",
            expected: vec![v, d, stride / 2 + 1, stride / 2 + 1],
            got: vec![v, d, h, w],
        });
    }
    let k = pairs.iter().map(|&p| matches.pair(p).len()).max().unwrap_or(0);
    let weight = 0.5 / matches.len() as f32;
    let rows = normalize_rows(pixels_last(descriptors));
    let grid_rows: Vec<i64> =
        (0..v).flat_map(|view| grid.iter().map(move |&p| (view * hw + p) as i64)).collect();
    let grid_rows = rows.clone().select(0, indices(grid_rows, &device)).reshape([v, g, d]);
    // One direction: queries at `from`'s samples, keys on the grid of the view of `to`'s.
    let one_way = |from: &[usize], to: &[usize]| {
        let mut query = vec![0i64; pairs.len() * k];
        let mut key_view = vec![0i64; pairs.len()];
        // 0 on a row's positives, MASKED elsewhere; a padded row counts every point (its loss
        // is then 0, and its weight 0 besides).
        let mut bias = vec![0.0f32; pairs.len() * k * g];
        let mut weights = vec![0.0f32; pairs.len() * k];
        for (row, &p) in pairs.iter().enumerate() {
            key_view[row] = (to[matches.offsets[p]] / hw) as i64;
            for (i, s) in matches.pair(p).enumerate() {
                let r = row * k + i;
                query[r] = from[s] as i64;
                weights[r] = weight;
                let (tx, ty) = (to[s] % w, (to[s] % hw) / w);
                for (j, &q) in grid.iter().enumerate() {
                    let near = (q % w).abs_diff(tx) <= stride && (q / w).abs_diff(ty) <= stride;
                    bias[r * g + j] = if near { 0.0 } else { MASKED };
                }
            }
        }
        let queries = rows.clone().select(0, indices(query, &device)).reshape([pairs.len(), k, d]);
        let keys = grid_rows.clone().select(0, indices(key_view, &device));
        let logits = queries.matmul(keys.swap_dims(1, 2)).mul_scalar(1.0 / TEMPERATURE);
        let positives = (log_softmax(logits, 2) + constant(bias, [pairs.len(), k, g], &device))
            .exp()
            .sum_dim(2)
            .log();
        (positives * constant(weights, [pairs.len(), k, 1], &device)).sum().neg()
    };
    Ok(one_way(&matches.a, &matches.b) + one_way(&matches.b, &matches.a))
}

/// A named error unless every match of `matches` lies inside a descriptor map of `dims`.
fn check_matches_inside(matches: &DescriptorMatches, dims: [usize; 4]) -> Result<(), LossError> {
    let [v, d, h, w] = dims;
    let worst = matches.a.iter().chain(&matches.b).max().copied().unwrap_or(0);
    if worst >= v * h * w {
        return Err(LossError::Shape {
            what: "descriptor map holding every match",
            expected: vec![worst / (h * w) + 1, d, h, w],
            got: vec![v, d, h, w],
        });
    }
    Ok(())
}

/// How well descriptors match on the true matches, for validation: over the samples of
/// [`descriptor_matches`], the share whose most alike descriptor among the points of b's
/// [`registration_grid`] of `stride` lies within `stride` pixels of the true match.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DescriptorScores {
    pub samples: usize,
    pub stride: usize,
    pub within_stride: f64,
}

impl DescriptorScores {
    /// The scores of both sample sets together.
    pub fn merge(self, o: DescriptorScores) -> DescriptorScores {
        let n = self.samples + o.samples;
        let hits = self.within_stride * self.samples as f64 + o.within_stride * o.samples as f64;
        DescriptorScores {
            samples: n,
            stride: self.stride.max(o.stride),
            within_stride: if n == 0 { 0.0 } else { hits / n as f64 },
        }
    }
}

/// [`DescriptorScores`] of host `descriptors` `[V][D][H][W]` on `matches`.
pub fn descriptor_scores(
    descriptors: &[f32],
    dims: [usize; 4],
    matches: &DescriptorMatches,
    stride: usize,
) -> DescriptorScores {
    let [v, d, h, w] = dims;
    let hw = h * w;
    // Pixel-major and unit length: row `view · H·W + p`.
    let mut rows = vec![0.0f32; v * hw * d];
    for (i, row) in rows.chunks_exact_mut(d).enumerate() {
        let (view, p) = (i / hw, i % hw);
        for (c, x) in row.iter_mut().enumerate() {
            *x = descriptors[(view * d + c) * hw + p];
        }
        let norm = row.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-12);
        row.iter_mut().for_each(|x| *x /= norm);
    }
    let row = |i: usize| &rows[i * d..(i + 1) * d];
    let grid = registration_grid(h, w, stride);
    let hits = matches
        .a
        .iter()
        .zip(&matches.b)
        .filter(|&(&a, &b)| {
            let view = b / hw;
            let cosine =
                |p: usize| row(view * hw + p).iter().zip(row(a)).map(|(x, y)| x * y).sum::<f32>();
            let best = grid.iter().map(|&p| (p, cosine(p))).max_by(|x, y| x.1.total_cmp(&y.1));
            let truth = b % hw;
            best.is_some_and(|(p, _)| {
                (p % w).abs_diff(truth % w) <= stride && (p / w).abs_diff(truth / w) <= stride
            })
        })
        .count();
    DescriptorScores {
        samples: matches.len(),
        stride,
        within_stride: hits as f64 / matches.len().max(1) as f64,
    }
}
