//! The raster crate's integration tests, one test binary (one link) for all of them: the
//! renderers against references and finite differences.

mod render_forward;
mod render_grad;
mod support;
