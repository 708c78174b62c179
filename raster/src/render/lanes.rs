//! Gaussians evaluated four pixels of a row at a time. Both passes go through these
//! functions, so the forward and the backward see bit-identical values; the lanes are one
//! SSE register (`wide::f32x4`, safe, with a plain-array fallback on other targets). A row's
//! pixels are independent of each other (the order that matters is along the depth list), so
//! the forward composites whole lanes without branches.

use wide::{f32x4, i32x4, u32x4};

use super::project::Projected;
use super::{ALPHA_MAX, ALPHA_MIN, AlphaCutoff};

/// Pixels evaluated together.
pub(crate) const LANES: usize = 4;

/// 0, 1, 2, 3: the column of each lane relative to the first.
const LANE_INDEX: i32x4 = i32x4::new([0, 1, 2, 3]);

/// e^x for x ≤ 0 (clamped below at −87, where it is already below f32's normal range), with
/// a relative error of a few ulp: Cody–Waite range reduction and the Cephes polynomial.
#[inline(always)]
fn exp_neg(x: f32x4) -> f32x4 {
    let x = x.fast_max(f32x4::splat(-87.0)).fast_min(f32x4::ZERO);
    // Round to nearest with the 1.5·2²³ trick (valid for |n| < 2²²): `shifted` lies in
    // [2²³, 2²⁴) with unit spacing, so its low bits hold n, from which 2ⁿ is built.
    let shifted = x * std::f32::consts::LOG2_E + 12_582_912.0;
    let n = shifted - 12_582_912.0;
    let r = x - n * 0.693_359_4 + n * 2.121_944_4e-4;
    let mut p = f32x4::splat(1.987_569_1e-4);
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let y = p * r * r + r + 1.0;
    y * f32x4::from_bits((shifted.to_bits() - (0x4B40_0000 - 127)) << 23)
}

/// Opacity × Gaussian at the four pixels `origin_x + base + 0..4` of the row whose centre
/// is `dy` below the Gaussian's.
#[inline(always)]
pub(crate) fn gaussian_values(g: &Projected, origin_x: u32, base: usize, dy: f32) -> f32x4 {
    let dx = column_offsets(origin_x, base, g.xy[0]);
    let [a, b, c] = g.conic;
    let power = (dx * a * dx + c * dy * dy) * -0.5 - dx * b * dy;
    exp_neg(power) * g.opacity
}

/// Offsets from `centre` of the centres of the four pixels `origin_x + base + 0..4` of a row
/// (lane by lane what `pixel_offset` gives).
#[inline(always)]
pub(crate) fn column_offsets(origin_x: u32, base: usize, centre: f32) -> f32x4 {
    let columns = i32x4::splat(origin_x as i32 + base as i32) + LANE_INDEX;
    columns.round_float() + 0.5 - centre
}

/// All-ones lanes for the columns `base + 0..4` that lie in `[x0, x1]`.
#[inline(always)]
pub(crate) fn span_mask(base: usize, x0: usize, x1: usize) -> u32x4 {
    let columns = i32x4::splat(base as i32) + LANE_INDEX;
    let outside =
        columns.simd_lt(i32x4::splat(x0 as i32)) | columns.simd_gt(i32x4::splat(x1 as i32));
    (!outside).cast_unsigned()
}

/// First columns of the lane groups that cover `[x0, x1]`, starting at `x0`: the last
/// group may reach up to `LANES − 1` columns past the tile's edge.
pub(crate) fn chunk_starts(x0: usize, x1: usize) -> impl Iterator<Item = usize> {
    (x0..=x1).step_by(LANES)
}

impl AlphaCutoff {
    /// Alpha of four pairs whose opacity × Gaussian is `v`: `v` itself from 1/255 on (hard
    /// cutoff), or v·s(t) with s the smoothstep of t = (v − ½/255)·255 on [0, 1] (smooth);
    /// at most [`ALPHA_MAX`].
    #[inline(always)]
    pub(crate) fn alpha_lanes(self, v: f32x4) -> f32x4 {
        self.alpha_and_slope_lanes(v).0
    }

    /// [`AlphaCutoff::alpha_lanes`] and dα/dv (0 where α is clamped at the maximum), from one
    /// evaluation: the backward needs both, the forward only the first.
    #[inline(always)]
    pub(crate) fn alpha_and_slope_lanes(self, v: f32x4) -> (f32x4, f32x4) {
        let (a, slope) = match self {
            AlphaCutoff::Hard => {
                let on = !v.simd_lt(f32x4::splat(ALPHA_MIN));
                (v & on, f32x4::ONE & on)
            }
            AlphaCutoff::Smooth => {
                let t =
                    ((v - 0.5 * ALPHA_MIN) / ALPHA_MIN).fast_max(f32x4::ZERO).fast_min(f32x4::ONE);
                let s = t * t * (f32x4::splat(3.0) - t * 2.0);
                (v * s, s + v * t * (f32x4::ONE - t) * (6.0 / ALPHA_MIN))
            }
        };
        let max = f32x4::splat(ALPHA_MAX);
        (a.fast_min(max), a.simd_gt(max).select(f32x4::ZERO, slope))
    }
}
