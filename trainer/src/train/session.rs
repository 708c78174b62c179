//! The settings of one training session that do not change what it computes: checkpoint
//! cadence, validation, time limit, stop signal, progress, and where the network trains.

use std::sync::Arc;
use std::sync::atomic::AtomicUsize;
use std::time::Duration;

use burn::prelude::*;

use super::TrainError;
use super::sample::DataSpec;
#[cfg(doc)]
use super::{Summary, checkpoint};

/// Settings of one session of a run that do not change what it computes.
#[derive(Debug, Clone)]
pub struct Session {
    /// Write a checkpoint after this much time since the last one.
    pub checkpoint_every: Duration,
    /// Checkpoints kept (`None`: as many as the session that wrote the checkpoint this one
    /// resumes kept, else [`checkpoint::DEFAULT_KEEP`]).
    pub keep: Option<usize>,
    /// Validate every this many steps (0 = never) on `val_samples` fixed samples.
    pub val_every: u64,
    pub val_samples: usize,
    /// Where validation samples come from (`None`: the val split synthesized like the data).
    pub val_data: Option<DataSpec>,
    /// Stop (with a checkpoint) after this much time in this session.
    pub time_limit: Option<Duration>,
    /// Stop (with a checkpoint) after the step in progress once this holds a signal's number
    /// (0: none), which the caller's signal handler stores; [`Summary::signal`] says which.
    pub stop: Option<Arc<AtomicUsize>>,
    /// Show a progress bar on stderr.
    pub progress: bool,
    /// Where the network trains.
    pub compute: Compute,
}

/// Where a session trains the network. The rasterizer runs on the CPU cores either way.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Compute {
    /// burn's Flex backend on the CPU cores.
    #[default]
    Cpu,
    /// burn's wgpu backend on the GPU wgpu finds (Vulkan); builds with the `gpu` feature only.
    Gpu,
}

impl Compute {
    /// The autodiff device the session trains on.
    pub fn device(self) -> Result<Device, TrainError> {
        match self {
            Compute::Cpu => Ok(Device::flex().autodiff()),
            #[cfg(feature = "gpu")]
            Compute::Gpu => Ok(Device::wgpu(burn::tensor::DeviceKind::DefaultDevice).autodiff()),
            #[cfg(not(feature = "gpu"))]
            Compute::Gpu => Err(TrainError::Config(
                "--device gpu: this inssplat-train was built without the `gpu` feature \
                 (cargo build --release -p inssplat-trainer --features gpu)"
                    .into(),
            )),
        }
    }
}

impl Default for Session {
    fn default() -> Self {
        Self {
            checkpoint_every: Duration::from_secs(300),
            keep: None,
            val_every: 250,
            val_samples: 4,
            val_data: None,
            time_limit: None,
            stop: None,
            progress: true,
            compute: Compute::Cpu,
        }
    }
}
