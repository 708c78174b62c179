//! Colour superpixels of a view, and the network's per-pixel features snapped to them. The
//! decoder's instance embeddings are smooth across object outlines (it upsamples 8×8-patch
//! tokens); the photo's own colour edges are sharp. Felzenszwalb & Huttenlocher's graph-based
//! segmentation (IJCV 2004) over-segments the photo along those edges, and each segment's
//! pixels then take their segment's mean feature, so that an object's outline in the
//! features follows its outline in the photo. An input view's instance map, read back from
//! the merged Gaussians, is voted over the same segments.

use imageproc::union_find::DisjointSetForest;

/// Tunables of [`segment`], in the units of `skimage.segmentation.felzenszwalb`. The default
/// scale was chosen on the validation split: 200 scored within noise of 100 and above 400 and
/// 800 (the model card's history).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SuperpixelParams {
    /// Larger gives larger segments: a segment joins a neighbour across an edge only while
    /// the edge is no stronger than its inner variation plus `scale / 255 / its size`
    /// (colours in [0, 1]).
    pub scale: f32,
    /// Gaussian blur of the photo before its edges are weighed (pixels; 0: none).
    pub sigma: f32,
    /// Segments smaller than this (pixels) join their most alike neighbour afterwards.
    pub min_size: usize,
}

impl Default for SuperpixelParams {
    fn default() -> Self {
        SuperpixelParams { scale: 200.0, sigma: 0.5, min_size: 10 }
    }
}

/// Felzenszwalb segmentation of a planar `[3][height][width]` image (values in [0, 1]) on its
/// 8-connected pixel grid: a segment id for each pixel, numbered 0.. in order of first pixel.
pub fn segment(planar: &[f32], width: usize, height: usize, params: &SuperpixelParams) -> Vec<u32> {
    let n = width * height;
    assert_eq!(planar.len(), 3 * n, "a planar RGB image of {width}×{height}");
    assert!(
        4 * n as u64 <= 1 << 32,
        "{width}×{height}: too many pixels to number the edges in 32 bits"
    );
    let image = blur(planar, width, height, params.sigma);
    let colour = |i: usize| [image[i], image[n + i], image[2 * n + i]];
    // Each edge as one sortable word: its weight's bits (non-negative floats sort as their
    // bits do) above its pixel and direction, so that equal weights keep the grid's order
    // and the segments do not depend on the sort's implementation.
    const STEPS: [(isize, isize); 4] = [(0, 1), (1, 0), (1, 1), (-1, 1)];
    let mut edges = Vec::with_capacity(4 * n);
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            for (d, &(dy, dx)) in STEPS.iter().enumerate() {
                let (ny, nx) = (y as isize + dy, x as isize + dx);
                if ny < 0 || ny >= height as isize || nx >= width as isize {
                    continue;
                }
                let (a, b) = (colour(i), colour(ny as usize * width + nx as usize));
                let w =
                    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
                edges.push(u64::from(w.to_bits()) << 32 | (4 * i + d) as u64);
            }
        }
    }
    edges.sort_unstable();
    let ends = |e: u64| {
        let id = (e & 0xffff_ffff) as usize;
        let (i, (dy, dx)) = (id / 4, STEPS[id % 4]);
        (
            f32::from_bits((e >> 32) as u32),
            i,
            ((i / width) as isize + dy) as usize * width + ((i % width) as isize + dx) as usize,
        )
    };
    let k = params.scale / 255.0;
    let mut forest = DisjointSetForest::new(n);
    // Size and threshold of each tree, valid at its root.
    let mut size = vec![1usize; n];
    let mut threshold = vec![k; n];
    for &e in &edges {
        let (w, a, b) = ends(e);
        let (ra, rb) = (forest.root(a), forest.root(b));
        if ra != rb && w <= threshold[ra].min(threshold[rb]) {
            join(&mut forest, &mut size, ra, rb);
            let r = forest.root(ra);
            threshold[r] = w + k / size[r] as f32;
        }
    }
    for &e in &edges {
        let (_, a, b) = ends(e);
        let (ra, rb) = (forest.root(a), forest.root(b));
        if ra != rb && (size[ra] < params.min_size || size[rb] < params.min_size) {
            join(&mut forest, &mut size, ra, rb);
        }
    }
    let mut label_of_root = vec![u32::MAX; n];
    let mut next = 0;
    (0..n)
        .map(|i| {
            let r = forest.root(i);
            if label_of_root[r] == u32::MAX {
                label_of_root[r] = next;
                next += 1;
            }
            label_of_root[r]
        })
        .collect()
}

/// Joins two roots' trees and keeps the size at the new root.
fn join(forest: &mut DisjointSetForest, size: &mut [usize], ra: usize, rb: usize) {
    let total = size[ra] + size[rb];
    forest.union(ra, rb);
    size[forest.root(ra)] = total;
}

/// Separable Gaussian blur of each plane, the kernel cut at 4σ and renormalized at the borders.
fn blur(planar: &[f32], width: usize, height: usize, sigma: f32) -> Vec<f32> {
    if sigma <= 0.0 {
        return planar.to_vec();
    }
    let radius = (4.0 * sigma).ceil() as isize;
    let kernel: Vec<f32> =
        (-radius..=radius).map(|t| (-(t * t) as f32 / (2.0 * sigma * sigma)).exp()).collect();
    let pass = |src: &[f32], along_x: bool| -> Vec<f32> {
        let mut dst = vec![0.0; src.len()];
        for (p, plane) in src.chunks_exact(width * height).enumerate() {
            for y in 0..height as isize {
                for x in 0..width as isize {
                    let (mut sum, mut weight) = (0.0, 0.0);
                    for (t, &g) in (-radius..=radius).zip(&kernel) {
                        let (sx, sy) = if along_x { (x + t, y) } else { (x, y + t) };
                        if (0..width as isize).contains(&sx) && (0..height as isize).contains(&sy) {
                            sum += g * plane[sy as usize * width + sx as usize];
                            weight += g;
                        }
                    }
                    dst[p * width * height + y as usize * width + x as usize] = sum / weight;
                }
            }
        }
        dst
    };
    pass(&pass(planar, true), false)
}

/// Replaces each pixel's feature in a planar `[channels][pixels]` map (the instance
/// embeddings, which the clustering reads as directions) by the mean direction over its
/// segment: each pixel's feature counts as a unit vector, and the mean is rescaled to unit
/// length.
pub fn snap(features: &mut [f32], segments: &[u32]) {
    let pixels = segments.len();
    assert_eq!(features.len() % pixels.max(1), 0, "a planar map of {pixels} pixels");
    let channels = features.len() / pixels.max(1);
    let count = segments.iter().max().map_or(0, |&m| m as usize + 1);
    let length = |p: usize| {
        (0..channels).map(|c| features[c * pixels + p].powi(2)).sum::<f32>().sqrt().max(1e-12)
    };
    let lengths: Vec<f32> = (0..pixels).map(length).collect();
    let mut sums = vec![0.0f32; count * channels];
    for (p, &s) in segments.iter().enumerate() {
        for c in 0..channels {
            sums[s as usize * channels + c] += features[c * pixels + p] / lengths[p];
        }
    }
    for mean in sums.chunks_exact_mut(channels) {
        let norm = mean.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-12);
        mean.iter_mut().for_each(|v| *v /= norm);
    }
    for (c, plane) in features.chunks_exact_mut(pixels).enumerate() {
        for (&s, f) in segments.iter().zip(plane) {
            *f = sums[s as usize * channels + c];
        }
    }
}

/// Gives every pixel of a segment the id most of the segment's pixels carry (ties: the
/// smallest id).
pub fn vote(ids: &mut [u32], segments: &[u32]) {
    let count = segments.iter().max().map_or(0, |&m| m as usize + 1);
    let mut tallies: Vec<rustc_hash::FxHashMap<u32, u32>> = vec![Default::default(); count];
    for (&s, &id) in segments.iter().zip(ids.iter()) {
        *tallies[s as usize].entry(id).or_default() += 1;
    }
    let winners: Vec<u32> = tallies
        .iter()
        .map(|t| {
            t.iter().max_by_key(|(id, n)| (**n, std::cmp::Reverse(**id))).map_or(0, |(id, _)| *id)
        })
        .collect();
    for (&s, id) in segments.iter().zip(ids.iter_mut()) {
        *id = winners[s as usize];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w`×`h` planar image whose left `split` columns are one colour and the rest another.
    fn two_halves(w: usize, h: usize, split: usize, left: [f32; 3], right: [f32; 3]) -> Vec<f32> {
        (0..3)
            .flat_map(|c| (0..w * h).map(move |i| if i % w < split { left[c] } else { right[c] }))
            .collect()
    }

    #[test]
    fn two_flat_regions_give_two_segments_along_their_edge() {
        let (w, h) = (20, 12);
        let image = two_halves(w, h, 7, [0.9, 0.1, 0.1], [0.1, 0.2, 0.8]);
        let seg =
            segment(&image, w, h, &SuperpixelParams { sigma: 0.0, ..SuperpixelParams::default() });
        for (i, &s) in seg.iter().enumerate() {
            assert_eq!(s, u32::from(i % w >= 7), "pixel {i}");
        }
    }

    #[test]
    fn a_region_smaller_than_the_minimum_joins_its_neighbour() {
        let (w, h) = (20, 12);
        // A 2-column strip (24 pixels) against a minimum of 30.
        let image = two_halves(w, h, 2, [0.9, 0.1, 0.1], [0.1, 0.2, 0.8]);
        let params = SuperpixelParams { sigma: 0.0, min_size: 30, ..SuperpixelParams::default() };
        assert!(segment(&image, w, h, &params).iter().all(|&s| s == 0));
    }

    #[test]
    fn voting_gives_each_segment_its_majority_id() {
        let segments = [0, 0, 0, 1, 1, 2, 2];
        let mut ids = [4, 7, 4, 9, 2, 5, 5];
        vote(&mut ids, &segments);
        // Segment 1 ties between 9 and 2: the smaller id wins, whatever the order.
        assert_eq!(ids, [4, 4, 4, 2, 2, 5, 5]);
    }

    #[test]
    fn snapping_takes_each_segments_mean_direction() {
        // Two channels, planar, three pixels in segment 0 and two in segment 1. Each pixel
        // counts once whatever its length, and a zero vector adds nothing.
        let mut f = vec![10.0, 0.0, 0.0, 3.0, 0.0, 0.0, 1.0, 0.0, 0.0, -2.0];
        snap(&mut f, &[0, 0, 0, 1, 1]);
        let s = 0.5f32.sqrt();
        let want = [s, s, s, s, s, s, s, s, -s, -s];
        assert!(f.iter().zip(want).all(|(g, w)| (g - w).abs() < 1e-6), "{f:?}");
    }
}
