//! Validation: the fixed val-split samples a run validates on, their mean loss without
//! gradients, and the scores of a saved checkpoint on them (its validation loss sample by
//! sample, and its depth's AbsRel; on views that overlap, if asked), for choosing between runs
//! and checkpoints.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use burn::prelude::*;
use inssplat_text::LabelCache;

use super::checkpoint::{self, CheckpointState};
use super::sample::{DataSpec, Sample, Sampler, Source, ViewPlan};
use super::step::{LossValues, StepError, objective};
use super::{Session, TrainError, label_cache};
use crate::loss::LossConfig;
use crate::model::InsSplatNet;

/// Which fixed samples [`score_checkpoint`] scores: the first
/// `samples` of `data` (default: the val split at the run's size), 4 views each, drawn from
/// `window` consecutive frames ([`ViewPlan::window`]; `None`: the whole trajectory, as a run
/// validates).
#[derive(Debug, Clone, Default)]
pub struct ValidationSet {
    pub samples: usize,
    pub data: Option<DataSpec>,
    pub window: Option<usize>,
}

/// What [`score_checkpoint`] measured of one checkpoint.
pub struct CheckpointScores {
    /// The checkpoint folder and its step.
    pub dir: PathBuf,
    pub step: u64,
    /// Each sample's validation loss (their mean: [`mean_loss`]).
    pub losses: Vec<LossValues>,
    /// With `depth`: the depth's AbsRel ([`DepthScores`]).
    pub depth: Option<DepthScores>,
}

/// The validation loss of the newest checkpoint of `from` (a run or a checkpoint folder) on
/// `set` — by default the samples a run validates on while it trains, and as many more as
/// asked: model selection between runs and checkpoints on more samples than a run spends
/// while training — and, with `depth`, on the same samples and weights (loaded and
/// synthesized once), the depth's AbsRel ([`DepthScores`]).
pub fn score_checkpoint(
    from: &Path,
    set: &ValidationSet,
    depth: bool,
) -> Result<CheckpointScores, TrainError> {
    let device = Device::flex();
    let (dir, state, net, val) = checkpoint_with_samples(from, set, &device)?;
    let losses = validate_each(&net, &val, &state.config.loss, &device).map_err(|source| {
        TrainError::Step { step: state.step, scene: "validation".into(), source }
    })?;
    let depth = depth
        .then(|| depth_scores(&net, &val, &device))
        .transpose()
        .map_err(|source| TrainError::Step { step: state.step, scene: "depth".into(), source })?;
    Ok(CheckpointScores { dir, step: state.step, losses, depth })
}

/// The mean of per-sample losses (zero for none).
pub fn mean_loss(losses: &[LossValues]) -> LossValues {
    losses.iter().fold(LossValues::default(), |sum, l| sum + *l)
        * (1.0 / losses.len().max(1) as f32)
}

/// The depth's AbsRel of `net` on each sample of `val` ([`DepthScores`]).
fn depth_scores(
    net: &InsSplatNet,
    val: &[Sample],
    device: &Device,
) -> Result<DepthScores, StepError> {
    let mut abs_rel = Vec::with_capacity(val.len());
    for s in val {
        let pixels = s.size * s.size;
        let images = Tensor::<4>::from_data(
            TensorData::new(
                s.images[..s.inputs * 3 * pixels].to_vec(),
                [s.inputs, 3, s.size, s.size],
            ),
            device,
        );
        let out = net
            .forward_with_rays(images, super::step::input_rays(net, s, device))
            .map_err(StepError::from)?;
        let predicted = crate::loss::host("depth", &out.depth).map_err(StepError::from)?;
        let scores =
            inssplat_metrics::image::depth_abs_rel(&predicted, &s.depth[..s.inputs * pixels])
                .map_err(|e| {
                    StepError::from(crate::loss::LossError::Read {
                        what: "depth",
                        message: e.to_string(),
                    })
                })?;
        abs_rel.push(scores.map(|d| d.abs_rel));
    }
    Ok(DepthScores { abs_rel })
}

/// What [`score_checkpoint`] measures of the depth.
pub struct DepthScores {
    /// The network's depth AbsRel at each sample's median scale (all its input views at one
    /// scale), sample by sample (`None`: no pixel with a true depth).
    pub abs_rel: Vec<Option<f64>>,
}

impl DepthScores {
    /// The mean of [`DepthScores::abs_rel`] over the samples that have one.
    pub fn mean_abs_rel(&self) -> Option<f64> {
        let scored: Vec<f64> = self.abs_rel.iter().flatten().copied().collect();
        (!scored.is_empty()).then(|| scored.iter().sum::<f64>() / scored.len() as f64)
    }
}

/// The newest checkpoint of `from` (a run or a checkpoint folder) on `device`, with the
/// samples of `set`.
fn checkpoint_with_samples(
    from: &Path,
    set: &ValidationSet,
    device: &Device,
) -> Result<(PathBuf, CheckpointState, InsSplatNet, Vec<Sample>), TrainError> {
    let dir =
        checkpoint::latest(from)?.ok_or_else(|| TrainError::NoCheckpoint(from.to_path_buf()))?;
    let state = checkpoint::read_state(&dir)?;
    let net = checkpoint::load_model(&dir, &state, device)?;
    let session = Session {
        val_every: 1,
        val_samples: set.samples,
        val_data: set.data.clone(),
        ..Session::default()
    };
    let val = val_samples(&state, &session, &label_cache()?, set.window)?;
    if val.is_empty() {
        return Err(TrainError::Config(format!(
            "{}: no validation samples (a folder-trained run needs --val-data)",
            dir.display()
        )));
    }
    Ok((dir, state, net, val))
}

/// The validation loss: mean over fixed samples, without gradients (`device`: the training
/// device, whose inner device runs it).
pub(super) fn validate(
    net: &InsSplatNet,
    samples: &[Sample],
    loss: &LossConfig,
    device: &Device,
) -> Result<LossValues, StepError> {
    Ok(mean_loss(&validate_each(&net.valid(), samples, loss, &device.clone().inner())?))
}

/// Each sample's loss for `net` on `device` (not an autodiff one: no gradients are kept).
fn validate_each(
    net: &InsSplatNet,
    samples: &[Sample],
    loss: &LossConfig,
    device: &Device,
) -> Result<Vec<LossValues>, StepError> {
    samples.iter().map(|s| Ok(objective(net, s, loss, device)?.values())).collect()
}

pub(super) fn val_samples(
    state: &CheckpointState,
    session: &Session,
    labels: &Arc<LabelCache>,
    window: Option<usize>,
) -> Result<Vec<Sample>, TrainError> {
    if session.val_every == 0 || session.val_samples == 0 {
        return Ok(Vec::new());
    }
    let spec = match (&session.val_data, &state.data) {
        (Some(spec), _) => spec.clone(),
        (None, DataSpec::Synth { furniture_dir, size, structure, antialias, .. }) => {
            DataSpec::Synth {
                split: inssplat_synth::Split::Val,
                furniture_dir: furniture_dir.clone(),
                size: *size,
                structure: *structure,
                antialias: *antialias,
            }
        }
        (None, DataSpec::Folder(_)) => return Ok(Vec::new()),
    };
    let plan = ViewPlan {
        min_views: 4,
        max_views: 4,
        targets: state.config.targets,
        reuse: 1,
        first_scene: 0,
        window,
    };
    let sampler = Sampler { source: Source::open(&spec)?, plan, seed: 7, labels: labels.clone() };
    Ok((0..session.val_samples as u64).map(|i| sampler.sample(i)).collect::<Result<_, _>>()?)
}
