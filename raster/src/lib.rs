//! inssplat-raster: everything geometric between network output and pixels. Back-projection
//! of predicted depth into per-pixel Gaussians, confidence-aware voxelization and feature
//! fusion, the differentiable CPU tile rasterizer (forward and hand-written backward, any
//! channel count), the wgpu forward rasterizer for serving, instance clustering in 3D
//! (HDBSCAN) and label assignment, the image metrics of the evaluation protocol (and the
//! test-time refinement of a target camera's pose that a flag of it asks for), the test-time
//! refinement of a scene against its input photos, and the
//! ideal network outputs of views with known ground truth that prove the chain. It knows
//! nothing of HTTP or ONNX.

mod adam;
pub mod backproject;
pub mod cluster;
pub mod fill;
pub mod heading;
pub mod ideal;
pub mod label;
pub mod metrics;
pub mod refine;
pub mod register;
pub mod render;
pub mod rotation;
pub mod superpixel;
pub mod target_pose;
pub mod voxel;
