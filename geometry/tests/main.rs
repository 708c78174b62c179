//! The geometry crate's integration tests, one test binary (one link) for all of them:
//! heading search, scene and pose refinement, registration on learned descriptors, and the
//! back-projection and voxelization of ideal views.

mod heading;
mod refine;
mod register_learned;
mod ring_room;
mod target_pose;
