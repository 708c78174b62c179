//! Stage "voxelize": the per-pixel Gaussians merged per voxel, confidence-weighted, with
//! their features fused ([`inssplat_geometry::voxel`]).

use inssplat_geometry::backproject::BackProjected;
use inssplat_geometry::voxel::{VoxelParams, Voxelized, voxelize};

use super::stage_err;
use crate::reconstruct::PipelineError;

/// Voxelizes the back-projected Gaussians.
pub fn run(per_pixel: &BackProjected, params: &VoxelParams) -> Result<Voxelized, PipelineError> {
    voxelize(&per_pixel.scene, params).map_err(|e| stage_err("voxelize")(&e))
}
