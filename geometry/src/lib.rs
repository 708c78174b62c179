//! inssplat-geometry: the geometry of the request path. Back-projection of predicted depth
//! into per-pixel Gaussians ([`backproject`]), confidence-aware voxelization and feature
//! fusion ([`voxel`]), camera registration from matched keypoints and predicted depth
//! ([`register`]), the heading search for views no match links ([`heading`]), test-time
//! refinement of a scene and its cameras against the photos ([`refine`]) and of one camera's
//! pose ([`target_pose`]), and the ideal network outputs of views with known ground truth
//! ([`ideal`], and [`analytic_room`], the small room the tests score them on). It renders through
//! `inssplat-raster` and knows nothing of networks or HTTP.

mod adam;
pub mod analytic_room;
pub mod backproject;
pub mod heading;
pub mod ideal;
pub mod refine;
pub mod register;
pub mod rotation;
pub mod target_pose;
pub mod voxel;
