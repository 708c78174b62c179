//! The raster crate's integration tests, one test binary (one link) for all of them: the
//! renderers against references and finite differences, and the post-processing chain.

mod heading;
mod post_pipeline;
mod post_scene;
mod refine;
mod register_learned;
mod render_forward;
mod render_grad;
mod ring_room;
mod support;
mod target_pose;
