//! The trainer's integration tests, one test binary (one link) for all of them: synthesis,
//! model, losses and their gradients, the training loop, export parity and fit-scene.

mod export_parity;
mod fit_scene;
mod loss_instance;
mod loss_terms;
mod model_forward;
mod render_op_grad;
mod synth_cli;
mod synth_dataset;
mod synth_geometry;
mod synth_stats;
mod train_loop;
