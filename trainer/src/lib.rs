//! inssplat-trainer: the offline half of inssplat. The VGGT-style network, the InstanceSplat
//! losses, the
//! training loop with checkpoints, and ONNX export of the graph the server runs. The server
//! never depends on it: the exported ONNX file is the only hand-off.

pub mod export;
pub mod fit;
pub mod loss;
pub mod model;
pub mod recipe;
pub mod render_op;
pub mod shapes;
pub mod train;
