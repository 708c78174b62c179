//! The trainer's integration tests, one test binary (one link) for all of them: the synth
//! command, training recipes, the model, losses and their gradients, the training loop, its
//! checkpoints and configurations, export parity, fit-scene and the shape classifier.

mod average;
mod encoder_reference;
mod export_parity;
mod fit_scene;
mod loss_instance;
mod loss_terms;
mod model_forward;
mod recipe;
mod render_op_grad;
mod shapes;
mod synth_cli;
mod synth_stats;
mod train_checkpoints;
mod train_loop;
mod train_resume;
