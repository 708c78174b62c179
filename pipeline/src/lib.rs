//! inssplat-pipeline: the request path. Photos in, a reconstruction out: decode → detect →
//! network → superpixels → register → heading → rays → back-project → voxelize → cluster → vote
//! → masks → label → refine → upsample ([`reconstruct`], one file a stage in [`stages`]), the
//! network behind the [`backend::Backend`] trait (ONNX Runtime today), the pretrained keypoint
//! matcher ([`matcher`]) and object detector ([`detector`]),
//! the inputs a user gives ([`inputs`], [`vocab`]) and the outputs written and read back
//! ([`output`], [`saved`], [`query`], [`render_view`]). No HTTP, no evaluation.

pub mod backend;
pub mod detector;
pub mod inputs;
pub mod matcher;
pub mod output;
pub mod photo_depth;
pub mod query;
pub mod reconstruct;
pub mod render_view;
pub mod saved;
pub mod stages;
pub mod switches;
pub mod vocab;
pub mod warnings;
