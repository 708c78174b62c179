//! Durable batch jobs: a job is a list of scenes (photo sets or dataset scene folders,
//! unpacked by [`intake`] into the data directory) that the model workers reconstruct one at a
//! time between interactive requests, scoring the ones that carry ground truth ([`run`]).
//! The state lives behind [`JobStore`], SQLite by default ([`sqlite`]); each scene's state is
//! committed before it runs and its result after, so a killed server resumes where it stopped:
//! scenes found `running` at start were interrupted and run again, under the same scene id.

pub mod intake;
pub mod run;
pub mod sqlite;

use std::path::PathBuf;

use inssplat_proto::api::{JobState, JobStatus};

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
    /// Records the outcome of a claimed scene.
    fn finish(&self, task: &SceneTask, outcome: &SceneOutcome) -> anyhow::Result<()>;
    /// Cancels the job's queued scenes (a running one finishes); `None` if there is no such job.
    fn cancel(&self, job_id: &str) -> anyhow::Result<Option<JobStatus>>;
    /// Puts scenes left `running` by a previous process back in the queue; returns how many.
    fn requeue_interrupted(&self) -> anyhow::Result<usize>;
    /// Number of jobs in each state.
    fn count_by_state(&self) -> anyhow::Result<Vec<(JobState, usize)>>;
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
