//! Keypoints and binary descriptors of one view, and their matches between two views. Corners
//! are FAST-9 (imageproc) on a grey image of the view ([`KeypointImage`]): the photo itself
//! where it is larger than the model's input (a user's photo keeps the detail the input has
//! lost), else the view upsampled ×2 — at the model's 128² a BRIEF patch (31 px) would
//! otherwise cover a quarter of the image — padded by its edge pixels, so corners up to the
//! border get a descriptor; one corner per grid cell of the view (the strongest) spreads them
//! over the image, and their positions come back in view pixels. Descriptors are 256-bit BRIEF
//! with test pairs drawn from a fixed seed, so every view and every run compares the same
//! tests. Matching is brute force on Hamming distance, kept when mutual, below a distance bound
//! and clearly better than the second best (ratio test).

use glam::Vec2;
use image::{GrayImage, Luma, RgbImage, imageops};
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
    (0..BITS)
        .map(|_| TestPair { p0: Point::new(coord(), coord()), p1: Point::new(coord(), coord()) })
        .collect()
}

/// BT.601 luma of an RGB colour in [0, 1], as an 8-bit grey.
fn luma(r: f32, g: f32, b: f32) -> Luma<u8> {
    Luma([((0.299 * r + 0.587 * g + 0.114 * b).clamp(0.0, 1.0) * 255.0).round() as u8])
}

/// Edge-padded by [`PAD`], so that corners up to the border get a BRIEF patch.
fn padded(image: &GrayImage) -> GrayImage {
    let (w, h) = image.dimensions();
    GrayImage::from_fn(w + 2 * PAD, h + 2 * PAD, |x, y| {
        let cx = x.saturating_sub(PAD).min(w - 1);
        let cy = y.saturating_sub(PAD).min(h - 1);
        *image.get_pixel(cx, cy)
    })
}

/// Keypoints stay this far (view pixels) inside the photo, off the edge between a
/// letterboxed photo and its padding.
const PHOTO_MARGIN: f32 = 3.0;

/// A grey image that keypoints are found in, and where it lies in its view: the view's photo
/// rectangle upsampled ×[`UPSAMPLE`], or the photo itself at a finer scale than the model's
/// input (what a user's photo has and the network's input has lost).
#[derive(Debug, Clone)]
pub struct KeypointImage {
    /// The image, edge-padded by [`PAD`].
    grey: GrayImage,
    /// Its pixels per view pixel.
    per_view: f32,
    /// The view pixel position of its top-left corner.
    origin: Vec2,
}

impl KeypointImage {
    /// The photo rectangle `photo` = `[x0, y0, x1, y1)` of a view (planar RGB `[3][H][W]` in
    /// [0, 1]), upsampled ×[`UPSAMPLE`].
    pub fn of_view(rgb: &[f32], width: u32, height: u32, photo: [u32; 4]) -> Self {
        let px = (width * height) as usize;
        let [x0, y0, x1, y1] = photo;
        let (w, h) = (x1.saturating_sub(x0).max(1), y1.saturating_sub(y0).max(1));
        let grey = GrayImage::from_fn(w, h, |x, y| {
            let i = ((y0 + y).min(height - 1) * width + (x0 + x).min(width - 1)) as usize;
            luma(rgb[i], rgb[px + i], rgb[2 * px + i])
        });
        let up =
            imageops::resize(&grey, w * UPSAMPLE, h * UPSAMPLE, imageops::FilterType::Triangle);
        Self {
            grey: padded(&up),
            per_view: UPSAMPLE as f32,
            origin: Vec2::new(x0 as f32, y0 as f32),
        }
    }

    /// A photo with `per_view` of its pixels to a view pixel, its top-left corner at view
    /// pixel `origin`.
    pub fn of_photo(rgb: &RgbImage, per_view: f32, origin: Vec2) -> Self {
        let unit = |v: u8| f32::from(v) / 255.0;
        let grey = GrayImage::from_fn(rgb.width(), rgb.height(), |x, y| {
            let p = rgb.get_pixel(x, y);
            luma(unit(p[0]), unit(p[1]), unit(p[2]))
        });
        Self { grey: padded(&grey), per_view, origin }
    }

    /// Width and height without the padding.
    fn size(&self) -> (u32, u32) {
        (self.grey.width() - 2 * PAD, self.grey.height() - 2 * PAD)
    }
}

/// Detects and describes the keypoints of one view in `image`, one per cell of
/// `params.grid_cell` view pixels, at most `params.max_keypoints` (the strongest).
pub fn detect(image: &KeypointImage, pairs: &[TestPair], params: &RegisterParams) -> Features {
    let (w, h) = image.size();
    let cell = params.grid_cell as f32 * image.per_view;
    let cols = (w as f32 / cell).ceil() as usize;
    let rows = (h as f32 / cell).ceil() as usize;
    let margin = (PHOTO_MARGIN * image.per_view).round() as u32;
    let mut best: Vec<Option<(f32, u32, u32)>> = vec![None; cols * rows];
    for c in corners_fast9(&image.grey, params.fast_threshold) {
        let inside = (PAD + margin..(PAD + w).saturating_sub(margin)).contains(&c.x)
            && (PAD + margin..(PAD + h).saturating_sub(margin)).contains(&c.y);
        if !inside {
            continue;
        }
        let (col, row) =
            (((c.x - PAD) as f32 / cell) as usize, ((c.y - PAD) as f32 / cell) as usize);
        let slot = &mut best[row.min(rows - 1) * cols + col.min(cols - 1)];
        if slot.is_none_or(|(s, _, _)| c.score > s) {
            *slot = Some((c.score, c.x, c.y));
        }
    }
    let mut kept: Vec<(f32, u32, u32)> = best.into_iter().flatten().collect();
    kept.sort_by(|a, b| b.0.total_cmp(&a.0));
    kept.truncate(params.max_keypoints);
    let keypoints: Vec<Point<u32>> = kept.iter().map(|&(_, x, y)| Point::new(x, y)).collect();
    let pairs = pairs.to_vec();
    let (briefs, _) = brief(&image.grey, &keypoints, BITS, Some(&pairs))
        .expect("padded keypoints are a patch radius inside");
    let descriptors = briefs.iter().map(|d| std::array::from_fn(|k| d.bits[k])).collect();
    let points = keypoints
        .iter()
        .map(|p| {
            image.origin
                + Vec2::new((p.x - PAD) as f32 + 0.5, (p.y - PAD) as f32 + 0.5) / image.per_view
        })
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
    let best_in_a_for =
        |j: usize| (0..a.len()).min_by_key(|&i| dist[i * nb + j]).expect("a is not empty");
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A 96×64 grey image of seeded random 6-pixel blocks (corners everywhere) in a flat
    /// border 12 pixels wide (no corner where margins differ).
    fn blocks() -> RgbImage {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let shades: Vec<u8> = (0..16 * 11).map(|_| rng.random()).collect();
        RgbImage::from_fn(96, 64, |x, y| {
            let inside = (12..84).contains(&x) && (12..52).contains(&y);
            image::Rgb([if inside { shades[(y / 6 * 16 + x / 6) as usize] } else { 128 }; 3])
        })
    }

    #[test]
    fn grey_is_the_bt601_luma_of_the_photo() {
        // (50, 0, 200): 0.299 · 50 + 0.114 · 200 = 37.75.
        let photo = RgbImage::from_pixel(1, 1, image::Rgb([50, 0, 200]));
        let image = KeypointImage::of_photo(&photo, 1.0, Vec2::ZERO);
        assert_eq!(image.grey.get_pixel(PAD, PAD)[0], 38);
        assert_eq!(luma(50.0 / 255.0, 0.0, 200.0 / 255.0)[0], 38);
    }

    #[test]
    fn keypoints_of_a_finer_photo_come_back_in_view_pixels() {
        let photo = blocks();
        let pairs = test_pairs();
        // The same cells of 8 image pixels: the photo as its own view, and as a view at half
        // its scale whose photo starts at (3, 5).
        let own = detect(
            &KeypointImage::of_photo(&photo, 1.0, Vec2::ZERO),
            &pairs,
            &RegisterParams { grid_cell: 8, ..RegisterParams::default() },
        );
        let half = detect(
            &KeypointImage::of_photo(&photo, 2.0, Vec2::new(3.0, 5.0)),
            &pairs,
            &RegisterParams::default(),
        );
        assert!(own.len() > 20, "{} keypoints", own.len());
        assert_eq!(own.descriptors, half.descriptors);
        for (a, b) in own.points.iter().zip(&half.points) {
            assert_eq!(Vec2::new(3.0, 5.0) + *a / 2.0, *b);
        }
    }

    #[test]
    fn keypoints_of_a_letterboxed_view_stay_inside_its_photo() {
        // A 96×96 view whose photo fills rows 16..80; black padding, so that the photo's edge
        // is a strong one.
        let photo = blocks();
        let px = 96 * 96;
        let mut rgb = vec![0.0; 3 * px];
        for (x, y, p) in photo.enumerate_pixels() {
            (0..3)
                .for_each(|c| rgb[c * px + ((y + 16) * 96 + x) as usize] = f32::from(p[c]) / 255.0);
        }
        let found = detect(
            &KeypointImage::of_view(&rgb, 96, 96, [0, 16, 96, 80]),
            &test_pairs(),
            &RegisterParams::default(),
        );
        assert!(found.len() > 20, "{} keypoints", found.len());
        let m = PHOTO_MARGIN;
        assert!(
            found
                .points
                .iter()
                .all(|p| p.y >= 16.0 + m && p.y <= 80.0 - m && p.x >= m && p.x <= 96.0 - m),
            "{:?}",
            found.points
        );
    }
}
