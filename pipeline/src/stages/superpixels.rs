//! Stage "superpixels": each view's instance embeddings snapped to its photo's colour
//! superpixels ([`inssplat_understand::superpixel`]), so the instances' outlines follow the
//! photo's edges instead of the decoder's patch blur. The segments are kept for the second
//! network pass and the vote.

use inssplat_proto::INSTANCE_DIM;
use inssplat_understand::superpixel::{SuperpixelParams, segment, snap};
use rayon::prelude::*;

use super::decode::ModelImage;
use crate::backend::ModelOutput;

/// Each view's superpixel segments, `[V][H·W]`.
pub type Segments = Vec<Vec<u32>>;

/// Segments every view and snaps its instance embeddings to the segments.
pub fn run(out: &mut ModelOutput, decoded: &[ModelImage], params: &SuperpixelParams) -> Segments {
    let (width, height) = (out.width, out.height);
    out.instance
        .par_chunks_exact_mut(INSTANCE_DIM * width * height)
        .zip(decoded)
        .map(|(map, d)| {
            let segments = segment(&d.planar, width, height, params);
            snap(map, &segments);
            segments
        })
        .collect()
}
