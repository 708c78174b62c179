//! Front-to-back alpha compositing of one 16×16 tile (the forward pass), plus the per-pair
//! alpha function and pixel spans both passes share. A tile walks its depth-sorted list once;
//! for each Gaussian it visits only the rows and columns inside the ellipse where its alpha
//! can reach the cutoff, so work follows footprints rather than tiles. Columns are handled
//! four at a time without branches (the loop vectorizes); a pixel's weight then goes to a
//! [`TileSink`], which accumulates whatever the caller renders (feature channels and depth,
//! or instance ids). Pixels stop when the next Gaussian would take their transmittance below
//! [`T_MIN`] (that Gaussian is not composited, as in gsplat), or when the sink says their
//! result is settled; the tile stops when all its pixels have. Per pixel it keeps what the backward
//! needs: the final transmittance and the
//! number of list entries up to the last one that contributed.

use wide::{f32x4, u32x4};

use super::lanes::{LANES, chunk_starts, gaussian_values, span_mask};
use super::project::Projected;
use super::{ALPHA_MIN, AlphaCutoff, T_MIN, TILE};

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

/// A Gaussian's cutoff ellipse a·dx² + 2b·dx·dy + c·dy² ≤ k2, ready to be cut into rows:
/// the row at vertical offset dy holds |dx + b·dy/a| ≤ √((k2 − dy²·(ac − b²)/a) / a).
/// Outside it alpha is below the floor, so both passes visit exactly these pixels.
pub(crate) struct Ellipse {
    centre_x: f32,
    k2: f32,
    inv_a: f32,
    b_over_a: f32,
    det_over_a: f32,
}

impl Ellipse {
    #[inline(always)]
    pub fn new(g: &Projected) -> Self {
        let [a, b, c] = g.conic;
        let inv_a = 1.0 / a;
        Self {
            centre_x: g.xy[0],
            k2: g.k2,
            inv_a,
            b_over_a: b * inv_a,
            det_over_a: (a * c - b * b) * inv_a,
        }
    }

    /// Tile-relative columns of the row at vertical offset `dy` from the centre, in the tile
    /// that starts at column `origin_x`.
    #[inline(always)]
    pub fn row_span(&self, dy: f32, origin_x: u32) -> Option<(usize, usize)> {
        let rest = self.k2 - self.det_over_a * dy * dy;
        if rest.is_nan() || rest < 0.0 {
            return None;
        }
        span(self.centre_x - self.b_over_a * dy, (rest * self.inv_a).sqrt(), origin_x)
    }
}

/// Receives a tile's contributions: for every (Gaussian, pixel) pair that composites, the
/// Gaussian's depth rank and the pixel's weight w = α·T. Each pixel sees its Gaussians front
/// to back, so sums come out in the same order whatever the sink.
pub(crate) trait TileSink {
    /// Whether the sink may settle pixels early (see [`TileSink::settled`]).
    const SETTLES: bool = false;

    /// Gaussian `g` of depth rank `rank` contributes to each tile pixel of `taken` with its weight.
    fn add(&mut self, g: &Projected, rank: usize, taken: &[(usize, f32)]);

    /// Whether the pixel's result can no longer change, its transmittance now being
    /// `transmittance`: the compositor then stops it (its coverage stays as it is). Asked after
    /// each contribution, only when [`TileSink::SETTLES`].
    fn settled(&self, _pixel: usize, _transmittance: f32) -> bool {
        false
    }
}

/// Feature channels and depth of one tile: Σ w·f per channel (`[pixel][channel]`, no
/// background yet) and Σ w·z.
pub(crate) struct FeatureSink<'a> {
    /// Features of each depth rank, `[rank][channel]`.
    sorted_features: &'a [f32],
    channels: usize,
    pub features: Vec<f32>,
    pub depth_sum: [f32; TILE_PIXELS],
}

impl<'a> FeatureSink<'a> {
    pub fn new(sorted_features: &'a [f32], channels: usize) -> Self {
        Self {
            sorted_features,
            channels,
            features: vec![0.0; channels * TILE_PIXELS],
            depth_sum: [0.0; TILE_PIXELS],
        }
    }
}

impl TileSink for FeatureSink<'_> {
    fn add(&mut self, g: &Projected, rank: usize, taken: &[(usize, f32)]) {
        let c = self.channels;
        let f = &self.sorted_features[rank * c..(rank + 1) * c];
        for &(pixel, weight) in taken {
            for (acc, &fc) in self.features[pixel * c..(pixel + 1) * c].iter_mut().zip(f) {
                *acc += weight * fc;
            }
            self.depth_sum[pixel] += weight * g.depth;
        }
    }
}

impl FeatureSink<'_> {
    /// The tile's feature planes over `background` (`[channel][pixel]`) and its expected depth.
    pub fn into_planes(
        self,
        cov: &TileCoverage,
        background: &[f32],
    ) -> (Vec<f32>, [f32; TILE_PIXELS]) {
        let c = self.channels;
        let mut planes = vec![0.0; c * TILE_PIXELS];
        for (p, sums) in self.features.chunks_exact(c.max(1)).enumerate().take(TILE_PIXELS) {
            let t = cov.transmittance[p];
            for (ch, (&sum, &bg)) in sums.iter().zip(background).enumerate() {
                planes[ch * TILE_PIXELS + p] = sum + t * bg;
            }
        }
        let depth =
            std::array::from_fn(|p| self.depth_sum[p] / (1.0 - cov.transmittance[p]).max(1e-10));
        (planes, depth)
    }
}

/// What compositing leaves per pixel of a tile (row-major 16×16).
pub(crate) struct TileCoverage {
    pub transmittance: [f32; TILE_PIXELS],
    /// One past the list index of the last Gaussian that contributed to the pixel.
    pub last: [u32; TILE_PIXELS],
}

/// Offset from `centre` of the centre of pixel `origin + i` along one axis. Both passes
/// compute it this way, so they see the same values.
#[inline(always)]
pub(crate) fn pixel_offset(origin: u32, i: usize, centre: f32) -> f32 {
    (origin as i32 + i as i32) as f32 + 0.5 - centre
}

/// `LANES` pixels of a row that one Gaussian covers.
#[derive(Debug, Clone, Copy, Default)]
struct LaneGroup {
    /// Tile pixel of the first lane.
    at: usize,
    /// Its column.
    base: usize,
    /// Vertical offset of the row from the Gaussian's centre.
    dy: f32,
    /// All ones for the lanes inside the Gaussian's row span.
    span: u32x4,
}

/// Composites the depth ranks `ranks` (increasing) of `sorted` Gaussians over the tile whose
/// top-left pixel is `origin`, inside an image of `size` (pixels past the border are never
/// touched), feeding every contribution to `sink`.
pub(crate) fn composite_tile<S: TileSink>(
    ranks: &[u32],
    sorted: &[Projected],
    cutoff: AlphaCutoff,
    origin: [u32; 2],
    size: [u32; 2],
    sink: &mut S,
) -> TileCoverage {
    // One copy per cutoff, so the per-pixel alpha has no branch on it.
    match cutoff {
        AlphaCutoff::Hard => composite::<false, S>(ranks, sorted, origin, size, sink),
        AlphaCutoff::Smooth => composite::<true, S>(ranks, sorted, origin, size, sink),
    }
}

fn composite<const SMOOTH: bool, S: TileSink>(
    ranks: &[u32],
    sorted: &[Projected],
    origin: [u32; 2],
    size: [u32; 2],
    sink: &mut S,
) -> TileCoverage {
    let cutoff = if SMOOTH { AlphaCutoff::Smooth } else { AlphaCutoff::Hard };
    // Per-pixel state, with room for the lanes a group may reach past the tile's last pixel.
    let mut transmittance = [1.0f32; TILE_PIXELS + LANES];
    let mut last = [0u32; TILE_PIXELS + LANES];
    let tile = TILE as usize;
    let cols = (size[0] - origin[0]).min(TILE) as usize;
    let rows = (size[1] - origin[1]).min(TILE) as usize;
    // Per pixel: all ones while it still composites, else zero (pixels past the border never do).
    let mut live = [0u32; TILE_PIXELS + LANES];
    for row in live.chunks_exact_mut(tile).take(rows) {
        row[..cols].fill(u32::MAX);
    }
    let mut row_live = [0u32; TILE as usize];
    row_live[..rows].fill(cols as u32);
    let mut live_count = rows * cols;
    // The pixels the current Gaussian contributes to and their weights (w = α·T); room for
    // a whole tile plus the lanes written past the last one.
    let mut taken = [(0usize, 0.0f32); TILE_PIXELS + LANES];
    // The current Gaussian's lane groups (at most 4 per row) and their alphas.
    let mut lane_groups = [LaneGroup::default(); TILE_PIXELS / LANES * 2];
    let mut alphas = [f32x4::ZERO; TILE_PIXELS / LANES * 2];
    for (k, &rank) in ranks.iter().enumerate() {
        if live_count == 0 {
            break;
        }
        let rank = rank as usize;
        let g = &sorted[rank];
        let Some((y0, y1)) = span(g.xy[1], g.extent[1], origin[1]) else { continue };
        let ellipse = Ellipse::new(g);
        let stamp = u32x4::splat(k as u32 + 1);
        // The lane groups the Gaussian covers in still-compositing rows, then all their alphas
        // (independent chains the CPU overlaps), then the compositing proper.
        let mut groups = 0;
        for (y, &row_live) in row_live.iter().enumerate().take(y1 + 1).skip(y0) {
            if row_live == 0 {
                continue;
            }
            let dy = pixel_offset(origin[1], y, g.xy[1]);
            let Some((x0, x1)) = ellipse.row_span(dy, origin[0]) else { continue };
            for base in chunk_starts(x0, x1) {
                lane_groups[groups] =
                    LaneGroup { at: y * tile + base, base, dy, span: span_mask(base, x0, x1) };
                groups += 1;
            }
        }
        for (alpha, group) in alphas.iter_mut().zip(&lane_groups[..groups]) {
            *alpha = cutoff.alpha_lanes(gaussian_values(g, origin[0], group.base, group.dy));
        }
        let mut count = 0;
        for (&alpha, group) in alphas.iter().zip(&lane_groups[..groups]) {
            let at = group.at;
            let lanes = at..at + LANES;
            let t = f32x4::new(transmittance[lanes.clone()].try_into().unwrap());
            let next = t * (f32x4::ONE - alpha);
            let live_now = u32x4::new(live[lanes.clone()].try_into().unwrap());
            let hit = f32x4::from_bits(live_now & group.span) & alpha.simd_gt(f32x4::ZERO);
            let stop = hit & next.simd_lt(f32x4::splat(T_MIN));
            let take = hit ^ stop;
            transmittance[lanes.clone()].copy_from_slice(take.select(next, t).as_array());
            let before = u32x4::new(last[lanes.clone()].try_into().unwrap());
            last[lanes.clone()].copy_from_slice(take.to_bits().select(stamp, before).as_array());
            live[lanes].copy_from_slice((live_now & !stop.to_bits()).as_array());
            let stops = stop.to_bitmask().count_ones();
            row_live[at / tile] -= stops;
            live_count -= stops as usize;
            // Branch-free compaction of the contributing lanes.
            let weight = (alpha * t).to_array();
            let bits = take.to_bitmask();
            for (l, &w) in weight.iter().enumerate() {
                taken[count] = (at + l, w);
                count += (bits >> l) as usize & 1;
            }
        }
        if count > 0 {
            sink.add(g, rank, &taken[..count]);
        }
        if S::SETTLES {
            for &(p, _) in &taken[..count] {
                if live[p] != 0 && sink.settled(p, transmittance[p]) {
                    live[p] = 0;
                    row_live[p / tile] -= 1;
                    live_count -= 1;
                }
            }
        }
    }
    TileCoverage {
        transmittance: transmittance[..TILE_PIXELS].try_into().unwrap(),
        last: last[..TILE_PIXELS].try_into().unwrap(),
    }
}
