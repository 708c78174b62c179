//! Stage "masks": every input view's instance and label maps. They need no rendering: each
//! pixel's own Gaussian was merged into one clustered Gaussian, whose id it takes (exact at the
//! pixel's own surface, and the same id in every view that sees that Gaussian), and then each
//! superpixel takes its pixels' majority id. Novel views are rendered
//! ([`crate::render_view`]).

use inssplat_geometry::backproject::BackProjected;
use inssplat_geometry::voxel::{DROPPED, Voxelized};
use inssplat_proto::Camera;
use inssplat_proto::api::{CameraFit, FocalSource, Placement};
use inssplat_raster::masks::label_map;

use super::decode::ModelImage;
use super::plane;
use super::superpixels::Segments;
use super::vote::voted_maps;
use crate::backend::ModelOutput;
use crate::reconstruct::ViewResult;

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
    parts: &ViewParts<'_>,
) -> Vec<ViewResult> {
    let pixels = parts.out.height * parts.out.width;
    let merged_into: Vec<u32> =
        parts.voxelized.voxel_of.iter().map(|&v| if v == DROPPED { 0 } else { v + 1 }).collect();
    let gaussian_maps = parts.per_pixel.to_pixels(&merged_into);
    decoded
        .into_iter()
        .zip(id_maps)
        .zip(gaussian_maps.chunks_exact(pixels))
        .enumerate()
        .map(|(v, ((d, ids), gaussians))| ViewResult {
            camera: parts.cameras[v],
            placement: parts.placements[v],
            focal: parts.focal[v],
            fit: parts.fit.map(|f| f[v]),
            letterbox: d.letterbox,
            labels: label_map(&ids, parts.label_of_id),
            instance_ids: ids,
            gaussians: gaussians.to_vec(),
            depth: parts.out.depth[plane(1, pixels, v)].to_vec(),
            rgb: (0..pixels)
                .flat_map(|p| [0, 1, 2].map(|c| (d.planar[c * pixels + p] * 255.0).round() as u8))
                .collect(),
        })
        .collect()
}
