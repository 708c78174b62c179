//! inssplat-server: the online half of inssplat. The inference pipeline (ONNX Runtime session
//! → back-projection → voxelization → 3D clustering → labels → rendering), the axum HTTP
//! service and its job store, and the `inssplat` CLI (`check`, `reconstruct`, `query`,
//! `render`, `eval`, `bench`, `serve`). It never trains.

pub mod bench;
pub mod check;
pub mod eval;
pub mod http;
pub mod inputs;
pub mod jobs;
pub mod metrics;
pub mod output;
pub mod pipeline;
pub mod query;
pub mod render_view;
pub mod runtime;
pub mod saved;
pub mod scene_store;
pub mod vocab;
pub mod worker;
