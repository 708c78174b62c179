//! The pipeline switches that `reconstruct`, `serve` and `inssplat-eval score` share, declared
//! once as flags with their environment variables.

use super::reconstruct::PipelineConfig;

#[derive(clap::Args, Debug, Clone, Default)]
pub struct PipelineSwitches {
    /// Refine the Gaussians and the input cameras against the input photos for this many
    /// Adam steps after the network (test-time optimization, one view a step, about 50 ms a
    /// step at 8 views on two cores; 0, the default, is the feed-forward pipeline). At 8
    /// views new viewpoints gain up to about 200 steps and little more after. A server's
    /// request or job may set its own with a `refine_steps` form field.
    #[arg(long, env = "INSSPLAT_REFINE_STEPS", default_value_t = 0, value_name = "STEPS")]
    pub refine_steps: usize,
    /// With a network that reads its cameras as rays (the shipped one since 0.12): keep its
    /// first pass (every ray zero) instead of running it again on the registered cameras,
    /// for about 0.7× the time and the instances of that pass (stage "rays" left out; in
    /// `inssplat-eval score`, the ablation of that stage).
    #[arg(long, env = "INSSPLAT_NO_RAY_PASS")]
    pub no_ray_pass: bool,
}

impl PipelineSwitches {
    /// `config` with these switches set.
    pub fn apply(&self, config: PipelineConfig) -> PipelineConfig {
        PipelineConfig { refine_steps: self.refine_steps, ray_pass: !self.no_ray_pass, ..config }
    }
}
