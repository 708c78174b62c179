//! Stage "backproject": every valid pixel of the chosen views becomes a Gaussian at its depth
//! along its camera's ray, with the network's offsets, instance and semantic features
//! ([`inssplat_geometry::backproject`]).

use inssplat_geometry::backproject::{BackProjected, ViewOutputs, backproject};
use inssplat_proto::signature::GAUSSIAN_CHANNELS;
use inssplat_proto::{Camera, INSTANCE_DIM};

use super::{plane, stage_err};
use crate::backend::ModelOutput;
use crate::reconstruct::PipelineError;

/// Back-projects `views` (indices into the outputs) with `cameras`.
pub fn run(
    out: &ModelOutput,
    cameras: &[Camera],
    views: &[usize],
) -> Result<BackProjected, PipelineError> {
    let pixels = out.height * out.width;
    let views: Vec<ViewOutputs<'_>> = views
        .iter()
        .map(|&v| ViewOutputs {
            camera: &cameras[v],
            depth: &out.depth[plane(1, pixels, v)],
            depth_conf: &out.depth_conf[plane(1, pixels, v)],
            gaussians: &out.gaussians[plane(GAUSSIAN_CHANNELS, pixels, v)],
            instance: &out.instance[plane(INSTANCE_DIM, pixels, v)],
            semantic: &out.semantic[plane(out.sem_dim, pixels, v)],
        })
        .collect();
    backproject(&views, out.sem_dim).map_err(|e| stage_err("backproject")(&e))
}
