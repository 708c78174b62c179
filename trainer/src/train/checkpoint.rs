//! Checkpoints of a training run: `RUN/checkpoints/step_NNNNNNNN/` holds the network
//! (`model.bpk`), the AdamW state (`optim.bpk`) and `state.json` (step, elapsed time, the run's
//! configuration and data). A checkpoint is written into a temporary folder and renamed into
//! place, then `RUN/checkpoints/latest` is replaced atomically, so an interrupted write never
//! leaves a half checkpoint behind; older ones beyond `keep` are deleted afterwards.

use std::path::{Path, PathBuf};

use burn::module::Module;
use burn::optim::ModuleOptimizer;
use burn::prelude::*;
use burn::store::{BurnpackStore, ModuleSnapshot};
use serde::{Deserialize, Serialize};

use super::TrainConfig;
use super::sample::DataSpec;
use crate::model::InsSplatNet;

/// Bumped when the layout of a checkpoint changes.
pub const CHECKPOINT_FORMAT: u32 = 1;

/// What `state.json` says.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CheckpointState {
    pub format: u32,
    /// Optimizer steps done.
    pub step: u64,
    /// Training wall time so far, seconds (all sessions).
    pub elapsed_s: f64,
    pub config: TrainConfig,
    pub data: DataSpec,
    /// The checkpoint whose weights started this run (a fine-tune), if any.
    #[serde(default)]
    pub init_from: Option<InitFrom>,
    /// How many checkpoints the session that wrote this one kept (none in checkpoints older
    /// than this field: [`DEFAULT_KEEP`]), which a session resuming the run keeps too unless
    /// told otherwise.
    #[serde(default)]
    pub keep: Option<usize>,
}

/// Where a fine-tune's starting weights came from.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct InitFrom {
    pub checkpoint: PathBuf,
    pub step: u64,
}

/// Why a checkpoint could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("{path}: {problem}")]
    Io { path: PathBuf, problem: String },
    #[error("{path}: incompatible checkpoint: {problem}")]
    Incompatible { path: PathBuf, problem: String },
}

fn io(path: &Path, e: impl std::fmt::Display) -> CheckpointError {
    CheckpointError::Io { path: path.to_path_buf(), problem: e.to_string() }
}

/// Folder of the checkpoints of run `run`.
pub fn checkpoints_dir(run: &Path) -> PathBuf {
    run.join("checkpoints")
}

/// Checkpoints a run keeps when neither its session nor the checkpoint it resumes says.
pub const DEFAULT_KEEP: usize = 2;

/// Writes a checkpoint of `net` and `optim` at `state.step`; keeps the newest `state.keep`.
pub fn save(
    run: &Path,
    net: &InsSplatNet,
    optim: &ModuleOptimizer,
    state: &CheckpointState,
) -> Result<PathBuf, CheckpointError> {
    let root = checkpoints_dir(run);
    std::fs::create_dir_all(&root).map_err(|e| io(&root, e))?;
    let name = format!("step_{:08}", state.step);
    let tmp = root.join(format!(".{name}.tmp"));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).map_err(|e| io(&tmp, e))?;
    let model = tmp.join("model.bpk");
    net.save_into(&mut BurnpackStore::from_file(&model).overwrite(true))
        .map_err(|e| io(&model, e))?;
    let opt = tmp.join("optim.bpk");
    optim.save(&opt).map_err(|e| io(&opt, format!("{e:?}")))?;
    let json = tmp.join("state.json");
    let text = serde_json::to_string_pretty(state).map_err(|e| io(&json, e))?;
    std::fs::write(&json, text).map_err(|e| io(&json, e))?;
    let dir = root.join(&name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::rename(&tmp, &dir).map_err(|e| io(&dir, e))?;
    let latest = root.join("latest");
    let latest_tmp = root.join(".latest.tmp");
    std::fs::write(&latest_tmp, &name).map_err(|e| io(&latest_tmp, e))?;
    std::fs::rename(&latest_tmp, &latest).map_err(|e| io(&latest, e))?;
    prune(&root, state.keep.unwrap_or(DEFAULT_KEEP));
    Ok(dir)
}

/// The checkpoint folders under `root` (a run's [`checkpoints_dir`]), oldest first; none if
/// it cannot be read.
fn step_folders(root: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(root) else { return Vec::new() };
    let mut steps: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with("step_")))
        .collect();
    steps.sort();
    steps
}

/// Deletes all but the newest `keep` checkpoints (best effort).
fn prune(root: &Path, keep: usize) {
    let steps = step_folders(root);
    let excess = steps.len().saturating_sub(keep.max(1));
    for old in &steps[..excess] {
        let _ = std::fs::remove_dir_all(old);
    }
}

/// The newest checkpoint of run `run`, if any: a run folder or a checkpoint folder itself.
pub fn latest(run: &Path) -> Result<Option<PathBuf>, CheckpointError> {
    if run.join("state.json").is_file() {
        return Ok(Some(run.to_path_buf()));
    }
    let pointer = checkpoints_dir(run).join("latest");
    if !pointer.is_file() {
        return Ok(None);
    }
    let name = std::fs::read_to_string(&pointer).map_err(|e| io(&pointer, e))?;
    let dir = checkpoints_dir(run).join(name.trim());
    if !dir.join("state.json").is_file() {
        return Err(io(&pointer, format!("points at {}, which has no state.json", dir.display())));
    }
    Ok(Some(dir))
}

/// Every checkpoint of run `run`, oldest first (those with a `state.json`): a run folder, or
/// a checkpoint folder itself.
pub fn all(run: &Path) -> Vec<PathBuf> {
    if run.join("state.json").is_file() {
        return vec![run.to_path_buf()];
    }
    step_folders(&checkpoints_dir(run))
        .into_iter()
        .filter(|d| d.join("state.json").is_file())
        .collect()
}

/// Reads the `state.json` of checkpoint folder `dir`.
pub fn read_state(dir: &Path) -> Result<CheckpointState, CheckpointError> {
    let json = dir.join("state.json");
    let text = std::fs::read_to_string(&json).map_err(|e| io(&json, e))?;
    let state: CheckpointState = serde_json::from_str(&text)
        .map_err(|e| io(&json, format!("not a checkpoint state: {e}")))?;
    if state.format != CHECKPOINT_FORMAT {
        return Err(CheckpointError::Incompatible {
            path: json,
            problem: format!(
                "format {} but this trainer reads format {CHECKPOINT_FORMAT}",
                state.format
            ),
        });
    }
    Ok(state)
}

/// Loads the network of checkpoint `dir` (built from its own configuration) onto `device`.
pub fn load_model(
    dir: &Path,
    state: &CheckpointState,
    device: &Device,
) -> Result<InsSplatNet, CheckpointError> {
    let model = dir.join("model.bpk");
    // Initialised under the seeding lock so that loading never draws from a training run's RNG.
    let mut net = super::seeded_init(&state.config.model, 0, device).map_err(|e| {
        CheckpointError::Incompatible { path: dir.join("state.json"), problem: e.to_string() }
    })?;
    let result = net.load_from(&mut BurnpackStore::from_file(&model)).map_err(|e| {
        CheckpointError::Incompatible { path: model.clone(), problem: e.to_string() }
    })?;
    // A tensor the network does not read (a ray layer's bias saved before the layer lost it)
    // would be dropped without a word, and the network would compute something else.
    if !result.errors.is_empty() || !result.missing.is_empty() || !result.unused.is_empty() {
        return Err(CheckpointError::Incompatible {
            path: model,
            problem: format!(
                "tensors missing {:?}, not read by this network {:?}, errors {:?}",
                result.missing, result.unused, result.errors
            ),
        });
    }
    Ok(net.fork(device))
}

/// Loads the optimizer state of checkpoint `dir` into `optim`.
pub fn load_optimizer(
    dir: &Path,
    optim: ModuleOptimizer,
) -> Result<ModuleOptimizer, CheckpointError> {
    let path = dir.join("optim.bpk");
    optim.load(&path).map_err(|e| io(&path, format!("{e:?}")))
}
