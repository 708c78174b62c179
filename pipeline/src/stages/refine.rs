//! Stage "refine": test-time refinement of the Gaussians (and the registered cameras) against
//! the photos for a number of Adam steps, one photo a step, with each photo's brightness gain;
//! the instances and their names are kept ([`inssplat_geometry::refine`]).

use inssplat_geometry::refine::{RefineParams, RefineView, SceneRefinement, refine_scene};
use inssplat_proto::{Camera, GaussianScene};

use super::decode::ModelImage;
use super::stage_err;
use crate::reconstruct::PipelineError;

/// Refines `scene` for `steps` steps; `move_cameras` lets the cameras move with it (not when
/// the caller gave them).
pub fn run(
    scene: &mut GaussianScene,
    cameras: &mut [Camera],
    decoded: &[ModelImage],
    steps: usize,
    move_cameras: bool,
) -> Result<SceneRefinement, PipelineError> {
    let views: Vec<RefineView<'_>> = decoded
        .iter()
        .map(|d| RefineView { photo: &d.planar, rect: d.letterbox.photo_rect() })
        .collect();
    let params = RefineParams { steps, cameras: move_cameras };
    refine_scene(scene, cameras, &views, params).map_err(|e| stage_err("refine")(&e))
}
