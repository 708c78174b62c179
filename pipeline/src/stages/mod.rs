//! The stages of the request path, one file each, in the order [`crate::reconstruct`] runs
//! them: [`decode`] → [`detect`] → [`network`] → [`superpixels`] → [`cameras`]
//! (registration) → [`heading`] → [`rays`] → [`backproject`] → [`voxelize`] → [`cluster`] →
//! [`vote`] → [`masks`] → [`label`] → [`refine`] → the maps at the photos' size. Each has one
//! entry function `run` over its own parameters; [`Stopwatch`] times every stage in one place.

pub mod backproject;
pub mod cameras;
pub mod cluster;
pub mod decode;
pub mod detect;
pub mod exif;
pub mod heading;
pub mod label;
pub mod masks;
pub mod network;
pub mod rays;
pub mod refine;
pub mod superpixels;
pub mod vote;
pub mod voxelize;

use std::ops::Range;
use std::time::Instant;

use inssplat_proto::api::StageTiming;

use crate::reconstruct::PipelineError;

/// Collects stage timings and tells an observer when each stage starts.
pub struct Stopwatch<'a> {
    pub timings: Vec<StageTiming>,
    on_stage: &'a dyn Fn(&str),
}

impl<'a> Stopwatch<'a> {
    pub fn new(on_stage: &'a dyn Fn(&str)) -> Self {
        Self { timings: Vec::new(), on_stage }
    }

    /// Runs `f` as the stage `stage`: announced, timed, recorded.
    pub fn time<T>(&mut self, stage: &str, f: impl FnOnce() -> T) -> T {
        (self.on_stage)(stage);
        let start = Instant::now();
        let out = f();
        self.timings.push(StageTiming {
            stage: stage.to_string(),
            ms: start.elapsed().as_secs_f64() * 1e3,
        });
        out
    }
}

/// The error of stage `stage`, its message from any displayable error.
pub(crate) fn stage_err(stage: &'static str) -> impl Fn(&dyn std::fmt::Display) -> PipelineError {
    move |e| PipelineError::Stage { stage, message: e.to_string() }
}

/// The index range of view `v`'s values in a planar `[V][channels][pixels]` array.
pub(crate) fn plane(channels: usize, pixels: usize, v: usize) -> Range<usize> {
    v * channels * pixels..(v + 1) * channels * pixels
}
