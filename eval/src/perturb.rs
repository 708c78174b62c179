//! Robustness perturbations for `inssplat-eval score --perturb`: what happens to the scores when
//! the
//! input photos get worse or the views change. Image perturbations act on the context photos
//! before the pipeline sees them (seeded, so runs repeat); `overlap` changes which frames are
//! the context (consecutive frames `stride` apart: stride 1 = the most overlap); `repeats`
//! changes nothing and instead groups the unperturbed scores by how many instances the
//! scene's most repeated category has.

use inssplat_proto::dataset::Scene;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// A kind of perturbation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PerturbKind {
    /// Gaussian sensor noise, σ as a fraction of full scale.
    Noise,
    /// Gaussian blur, σ in pixels.
    Blur,
    /// Exposure change, in stops.
    Exposure,
    /// Context views `stride` frames apart.
    Overlap,
    /// Scores grouped by the scene's largest number of same-category instances.
    Repeats,
}

impl PerturbKind {
    /// The strengths a sweep tries; the first is "none".
    pub fn strengths(self) -> &'static [f32] {
        match self {
            PerturbKind::Noise => &[0.0, 0.02, 0.05, 0.1],
            PerturbKind::Blur => &[0.0, 1.0, 2.0, 3.0],
            PerturbKind::Exposure => &[0.0, -1.5, -0.75, 0.75, 1.5],
            PerturbKind::Overlap => &[1.0, 2.0, 3.0],
            PerturbKind::Repeats => &[0.0],
        }
    }

    pub fn unit(self) -> &'static str {
        match self {
            PerturbKind::Noise => "σ (full scale)",
            PerturbKind::Blur => "σ (px)",
            PerturbKind::Exposure => "stops",
            PerturbKind::Overlap => "frame stride",
            PerturbKind::Repeats => "instances of the most repeated category",
        }
    }
}

/// One perturbation at one strength.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Perturbation {
    pub kind: PerturbKind,
    pub strength: f32,
}

impl Perturbation {
    /// Applies an image perturbation to an RGB8 image in place (others leave it unchanged).
    pub fn apply(&self, rgb: &mut [u8], width: usize, height: usize, seed: u64) {
        match self.kind {
            PerturbKind::Noise if self.strength > 0.0 => {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                let sigma = self.strength * 255.0;
                for v in rgb.iter_mut() {
                    // Box–Muller: a standard normal from two uniforms.
                    let (u1, u2): (f32, f32) = (rng.random_range(f32::EPSILON..1.0), rng.random());
                    let z = (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos();
                    *v = (f32::from(*v) + sigma * z).round().clamp(0.0, 255.0) as u8;
                }
            }
            PerturbKind::Blur if self.strength > 0.0 => {
                let img = image::RgbImage::from_raw(width as u32, height as u32, rgb.to_vec())
                    .expect("w·h·3 bytes");
                let blurred = image::imageops::blur(&img, self.strength);
                rgb.copy_from_slice(blurred.as_raw());
            }
            PerturbKind::Exposure if self.strength != 0.0 => {
                let gain = 2f32.powf(self.strength);
                for v in rgb.iter_mut() {
                    // In linear light (gamma 2.2), then back.
                    let linear = (f32::from(*v) / 255.0).powf(2.2) * gain;
                    *v = (linear.min(1.0).powf(1.0 / 2.2) * 255.0).round() as u8;
                }
            }
            _ => {}
        }
    }

    /// The context frames for `views` views: `context` itself, or for `overlap` consecutive
    /// non-target frames `stride` apart (starting at the first context frame).
    pub fn context(
        &self,
        context: &[usize],
        targets: &[usize],
        frames: usize,
        views: usize,
    ) -> Vec<usize> {
        if self.kind != PerturbKind::Overlap {
            return context.to_vec();
        }
        let pool: Vec<usize> = (0..frames).filter(|f| !targets.contains(f)).collect();
        let stride = (self.strength.round() as usize).max(1);
        let start = pool.iter().position(|f| Some(f) == context.first()).unwrap_or(0);
        let start = start.min(pool.len().saturating_sub((views - 1) * stride + 1));
        (0..views).map(|i| pool[(start + i * stride).min(pool.len() - 1)]).collect()
    }
}

/// The largest number of instances that share one label in `scene`.
pub fn most_repeated(scene: &Scene) -> usize {
    let mut counts = std::collections::BTreeMap::<&str, usize>::new();
    for i in &scene.instances {
        *counts.entry(i.label.as_str()).or_default() += 1;
    }
    counts.values().copied().max().unwrap_or(0)
}

/// A seed per (scene, frame) so every run perturbs the same way.
pub fn seed(scene: &str, frame: usize) -> u64 {
    scene
        .bytes()
        .fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3))
        ^ frame as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_perturbations_change_what_they_should() {
        let (w, h) = (16, 16);
        let base: Vec<u8> =
            (0..w * h * 3).map(|i| if (i / 3) % w < 8 { 60 } else { 200 }).collect();
        let run = |kind, strength| {
            let mut x = base.clone();
            Perturbation { kind, strength }.apply(&mut x, w, h, 1);
            x
        };
        assert_eq!(run(PerturbKind::Noise, 0.0), base, "strength 0 is the identity");
        let noisy = run(PerturbKind::Noise, 0.05);
        let rms = (noisy
            .iter()
            .zip(&base)
            .map(|(a, b)| (f64::from(*a) - f64::from(*b)).powi(2))
            .sum::<f64>()
            / base.len() as f64)
            .sqrt();
        assert!((rms - 0.05 * 255.0).abs() < 2.0, "noise rms {rms}");
        let blurred = run(PerturbKind::Blur, 2.0);
        // The edge between columns 7 and 8 softens; flat far regions stay.
        assert!(
            blurred[7 * 3] > 60 && blurred[8 * 3] < 200 && blurred[0] == 60,
            "{:?}",
            &blurred[..30]
        );
        let bright = run(PerturbKind::Exposure, 1.0);
        // One stop up: 60 → 60·2^(1/2.2) ≈ 82, and 200 → 274 clips at white.
        assert!(bright[0] > 60 && bright[0] < 120 && bright[15 * 3] == 255, "{:?}", &bright[..48]);
        assert!(run(PerturbKind::Exposure, -1.0)[0] < 60);
    }

    #[test]
    fn overlap_picks_strided_frames_that_are_not_targets() {
        let p = Perturbation { kind: PerturbKind::Overlap, strength: 2.0 };
        let got = p.context(&[3, 9, 15, 21], &[0, 5, 10], 24, 4);
        assert_eq!(got, vec![3, 6, 8, 11]);
        assert!(got.iter().all(|f| ![0, 5, 10].contains(f)));
        let same =
            Perturbation { kind: PerturbKind::Noise, strength: 0.1 }.context(&[3, 9], &[0], 24, 2);
        assert_eq!(same, vec![3, 9]);
    }
}
