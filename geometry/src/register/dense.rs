//! Matches of two views on the network's learned per-pixel descriptors (the optional
//! `descriptors` output, `[D][H][W]` per view, compared after L2 normalization), which
//! registration matches where a pair's keypoints found no pose: on the synthetic rooms at 128²
//! BRIEF
//! links no pair to 79 of the 280 non-reference views of the 40 val scenes at 8 views, though
//! they overlap another view by 80% (median). This module owns the descriptor maps'
//! preparation (every pixel normalized, a grid of points every
//! [`RegisterParams::descriptor_stride`] pixels inside the photo where the depth is valid),
//! the grid-to-grid matching, and the refinement of each match to a full-resolution pixel;
//! lifting the matches by depth is the caller's, as for the keypoints.
//!
//! A pair's matches are mutual nearest neighbours by cosine between the two grids, at
//! [`RegisterParams::descriptor_min_cos`] or more, and clearly better than the runner-up
//! (ratio test on 1 − cos, [`RegisterParams::descriptor_ratio`]). A descriptor field is smooth
//! across neighbouring pixels, so the grid points next to the best (one cell around it) are
//! no rivals: the runner-up is the best outside them. The matched point in the second view
//! then moves to the pixel, within one stride of its grid point, whose descriptor is most
//! like the first's, so that matches are not quantized to the grid.
//!
//! The search of the nearest grid points is the costly part (at 128² and stride 4 a view has
//! up to 1024 grid points, and a pair a million cosines): blocked so that it vectorizes, and
//! compiled for AVX2 where the CPU has it (about 2 ms a pair at D = 16).

use glam::Vec2;

use super::{RegisterParams, RegisterView};

/// A view's dense descriptor map, as the network outputs it.
#[derive(Debug, Clone, Copy)]
pub struct Descriptors<'a> {
    /// Planar `[D][H][W]` at the view's size (its intrinsics' width × height); compared after
    /// L2 normalization, so any scale.
    pub data: &'a [f32],
    /// D, the descriptor's length.
    pub dim: usize,
}

/// A grid point: its pixel and its cell (column, row) in the grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct GridPoint {
    x: u32,
    y: u32,
    col: u32,
    row: u32,
}

impl GridPoint {
    /// The pixel's centre (+0.5, as the keypoints).
    fn centre(&self) -> Vec2 {
        Vec2::new(self.x as f32 + 0.5, self.y as f32 + 0.5)
    }
}

/// Grid points whose cosines one block of the similarity loop computes at once (independent
/// accumulators, so that the loop is not bound by the latency of an addition).
const TILE: usize = 32;
/// Lanes of the loops that reduce a row of cosines.
const LANES: usize = 8;
/// No grid point (in [`DenseView::cells`]).
const NONE: u32 = u32::MAX;

/// One view's descriptors ready for matching.
pub struct DenseView {
    width: usize,
    dim: usize,
    photo: [u32; 4],
    /// Window radius of the refinement, pixels (the grid's stride).
    radius: u32,
    /// Every pixel's unit descriptor, pixel-major `[H·W][D]` (zero where the map's is zero or
    /// not finite).
    pixels: Vec<f32>,
    /// The grid points with a descriptor and a valid depth.
    grid: Vec<GridPoint>,
    /// The grid's columns and rows, and the index in `grid` of each cell's point, row-major
    /// ([`NONE`] where the cell has none).
    cols: u32,
    rows: u32,
    cells: Vec<u32>,
    /// The grid points' unit descriptors in blocks of [`TILE`] points, `[block][D][TILE]`
    /// (zero past the last point): a block's similarities with one descriptor read contiguous
    /// memory.
    blocks: Vec<f32>,
}

impl DenseView {
    /// Number of grid points.
    pub fn len(&self) -> usize {
        self.grid.len()
    }

    pub fn is_empty(&self) -> bool {
        self.grid.is_empty()
    }

    /// The grid points with their padding to whole [`TILE`]s.
    fn padded(&self) -> usize {
        self.len().next_multiple_of(TILE)
    }

    /// The unit descriptor of pixel (x, y).
    fn descriptor(&self, x: u32, y: u32) -> &[f32] {
        let p = y as usize * self.width + x as usize;
        &self.pixels[p * self.dim..(p + 1) * self.dim]
    }

    /// The grid points in the cell of point `k` and the eight around it (`k` included).
    fn around(&self, k: usize) -> impl Iterator<Item = usize> + '_ {
        let g = self.grid[k];
        let cols = g.col.saturating_sub(1)..(g.col + 2).min(self.cols);
        (g.row.saturating_sub(1)..(g.row + 2).min(self.rows))
            .flat_map(move |row| {
                cols.clone().map(move |col| self.cells[(row * self.cols + col) as usize])
            })
            .filter(|&i| i != NONE)
            .map(|i| i as usize)
    }
}

/// The descriptors of `view` prepared for matching; `None` when it has none.
///
/// # Panics
/// When the map's size is not D × the view's pixels.
pub fn prepare(view: &RegisterView<'_>, params: &RegisterParams) -> Option<DenseView> {
    let map = view.descriptors?;
    let (width, height) =
        (view.camera.intrinsics.width as usize, view.camera.intrinsics.height as usize);
    let (dim, size) = (map.dim, width * height);
    assert!(
        dim > 0 && map.data.len() == dim * size,
        "descriptor map of {} values for D = {dim} at {width}×{height}",
        map.data.len()
    );
    let mut pixels = vec![0.0f32; size * dim];
    for (d, plane) in map.data.chunks_exact(size).enumerate() {
        for (p, &v) in plane.iter().enumerate() {
            pixels[p * dim + d] = v;
        }
    }
    for row in pixels.chunks_exact_mut(dim) {
        let norm = row.iter().map(|v| v * v).sum::<f32>().sqrt();
        if norm.is_finite() && norm > 1e-12 {
            row.iter_mut().for_each(|v| *v /= norm);
        } else {
            row.fill(0.0);
        }
    }
    let stride = params.descriptor_stride.max(1);
    let [x0, y0, x1, y1] = view.photo;
    let (x1, y1) = (x1.min(width as u32), y1.min(height as u32));
    let (xs, ys) = (
        (x0 + stride / 2..x1).step_by(stride as usize),
        (y0 + stride / 2..y1).step_by(stride as usize),
    );
    let (cols, rows) = (xs.len() as u32, ys.len() as u32);
    let mut dense = DenseView {
        width,
        dim,
        photo: [x0, y0, x1, y1],
        radius: stride,
        pixels,
        grid: Vec::new(),
        cols,
        rows,
        cells: vec![NONE; (cols * rows) as usize],
        blocks: Vec::new(),
    };
    for (row, y) in ys.enumerate() {
        for (col, x) in xs.clone().enumerate() {
            let z = view.depth[y as usize * width + x as usize];
            if z.is_finite() && z > 0.0 && dense.descriptor(x, y).iter().any(|&v| v != 0.0) {
                dense.cells[row * cols as usize + col] = dense.grid.len() as u32;
                dense.grid.push(GridPoint { x, y, col: col as u32, row: row as u32 });
            }
        }
    }
    let mut blocks = vec![0.0f32; dim * dense.padded()];
    for (k, g) in dense.grid.iter().enumerate() {
        let block = &mut blocks[(k / TILE) * dim * TILE..][..dim * TILE];
        for (d, &v) in dense.descriptor(g.x, g.y).iter().enumerate() {
            block[d * TILE + k % TILE] = v;
        }
    }
    dense.blocks = blocks;
    Some(dense)
}

/// Cosines of `query` (a unit descriptor) with every grid point of `blocks` into `row` (the
/// padded length). Each block's [`TILE`] sums are independent lanes, which the compiler
/// vectorizes as written (no reassociation needed).
#[inline(always)]
fn similarity_row(query: &[f32], blocks: &[f32], row: &mut [f32]) {
    for (out, block) in row.chunks_exact_mut(TILE).zip(blocks.chunks_exact(query.len() * TILE)) {
        let mut acc = [0.0f32; TILE];
        for (&q, column) in query.iter().zip(block.chunks_exact(TILE)) {
            for (a, &c) in acc.iter_mut().zip(column) {
                *a += q * c;
            }
        }
        out.copy_from_slice(&acc);
    }
}

/// The largest entry of `row`, [`LANES`] at a time.
#[inline(always)]
fn max_of(row: &[f32]) -> f32 {
    let mut top = [f32::NEG_INFINITY; LANES];
    for chunk in row.chunks_exact(LANES) {
        for (t, &s) in top.iter_mut().zip(chunk) {
            *t = if s > *t { s } else { *t };
        }
    }
    top.into_iter().fold(f32::NEG_INFINITY, |m, t| if t > m { t } else { m })
}

/// The largest entry of `row` and its index (the first of equals). The largest is found
/// first and then looked for: tracking the index alongside does not vectorize.
#[inline(always)]
fn arg_max(row: &[f32]) -> (f32, usize) {
    let top = max_of(row);
    let chunk = row
        .chunks_exact(LANES)
        .position(|c| c.iter().fold(false, |hit, &s| hit | (s == top)))
        .unwrap_or(0);
    let at = row[chunk * LANES..].iter().position(|&s| s == top).unwrap_or(0);
    (top, chunk * LANES + at)
}

/// For each grid point of a: its cosine with its nearest in b, that point's index, and the
/// largest cosine outside the nearest's neighbourhood (−∞ if none); and for each grid point of
/// b the index of its nearest in a.
#[inline(always)]
fn nearest_portable(a: &DenseView, b: &DenseView) -> (Vec<(f32, usize, f32)>, Vec<u32>) {
    let (nb, padded) = (b.len(), b.padded());
    let mut row = vec![0.0f32; padded];
    let (mut col_top, mut col_at) = (vec![f32::NEG_INFINITY; padded], vec![0u32; padded]);
    let mut out = Vec::with_capacity(a.len());
    for (ia, g) in a.grid.iter().enumerate() {
        similarity_row(a.descriptor(g.x, g.y), &b.blocks, &mut row);
        row[nb..].fill(f32::NEG_INFINITY);
        for ((&s, top), at) in row.iter().zip(&mut col_top).zip(&mut col_at) {
            let better = s > *top;
            *top = if better { s } else { *top };
            *at = if better { ia as u32 } else { *at };
        }
        let (cos, ib) = arg_max(&row);
        for k in b.around(ib) {
            row[k] = f32::NEG_INFINITY;
        }
        out.push((cos, ib, max_of(&row)));
    }
    col_at.truncate(nb);
    (out, col_at)
}

/// [`nearest_portable`] compiled for AVX2 (the results are the same: Rust does not fuse the
/// multiply-adds).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn nearest_avx2(a: &DenseView, b: &DenseView) -> (Vec<(f32, usize, f32)>, Vec<u32>) {
    nearest_portable(a, b)
}

fn nearest(a: &DenseView, b: &DenseView) -> (Vec<(f32, usize, f32)>, Vec<u32>) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has the instructions the function is compiled for.
        return unsafe { nearest_avx2(a, b) };
    }
    nearest_portable(a, b)
}

/// Dot product of two descriptors.
fn dot(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The matches of views a and b as pixel centres in each (see the module documentation):
/// a's grid point, and the pixel in b whose descriptor is most like it within one stride of
/// the matched grid point.
///
/// # Panics
/// When the views' descriptors differ in length.
pub fn match_views(a: &DenseView, b: &DenseView, params: &RegisterParams) -> Vec<(Vec2, Vec2)> {
    assert_eq!(a.dim, b.dim, "the views' descriptors differ in length");
    if a.is_empty() || b.is_empty() {
        return Vec::new();
    }
    let (best_in_b, best_in_a) = nearest(a, b);
    let mut out = Vec::new();
    for (ia, (cos, ib, second)) in best_in_b.into_iter().enumerate() {
        let distinct =
            second == f32::NEG_INFINITY || (1.0 - cos) < params.descriptor_ratio * (1.0 - second);
        if cos >= params.descriptor_min_cos && distinct && best_in_a[ib] as usize == ia {
            let ga = &a.grid[ia];
            out.push((ga.centre(), refine(b, a.descriptor(ga.x, ga.y), &b.grid[ib])));
        }
    }
    out
}

/// The centre of the pixel of `view` within its refinement radius of `around` (and inside the
/// photo) whose descriptor is most like `query`; the grid point itself on ties.
fn refine(view: &DenseView, query: &[f32], around: &GridPoint) -> Vec2 {
    let [x0, y0, x1, y1] = view.photo;
    let r = view.radius;
    let mut best = (dot(query, view.descriptor(around.x, around.y)), around.x, around.y);
    for y in around.y.saturating_sub(r).max(y0)..(around.y + r + 1).min(y1) {
        for x in around.x.saturating_sub(r).max(x0)..(around.x + r + 1).min(x1) {
            let s = dot(query, view.descriptor(x, y));
            if s > best.0 {
                best = (s, x, y);
            }
        }
    }
    Vec2::new(best.1 as f32 + 0.5, best.2 as f32 + 0.5)
}

#[cfg(test)]
mod tests {
    use glam::{Quat, Vec2, Vec3};
    use inssplat_proto::Camera;
    use inssplat_proto::camera::Intrinsics;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::{Descriptors, match_views, nearest, nearest_portable, prepare};
    use crate::register::{RegisterParams, RegisterView};

    const SIZE: u32 = 40;
    const DIM: usize = 16;

    fn camera() -> Camera {
        Camera {
            intrinsics: Intrinsics::from_fov_y(SIZE, SIZE, 1.0),
            rotation: Quat::IDENTITY,
            translation: Vec3::ZERO,
        }
    }

    /// A smooth map: the sines and cosines of 8 random projections of each pixel's position
    /// (0.15–0.8 rad per pixel) shifted by `shift`, as a descriptor of the surface it sees.
    fn smooth_map(shift: Vec2, seed: u64) -> Vec<f32> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let waves: Vec<(Vec2, f32)> = (0..DIM / 2)
            .map(|_| {
                let angle = rng.random_range(0.0..std::f32::consts::TAU);
                (
                    Vec2::from_angle(angle) * rng.random_range(0.15..0.8),
                    rng.random_range(0.0..std::f32::consts::TAU),
                )
            })
            .collect();
        let pixels = (SIZE * SIZE) as usize;
        let mut map = vec![0.0; DIM * pixels];
        for p in 0..pixels {
            let at = Vec2::new((p % SIZE as usize) as f32, (p / SIZE as usize) as f32) - shift;
            for (k, (omega, phase)) in waves.iter().enumerate() {
                let (s, c) = (omega.dot(at) + phase).sin_cos();
                map[2 * k * pixels + p] = s;
                map[(2 * k + 1) * pixels + p] = c;
            }
        }
        map
    }

    #[test]
    fn identical_maps_match_every_grid_point_to_itself() {
        let pixels = (SIZE * SIZE) as usize;
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        // Any scale: the matcher normalizes.
        let data: Vec<f32> = (0..DIM * pixels).map(|_| rng.random_range(-2.0..2.0)).collect();
        let (rgb, depth, camera) = (vec![0.5; 3 * pixels], vec![2.0; pixels], camera());
        // A letterboxed photo: the grid starts inside it.
        let photo = [0, 4, SIZE, SIZE - 4];
        let view = RegisterView {
            rgb: &rgb,
            depth: &depth,
            photo,
            camera: &camera,
            descriptors: Some(Descriptors { data: &data, dim: DIM }),
            detail: None,
        };
        let params = RegisterParams::default();
        let dense = prepare(&view, &params).expect("descriptors");
        // Every 4th pixel from 2 across 40 columns, and from 6 in rows 4..36.
        assert_eq!(dense.len(), 10 * 8);
        let matches = match_views(&dense, &dense, &params);
        let grid: Vec<(Vec2, Vec2)> = dense.grid.iter().map(|g| (g.centre(), g.centre())).collect();
        assert_eq!(matches, grid);
        assert!(matches.iter().all(|(p, _)| p.y > 4.0 && p.y < (SIZE - 4) as f32));
    }

    #[test]
    fn a_shifted_map_matches_off_the_grid() {
        // View b sees view a's surface 3 pixels to the right and 1 down: a's grid points fall
        // between b's, and the refinement must find the exact pixels.
        let shift = Vec2::new(3.0, 1.0);
        let (map_a, map_b) = (smooth_map(Vec2::ZERO, 5), smooth_map(shift, 5));
        let pixels = (SIZE * SIZE) as usize;
        let (rgb, depth, camera) = (vec![0.5; 3 * pixels], vec![2.0; pixels], camera());
        let view = |data| RegisterView {
            rgb: &rgb,
            depth: &depth,
            photo: [0, 0, SIZE, SIZE],
            camera: &camera,
            descriptors: Some(Descriptors { data, dim: DIM }),
            detail: None,
        };
        let params = RegisterParams::default();
        let (a, b) =
            (prepare(&view(&map_a), &params).unwrap(), prepare(&view(&map_b), &params).unwrap());
        let matches = match_views(&a, &b, &params);
        let inside = |p: Vec2| p.x < SIZE as f32 && p.y < SIZE as f32;
        let seen = a.grid.iter().filter(|g| inside(g.centre() + shift)).count();
        let exact = matches.iter().filter(|(pa, pb)| *pb == *pa + shift).count();
        assert!(
            matches.iter().all(|(pa, pb)| *pb == *pa + shift || !inside(*pa + shift)),
            "{matches:?}"
        );
        assert!(exact * 10 >= seen * 8, "{exact} exact matches of {seen} grid points that b sees");
    }

    #[test]
    fn the_vectorized_search_finds_what_the_portable_one_does() {
        let pixels = (SIZE * SIZE) as usize;
        let (rgb, depth, camera) = (vec![0.5; 3 * pixels], vec![2.0; pixels], camera());
        let maps = [smooth_map(Vec2::ZERO, 7), smooth_map(Vec2::new(-2.0, 5.0), 7)];
        let params = RegisterParams { descriptor_stride: 3, ..RegisterParams::default() };
        let views: Vec<_> = maps
            .iter()
            .map(|m| {
                let v = RegisterView {
                    rgb: &rgb,
                    depth: &depth,
                    photo: [1, 0, SIZE, SIZE - 1],
                    camera: &camera,
                    descriptors: Some(Descriptors { data: m, dim: DIM }),
                    detail: None,
                };
                prepare(&v, &params).unwrap()
            })
            .collect();
        assert_eq!(nearest(&views[0], &views[1]), nearest_portable(&views[0], &views[1]));
    }

    #[test]
    fn views_without_descriptors_are_not_prepared() {
        let (rgb, depth, camera) = (vec![0.5; 3 * 1600], vec![1.0; 1600], camera());
        let view = RegisterView {
            rgb: &rgb,
            depth: &depth,
            photo: [0, 0, SIZE, SIZE],
            camera: &camera,
            descriptors: None,
            detail: None,
        };
        assert!(prepare(&view, &RegisterParams::default()).is_none());
    }
}
