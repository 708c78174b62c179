//! Stage "rays": a network that reads its cameras as rays runs again on the registered
//! cameras' rays, and that pass's instance and semantic features replace the first pass's
//! (snapped to the same superpixels); the depth, Gaussians and cameras stay the first pass's.

use inssplat_proto::rays::{median_depth, patch_rays};
use inssplat_proto::{Camera, INSTANCE_DIM};
use inssplat_understand::superpixel::snap;
use rayon::prelude::*;

use super::network::NetworkPass;
use super::superpixels::Segments;
use crate::backend::{Backend, RayInput};
use crate::reconstruct::PipelineError;

/// Runs the second pass with `input`'s rays of `cameras`.
pub fn run(
    backend: &mut dyn Backend,
    input: RayInput,
    pass: &mut NetworkPass,
    cameras: &[Camera],
    segments: Option<&Segments>,
) -> Result<(), PipelineError> {
    let out = &mut pass.out;
    // The registered cameras are in the depth's units, as the true ones are in the true
    // depth's when the network learns.
    let scale = median_depth(&out.depth).unwrap_or(1.0);
    let size = [out.height, out.width];
    let rays = patch_rays(cameras, size, input.patch, input.k, scale);
    let second = backend.run(&pass.batch, out.views, size, Some(&rays))?;
    out.instance = second.instance;
    out.semantic = second.semantic;
    if let Some(segments) = segments {
        let pixels = out.height * out.width;
        out.instance
            .par_chunks_exact_mut(INSTANCE_DIM * pixels)
            .zip(segments)
            .for_each(|(map, s)| snap(map, s));
    }
    Ok(())
}
