//! Front-to-back alpha compositing of one 16×16 tile (the forward pass), plus the per-pair
//! alpha function and pixel spans both passes share. A tile walks its depth-sorted list once;
//! for each Gaussian it visits only the still-compositing pixels inside the ellipse where its
//! alpha can reach the cutoff, so work follows footprints rather than tiles. Pixels stop when the next Gaussian would take their
//! transmittance below [`T_MIN`] (that Gaussian is not composited, as in gsplat); the tile
//! stops when all its pixels have. Per pixel it keeps what the backward needs: the final
//! transmittance and the number of list entries up to the last one that contributed.

use super::project::Projected;
use super::{ALPHA_MAX, ALPHA_MIN, AlphaCutoff, T_MIN, TILE};

/// Pixels in one tile.
pub(crate) const TILE_PIXELS: usize = (TILE * TILE) as usize;

impl AlphaCutoff {
    /// Smallest value of opacity × Gaussian that can give a nonzero alpha.
    pub(crate) fn floor(self) -> f32 {
        match self {
            AlphaCutoff::Hard => ALPHA_MIN,
            AlphaCutoff::Smooth => 0.5 * ALPHA_MIN,
        }
    }

    /// Alpha of a pair whose opacity × Gaussian is `v`, and dα/dv.
    #[inline(always)]
    pub(crate) fn alpha(self, v: f32) -> (f32, f32) {
        let (a, da) = match self {
            AlphaCutoff::Hard if v < ALPHA_MIN => (0.0, 0.0),
            AlphaCutoff::Hard => (v, 1.0),
            AlphaCutoff::Smooth => {
                // α = v·s(t), s the smoothstep of t = (v − ½/255)·255 on [0, 1].
                let t = ((v - 0.5 * ALPHA_MIN) / ALPHA_MIN).clamp(0.0, 1.0);
                let s = t * t * (3.0 - 2.0 * t);
                (v * s, s + v * 6.0 * t * (1.0 - t) / ALPHA_MIN)
            }
        };
        if a > ALPHA_MAX { (ALPHA_MAX, 0.0) } else { (a, da) }
    }
}

/// e^x for x ≤ 0 (clamped below at −87, where it is already below f32's normal range), with
/// a relative error of a few ulp: Cody–Waite range reduction and the Cephes polynomial.
/// Written without calls or branches so the pixel loops vectorize.
#[inline(always)]
pub(crate) fn exp_neg(x: f32) -> f32 {
    let x = x.clamp(-87.0, 0.0);
    // Round to nearest with the 1.5·2²³ trick (valid for |n| < 2²²).
    let n = (x * std::f32::consts::LOG2_E + 12_582_912.0) - 12_582_912.0;
    let r = x - n * 0.693_359_4 + n * 2.121_944_4e-4;
    let mut p = 1.987_569_1e-4_f32;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let y = p * r * r + r + 1.0;
    y * f32::from_bits(((n as i32 + 127) as u32) << 23)
}

/// Inclusive pixel range, relative to the tile origin `origin`, of centres within `extent`
/// of `centre` along one axis; `None` when empty.
#[inline]
pub(crate) fn span(centre: f32, extent: f32, origin: u32) -> Option<(usize, usize)> {
    // Pixel i has its centre at i + 0.5. Casts truncate (= floor for the non-negative values
    // they see) and saturate; f32::ceil/floor would be libm calls on baseline x86-64.
    let lo = centre - extent - 0.5 - origin as f32;
    let hi = centre + extent - 0.5 - origin as f32;
    if !(hi >= 0.0 && lo <= (TILE - 1) as f32) {
        return None;
    }
    let lo = if lo <= 0.0 { 0 } else { lo as usize + (lo as usize as f32 != lo) as usize };
    let hi = (hi as usize).min(TILE as usize - 1);
    (lo <= hi).then_some((lo, hi))
}

/// Tile-relative columns of the pixel row at vertical offset `dy` from the centre that lie
/// inside the Gaussian's cutoff ellipse a·dx² + 2b·dx·dy + c·dy² ≤ k2, i.e.
/// |dx + b·dy/a| ≤ √((k2 − dy²·(ac − b²)/a) / a). Outside it alpha is below the floor, so
/// both passes visit exactly these pixels.
#[inline]
pub(crate) fn row_span(g: &Projected, dy: f32, origin_x: u32) -> Option<(usize, usize)> {
    let [a, b, c] = g.conic;
    let rest = g.k2 - (a * c - b * b) / a * dy * dy;
    if rest.is_nan() || rest < 0.0 {
        return None;
    }
    span(g.xy[0] - b * dy / a, (rest / a).sqrt(), origin_x)
}

/// Opacity × Gaussian at pixel offset (dx, dy) from the centre.
#[inline(always)]
pub(crate) fn gaussian_value(g: &Projected, dx: f32, dy: f32) -> f32 {
    let [a, b, c] = g.conic;
    let power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy;
    g.opacity * exp_neg(power)
}

/// One tile's forward result, tile-local (row-major 16×16).
pub(crate) struct TileForward {
    /// `[pixel][channel]` colour accumulated over Gaussians (no background yet).
    pub features: Vec<f32>,
    /// Σ w·z.
    pub depth_sum: Vec<f32>,
    pub transmittance: Vec<f32>,
    /// One past the list index of the last Gaussian that contributed to the pixel.
    pub last: Vec<u32>,
}

/// Composites the depth ranks `ranks` (increasing) of `sorted` Gaussians with
/// `sorted_features` over the tile whose top-left pixel is `origin`, inside an image of
/// `size` (pixels past the border are never touched).
pub(crate) fn composite_tile(
    ranks: &[u32],
    sorted: &[Projected],
    sorted_features: &[f32],
    channels: usize,
    cutoff: AlphaCutoff,
    origin: [u32; 2],
    size: [u32; 2],
) -> TileForward {
    let mut out = TileForward {
        features: vec![0.0; channels * TILE_PIXELS],
        depth_sum: vec![0.0; TILE_PIXELS],
        transmittance: vec![1.0; TILE_PIXELS],
        last: vec![0; TILE_PIXELS],
    };
    let cols = (size[0] - origin[0]).min(TILE);
    let rows = (size[1] - origin[1]).min(TILE) as usize;
    // Bit x of row y: pixel (x, y) still composites.
    let mut alive = [0u16; TILE as usize];
    alive[..rows].fill((((1u32 << cols) - 1) & 0xffff) as u16);
    let mut alive_count = rows * cols as usize;
    // Pixels the current Gaussian contributes to, and their weights.
    let mut taken = Vec::with_capacity(TILE_PIXELS);
    for (k, &rank) in ranks.iter().enumerate() {
        if alive_count == 0 {
            break;
        }
        let g = &sorted[rank as usize];
        let Some((y0, y1)) = span(g.xy[1], g.extent[1], origin[1]) else { continue };
        taken.clear();
        for (y, row_alive) in alive.iter_mut().enumerate().take(y1 + 1).skip(y0) {
            if *row_alive == 0 {
                continue;
            }
            let dy = (origin[1] + y as u32) as f32 + 0.5 - g.xy[1];
            let Some((x0, x1)) = row_span(g, dy, origin[0]) else { continue };
            for x in x0..=x1 {
                if *row_alive & (1 << x) == 0 {
                    continue;
                }
                let p = y * TILE as usize + x;
                let dx = (origin[0] + x as u32) as f32 + 0.5 - g.xy[0];
                let (alpha, _) = cutoff.alpha(gaussian_value(g, dx, dy));
                if alpha <= 0.0 {
                    continue;
                }
                let t = out.transmittance[p];
                let next = t * (1.0 - alpha);
                if next < T_MIN {
                    *row_alive &= !(1 << x);
                    alive_count -= 1;
                    continue;
                }
                taken.push((p, alpha * t));
                out.transmittance[p] = next;
                out.last[p] = k as u32 + 1;
            }
        }
        let f = &sorted_features[rank as usize * channels..(rank as usize + 1) * channels];
        for &(p, w) in &taken {
            for (acc, &fc) in out.features[p * channels..(p + 1) * channels].iter_mut().zip(f) {
                *acc += w * fc;
            }
            out.depth_sum[p] += w * g.depth;
        }
    }
    out
}
