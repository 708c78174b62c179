//! Stage "heading": each group of views that registration could not link to the first photo
//! is turned about the room's up axis to the heading at which the linked views' Gaussians,
//! rendered small, match its photos and depth best ([`inssplat_geometry::heading`]).

use inssplat_geometry::heading::{HeadingParams, place_by_heading};
use inssplat_proto::{Camera, GaussianScene};

use super::decode::ModelImage;
use super::{backproject, plane, stage_err};
use crate::backend::ModelOutput;
use crate::reconstruct::PipelineError;

/// Turns the unlinked groups of `component` in `cameras`.
pub fn run(
    cameras: &mut [Camera],
    component: &[usize],
    out: &ModelOutput,
    decoded: &[ModelImage],
    params: &HeadingParams,
) -> Result<(), PipelineError> {
    let pixels = out.height * out.width;
    let photos: Vec<&[f32]> = decoded.iter().map(|d| d.planar.as_slice()).collect();
    let depths: Vec<&[f32]> = (0..out.views).map(|v| &out.depth[plane(1, pixels, v)]).collect();
    // Every `factor`-th pixel's Gaussian, grown to cover as many, for the renders at
    // 1/`factor` of the size: a tenth of the cost of all of them (val40, 8 views). A
    // back-projection error is named by the stage "backproject" right after.
    let stride = params.factor as u32;
    let gaussians = |cameras: &[Camera], views: &[usize]| {
        backproject::run(out, cameras, views).map_or_else(
            |_| GaussianScene::with_sem_dim(0),
            |b| b.thinned(out.width as u32, out.height as u32, stride),
        )
    };
    place_by_heading(cameras, component, &photos, &depths, params, &gaussians)
        .map_err(|e| stage_err("heading")(&e))?;
    Ok(())
}
