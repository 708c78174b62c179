//! Binning of projected Gaussians into 16×16-pixel tiles, each tile's list sorted front to
//! back. The visible Gaussians are sorted once by camera depth (ties by index, so the order
//! is deterministic) and copied, with their features, into that order ("ranks"); the tiles'
//! lists hold ranks, filled with a counting pass and a prefix sum. Because the scatter walks
//! ranks in order, every list comes out sorted, and compositing reads the copies at
//! increasing addresses instead of all over the input.

use rayon::prelude::*;

use super::TILE;
use super::project::Projected;

/// The visible Gaussians in depth order and the per-tile, depth-sorted lists of them
/// ("intersections").
#[derive(Debug, Clone, Default)]
pub(crate) struct TileBins {
    pub tiles_x: u32,
    pub tiles_y: u32,
    /// Tile `t`'s intersections are `tile_offsets[t]..tile_offsets[t + 1]`.
    pub tile_offsets: Vec<u32>,
    /// Depth rank of each intersection's Gaussian.
    pub rank_from_isect: Vec<u32>,
    /// Input index of the Gaussian of each depth rank.
    pub gid_from_rank: Vec<u32>,
    /// Projection of each rank.
    pub sorted: Vec<Projected>,
    /// Features of each rank, `[rank][channel]`.
    pub sorted_features: Vec<f32>,
}

impl TileBins {
    pub fn tile_count(&self) -> usize {
        (self.tiles_x * self.tiles_y) as usize
    }

    pub fn isects(&self, tile: usize) -> &[u32] {
        &self.rank_from_isect
            [self.tile_offsets[tile] as usize..self.tile_offsets[tile + 1] as usize]
    }
}

/// Inclusive tile rectangle `[x0, x1] × [y0, y1]` a projected Gaussian touches, if any.
fn tile_rect(
    p: &Projected,
    tiles_x: u32,
    tiles_y: u32,
    width: u32,
    height: u32,
) -> Option<[u32; 4]> {
    let [u, v] = p.xy;
    let [ex, ey] = p.extent;
    let (lo_x, hi_x, lo_y, hi_y) = (u - ex, u + ex, v - ey, v + ey);
    // Pixel centres lie in [0.5, size − 0.5].
    if hi_x < 0.5 || hi_y < 0.5 || lo_x > width as f32 - 0.5 || lo_y > height as f32 - 0.5 {
        return None;
    }
    let t = TILE as f32;
    // `as u32` saturates, so huge footprints clamp instead of wrapping.
    let x0 = (lo_x.max(0.0) / t) as u32;
    let y0 = (lo_y.max(0.0) / t) as u32;
    let x1 = ((hi_x / t) as u32).min(tiles_x - 1);
    let y1 = ((hi_y / t) as u32).min(tiles_y - 1);
    Some([x0, x1, y0, y1])
}

/// Bins the visible Gaussians (`projected[i]` is `Some`) of an image of `width` × `height`;
/// `features` is the input's `n × channels` array.
pub(crate) fn bin(
    projected: &[Option<Projected>],
    features: &[f32],
    channels: usize,
    width: u32,
    height: u32,
) -> TileBins {
    let tiles_x = width.div_ceil(TILE);
    let tiles_y = height.div_ceil(TILE);
    let tile_count = (tiles_x * tiles_y) as usize;

    // Depth order. Depths are positive finite floats, whose bit patterns order like the values.
    let mut keyed: Vec<(u64, [u32; 4])> = projected
        .par_iter()
        .enumerate()
        .filter_map(|(gid, p)| {
            let p = p.as_ref()?;
            let rect = tile_rect(p, tiles_x, tiles_y, width, height)?;
            Some((((p.depth.to_bits() as u64) << 32) | gid as u64, rect))
        })
        .collect();
    keyed.par_sort_unstable_by_key(|&(key, _)| key);
    let gid_from_rank: Vec<u32> = keyed.iter().map(|&(key, _)| key as u32).collect();
    let sorted: Vec<Projected> =
        gid_from_rank.iter().filter_map(|&gid| projected[gid as usize]).collect();
    let mut sorted_features = Vec::with_capacity(gid_from_rank.len() * channels);
    for &gid in &gid_from_rank {
        sorted_features
            .extend_from_slice(&features[gid as usize * channels..(gid as usize + 1) * channels]);
    }

    let mut counts = vec![0u32; tile_count + 1];
    for (_, [x0, x1, y0, y1]) in &keyed {
        for ty in *y0..=*y1 {
            for tx in *x0..=*x1 {
                counts[(ty * tiles_x + tx) as usize + 1] += 1;
            }
        }
    }
    for t in 0..tile_count {
        counts[t + 1] += counts[t];
    }
    let tile_offsets = counts;
    let mut cursor = tile_offsets[..tile_count].to_vec();
    let mut rank_from_isect = vec![0u32; tile_offsets[tile_count] as usize];
    for (rank, (_, [x0, x1, y0, y1])) in keyed.iter().enumerate() {
        for ty in *y0..=*y1 {
            for tx in *x0..=*x1 {
                let slot = &mut cursor[(ty * tiles_x + tx) as usize];
                rank_from_isect[*slot as usize] = rank as u32;
                *slot += 1;
            }
        }
    }
    TileBins {
        tiles_x,
        tiles_y,
        tile_offsets,
        rank_from_isect,
        gid_from_rank,
        sorted,
        sorted_features,
    }
}

/// Copies tile-local results (`tile_plane(t)`: tile `t`'s 16×16 values, row-major) into the
/// row-major plane of an image `width` pixels wide; tiles past the border are cut.
pub(crate) fn untile<'a, T: Copy + 'a>(
    plane: &mut [T],
    width: usize,
    tiles_x: usize,
    tile_plane: impl Fn(usize) -> &'a [T],
) {
    let tile = TILE as usize;
    for (y, row) in plane.chunks_exact_mut(width).enumerate() {
        let (ty, ly) = (y / tile, y % tile);
        for (tx, dst) in row.chunks_mut(tile).enumerate() {
            let src = &tile_plane(ty * tiles_x + tx)[ly * tile..];
            dst.copy_from_slice(&src[..dst.len()]);
        }
    }
}
