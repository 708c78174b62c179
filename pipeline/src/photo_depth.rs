//! A view's depth over its photo, as the output folder's `depth/NNN.png` holds it (at the size
//! of the view's masks: the photo's, up to the mask size): the model's map without the
//! letterbox, sampled bilinearly at each pixel's centre from the model pixels that have a
//! depth, in the dataset format's 16-bit millimetres.

use image::{ImageBuffer, Luma};
use inssplat_proto::dataset::DEFAULT_DEPTH_UNIT_M;
use rayon::prelude::*;

use crate::stages::decode::Letterbox;

/// `depth`, the model's map of a photo placed by `lb` (at its input's size), over the photo at
/// `size` (its own size, or smaller with its shape); 0 where no model pixel near has a depth.
pub fn photo_depth(depth: &[f32], lb: &Letterbox, size: (u32, u32)) -> Vec<f32> {
    let input_width = lb.input[0];
    let [x0, y0, x1, y1] = lb.photo_rect();
    let (last_x, last_y) = (x1.max(x0 + 1) - 1, y1.max(y0 + 1) - 1);
    // Where an output pixel's centre falls in the model's grid along one axis, kept inside the
    // photo: the two model pixels either side and the weight of the second.
    let taps = |n: u32, photo: u32, pad: f32, lo: u32, hi: u32| -> Vec<(u32, u32, f32)> {
        let step = photo as f32 / n as f32 * lb.scale;
        (0..n)
            .map(|p| {
                let m = ((p as f32 + 0.5) * step + pad - 0.5).clamp(lo as f32, hi as f32);
                let a = m.floor() as u32;
                (a, (a + 1).min(hi), m - a as f32)
            })
            .collect()
    };
    let (w, h) = size;
    let columns = taps(w, lb.width, lb.pad_x, x0, last_x);
    let rows = taps(h, lb.height, lb.pad_y, y0, last_y);
    let at = |x: u32, y: u32| {
        let d = depth[(y * input_width + x) as usize];
        if d.is_finite() && d > 0.0 { d } else { 0.0 }
    };
    let mut out = vec![0.0; (w * h) as usize];
    out.par_chunks_mut(w as usize).zip(&rows).for_each(|(row, &(ya, yb, fy))| {
        for (d, &(xa, xb, fx)) in row.iter_mut().zip(&columns) {
            let corners = [
                (at(xa, ya), (1.0 - fx) * (1.0 - fy)),
                (at(xb, ya), fx * (1.0 - fy)),
                (at(xa, yb), (1.0 - fx) * fy),
                (at(xb, yb), fx * fy),
            ];
            // Pixels without a depth take no part: the rest's weights are renormalised.
            let (sum, weight) = corners
                .iter()
                .filter(|(d, _)| *d > 0.0)
                .fold((0.0, 0.0), |(s, t), &(d, wt)| (s + d * wt, t + wt));
            *d = if weight > 1e-6 { sum / weight } else { 0.0 };
        }
    });
    out
}

/// A depth map as a 16-bit grey PNG in [`DEFAULT_DEPTH_UNIT_M`] steps (0: no
/// depth; depths past 65.535 m saturate).
pub fn depth_png(width: u32, height: u32, depth: &[f32]) -> Vec<u8> {
    let steps = |d: f32| (f64::from(d) / DEFAULT_DEPTH_UNIT_M).round().clamp(0.0, 65535.0) as u16;
    crate::output::png_bytes(&ImageBuffer::<Luma<u16>, _>::from_fn(width, height, |x, y| {
        Luma([steps(depth[(y * width + x) as usize])])
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_the_photo_inside_the_letterbox_and_skips_pixels_without_depth() {
        // A 4×4 model map of an 8×4 photo at half scale, padded by one row above and below:
        // depth rises 1 m per model column; row 2, column 3 has none.
        let mut depth: Vec<f32> = (0..16).map(|i| 1.0 + (i % 4) as f32).collect();
        depth[2 * 4 + 3] = 0.0;
        depth[0] = 99.0; // padding: never sampled
        let lb =
            Letterbox { width: 8, height: 4, input: [4, 4], scale: 0.5, pad_x: 0.0, pad_y: 1.0 };
        let d = photo_depth(&depth, &lb, (8, 4));
        assert_eq!(d.len(), 32);
        // Photo pixel (2, 0) is model (0.75, 1.0): between columns 0 and 1 of row 1.
        assert!((d[2] - 1.75).abs() < 1e-5, "{}", d[2]);
        // The right edge clamps to the last column. Row 3 of the photo reads model row 2,
        // whose last pixel has no depth: pixel 6 takes its neighbour's alone, pixel 7 none.
        assert!((d[7] - 4.0).abs() < 1e-5, "{}", d[7]);
        assert!((d[3 * 8 + 6] - 3.0).abs() < 1e-5, "{}", d[3 * 8 + 6]);
        assert_eq!(d[3 * 8 + 7], 0.0);
        assert!(d.iter().all(|&x| x < 10.0), "the padding leaked in");
        // At half the photo's size each pixel stands for two: pixel (1, 0) for photo (3, 1).
        let half = photo_depth(&depth, &lb, (4, 2));
        assert!((half[1] - 2.0).abs() < 1e-5, "{}", half[1]);
    }
}
