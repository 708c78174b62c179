//! The eval crate's integration tests, one test binary: the post-processing chain scored by
//! the protocol's metrics.

mod post_pipeline;
