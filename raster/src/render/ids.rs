//! Instance ids by rendering: every Gaussian carries an id (0 = none), one compositing pass
//! sums each pixel's weights w = α·T per id, and a pixel whose accumulated alpha exceeds a
//! threshold takes the id of largest weight (0 otherwise). The cost does not grow with the
//! number of ids: a tile keeps one weight plane per id that actually occurs in its list (a
//! handful), not one channel per instance of the scene. A pixel stops compositing as soon as
//! its answer is settled: its alpha is past the threshold and its leading id is ahead of the
//! runner-up by more than the transmittance left (all that later Gaussians can still add),
//! with a margin for float rounding.
//!
//! This is what compositing one one-hot channel per id and taking each pixel's largest
//! channel gives, exactly: per pixel and id the same weights are added in the same order, and
//! ties go to the smallest id as a first-largest scan over channels does. The wgpu path does
//! just that ([`IdImage::from_one_hot`]), which the tests also use as the oracle.

use inssplat_proto::Camera;
use rayon::prelude::*;

use super::composite::{TILE_PIXELS, TileCoverage, TileSink};
use super::project::{Projected, View};
use super::{
    AlphaCutoff, Backend, GpuRenderer, Image, RenderError, Splats, composite_tiles, prepare, tiles,
    validate,
};

/// Relative margin by which a pixel's leading weight must beat the runner-up plus the
/// transmittance left before the pixel is settled: float sums of up to ~10⁴ weights stay
/// within it.
const SETTLE_MARGIN: f32 = 1e-3;

/// A rendered id map.
#[derive(Debug, Clone, PartialEq)]
pub struct IdImage {
    pub width: u32,
    pub height: u32,
    /// `[height][width]` id of largest accumulated weight where the accumulated alpha exceeds
    /// the threshold, else 0 (also where no Gaussian with an id contributes).
    pub ids: Vec<u32>,
}

impl IdImage {
    /// The id map of an image whose channel `k` is the one-hot weight of id `k + 1`.
    pub fn from_one_hot(image: &Image, min_alpha: f32) -> Self {
        let pixels = image.alpha.len();
        let ids = (0..pixels)
            .map(|p| {
                let (mut best, mut best_w) = (0, 0.0);
                if image.alpha[p] > min_alpha {
                    for k in 0..image.channels {
                        let w = image.features[k * pixels + p];
                        if w > best_w {
                            (best, best_w) = (k as u32 + 1, w);
                        }
                    }
                }
                best
            })
            .collect();
        Self { width: image.width, height: image.height, ids }
    }
}

/// One tile's weights per id (one 16×16 plane for each id met in the tile's list) and, per
/// pixel, the leading id, its weight and the runner-up's weight.
struct IdSink<'a> {
    /// Id of each depth rank.
    id_from_rank: &'a [u32],
    min_alpha: f32,
    /// The ids met so far, in order of appearance; `planes` holds their weights.
    ids: Vec<u32>,
    planes: Vec<f32>,
    best: [u32; TILE_PIXELS],
    best_weight: [f32; TILE_PIXELS],
    second_weight: [f32; TILE_PIXELS],
}

impl<'a> IdSink<'a> {
    fn new(id_from_rank: &'a [u32], min_alpha: f32) -> Self {
        Self {
            id_from_rank,
            min_alpha,
            ids: Vec::new(),
            planes: Vec::new(),
            best: [0; TILE_PIXELS],
            best_weight: [0.0; TILE_PIXELS],
            second_weight: [0.0; TILE_PIXELS],
        }
    }

    /// Index of `id` in `ids`, adding it (and a zero plane) when new.
    fn plane_of(&mut self, id: u32) -> usize {
        match self.ids.iter().position(|&seen| seen == id) {
            Some(i) => i,
            None => {
                self.ids.push(id);
                self.planes.resize(self.planes.len() + TILE_PIXELS, 0.0);
                self.ids.len() - 1
            }
        }
    }

    /// The tile's ids: the leading id where alpha passed the threshold (settled pixels have).
    fn into_ids(self, cov: &TileCoverage) -> [u32; TILE_PIXELS] {
        std::array::from_fn(|p| {
            if 1.0 - cov.transmittance[p] > self.min_alpha { self.best[p] } else { 0 }
        })
    }
}

impl TileSink for IdSink<'_> {
    const SETTLES: bool = true;

    fn add(&mut self, _: &Projected, rank: usize, taken: &[(usize, f32)]) {
        let id = self.id_from_rank[rank];
        if id == 0 {
            return;
        }
        let i = self.plane_of(id);
        let plane = &mut self.planes[i * TILE_PIXELS..(i + 1) * TILE_PIXELS];
        for &(p, w) in taken {
            plane[p] += w;
            let v = plane[p];
            // Weights only grow: the leader changes when another id overtakes it (or ties it
            // with a smaller id), and the old leader becomes the runner-up.
            if id == self.best[p] {
                self.best_weight[p] = v;
            } else if v > self.best_weight[p] || (v == self.best_weight[p] && id < self.best[p]) {
                self.second_weight[p] = self.best_weight[p];
                (self.best[p], self.best_weight[p]) = (id, v);
            } else if v > self.second_weight[p] {
                self.second_weight[p] = v;
            }
        }
    }

    fn settled(&self, p: usize, transmittance: f32) -> bool {
        1.0 - transmittance > self.min_alpha
            && self.best_weight[p] > (self.second_weight[p] + transmittance) * (1.0 + SETTLE_MARGIN)
    }
}

/// Renders the id map of `splats` (geometry only: features are not read and may be empty)
/// whose Gaussian `i` has id `ids[i]`, seen by `camera`, on the CPU: per pixel the id of
/// largest weight where the accumulated alpha exceeds `min_alpha`, else 0.
pub fn render_ids(
    splats: &Splats,
    ids: &[u32],
    camera: &Camera,
    min_alpha: f32,
) -> Result<IdImage, RenderError> {
    let geometry = Splats { features: &[], channels: 0, ..*splats };
    validate(&geometry, camera, &[])?;
    if ids.len() != splats.means.len() {
        return Err(RenderError::Length {
            field: "ids",
            expected: splats.means.len(),
            got: ids.len(),
        });
    }
    let (width, height) = (camera.intrinsics.width, camera.intrinsics.height);
    let (_, bins) = prepare(&geometry, &View::new(camera), AlphaCutoff::Hard, width, height);
    let id_from_rank: Vec<u32> = bins.gid_from_rank.iter().map(|&gid| ids[gid as usize]).collect();
    let tiles = composite_tiles(
        &bins,
        AlphaCutoff::Hard,
        [width, height],
        || IdSink::new(&id_from_rank, min_alpha),
        |sink, cov| sink.into_ids(&cov),
    );
    let mut image_ids = vec![0; width as usize * height as usize];
    tiles::untile(&mut image_ids, width as usize, bins.tiles_x as usize, |t| &tiles[t]);
    Ok(IdImage { width, height, ids: image_ids })
}

/// [`render_ids`] on `gpu` when given and working (one one-hot channel per id up to the
/// largest, then [`IdImage::from_one_hot`]), else on the CPU; says which ran.
pub fn render_ids_any(
    gpu: Option<&GpuRenderer>,
    splats: &Splats,
    ids: &[u32],
    camera: &Camera,
    min_alpha: f32,
) -> Result<(IdImage, Backend), RenderError> {
    if let Some(gpu) = gpu.filter(|_| ids.len() == splats.means.len()) {
        let channels = ids.iter().copied().max().unwrap_or(0) as usize;
        let mut one_hot = vec![0.0f32; ids.len() * channels];
        one_hot.par_chunks_mut(channels.max(1)).zip(ids).for_each(|(row, &id)| {
            if id > 0 {
                row[id as usize - 1] = 1.0;
            }
        });
        let splats = Splats { features: &one_hot, channels, ..*splats };
        match gpu.render(&splats, camera, &[]) {
            Ok(image) => return Ok((IdImage::from_one_hot(&image, min_alpha), Backend::Wgpu)),
            Err(RenderError::Gpu(_) | RenderError::NoAdapter) => {}
            Err(e) => return Err(e),
        }
    }
    render_ids(splats, ids, camera, min_alpha).map(|image| (image, Backend::Cpu))
}
