//! Stage "vote": each input view's mask read from the merged Gaussians, every superpixel given
//! the id most of its pixels carry, so that the masks follow the photo's edges where merged
//! Gaussians of two instances meet; each merged Gaussian then takes the voted id that most of
//! the pixels merged into it carry, so the views rendered anew follow the vote too.

use inssplat_geometry::backproject::BackProjected;
use inssplat_geometry::voxel::Voxelized;
use inssplat_understand::superpixel::vote;

use super::superpixels::Segments;

/// Every input view's id map (`pixels` a view), `[V][pixels]` flattened, voted over the
/// superpixels if given.
pub fn voted_maps(
    voxelized: &Voxelized,
    per_pixel: &BackProjected,
    segments: Option<&Segments>,
    pixels: usize,
) -> Vec<u32> {
    let mut maps = per_pixel.to_pixels(&voxelized.input_instance_ids());
    if let Some(segments) = segments {
        maps.chunks_exact_mut(pixels).zip(segments).for_each(|(ids, s)| vote(ids, s));
    }
    maps
}

/// Gives every merged Gaussian the voted id of most of its pixels (`pixels` a view).
pub fn run(
    voxelized: &mut Voxelized,
    per_pixel: &BackProjected,
    segments: &Segments,
    pixels: usize,
) {
    let maps = voted_maps(voxelized, per_pixel, Some(segments), pixels);
    let input_ids: Vec<u32> = per_pixel.pixel.iter().map(|&p| maps[p as usize]).collect();
    voxelized.adopt_member_majority(&input_ids);
}
