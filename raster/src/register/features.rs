//! Keypoints and binary descriptors of one view, and their matches between two views.
//! Corners are FAST-9 (imageproc) on the grey image upsampled ×2 — at the model's 128² a
//! BRIEF patch (31 px) would otherwise cover a quarter of the image — and padded by its edge
//! pixels, so corners up to the border get a descriptor; one corner per grid cell (the
//! strongest) spreads them over the image. Descriptors are 256-bit BRIEF with test pairs drawn
//! from a fixed seed, so every view and every run compares the same tests. Matching is brute
//! force on Hamming distance, kept when mutual, below a distance bound and clearly better than
//! the second best (ratio test).

use glam::Vec2;
use image::{GrayImage, Luma, imageops};
use imageproc::binary_descriptors::brief::{TestPair, brief};
use imageproc::corners::corners_fast9;
use imageproc::point::Point;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::RegisterParams;

/// Upsampling of the grey image before detection and description.
const UPSAMPLE: u32 = 2;
/// Padding around the upsampled image: BRIEF needs its 15-pixel patch radius plus one.
const PAD: u32 = 16;
/// BRIEF descriptor length in bits.
const BITS: usize = 256;
/// Side of the patch the BRIEF tests are drawn in (imageproc's 31 px).
const PATCH: u32 = 31;

/// The keypoints of one view: positions in view pixels (pixel centres at +0.5) and their
/// descriptors, in the same order.
pub struct Features {
    pub points: Vec<Vec2>,
    descriptors: Vec<Descriptor>,
}

/// A BRIEF descriptor's bits.
type Descriptor = [u128; BITS / 128];

#[inline(always)]
fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    a.iter().zip(b).map(|(x, y)| (x ^ y).count_ones()).sum()
}

impl Features {
    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

/// The BRIEF test pairs every view uses: isotropic Gaussian around the patch centre
/// (σ = PATCH/5, the BRIEF paper's choice), clipped to the patch, from a fixed seed.
pub fn test_pairs() -> Vec<TestPair> {
    let mut rng = ChaCha8Rng::seed_from_u64(0x0062_7269_6566);
    let centre = (PATCH / 2) as f32;
    let sigma = PATCH as f32 / 5.0;
    let mut coord = || loop {
        // Box–Muller.
        let (u1, u2): (f32, f32) = (rng.random_range(1e-7..1.0), rng.random());
        let z = (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos();
        let c = (centre + sigma * z).round();
        if (0.0..PATCH as f32).contains(&c) {
            return c as u32;
        }
    };
    (0..BITS).map(|_| TestPair { p0: Point::new(coord(), coord()), p1: Point::new(coord(), coord()) }).collect()
}

/// Grey image of planar RGB `[3][H][W]` in [0, 1], upsampled ×[`UPSAMPLE`] and edge-padded
/// by [`PAD`].
fn grey_padded(rgb: &[f32], width: u32, height: u32) -> GrayImage {
    let px = (width * height) as usize;
    let grey = GrayImage::from_fn(width, height, |x, y| {
        let i = (y * width + x) as usize;
        let l = 0.299 * rgb[i] + 0.587 * rgb[px + i] + 0.114 * rgb[2 * px + i];
        Luma([(l.clamp(0.0, 1.0) * 255.0).round() as u8])
    });
    let up = imageops::resize(&grey, width * UPSAMPLE, height * UPSAMPLE, imageops::FilterType::Triangle);
    let (w, h) = up.dimensions();
    GrayImage::from_fn(w + 2 * PAD, h + 2 * PAD, |x, y| {
        let cx = x.saturating_sub(PAD).min(w - 1);
        let cy = y.saturating_sub(PAD).min(h - 1);
        *up.get_pixel(cx, cy)
    })
}

/// Keypoints stay this far (view pixels) inside the photo's rectangle, off the edge between a
/// letterboxed photo and its padding.
const PHOTO_MARGIN: u32 = 3;

/// Detects and describes the keypoints of one view (planar RGB `[3][H][W]` in [0, 1]) inside
/// the photo's rectangle `photo` = `[x0, y0, x1, y1)` (view pixels).
pub fn detect(rgb: &[f32], width: u32, height: u32, photo: [u32; 4], pairs: &[TestPair], params: &RegisterParams) -> Features {
    let image = grey_padded(rgb, width, height);
    let (w, h) = (width * UPSAMPLE, height * UPSAMPLE);
    let cell = params.grid_cell * UPSAMPLE;
    let (cols, rows) = (w.div_ceil(cell), h.div_ceil(cell));
    let mut best: Vec<Option<(f32, u32, u32)>> = vec![None; (cols * rows) as usize];
    for c in corners_fast9(&image, params.fast_threshold) {
        let [x0, y0, x1, y1] = photo.map(|v| v * UPSAMPLE + PAD);
        let m = PHOTO_MARGIN * UPSAMPLE;
        let inside = (x0 + m..x1.saturating_sub(m)).contains(&c.x) && (y0 + m..y1.saturating_sub(m)).contains(&c.y);
        if !inside {
            continue;
        }
        let slot = &mut best[(((c.y - PAD) / cell) * cols + (c.x - PAD) / cell) as usize];
        if slot.is_none_or(|(s, _, _)| c.score > s) {
            *slot = Some((c.score, c.x, c.y));
        }
    }
    let mut kept: Vec<(f32, u32, u32)> = best.into_iter().flatten().collect();
    kept.sort_by(|a, b| b.0.total_cmp(&a.0));
    kept.truncate(params.max_keypoints);
    let keypoints: Vec<Point<u32>> = kept.iter().map(|&(_, x, y)| Point::new(x, y)).collect();
    let pairs = pairs.to_vec();
    let (briefs, _) = brief(&image, &keypoints, BITS, Some(&pairs)).expect("padded keypoints are a patch radius inside");
    let descriptors = briefs.iter().map(|d| std::array::from_fn(|k| d.bits[k])).collect();
    let scale = UPSAMPLE as f32;
    let points = keypoints
        .iter()
        .map(|p| Vec2::new((p.x - PAD) as f32 + 0.5, (p.y - PAD) as f32 + 0.5) / scale)
        .collect();
    Features { points, descriptors }
}

/// All Hamming distances, row-major `[a][b]`; with the CPU's population-count instruction
/// where it has one (x86-64's baseline lacks it, and the bit-twiddling fallback took most of
/// the registration time).
fn distances(a: &[Descriptor], b: &[Descriptor]) -> Vec<u32> {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("popcnt") {
        // SAFETY: the CPU has the instruction the function is compiled for.
        return unsafe { distances_popcnt(a, b) };
    }
    distances_portable(a, b)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "popcnt")]
fn distances_popcnt(a: &[Descriptor], b: &[Descriptor]) -> Vec<u32> {
    distances_portable(a, b)
}

#[inline(always)]
fn distances_portable(a: &[Descriptor], b: &[Descriptor]) -> Vec<u32> {
    let mut dist = vec![0u32; a.len() * b.len()];
    for (row, da) in dist.chunks_exact_mut(b.len().max(1)).zip(a) {
        for (d, db) in row.iter_mut().zip(b) {
            *d = hamming(da, db);
        }
    }
    dist
}

/// Matches of `a` against `b` as index pairs: mutual nearest neighbours in Hamming distance,
/// at most `params.max_hamming` bits apart and below `params.ratio` × the second best.
pub fn match_features(a: &Features, b: &Features, params: &RegisterParams) -> Vec<(usize, usize)> {
    if a.is_empty() || b.is_empty() {
        return Vec::new();
    }
    let nb = b.len();
    let dist = distances(&a.descriptors, &b.descriptors);
    let best_in_a_for = |j: usize| (0..a.len()).min_by_key(|&i| dist[i * nb + j]).expect("a is not empty");
    let mut out = Vec::new();
    for i in 0..a.len() {
        let row = &dist[i * nb..(i + 1) * nb];
        let (mut first, mut second) = ((u32::MAX, usize::MAX), u32::MAX);
        for (j, &d) in row.iter().enumerate() {
            if d < first.0 {
                second = first.0;
                first = (d, j);
            } else if d < second {
                second = d;
            }
        }
        let (d, j) = first;
        let distinct = second == u32::MAX || (d as f32) < params.ratio * second as f32;
        if d <= params.max_hamming && distinct && best_in_a_for(j) == i {
            out.push((i, j));
        }
    }
    out
}
