//! What an instance looks like in the photos, for the shape classifier: in each view where
//! its mask holds at least [`MIN_PIXELS`] pixels, the photo is cropped to the square around
//! the mask (outside the mask grey) and described by
//! - a histogram of oriented gradients of the crop's grey levels at [`CROP`]² (9 unsigned
//!   orientations, 8-pixel cells, blocks of 2×2 cells: 324 entries),
//! - its silhouette, the mask at [`SILHOUETTE`]² (256),
//! - the hue, saturation and value of its pixels in 8 bins each, as shares (24),
//! - their mean colour and its spread (6),
//! - where the mask lies: its box's height and width over the view's, its area over the
//!   view's and over its box's, its box's centre row and column over the view's (6);
//!
//! and the views' vectors are averaged, each weighted by its mask's pixels. The pipeline's
//! instances are fragments and unions of objects placed by an uncertain depth, which their 3D
//! shape shows ("A richer shape descriptor" in the model history); their 2D look does not
//! depend on the depth.

use image::imageops::{FilterType, resize};
use image::{GrayImage, ImageBuffer, Luma, Rgb};
use imageproc::hog::{HogOptions, hog};
use inssplat_proto::shape::APPEARANCE;

/// Fewest pixels of an instance's mask in a view for that view to describe it.
pub const MIN_PIXELS: usize = 20;
/// Side of the square crop the gradient histogram reads.
pub const CROP: u32 = 32;
/// Side of the silhouette.
pub const SILHOUETTE: u32 = 16;
/// Bins of each of hue, saturation and value.
const HSV_BINS: usize = 8;

/// One input view: its photo (planar RGB in [0, 1], as the network reads it) and the
/// instance id of each pixel (0: none).
#[derive(Debug, Clone, Copy)]
pub struct AppearanceView<'a> {
    pub planar_rgb: &'a [f32],
    pub ids: &'a [u32],
    pub width: usize,
    pub height: usize,
}

/// The appearance of every instance (ids ≥ 1) that some view shows with at least
/// [`MIN_PIXELS`] pixels, by id.
pub fn instance_appearance(views: &[AppearanceView<'_>]) -> Vec<(u32, Vec<f32>)> {
    let mut sums: std::collections::BTreeMap<u32, (Vec<f32>, f32)> = Default::default();
    for v in views {
        let mut counts: std::collections::BTreeMap<u32, usize> = Default::default();
        v.ids.iter().filter(|&&id| id > 0).for_each(|&id| *counts.entry(id).or_default() += 1);
        for (&id, &n) in counts.iter().filter(|(_, n)| **n >= MIN_PIXELS) {
            let a = view_appearance(v, id);
            let (sum, weight) = sums.entry(id).or_insert_with(|| (vec![0.0; APPEARANCE], 0.0));
            sum.iter_mut().zip(&a).for_each(|(s, x)| *s += n as f32 * x);
            *weight += n as f32;
        }
    }
    sums.into_iter().map(|(id, (sum, w))| (id, sum.into_iter().map(|s| s / w).collect())).collect()
}

/// The appearance of instance `id` in `v` (which shows it).
fn view_appearance(v: &AppearanceView<'_>, id: u32) -> Vec<f32> {
    let (w, h) = (v.width, v.height);
    let plane = w * h;
    let rgb = |p: usize| [v.planar_rgb[p], v.planar_rgb[plane + p], v.planar_rgb[2 * plane + p]];
    let inside: Vec<usize> = (0..plane).filter(|&p| v.ids[p] == id).collect();
    let (mut x0, mut x1, mut y0, mut y1) = (w, 0, h, 0);
    for &p in &inside {
        let (x, y) = (p % w, p / w);
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x + 1), y0.min(y), y1.max(y + 1));
    }
    let (bw, bh) = (x1 - x0, y1 - y0);
    let side = bw.max(bh);
    let (cx, cy) = ((x0 + x1) as f32 / 2.0, (y0 + y1) as f32 / 2.0);
    let (sx, sy) = ((cx - side as f32 / 2.0).round() as i64, (cy - side as f32 / 2.0).round() as i64);
    // The square crop: the photo inside the mask, grey outside it and outside the photo.
    let mut crop = ImageBuffer::<Rgb<f32>, _>::from_pixel(side as u32, side as u32, Rgb([0.5; 3]));
    let mut mask = ImageBuffer::<Luma<f32>, _>::new(side as u32, side as u32);
    for (cx, cy, px) in crop.enumerate_pixels_mut() {
        let (x, y) = (sx + i64::from(cx), sy + i64::from(cy));
        if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
            continue;
        }
        let p = y as usize * w + x as usize;
        if v.ids[p] == id {
            *px = Rgb(rgb(p));
            mask.put_pixel(cx, cy, Luma([1.0]));
        }
    }
    let small = resize(&crop, CROP, CROP, FilterType::Triangle);
    let grey = GrayImage::from_fn(CROP, CROP, |x, y| {
        let [r, g, b] = small.get_pixel(x, y).0;
        Luma([((r + g + b) / 3.0 * 255.0).round().clamp(0.0, 255.0) as u8])
    });
    let options = HogOptions { orientations: 9, signed: false, cell_side: 8, block_side: 2, block_stride: 1 };
    let mut out = hog(&grey, options).expect("a 32² crop divides into 8-pixel cells");
    out.extend(resize(&mask, SILHOUETTE, SILHOUETTE, FilterType::Triangle).pixels().map(|p| p.0[0]));

    let n = inside.len() as f32;
    let mut bins = [[0usize; HSV_BINS]; 3];
    let (mut sum, mut square) = ([0.0f32; 3], [0.0f32; 3]);
    for &p in &inside {
        let c = rgb(p);
        for (k, x) in hsv(c).into_iter().enumerate() {
            bins[k][((x * HSV_BINS as f32) as usize).min(HSV_BINS - 1)] += 1;
        }
        for k in 0..3 {
            sum[k] += c[k];
            square[k] += c[k] * c[k];
        }
    }
    out.extend(bins.iter().flatten().map(|&b| b as f32 / n));
    let mean = sum.map(|s| s / n);
    let square = square.map(|s| s / n);
    out.extend(mean);
    out.extend((0..3).map(|k| (square[k] - mean[k] * mean[k]).max(0.0).sqrt()));
    let (wf, hf) = (w as f32, h as f32);
    out.extend([bh as f32 / hf, bw as f32 / wf, n / (wf * hf), n / (bw * bh) as f32, cy / hf, cx / wf]);
    assert_eq!(out.len(), APPEARANCE, "the parts add up to the contract's length");
    out
}

/// Hue, saturation and value of an RGB colour, each in [0, 1].
fn hsv([r, g, b]: [f32; 3]) -> [f32; 3] {
    let max = r.max(g).max(b);
    let d = max - r.min(g).min(b);
    let hue = if d <= 0.0 {
        0.0
    } else if max == r {
        ((g - b) / d).rem_euclid(6.0) / 6.0
    } else if max == g {
        ((b - r) / d + 2.0) / 6.0
    } else {
        ((r - g) / d + 4.0) / 6.0
    };
    [hue, if max > 0.0 { d / max } else { 0.0 }, max]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 40×30 view, black but for a red 10×6 block of instance 3 and a 4×4 block of
    /// instance 5 (too small to describe).
    fn view() -> (Vec<f32>, Vec<u32>) {
        let (w, h) = (40, 30);
        let mut rgb = vec![0.0; 3 * w * h];
        let mut ids = vec![0; w * h];
        for y in 12..18 {
            for x in 5..15 {
                ids[y * w + x] = 3;
                rgb[y * w + x] = 1.0;
            }
        }
        for y in 0..4 {
            for x in 30..34 {
                ids[y * w + x] = 5;
            }
        }
        (rgb, ids)
    }

    #[test]
    fn a_block_is_described_by_its_colour_box_and_silhouette() {
        let (rgb, ids) = view();
        let v = AppearanceView { planar_rgb: &rgb, ids: &ids, width: 40, height: 30 };
        let all = instance_appearance(&[v]);
        assert_eq!(all.iter().map(|(id, _)| *id).collect::<Vec<_>>(), [3], "instance 5 has 16 pixels");
        let a = &all[0].1;
        let tail = &a[APPEARANCE - 36..];
        // Hue bin 0 (red), saturation and value in the last bin.
        assert_eq!((tail[0], tail[HSV_BINS + HSV_BINS - 1], tail[3 * HSV_BINS - 1]), (1.0, 1.0, 1.0));
        assert_eq!(&tail[24..30], &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        let expect = [6.0 / 30.0, 10.0 / 40.0, 60.0 / 1200.0, 1.0, 15.0 / 30.0, 10.0 / 40.0];
        assert!(tail[30..].iter().zip(expect).all(|(a, b)| (a - b).abs() < 1e-6), "{:?}", &tail[30..]);
        // The 10×6 block fills the square's middle rows: silhouette 1 there, 0 at top and bottom.
        let sil = &a[324..324 + 256];
        assert!(sil[8 * 16 + 8] > 0.99 && sil[8] < 0.01 && sil[15 * 16 + 8] < 0.01, "{sil:?}");
        // The block's edges have gradients: the histogram is not empty.
        assert!(a[..324].iter().any(|&x| x > 0.0));
    }

    #[test]
    fn views_average_by_their_pixels() {
        let (rgb, ids) = view();
        let green: Vec<f32> = (0..rgb.len()).map(|i| if (1200..2400).contains(&i) { rgb[i - 1200] } else { 0.0 }).collect();
        let v = |rgb| AppearanceView { planar_rgb: rgb, ids: &ids, width: 40, height: 30 };
        let one = instance_appearance(&[v(&rgb)]);
        let two = instance_appearance(&[v(&rgb), v(&green)]);
        let mean = APPEARANCE - 12;
        assert_eq!(&one[0].1[mean..mean + 3], &[1.0, 0.0, 0.0]);
        let two = &two[0].1[mean..mean + 3];
        assert!((two[0] - 0.5).abs() < 1e-6 && (two[1] - 0.5).abs() < 1e-6 && two[2] == 0.0, "{two:?}");
    }

    #[test]
    fn hsv_of_primaries_and_grey() {
        assert_eq!(hsv([1.0, 0.0, 0.0]), [0.0, 1.0, 1.0]);
        assert!((hsv([0.0, 1.0, 0.0])[0] - 1.0 / 3.0).abs() < 1e-6);
        assert!((hsv([0.0, 0.0, 0.5])[0] - 2.0 / 3.0).abs() < 1e-6);
        assert_eq!(hsv([0.5, 0.5, 0.5]), [0.0, 0.0, 0.5]);
    }
}
