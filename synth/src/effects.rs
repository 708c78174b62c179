//! What a phone camera does to the light: auto exposure (the scene's median luminance to
//! mid-grey) with a per-frame jitter in stops, sRGB encoding, optional Gaussian blur (hand
//! motion, focus) and optional sensor noise. Only the RGB image is touched: depth and
//! instance masks stay exact.

use glam::Vec3;
use rand::Rng;

use super::texture::linear_to_srgb8;

/// Linear luminance the scene's median is mapped to.
const MID_GREY: f32 = 0.2;

/// Exposure factor that maps the median luminance of `frames` to mid-grey.
pub fn auto_exposure(frames: &[&[Vec3]]) -> f32 {
    let mut lum: Vec<f32> = frames
        .iter()
        .flat_map(|f| f.iter().step_by(7))
        .map(|c| c.dot(Vec3::new(0.2126, 0.7152, 0.0722)))
        .collect();
    if lum.is_empty() {
        return 1.0;
    }
    let mid = lum.len() / 2;
    let (_, m, _) = lum.select_nth_unstable_by(mid, f32::total_cmp);
    MID_GREY / m.max(1e-4)
}

/// Per-frame camera settings drawn from the scene's knobs.
#[derive(Debug, Clone, Copy)]
pub struct Shot {
    pub exposure: f32,
    pub blur_sigma: f32,
    pub noise_sigma: f32,
    pub noise_seed: u64,
}

impl Shot {
    pub fn random(
        rng: &mut impl Rng,
        base_exposure: f32,
        exposure_stops: f32,
        blur: f32,
        noise: f32,
    ) -> Shot {
        let stops = if exposure_stops > 0.0 {
            rng.random_range(-exposure_stops..=exposure_stops)
        } else {
            0.0
        };
        Shot {
            exposure: base_exposure * 2f32.powf(stops),
            blur_sigma: if blur > 0.0 { rng.random_range(0.0..=blur) } else { 0.0 },
            noise_sigma: if noise > 0.0 { rng.random_range(0.0..=noise) } else { 0.0 },
            noise_seed: rng.random(),
        }
    }

    /// Linear radiance → 8-bit sRGB with this shot's exposure, blur and noise.
    pub fn develop(&self, radiance: &[Vec3], width: usize, height: usize) -> Vec<u8> {
        let mut img: Vec<Vec3> = radiance.iter().map(|c| *c * self.exposure).collect();
        if self.blur_sigma > 0.05 {
            img = blur(&img, width, height, self.blur_sigma);
        }
        let mut rgb: Vec<u8> =
            img.iter().flat_map(|c| [c.x, c.y, c.z]).map(linear_to_srgb8).collect();
        if self.noise_sigma > 0.0 {
            use rand::SeedableRng;
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(self.noise_seed);
            for v in &mut rgb {
                let n = gaussian(&mut rng) * self.noise_sigma * 255.0;
                *v = (f32::from(*v) + n).round().clamp(0.0, 255.0) as u8;
            }
        }
        rgb
    }
}

/// Standard normal sample (Box–Muller).
fn gaussian(rng: &mut impl Rng) -> f32 {
    let u1: f32 = rng.random_range(f32::EPSILON..1.0);
    let u2: f32 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
}

/// Separable Gaussian blur with clamped borders.
fn blur(img: &[Vec3], w: usize, h: usize, sigma: f32) -> Vec<Vec3> {
    let r = (3.0 * sigma).ceil() as i64;
    let kernel: Vec<f32> =
        (-r..=r).map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp()).collect();
    let norm: f32 = kernel.iter().sum();
    let pass = |src: &[Vec3], horizontal: bool| -> Vec<Vec3> {
        let mut out = vec![Vec3::ZERO; src.len()];
        for y in 0..h as i64 {
            for x in 0..w as i64 {
                let mut acc = Vec3::ZERO;
                for (k, wgt) in kernel.iter().enumerate() {
                    let o = k as i64 - r;
                    let (sx, sy) = if horizontal {
                        ((x + o).clamp(0, w as i64 - 1), y)
                    } else {
                        (x, (y + o).clamp(0, h as i64 - 1))
                    };
                    acc += src[(sy * w as i64 + sx) as usize] * *wgt;
                }
                out[(y * w as i64 + x) as usize] = acc / norm;
            }
        }
        out
    };
    pass(&pass(img, true), false)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exposure_maps_median_to_mid_grey_and_blur_keeps_energy() {
        let f: Vec<Vec3> = (0..100).map(|i| Vec3::splat(i as f32 / 100.0)).collect();
        let e = auto_exposure(&[&f]);
        assert!((e * 0.5 - MID_GREY).abs() < 0.02, "{e}");
        let mut img = vec![Vec3::ZERO; 81];
        img[40] = Vec3::ONE;
        let b = blur(&img, 9, 9, 1.0);
        let sum: f32 = b.iter().map(|c| c.x).sum();
        assert!((sum - 1.0).abs() < 1e-3 && b[40].x < 0.5);
        let shot = Shot { exposure: 1.0, blur_sigma: 0.0, noise_sigma: 0.05, noise_seed: 1 };
        assert_eq!(shot.develop(&img, 9, 9), shot.develop(&img, 9, 9), "noise is seeded");
    }
}
