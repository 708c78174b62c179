//! Sampling a coarse map at image pixels exactly as XFeat's reference does (torch's
//! `grid_sample` with `align_corners = False` and zero padding, the pixel normalized by the
//! image size less one), so that the keypoints and descriptors match the reference's.

/// A `[channels][height][width]` map of a `[image_w, image_h]` image, coarser or not.
pub struct Map<'a> {
    pub data: &'a [f32],
    pub channels: usize,
    pub height: usize,
    pub width: usize,
}

/// The map coordinate torch samples for image pixel `p` of an image `image` pixels wide, on a
/// map `size` wide.
fn source(p: f32, image: usize, size: usize) -> f32 {
    let g = 2.0 * (p / (image as f32 - 1.0)) - 1.0;
    ((g + 1.0) * size as f32 - 1.0) / 2.0
}

impl Map<'_> {
    fn at(&self, c: usize, y: isize, x: isize) -> f32 {
        if y < 0 || x < 0 || y as usize >= self.height || x as usize >= self.width {
            return 0.0;
        }
        self.data[(c * self.height + y as usize) * self.width + x as usize]
    }

    /// Channel 0 at image pixel (x, y), bilinear.
    pub fn bilinear(&self, x: f32, y: f32, image: [usize; 2]) -> f32 {
        let (ix, iy) = (source(x, image[0], self.width), source(y, image[1], self.height));
        let (x0, y0) = (ix.floor(), iy.floor());
        let (tx, ty) = (ix - x0, iy - y0);
        let (x0, y0) = (x0 as isize, y0 as isize);
        self.at(0, y0, x0) * (1.0 - tx) * (1.0 - ty)
            + self.at(0, y0, x0 + 1) * tx * (1.0 - ty)
            + self.at(0, y0 + 1, x0) * (1.0 - tx) * ty
            + self.at(0, y0 + 1, x0 + 1) * tx * ty
    }

    /// Every channel at image pixel (x, y), bicubic (Keys' kernel, a = −0.75, as torch).
    pub fn bicubic(&self, x: f32, y: f32, image: [usize; 2], out: &mut [f32]) {
        let (ix, iy) = (source(x, image[0], self.width), source(y, image[1], self.height));
        let (x0, y0) = (ix.floor(), iy.floor());
        let (wx, wy) = (cubic_weights(ix - x0), cubic_weights(iy - y0));
        let (x0, y0) = (x0 as isize - 1, y0 as isize - 1);
        for (c, o) in out.iter_mut().enumerate().take(self.channels) {
            *o = (0..4)
                .map(|r| {
                    let row: f32 =
                        (0..4).map(|k| self.at(c, y0 + r, x0 + k) * wx[k as usize]).sum();
                    row * wy[r as usize]
                })
                .sum();
        }
    }
}

/// The four cubic-convolution weights at fractional offset `t`.
fn cubic_weights(t: f32) -> [f32; 4] {
    const A: f32 = -0.75;
    let near = |x: f32| ((A + 2.0) * x - (A + 3.0)) * x * x + 1.0;
    let far = |x: f32| ((A * x - 5.0 * A) * x + 8.0 * A) * x - 4.0 * A;
    [far(t + 1.0), near(t), near(1.0 - t), far(2.0 - t)]
}

/// Whether torch's nearest sampling of image pixel `p` (an integer) lands inside an image
/// `size` wide: everywhere but the last pixel of an even size, which rounds (half to even)
/// past the edge and reads the zero padding.
pub fn nearest_inside(p: usize, size: usize) -> bool {
    let s = source(p as f32, size, size).round_ties_even();
    s >= 0.0 && (s as usize) < size
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_sum_to_one_mirror_and_match_keys_kernel() {
        for t in [0.0, 0.25, 0.5, 0.9] {
            let w = cubic_weights(t);
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
            let mut mirrored = cubic_weights(1.0 - t);
            mirrored.reverse();
            assert!(w.iter().zip(&mirrored).all(|(a, b)| (a - b).abs() < 1e-6), "{t}");
        }
        assert_eq!(cubic_weights(0.0), [0.0, 1.0, 0.0, 0.0]);
        // Keys' kernel at a = −0.75, half way: 0.59375 near, −0.09375 far.
        assert_eq!(cubic_weights(0.5), [-0.09375, 0.59375, 0.59375, -0.09375]);
    }

    #[test]
    fn the_last_pixel_of_an_even_size_falls_outside() {
        assert!(nearest_inside(0, 64) && nearest_inside(62, 64));
        assert!(!nearest_inside(63, 64));
    }
}
