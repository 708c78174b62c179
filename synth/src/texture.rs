//! Procedural surface patterns for floors, walls, ceilings and primitive furniture: wood
//! planks, tiles, plaster, carpet, stripes and two-colour noise. Each pattern is a pure
//! function of a surface coordinate in metres and of parameters drawn once per scene, so a
//! surface looks the same from every camera (the geometric tests rely on that) and the same
//! seed gives the same pixels. Noise is integer-hash value noise: no tables, no global state.

use glam::{Vec2, Vec3};
use rand::Rng;

/// Which procedural pattern a surface carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PatternKind {
    Plaster,
    WoodPlanks,
    Tiles,
    Carpet,
    Stripes,
    Noise,
    /// Grain only, for furniture parts.
    WoodGrain,
}

/// A pattern with its colours and scale; `contrast` scales every deviation from `base`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pattern {
    pub kind: PatternKind,
    /// Linear RGB albedo.
    pub base: Vec3,
    pub accent: Vec3,
    /// Feature size in metres (plank width, tile size, stripe width, noise scale).
    pub scale: f32,
    pub contrast: f32,
    pub seed: u32,
}

impl Pattern {
    /// Linear albedo at surface coordinate `p` (metres).
    pub fn albedo(&self, p: Vec2) -> Vec3 {
        let c = self.contrast;
        let q = p / self.scale;
        let s = self.seed;
        let col = match self.kind {
            PatternKind::Plaster => {
                let n = fbm(q * 0.8, s, 4) - 0.5;
                self.base * (1.0 + 0.25 * c * n)
            }
            PatternKind::Carpet => {
                let fine = value_noise(p * 180.0, s) - 0.5;
                let blotch = fbm(q, s ^ 0x55, 3) - 0.5;
                self.base.lerp(self.accent, (0.5 + c * blotch).clamp(0.0, 1.0) * 0.5)
                    * (1.0 + 0.3 * c * fine)
            }
            PatternKind::Noise => {
                let n = fbm(q, s, 5);
                self.base.lerp(self.accent, smooth((n - 0.5) * 2.0 * c + 0.5))
            }
            PatternKind::Stripes => {
                let band = (q.x.floor() as i32).rem_euclid(2) as f32;
                let n = fbm(p * 4.0, s, 2) - 0.5;
                self.base.lerp(self.accent, band * c.min(1.0)) * (1.0 + 0.1 * c * n)
            }
            PatternKind::Tiles => {
                let cell = q.floor();
                let f = q - cell;
                let grout = 0.04 / self.scale.max(0.05);
                let edge = f.x.min(f.y).min((1.0 - f.x).min(1.0 - f.y));
                let checker = ((cell.x + cell.y) as i32).rem_euclid(2) as f32;
                let jitter = hash2(cell.x as i32, cell.y as i32, s) - 0.5;
                let tile = self.base.lerp(self.accent, checker * 0.6) * (1.0 + 0.2 * c * jitter);
                if edge < grout { self.base * (1.0 - 0.5 * c.min(1.5)).max(0.2) } else { tile }
            }
            PatternKind::WoodPlanks => {
                // Planks run along x; each plank row is offset and shaded on its own.
                let row = q.y.floor();
                let along = q.x * 0.25 + hash2(row as i32, 7, s) * 3.0;
                let plank = along.floor();
                let h = hash2(row as i32, plank as i32, s) - 0.5;
                let fy = q.y - row;
                let fx = along - plank;
                let seam = fy < 0.04 || fx < 0.01;
                let grain = grain(Vec2::new(p.x * 3.0, p.y * 40.0), s ^ row as u32);
                let tone = self
                    .base
                    .lerp(self.accent, (0.5 + c * (0.6 * h + 0.4 * (grain - 0.5))).clamp(0.0, 1.0));
                if seam { tone * (1.0 - 0.35 * c.min(1.5)).max(0.3) } else { tone }
            }
            PatternKind::WoodGrain => {
                let g = grain(Vec2::new(p.x * 4.0, p.y * 30.0), s);
                self.base.lerp(self.accent, (0.5 + c * (g - 0.5)).clamp(0.0, 1.0))
            }
        };
        col.clamp(Vec3::splat(0.0), Vec3::splat(1.0))
    }

    /// A random pattern of `kind` around colour `base` (linear RGB).
    pub fn random(rng: &mut impl Rng, kind: PatternKind, base: Vec3, contrast: f32) -> Self {
        let (scale, accent) = match kind {
            PatternKind::Plaster => (rng.random_range(0.3..1.5), base),
            PatternKind::WoodPlanks => {
                (rng.random_range(0.1..0.22), base * rng.random_range(0.45..0.75))
            }
            PatternKind::Tiles => (rng.random_range(0.2..0.6), jitter_colour(rng, base, 0.35)),
            PatternKind::Carpet => (rng.random_range(0.3..1.2), jitter_colour(rng, base, 0.3)),
            PatternKind::Stripes => (rng.random_range(0.05..0.3), jitter_colour(rng, base, 0.4)),
            PatternKind::Noise => (rng.random_range(0.2..1.0), jitter_colour(rng, base, 0.5)),
            PatternKind::WoodGrain => (1.0, base * rng.random_range(0.55..0.8)),
        };
        Self { kind, base, accent, scale, contrast, seed: rng.random() }
    }
}

/// `base` moved by up to `amount` per channel (multiplicatively), clamped to albedo range.
pub fn jitter_colour(rng: &mut impl Rng, base: Vec3, amount: f32) -> Vec3 {
    let f = Vec3::new(
        rng.random_range(1.0 - amount..1.0 + amount),
        rng.random_range(1.0 - amount..1.0 + amount),
        rng.random_range(1.0 - amount..1.0 + amount),
    );
    (base * f).clamp(Vec3::splat(0.02), Vec3::splat(0.95))
}

/// sRGB-encoded colour (0..1) to linear.
pub fn srgb_to_linear(c: Vec3) -> Vec3 {
    let f = |x: f32| if x <= 0.04045 { x / 12.92 } else { ((x + 0.055) / 1.055).powf(2.4) };
    Vec3::new(f(c.x), f(c.y), f(c.z))
}

/// Linear intensity to an 8-bit sRGB value.
pub fn linear_to_srgb8(x: f32) -> u8 {
    let x = x.clamp(0.0, 1.0);
    let s = if x <= 0.003_130_8 { 12.92 * x } else { 1.055 * x.powf(1.0 / 2.4) - 0.055 };
    (s * 255.0 + 0.5) as u8
}

fn smooth(x: f32) -> f32 {
    let x = x.clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// Ring-like wood grain in [0, 1].
fn grain(p: Vec2, seed: u32) -> f32 {
    let warp = fbm(p * 0.5, seed, 3);
    let v = (p.y + 4.0 * warp).fract();
    smooth((v - 0.5).abs() * 2.0)
}

/// Hash of an integer lattice point to [0, 1).
pub fn hash2(x: i32, y: i32, seed: u32) -> f32 {
    let mut h = (x as u32).wrapping_mul(0x27d4_eb2d)
        ^ (y as u32).wrapping_mul(0x1656_67b1)
        ^ seed.wrapping_mul(0x9e37_79b9);
    h ^= h >> 15;
    h = h.wrapping_mul(0x85eb_ca6b);
    h ^= h >> 13;
    h = h.wrapping_mul(0xc2b2_ae35);
    h ^= h >> 16;
    (h >> 8) as f32 / (1u32 << 24) as f32
}

/// Smoothly interpolated value noise in [0, 1).
pub fn value_noise(p: Vec2, seed: u32) -> f32 {
    let i = p.floor();
    let f = p - i;
    let (x, y) = (i.x as i32, i.y as i32);
    let u = f * f * (Vec2::splat(3.0) - 2.0 * f);
    let a = hash2(x, y, seed);
    let b = hash2(x + 1, y, seed);
    let c = hash2(x, y + 1, seed);
    let d = hash2(x + 1, y + 1, seed);
    let top = a + (b - a) * u.x;
    let bottom = c + (d - c) * u.x;
    top + (bottom - top) * u.y
}

/// Fractal sum of `octaves` value-noise layers, in [0, 1).
pub fn fbm(p: Vec2, seed: u32, octaves: u32) -> f32 {
    let (mut sum, mut amp, mut norm, mut q) = (0.0, 0.5, 0.0, p);
    for o in 0..octaves {
        sum += amp * value_noise(q, seed.wrapping_add(o * 101));
        norm += amp;
        amp *= 0.5;
        q *= 2.03;
    }
    sum / norm
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn patterns_stay_in_albedo_range_and_vary() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for kind in [
            PatternKind::Plaster,
            PatternKind::WoodPlanks,
            PatternKind::Tiles,
            PatternKind::Carpet,
            PatternKind::Stripes,
            PatternKind::Noise,
            PatternKind::WoodGrain,
        ] {
            let p = Pattern::random(&mut rng, kind, Vec3::new(0.5, 0.4, 0.3), 1.0);
            let samples: Vec<Vec3> = (0..200)
                .map(|i| p.albedo(Vec2::new(i as f32 * 0.037, (i * 7 % 13) as f32 * 0.05)))
                .collect();
            assert!(
                samples.iter().all(|c| c.min_element() >= 0.0 && c.max_element() <= 1.0),
                "{kind:?}"
            );
            let spread = samples.iter().map(|c| c.x).fold(0.0f32, f32::max)
                - samples.iter().map(|c| c.x).fold(1.0f32, f32::min);
            assert!(spread > 0.01, "{kind:?} is flat");
        }
    }

    #[test]
    fn srgb_round_trip() {
        for v in [0u8, 1, 50, 128, 200, 255] {
            let lin = srgb_to_linear(Vec3::splat(f32::from(v) / 255.0)).x;
            assert_eq!(linear_to_srgb8(lin), v);
        }
    }
}
