//! The analytic room of `inssplat_geometry::analytic_room` on a ring of cameras, reconstructed from
//! its ideal
//! outputs: the common start of the test-time optimization tests (`refine.rs`,
//! `target_pose.rs`).

use inssplat_geometry::backproject::{ViewOutputs, backproject};
use inssplat_geometry::voxel::{VoxelParams, voxelize};
use inssplat_proto::dataset::Scene;
use inssplat_proto::{Camera, GaussianScene};

use inssplat_geometry::analytic_room::{SEM_DIM, ideal_outputs, render_scene, ring_cameras};

/// The analytic room on a ring of 8 cameras of `size` pixels, and the scene reconstructed
/// from its ideal outputs with ±`noise` on their codes.
pub fn ring_reconstruction(
    size: u32,
    noise: f32,
    seed: u64,
) -> (Vec<Camera>, Scene, GaussianScene) {
    let cameras = ring_cameras(8, size);
    let room = render_scene(&cameras);
    let planes = ideal_outputs(&room, noise, seed);
    let views: Vec<ViewOutputs<'_>> =
        planes.iter().zip(&cameras).map(|(p, camera)| p.outputs(camera)).collect();
    let scene = voxelize(&backproject(&views, SEM_DIM).unwrap().scene, &VoxelParams::default())
        .unwrap()
        .scene;
    (cameras, room, scene)
}
