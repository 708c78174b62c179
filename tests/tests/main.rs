//! The workspace's end-to-end tests, one test binary (one link) for all of them: each module
//! starts the real `inssplat` binaries or runs the whole chain on synthesized scenes.

mod chain_synth;
mod check;
mod cli_reference;
mod eval;
mod eval_curve;
mod hard_photos;
mod http_errors;
mod http_load;
mod http_replicas;
mod http_resume;
mod http_service;
mod real_photos;
mod reconstruct;
mod register_synth;
mod shipped_model;
mod splat_transform;
mod superpixels_synth;
mod support;
mod web_page;
