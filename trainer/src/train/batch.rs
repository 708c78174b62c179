//! The gradients of one optimizer step over one or several samples. Several samples run side
//! by side, each on its own thread and its own fork of the network: burn keeps the autodiff
//! graph of tensors that share leaves under one lock, so a fork (the same weights as fresh
//! leaves with the same parameter ids) is what lets the forward and backward passes overlap.
//! On a CPU a single sample leaves much of a second core idle (the step is a long chain of
//! small operations). Each sample's loss is divided by their number, so the summed gradient
//! is the mean of the samples' gradients.

use std::time::{Duration, Instant};

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;

use super::sample::Sample;
use super::step::{LossValues, StepError, objective};
use crate::loss::LossConfig;
use crate::model::InsSplatNet;

/// The mean gradient of a step's samples, their mean loss values and where the time went
/// (the mean over samples of each sample's own time; the rasterizer's backward summed over
/// them).
pub struct StepGradients {
    pub grads: GradientsParams,
    pub values: LossValues,
    pub forward: Duration,
    pub render: Duration,
    pub backward: Duration,
    pub render_backward: Duration,
}

/// A sample that failed: its position in the step and why.
#[derive(Debug)]
pub struct SampleFailure {
    pub sample: usize,
    pub error: StepError,
}

/// The mean gradient of `net`'s objective over `samples` (at least one; more run in parallel).
pub fn gradients(
    net: &InsSplatNet,
    samples: &[Sample],
    loss: &LossConfig,
    device: &Device,
) -> Result<StepGradients, SampleFailure> {
    let k = samples.len();
    assert!(k > 0, "a step needs a sample");
    if k == 1 {
        return one(net, &samples[0], 1, loss, device)
            .map_err(|error| SampleFailure { sample: 0, error });
    }
    let results: Vec<Result<StepGradients, StepError>> = std::thread::scope(|scope| {
        let handles: Vec<_> = samples
            .iter()
            .map(|sample| {
                let fork = net.clone().fork(device);
                scope.spawn(move || one(&fork, sample, k, loss, device))
            })
            .collect();
        handles.into_iter().map(|h| h.join().expect("a training thread panicked")).collect()
    });
    let mut total: Option<StepGradients> = None;
    for (i, result) in results.into_iter().enumerate() {
        let mut part = result.map_err(|error| SampleFailure { sample: i, error })?;
        total = Some(match total {
            None => part,
            Some(mut acc) => {
                move_gradients(net, &mut part.grads, &mut acc.grads);
                acc.values = acc.values + part.values;
                (acc.forward, acc.render, acc.backward) = (
                    acc.forward + part.forward,
                    acc.render + part.render,
                    acc.backward + part.backward,
                );
                acc.render_backward += part.render_backward;
                acc
            }
        });
    }
    let mut total = total.expect("k > 0");
    let n = k as u32;
    total.values = total.values * (1.0 / k as f32);
    (total.forward, total.render, total.backward) =
        (total.forward / n, total.render / n, total.backward / n);
    Ok(total)
}

/// One sample's gradient with its loss divided by `k`.
fn one(
    net: &InsSplatNet,
    sample: &Sample,
    k: usize,
    loss: &LossConfig,
    device: &Device,
) -> Result<StepGradients, StepError> {
    let obj = objective(net, sample, loss, device)?;
    let values = obj.values();
    let t = Instant::now();
    let grads = GradientsParams::from_grads(obj.total.div_scalar(k as f64).backward(), net);
    Ok(StepGradients {
        grads,
        values,
        forward: obj.forward_time,
        render: obj.render_time,
        backward: t.elapsed(),
        render_backward: obj.render_backward.elapsed(),
    })
}

/// Moves the gradients of `module`'s parameters from `from` into `into`, adding them to any
/// already there.
pub fn move_gradients<M: Module>(
    module: &M,
    from: &mut GradientsParams,
    into: &mut GradientsParams,
) {
    module.visit(&mut Accumulate { from, into });
}

struct Accumulate<'a> {
    from: &'a mut GradientsParams,
    into: &'a mut GradientsParams,
}

impl ModuleVisitor for Accumulate<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.from.remove::<D>(param.id) {
            let sum = match self.into.remove::<D>(param.id) {
                Some(acc) => acc + g,
                None => g,
            };
            self.into.register(param.id, sum);
        }
    }
}
