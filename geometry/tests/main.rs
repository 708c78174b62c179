//! The geometry crate's integration tests, one test binary (one link) for all of them:
//! heading search, scene and pose refinement, and the
//! back-projection and voxelization of ideal views.

mod heading;
mod refine;
mod ring_room;
mod target_pose;
