//! The inference pipeline, one module per stage: decode → network → back-project → voxelize
//! → cluster in 3D → label → render. Each stage is timed.

pub mod decode;
pub mod reconstruct;
pub mod switches;
