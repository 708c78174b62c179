//! Stage "masks": every input view's instance and label maps. They need no rendering: each
//! pixel's own Gaussian was merged into one clustered Gaussian, whose id it takes (exact at the
//! pixel's own surface, and the same id in every view that sees that Gaussian), and then each
//! superpixel takes its pixels' majority id. Novel views are rendered
//! ([`crate::render_view`]). Stage "upsample" takes the maps to each photo's resolution
//! ([`photo_maps`]).

use inssplat_geometry::backproject::BackProjected;
use inssplat_geometry::voxel::{DROPPED, Voxelized};
use inssplat_proto::Camera;
use inssplat_proto::api::{CameraFit, FocalSource, Placement};
use inssplat_raster::masks::label_map;
use inssplat_understand::label::detections::{DetectedBox, ViewDetections};
use inssplat_understand::upsample::{LowRes, Placement as Grid, UpsampleParams, upsample_labels};
use rayon::prelude::*;

use super::decode::{Letterbox, ModelImage};
use super::plane;
use super::superpixels::Segments;
use super::vote::voted_maps;
use crate::backend::ModelOutput;
use crate::reconstruct::{PhotoMaps, ViewResult};

/// Each input view's instance id map (`pixels` a view).
pub fn run(
    voxelized: &Voxelized,
    per_pixel: &BackProjected,
    segments: Option<&Segments>,
    pixels: usize,
) -> Vec<Vec<u32>> {
    voted_maps(voxelized, per_pixel, segments, pixels)
        .chunks_exact(pixels)
        .map(<[u32]>::to_vec)
        .collect()
}

/// Each view's instance map with the detector's boxes in it (model pixels), as naming reads
/// them.
pub fn view_detections<'a>(
    id_maps: &'a [Vec<u32>],
    boxes: &'a [Vec<DetectedBox>],
    out: &ModelOutput,
) -> Vec<ViewDetections<'a>> {
    id_maps
        .iter()
        .zip(boxes)
        .map(|(ids, boxes)| ViewDetections { ids, width: out.width, height: out.height, boxes })
        .collect()
}

/// Each view's instance and label maps at its photo's resolution (up to the size of the
/// decode stage's guide, [`ModelImage::guide`]): upsampled along the photo's edges where the
/// photo has more pixels than its part of the model's input, else sampled at the nearest model
/// pixel; `None` for a view without a guide.
pub fn photo_maps(
    decoded: &[ModelImage],
    id_maps: &[Vec<u32>],
    label_of_id: &[Option<usize>],
) -> Vec<Option<PhotoMaps>> {
    decoded
        .par_iter()
        .zip(id_maps)
        .map(|(d, ids)| {
            let guide = d.guide.as_ref()?;
            let (w, h) = guide.dimensions();
            let lb = &d.letterbox;
            let at = grid(lb, w);
            let instance_ids = if at.step >= 1.0 {
                nearest_map(ids, lb, w, h)
            } else {
                let [iw, ih] = lb.input.map(|s| s as usize);
                let rgb = rgb8(&d.planar, iw * ih);
                let lo =
                    LowRes { labels: ids, rgb: &rgb, width: iw, height: ih, rect: lb.photo_rect() };
                let params = UpsampleParams::default();
                upsample_labels(&lo, guide.as_raw(), w as usize, h as usize, at, &params)
            };
            let labels = label_map(&instance_ids, label_of_id);
            Some(PhotoMaps { width: w, height: h, instance_ids, labels })
        })
        .collect()
}

/// A view's map at the model's input (letterbox `lb`) at `w`×`h` over its photo, each photo
/// pixel taking the model pixel its centre falls in.
pub fn nearest_map(ids: &[u32], lb: &Letterbox, w: u32, h: u32) -> Vec<u32> {
    let at = grid(lb, w);
    let [iw, ih] = lb.input.map(|s| s as usize);
    let cell = |v: u32, o: f32, n: usize| ((o + (v as f32 + 0.5) * at.step) as usize).min(n - 1);
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| ids[cell(y, at.origin[1], ih) * iw + cell(x, at.origin[0], iw)])
        .collect()
}

/// Where the pixels of a photo map `w` wide fall in the model's grid (letterbox `lb`).
fn grid(lb: &Letterbox, w: u32) -> Grid {
    Grid { origin: [lb.pad_x, lb.pad_y], step: lb.scale * lb.width as f32 / w as f32 }
}

/// A planar `[3][pixels]` image in [0, 1] as interleaved 8-bit RGB.
fn rgb8(planar: &[f32], pixels: usize) -> Vec<u8> {
    (0..pixels)
        .flat_map(|p| [0, 1, 2].map(|c| (planar[c * pixels + p] * 255.0).round() as u8))
        .collect()
}

/// What each input view looks like: its camera, maps, depth and letterboxed photo.
pub struct ViewParts<'a> {
    pub out: &'a ModelOutput,
    pub cameras: &'a [Camera],
    pub placements: &'a [Placement],
    /// Where each view's focal length came from.
    pub focal: &'a [FocalSource],
    /// Registration's fit of each view (`None` where it did not run).
    pub fit: Option<&'a [CameraFit]>,
    pub voxelized: &'a Voxelized,
    pub per_pixel: &'a BackProjected,
    /// Vocabulary index of each instance id's label at index id − 1.
    pub label_of_id: &'a [Option<usize>],
}

/// Assembles every view's result from its id map.
pub fn views(
    decoded: Vec<ModelImage>,
    id_maps: Vec<Vec<u32>>,
    photo_maps: Vec<Option<PhotoMaps>>,
    parts: &ViewParts<'_>,
) -> Vec<ViewResult> {
    let pixels = parts.out.height * parts.out.width;
    let merged_into: Vec<u32> =
        parts.voxelized.voxel_of.iter().map(|&v| if v == DROPPED { 0 } else { v + 1 }).collect();
    let gaussian_maps = parts.per_pixel.to_pixels(&merged_into);
    decoded
        .into_iter()
        .zip(id_maps)
        .zip(photo_maps)
        .zip(gaussian_maps.chunks_exact(pixels))
        .enumerate()
        .map(|(v, (((d, ids), photo_maps), gaussians))| ViewResult {
            photo_maps,
            camera: parts.cameras[v],
            placement: parts.placements[v],
            focal: parts.focal[v],
            fit: parts.fit.map(|f| f[v]),
            letterbox: d.letterbox,
            labels: label_map(&ids, parts.label_of_id),
            instance_ids: ids,
            gaussians: gaussians.to_vec(),
            depth: parts.out.depth[plane(1, pixels, v)].to_vec(),
            rgb: rgb8(&d.planar, pixels),
        })
        .collect()
}
