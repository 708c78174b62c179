//! Filling what no Gaussian covers in a render of a new view. A view away from the input
//! cameras sees places no input photo saw, and cracks open between splats; the rasterizer
//! leaves them at the background (black) and the id map at 0. [`fill_colour`] composites
//! the open pixels of the render (alpha at most a bound) over a push-pull fill of itself
//! (Gortler et al., 1996): the premultiplied colours and their alpha are averaged down a
//! pyramid, then each level's uncovered share is taken from the coarser level, bilinearly,
//! so a hole takes the colours around it, blended smoothly across it. The pixels above the
//! bound keep their render: their colours were fitted over black (by the network's training
//! and the test-time refinement), and a fill behind them would brighten them. [`nearest_covered`]
//! finds for every pixel without an instance the
//! nearest pixel with one (breadth first over the 4-neighbours, so the nearest along the
//! image, ties to the first reached), whose id and label it then takes. Covered pixels keep
//! what they rendered.

use std::collections::VecDeque;

/// `premultiplied` (planar `[C][H][W]`, the rasterizer's colours over a zero background)
/// composited over their own push-pull fill by `alpha` (`[H][W]`) where alpha is at most
/// `open` (pixel = colour + (1 − alpha) · fill); above it a pixel keeps its render, whose
/// colours were fitted over black. Without any covered pixel the image stays as it is.
pub fn fill_colour(
    premultiplied: &[f32],
    alpha: &[f32],
    width: usize,
    height: usize,
    open: f32,
) -> Vec<f32> {
    let pixels = width * height;
    assert_eq!(alpha.len(), pixels, "alpha must be [height][width]");
    assert_eq!(premultiplied.len() % pixels.max(1), 0, "colours must be [channels][height][width]");
    if pixels == 0 {
        return premultiplied.to_vec();
    }
    let weight: Vec<f32> = alpha.iter().map(|a| a.clamp(0.0, 1.0)).collect();
    let filled = pull(premultiplied, &weight, width, height);
    filled
        .iter()
        .zip(premultiplied)
        .enumerate()
        .map(|(i, (&f, &p))| if alpha[i % pixels] <= open { f } else { p })
        .collect()
}

/// Premultiplied colours `p` (planar `[C][H][W]`) with coverage `w` (each at most 1)
/// composited over the coarser level's result: every pixel fully coloured.
fn pull(p: &[f32], w: &[f32], width: usize, height: usize) -> Vec<f32> {
    let n = width * height;
    let channels = p.len() / n.max(1);
    if width <= 1 && height <= 1 {
        return (0..channels).map(|c| if w[0] > 1e-6 { p[c] / w[0] } else { 0.0 }).collect();
    }
    // One level down: 2 × 2 sums, the weight capped at 1 and the colours scaled with it.
    let (cw, ch) = (width.div_ceil(2), height.div_ceil(2));
    let cn = cw * ch;
    let mut cp = vec![0.0f32; channels * cn];
    let mut cwt = vec![0.0f32; cn];
    for y in 0..height {
        for x in 0..width {
            let (i, q) = (y * width + x, (y / 2) * cw + x / 2);
            cwt[q] += w[i];
            for c in 0..channels {
                cp[c * cn + q] += p[c * n + i];
            }
        }
    }
    for q in 0..cn {
        if cwt[q] > 1.0 {
            for c in 0..channels {
                cp[c * cn + q] /= cwt[q];
            }
            cwt[q] = 1.0;
        }
    }
    let coarse = pull(&cp, &cwt, cw, ch);
    // One level up: this level's own colours, and the coarse fill for what they leave.
    let mut out = vec![0.0f32; channels * n];
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            let rest = 1.0 - w[i];
            let (fx, fy) = ((x as f32 + 0.5) / 2.0 - 0.5, (y as f32 + 0.5) / 2.0 - 0.5);
            for c in 0..channels {
                let below = bilinear(&coarse[c * cn..(c + 1) * cn], cw, ch, fx, fy);
                out[c * n + i] = p[c * n + i] + rest * below;
            }
        }
    }
    out
}

/// `plane` (`[h][w]`) at the continuous pixel position (`x`, `y`), clamped at the borders.
fn bilinear(plane: &[f32], w: usize, h: usize, x: f32, y: f32) -> f32 {
    let (x, y) = (x.clamp(0.0, (w - 1) as f32), y.clamp(0.0, (h - 1) as f32));
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (tx, ty) = (x - x0 as f32, y - y0 as f32);
    let row = |yy: usize| plane[yy * w + x0] * (1.0 - tx) + plane[yy * w + x1] * tx;
    row(y0) * (1.0 - ty) + row(y1) * ty
}

/// For every pixel of a `width` × `height` map, the nearest pixel that is `covered` (itself
/// when it is); every pixel its own where none is. Any map of the view (ids, labels) is then
/// filled by reading each pixel's source.
pub fn nearest_covered(covered: &[bool], width: usize, height: usize) -> Vec<usize> {
    assert_eq!(covered.len(), width * height, "the coverage must be [height][width]");
    let mut source: Vec<Option<usize>> =
        covered.iter().enumerate().map(|(p, &c)| c.then_some(p)).collect();
    let mut queue: VecDeque<usize> = (0..covered.len()).filter(|&p| covered[p]).collect();
    while let Some(p) = queue.pop_front() {
        let (x, y) = (p % width, p / width);
        let neighbours = [
            (x > 0).then(|| p - 1),
            (x + 1 < width).then(|| p + 1),
            (y > 0).then(|| p - width),
            (y + 1 < height).then(|| p + width),
        ];
        for q in neighbours.into_iter().flatten() {
            if source[q].is_none() {
                source[q] = source[p];
                queue.push_back(q);
            }
        }
    }
    source.iter().enumerate().map(|(p, s)| s.unwrap_or(p)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hole_takes_the_colours_around_it_and_covered_pixels_keep_theirs() {
        // 16 × 16, one channel: the left half 0.2, the right half 0.8, a 4 × 4 hole across
        // the seam, and a half-covered pixel.
        let (w, h) = (16, 16);
        let mut colour: Vec<f32> = (0..w * h).map(|p| if p % w < 8 { 0.2 } else { 0.8 }).collect();
        let mut alpha = vec![1.0f32; w * h];
        for y in 6..10 {
            for x in 6..10 {
                colour[y * w + x] = 0.0;
                alpha[y * w + x] = 0.0;
            }
        }
        colour[2 * w + 2] = 0.1;
        alpha[2 * w + 2] = 0.5;
        let out = fill_colour(&colour, &alpha, w, h, 1.0);
        assert_eq!(out[0], 0.2);
        assert_eq!(out[w - 1], 0.8);
        // The hole's left edge lies nearer the left colours, its right edge the right ones.
        let (left, right) = (out[8 * w + 6], out[8 * w + 9]);
        assert!(
            (0.2..0.8).contains(&left) && (0.2..0.8).contains(&right) && left < right,
            "{left} {right}"
        );
        // Half covered by 0.2 (premultiplied 0.1): the other half is filled near 0.2.
        assert!((out[2 * w + 2] - 0.2).abs() < 0.05, "{}", out[2 * w + 2]);
        // Nothing covered: nothing to fill from.
        assert_eq!(fill_colour(&[0.0; 4], &[0.0; 4], 2, 2, 1.0), vec![0.0; 4]);
    }

    #[test]
    fn every_uncovered_pixel_reads_the_nearest_covered_one() {
        // 5 × 1: covered at both ends; the middle ties and goes to the first reached.
        let ids = [3, 0, 0, 0, 7];
        let source = nearest_covered(&ids.map(|i| i != 0), 5, 1);
        assert_eq!(source.iter().map(|&s| ids[s]).collect::<Vec<_>>(), [3, 3, 3, 7, 7]);
        // 3 × 3 with one covered corner: every pixel reads it.
        let mut covered = [false; 9];
        covered[8] = true;
        assert_eq!(nearest_covered(&covered, 3, 3), vec![8; 9]);
        assert_eq!(nearest_covered(&[false; 4], 2, 2), vec![0, 1, 2, 3]);
    }
}
