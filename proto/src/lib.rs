//! inssplat-proto: the contracts every other inssplat crate speaks. Cameras (OpenCV inside,
//! one conversion from the dataset's nerfstudio convention), `GaussianScene` (structure of
//! arrays) and its PLY form, the scene dataset format of docs/DATASET.md, the model's I/O
//! signature, the camera rays a network may read beside the images, its shape classifier,
//! and the HTTP request/response types. It depends on no other workspace crate and on
//! nothing heavy (no ONNX Runtime, GPU or training framework).

pub mod camera;
pub mod gaussian;
pub mod ply;
pub mod rays;

pub use camera::{Camera, CameraError, Intrinsics};
pub use gaussian::{GaussianScene, INSTANCE_DIM};
pub mod api;
pub mod dataset;
pub mod shape;
pub mod signature;
