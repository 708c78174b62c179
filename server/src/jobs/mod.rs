//! Durable batch jobs: a job is a list of scenes (photo sets or dataset scene folders,
//! unpacked by [`intake`] into the data directory) that the model workers reconstruct one at a
//! time between interactive requests, scoring the ones that carry ground truth ([`run`]).
//! The state lives behind [`JobStore`]: SQLite in the data directory by default ([`sqlite`]),
//! or PostgreSQL, which several replicas can share ([`postgres`]). Each scene's state is
//! committed before it runs and its result after, so a killed server resumes where it stopped:
//! scenes found `running` at start were interrupted and run again, under the same scene id.

pub mod intake;
pub mod postgres;
pub mod run;
pub mod sqlite;
#[cfg(test)]
mod suite;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use inssplat_proto::api::{JobSceneStatus, JobState, JobStatus};

/// A job as submitted: its id, scenes (name, input folder), and optional label vocabulary and
/// steps of test-time refinement (`None`: the server's).
#[derive(Debug, Clone)]
pub struct NewJob {
    pub id: String,
    pub scenes: Vec<(String, PathBuf)>,
    pub vocabulary: Option<Vec<String>>,
    pub refine_steps: Option<usize>,
}

/// One scene claimed by a worker (already committed as `running`).
#[derive(Debug, Clone)]
pub struct SceneTask {
    pub job_id: String,
    pub index: usize,
    pub name: String,
    pub input: PathBuf,
    /// Where the result goes; the same on every attempt, so a re-run replaces, never adds.
    pub scene_id: String,
    pub vocabulary: Option<Vec<String>>,
    pub refine_steps: Option<usize>,
}

/// How a scene ended.
#[derive(Debug, Clone)]
pub enum SceneOutcome {
    Done { metrics: Option<serde_json::Value> },
    Failed { error: String },
}

/// The job store. Implementations must make each call atomic and durable when it returns.
pub trait JobStore: Send + Sync {
    /// Records a new job with all its scenes queued.
    fn create(&self, job: &NewJob) -> anyhow::Result<()>;
    /// The job's status, `None` if there is no such job.
    fn status(&self, job_id: &str) -> anyhow::Result<Option<JobStatus>>;
    /// Marks the next queued scene (oldest job first) `running` and returns it.
    fn claim(&self) -> anyhow::Result<Option<SceneTask>>;
    /// Records the outcome of a claimed scene; `false` when the claim is no longer this
    /// replica's (it ran out and another took the scene), so nothing was recorded.
    fn finish(&self, task: &SceneTask, outcome: &SceneOutcome) -> anyhow::Result<bool>;
    /// How long a claim holds unless renewed (`None`: for as long as the process lives).
    fn lease(&self) -> Option<std::time::Duration>;
    /// Extends the claim on a running scene; `false` when it is no longer this replica's.
    fn renew(&self, task: &SceneTask) -> anyhow::Result<bool>;
    /// Cancels the job's queued scenes (a running one finishes); `None` if there is no such job.
    fn cancel(&self, job_id: &str) -> anyhow::Result<Option<JobStatus>>;
    /// Puts scenes left `running` by a previous process back in the queue; returns how many.
    fn requeue_interrupted(&self) -> anyhow::Result<usize>;
    /// Number of jobs in each state.
    fn count_by_state(&self) -> anyhow::Result<Vec<(JobState, usize)>>;
}

/// The job store `url` names (`postgres://…`), claiming scenes as `replica` (a name no other
/// replica sharing it has, the same after a restart) for `lease`, else SQLite's file in
/// `data_dir`.
pub fn open(
    url: Option<&str>,
    replica: &str,
    lease: std::time::Duration,
    data_dir: &Path,
) -> anyhow::Result<Arc<dyn JobStore>> {
    Ok(match url {
        Some(url) => Arc::new(postgres::PostgresStore::connect(url, replica, lease)?),
        None => Arc::new(sqlite::SqliteStore::open(&data_dir.join("jobs.sqlite"))?),
    })
}

/// The name a scene state has in the stores.
fn state_name(s: JobState) -> &'static str {
    match s {
        JobState::Queued => "queued",
        JobState::Running => "running",
        JobState::Done => "done",
        JobState::Failed => "failed",
        JobState::Cancelled => "cancelled",
    }
}

/// The scene state a store's name stands for.
fn parse_state(s: &str) -> Option<JobState> {
    ALL_STATES.into_iter().find(|&state| state_name(state) == s)
}

const ALL_STATES: [JobState; 5] =
    [JobState::Queued, JobState::Running, JobState::Done, JobState::Failed, JobState::Cancelled];

/// A job's status from its scenes' (in index order).
fn job_status(job_id: &str, cancelled: bool, scenes: Vec<JobSceneStatus>) -> JobStatus {
    let states: Vec<JobState> = scenes.iter().map(|s| s.state).collect();
    JobStatus {
        job_id: job_id.to_string(),
        state: job_state(cancelled, &states),
        done: scenes
            .iter()
            .filter(|s| matches!(s.state, JobState::Done | JobState::Failed))
            .count(),
        total: scenes.len(),
        scenes,
    }
}

/// How many of `jobs` are in each state, every state listed.
fn count_states(jobs: impl IntoIterator<Item = JobState>) -> Vec<(JobState, usize)> {
    let mut counts: Vec<(JobState, usize)> = ALL_STATES.map(|s| (s, 0)).to_vec();
    for state in jobs {
        counts.iter_mut().filter(|(s, _)| *s == state).for_each(|(_, n)| *n += 1);
    }
    counts
}

/// A job's state from its scenes': cancelled if asked, queued until one starts, running until
/// none is left to run, then done (failed if no scene succeeded).
pub fn job_state(cancelled: bool, scenes: &[JobState]) -> JobState {
    let finished =
        |s: &JobState| matches!(s, JobState::Done | JobState::Failed | JobState::Cancelled);
    if cancelled {
        JobState::Cancelled
    } else if scenes.iter().all(|s| *s == JobState::Queued) {
        JobState::Queued
    } else if !scenes.iter().all(finished) {
        JobState::Running
    } else if scenes.contains(&JobState::Done) {
        JobState::Done
    } else {
        JobState::Failed
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use JobState::*;

    #[test]
    fn job_state_follows_its_scenes() {
        assert_eq!(job_state(false, &[Queued, Queued]), Queued);
        assert_eq!(job_state(false, &[Done, Queued]), Running);
        assert_eq!(job_state(false, &[Done, Failed]), Done);
        assert_eq!(job_state(false, &[Failed, Failed]), Failed);
        assert_eq!(job_state(true, &[Done, Cancelled]), Cancelled);
    }
}
