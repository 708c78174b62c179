//! The PostgreSQL job store (`serve --jobs postgres://…`), for replicas that share one queue.
//! The tables are the SQLite store's, made by the migrations in `server/migrations/postgres/`
//! (run by refinery when the store opens), with a lease on each running scene: a replica claims
//! the oldest queued scene with `SELECT … FOR UPDATE SKIP LOCKED`, so two replicas never take
//! the same one, and holds it until `lease_until`, renewed while it runs. A scene whose lease
//! ran out (its replica died) is claimed again under the same scene id, at once by the same
//! replica restarted; a finish counts only from the lease's owner, so a scene is never
//! reported twice. The connection is made again when it drops (a restarted database).

use std::path::PathBuf;
use std::sync::Mutex;
use std::time::Duration;

use anyhow::Context;
use inssplat_proto::api::{JobSceneStatus, JobState, JobStatus};
use postgres::{Client, GenericClient, NoTls, Transaction};

use super::{JobStore, NewJob, SceneOutcome, SceneTask, count_states, job_status, state_name};

refinery::embed_migrations!("migrations/postgres");

/// The job store in a PostgreSQL database.
pub struct PostgresStore {
    url: String,
    client: Mutex<Option<Client>>,
    /// This replica's name on the leases it holds.
    owner: String,
    lease: Duration,
}

impl PostgresStore {
    /// Connects to `url` and brings the schema up to date; claims are made as `replica`, a name
    /// no other replica has and this one keeps across restarts, and hold for `lease`.
    pub fn connect(url: &str, replica: &str, lease: Duration) -> anyhow::Result<Self> {
        let mut client = open(url)?;
        migrations::runner()
            .run(&mut client)
            .with_context(|| format!("job store {}: cannot migrate its tables", redacted(url)))?;
        let owner = replica.to_string();
        Ok(Self { url: url.to_string(), client: Mutex::new(Some(client)), owner, lease })
    }

    /// Runs `f` on the connection, connecting again first if it dropped.
    fn with<T>(&self, f: impl FnOnce(&mut Client) -> anyhow::Result<T>) -> anyhow::Result<T> {
        let mut slot = self.client.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if slot.as_ref().is_none_or(Client::is_closed) {
            *slot = Some(open(&self.url)?);
        }
        let client = slot.as_mut().expect("connected above");
        let out = f(client);
        if client.is_closed() {
            *slot = None;
        }
        out
    }

    /// Runs `f` in a transaction and commits.
    fn write<T>(
        &self,
        f: impl FnOnce(&mut Transaction<'_>) -> anyhow::Result<T>,
    ) -> anyhow::Result<T> {
        self.with(|client| {
            let mut tx = client.transaction()?;
            let out = f(&mut tx)?;
            tx.commit()?;
            Ok(out)
        })
    }

    fn lease_seconds(&self) -> f64 {
        self.lease.as_secs_f64()
    }
}

fn open(url: &str) -> anyhow::Result<Client> {
    Client::connect(url, NoTls)
        .with_context(|| format!("cannot connect to the job store {}", redacted(url)))
}

/// `url` without its password, for messages.
fn redacted(url: &str) -> String {
    match (url.find("://"), url.rfind('@')) {
        (Some(scheme), Some(at)) if at > scheme => {
            let credentials = &url[scheme + 3..at];
            let user = credentials.split(':').next().unwrap_or("");
            format!("{}{user}:***{}", &url[..scheme + 3], &url[at..])
        }
        _ => url.to_string(),
    }
}

/// A scene state read from the table; an unknown name is an error naming it.
fn parse_state(s: &str) -> anyhow::Result<JobState> {
    super::parse_state(s).with_context(|| format!("job state `{s}`"))
}

fn read_status(client: &mut impl GenericClient, job_id: &str) -> anyhow::Result<Option<JobStatus>> {
    let Some(row) = client.query_opt("SELECT cancelled FROM jobs WHERE id = $1", &[&job_id])?
    else {
        return Ok(None);
    };
    let cancelled: bool = row.get(0);
    let rows = client.query(
        "SELECT idx, name, state, scene_id, error, metrics FROM job_scenes WHERE job_id = $1 ORDER BY idx",
        &[&job_id],
    )?;
    let scenes = rows
        .iter()
        .map(|r| {
            let state: &str = r.get(2);
            Ok(JobSceneStatus {
                index: r.get::<_, i32>(0) as usize,
                name: r.get(1),
                state: parse_state(state)?,
                scene_id: r.get(3),
                error: r.get(4),
                metrics: r.get(5),
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(Some(job_status(job_id, cancelled, scenes)))
}

impl JobStore for PostgresStore {
    fn create(&self, job: &NewJob) -> anyhow::Result<()> {
        let vocabulary = job.vocabulary.as_ref().map(serde_json::to_value).transpose()?;
        let refine_steps = job.refine_steps.map(|n| n as i32);
        self.write(|tx| {
            tx.execute(
                "INSERT INTO jobs (id, vocabulary, refine_steps) VALUES ($1, $2, $3)",
                &[&job.id, &vocabulary, &refine_steps],
            )?;
            for (i, (name, input)) in job.scenes.iter().enumerate() {
                tx.execute(
                    "INSERT INTO job_scenes (job_id, idx, name, input, state) VALUES ($1, $2, $3, $4, 'queued')",
                    &[&job.id, &(i as i32), name, &input.to_string_lossy().as_ref()],
                )?;
            }
            Ok(())
        })
    }

    fn status(&self, job_id: &str) -> anyhow::Result<Option<JobStatus>> {
        self.with(|client| read_status(client, job_id))
    }

    fn claim(&self) -> anyhow::Result<Option<SceneTask>> {
        let fresh_id = crate::scene_store::SceneId::new().to_string();
        let row = self.write(|tx| {
            Ok(tx.query_opt(
                "WITH next AS (
                     SELECT s.job_id, s.idx FROM job_scenes s JOIN jobs j ON j.id = s.job_id
                     WHERE NOT j.cancelled
                       AND (s.state = 'queued' OR (s.state = 'running' AND s.lease_until < now()))
                     ORDER BY j.seq, s.idx LIMIT 1
                     FOR UPDATE OF s SKIP LOCKED)
                 UPDATE job_scenes s
                 SET state = 'running', scene_id = COALESCE(s.scene_id, $1),
                     attempts = s.attempts + 1, lease_owner = $2,
                     lease_until = now() + make_interval(secs => $3)
                 FROM next, jobs j
                 WHERE s.job_id = next.job_id AND s.idx = next.idx AND j.id = s.job_id
                 RETURNING s.job_id, s.idx, s.name, s.input, s.scene_id, j.vocabulary, j.refine_steps",
                &[&fresh_id, &self.owner, &self.lease_seconds()],
            )?)
        })?;
        let Some(r) = row else { return Ok(None) };
        let vocabulary: Option<serde_json::Value> = r.get(5);
        Ok(Some(SceneTask {
            job_id: r.get(0),
            index: r.get::<_, i32>(1) as usize,
            name: r.get(2),
            input: PathBuf::from(r.get::<_, String>(3)),
            scene_id: r.get(4),
            vocabulary: vocabulary.and_then(|v| serde_json::from_value(v).ok()),
            refine_steps: r.get::<_, Option<i32>>(6).map(|n| n as usize),
        }))
    }

    fn finish(&self, task: &SceneTask, outcome: &SceneOutcome) -> anyhow::Result<bool> {
        let (state, error, metrics) = match outcome {
            SceneOutcome::Done { metrics } => (JobState::Done, None, metrics.clone()),
            SceneOutcome::Failed { error } => (JobState::Failed, Some(error.as_str()), None),
        };
        let updated = self.write(|tx| {
            Ok(tx.execute(
                "UPDATE job_scenes SET state = $3, error = $4, metrics = $5, lease_owner = NULL, lease_until = NULL
                 WHERE job_id = $1 AND idx = $2 AND state = 'running' AND lease_owner = $6",
                &[
                    &task.job_id,
                    &(task.index as i32),
                    &state_name(state),
                    &error,
                    &metrics,
                    &self.owner,
                ],
            )?)
        })?;
        Ok(updated == 1)
    }

    fn lease(&self) -> Option<Duration> {
        Some(self.lease)
    }

    fn renew(&self, task: &SceneTask) -> anyhow::Result<bool> {
        let updated = self.write(|tx| {
            Ok(tx.execute(
                "UPDATE job_scenes SET lease_until = now() + make_interval(secs => $4)
                 WHERE job_id = $1 AND idx = $2 AND state = 'running' AND lease_owner = $3",
                &[&task.job_id, &(task.index as i32), &self.owner, &self.lease_seconds()],
            )?)
        })?;
        Ok(updated == 1)
    }

    fn cancel(&self, job_id: &str) -> anyhow::Result<Option<JobStatus>> {
        self.write(|tx| {
            if tx.execute("UPDATE jobs SET cancelled = TRUE WHERE id = $1", &[&job_id])? == 0 {
                return Ok(None);
            }
            tx.execute(
                "UPDATE job_scenes SET state = 'cancelled' WHERE job_id = $1 AND state = 'queued'",
                &[&job_id],
            )?;
            read_status(tx, job_id)
        })
    }

    /// The scenes this replica held when it stopped, and those whose lease ran out (a replica
    /// that died; the claim would take them anyway), go back to the queue.
    fn requeue_interrupted(&self) -> anyhow::Result<usize> {
        self.write(|tx| {
            Ok(tx.execute(
                "UPDATE job_scenes SET state = 'queued', lease_owner = NULL, lease_until = NULL
                 WHERE state = 'running' AND (lease_owner = $1 OR lease_until < now())",
                &[&self.owner],
            )? as usize)
        })
    }

    fn count_by_state(&self) -> anyhow::Result<Vec<(JobState, usize)>> {
        self.with(|client| {
            let rows = client.query(
                "SELECT j.id, j.cancelled, array_agg(s.state ORDER BY s.idx)
                 FROM jobs j JOIN job_scenes s ON s.job_id = j.id GROUP BY j.id, j.cancelled",
                &[],
            )?;
            let mut states = Vec::with_capacity(rows.len());
            for r in &rows {
                let scenes = r
                    .get::<_, Vec<String>>(2)
                    .iter()
                    .map(|s| parse_state(s))
                    .collect::<anyhow::Result<Vec<_>>>()?;
                states.push(super::job_state(r.get(1), &scenes));
            }
            Ok(count_states(states))
        })
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn passwords_stay_out_of_messages() {
        assert_eq!(
            super::redacted("postgres://jobs:secret@db:5432/inssplat"),
            "postgres://jobs:***@db:5432/inssplat"
        );
        assert_eq!(super::redacted("postgres://db/inssplat"), "postgres://db/inssplat");
    }
}
