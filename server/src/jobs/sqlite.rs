//! The SQLite job store: one file in the data directory, WAL journal, `synchronous=FULL` so a
//! commit survives a killed process (and a power cut). Two tables: `jobs` (id, vocabulary,
//! refinement steps, cancelled) and `job_scenes` (state, scene id, error, metrics per scene).
//! A job's own state is derived from its scenes' on every read, so the two can never disagree.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use anyhow::Context;
use inssplat_proto::api::{JobSceneStatus, JobState, JobStatus};
use rusqlite::{Connection, OptionalExtension, Transaction, TransactionBehavior, params};

use super::{JobStore, NewJob, SceneOutcome, SceneTask, count_states, job_status, state_name};

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS jobs (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    id TEXT NOT NULL UNIQUE,
    vocabulary TEXT,
    refine_steps INTEGER,
    cancelled INTEGER NOT NULL DEFAULT 0,
    created_at INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS job_scenes (
    job_id TEXT NOT NULL REFERENCES jobs(id),
    idx INTEGER NOT NULL,
    name TEXT NOT NULL,
    input TEXT NOT NULL,
    state TEXT NOT NULL,
    scene_id TEXT,
    error TEXT,
    metrics TEXT,
    attempts INTEGER NOT NULL DEFAULT 0,
    PRIMARY KEY (job_id, idx)
);
CREATE INDEX IF NOT EXISTS job_scenes_state ON job_scenes (state);
";

/// The job store in one SQLite file.
pub struct SqliteStore {
    conn: Mutex<Connection>,
}

fn parse_state(s: &str) -> rusqlite::Result<JobState> {
    super::parse_state(s).ok_or_else(|| {
        rusqlite::Error::InvalidColumnType(
            0,
            format!("job state `{s}`"),
            rusqlite::types::Type::Text,
        )
    })
}

impl SqliteStore {
    /// Opens (creating) the store at `path`.
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        let conn = Connection::open(path)
            .with_context(|| format!("cannot open the job store {}", path.display()))?;
        conn.pragma_update(None, "journal_mode", "WAL")?;
        conn.pragma_update(None, "synchronous", "FULL")?;
        conn.pragma_update(None, "foreign_keys", true)?;
        conn.busy_timeout(std::time::Duration::from_secs(5))?;
        conn.execute_batch(SCHEMA)
            .with_context(|| format!("{}: cannot create the job tables", path.display()))?;
        add_missing_columns(&conn).with_context(|| {
            format!("{}: cannot add the job tables' new columns", path.display())
        })?;
        Ok(Self { conn: Mutex::new(conn) })
    }

    /// Runs `f` in an immediate transaction and commits.
    fn write<T>(
        &self,
        f: impl FnOnce(&Transaction<'_>) -> rusqlite::Result<T>,
    ) -> anyhow::Result<T> {
        let mut conn = self.conn.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let tx = conn.transaction_with_behavior(TransactionBehavior::Immediate)?;
        let out = f(&tx)?;
        tx.commit()?;
        Ok(out)
    }
}

/// Brings a store made by an older version up to [`SCHEMA`]: `jobs.refine_steps` came later
/// (its jobs keep the server's setting).
fn add_missing_columns(conn: &Connection) -> rusqlite::Result<()> {
    let mut stmt = conn.prepare("SELECT name FROM pragma_table_info('jobs')")?;
    let columns =
        stmt.query_map([], |r| r.get::<_, String>(0))?.collect::<rusqlite::Result<Vec<_>>>()?;
    if !columns.iter().any(|c| c == "refine_steps") {
        conn.execute_batch("ALTER TABLE jobs ADD COLUMN refine_steps INTEGER")?;
    }
    Ok(())
}

fn read_status(conn: &Connection, job_id: &str) -> rusqlite::Result<Option<JobStatus>> {
    let Some(cancelled) = conn
        .query_row("SELECT cancelled FROM jobs WHERE id = ?1", [job_id], |r| r.get::<_, bool>(0))
        .optional()?
    else {
        return Ok(None);
    };
    let mut stmt = conn.prepare("SELECT idx, name, state, scene_id, error, metrics FROM job_scenes WHERE job_id = ?1 ORDER BY idx")?;
    let scenes = stmt
        .query_map([job_id], |r| {
            let metrics: Option<String> = r.get(5)?;
            Ok(JobSceneStatus {
                index: r.get::<_, i64>(0)? as usize,
                name: r.get(1)?,
                state: parse_state(&r.get::<_, String>(2)?)?,
                scene_id: r.get(3)?,
                error: r.get(4)?,
                metrics: metrics.and_then(|m| serde_json::from_str(&m).ok()),
            })
        })?
        .collect::<rusqlite::Result<Vec<_>>>()?;
    Ok(Some(job_status(job_id, cancelled, scenes)))
}

impl JobStore for SqliteStore {
    fn create(&self, job: &NewJob) -> anyhow::Result<()> {
        let vocabulary = job.vocabulary.as_ref().map(serde_json::to_string).transpose()?;
        let refine_steps = job.refine_steps.map(|n| n as i64);
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs() as i64);
        self.write(|tx| {
            tx.execute(
                "INSERT INTO jobs (id, vocabulary, refine_steps, created_at) VALUES (?1, ?2, ?3, ?4)",
                params![job.id, vocabulary, refine_steps, now],
            )?;
            for (i, (name, input)) in job.scenes.iter().enumerate() {
                tx.execute(
                    "INSERT INTO job_scenes (job_id, idx, name, input, state) VALUES (?1, ?2, ?3, ?4, 'queued')",
                    params![job.id, i as i64, name, input.to_string_lossy()],
                )?;
            }
            Ok(())
        })
    }

    fn status(&self, job_id: &str) -> anyhow::Result<Option<JobStatus>> {
        let conn = self.conn.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        Ok(read_status(&conn, job_id)?)
    }

    fn claim(&self) -> anyhow::Result<Option<SceneTask>> {
        self.write(|tx| {
            let row = tx
                .query_row(
                    "SELECT s.job_id, s.idx, s.name, s.input, s.scene_id, j.vocabulary, j.refine_steps FROM job_scenes s JOIN jobs j ON j.id = s.job_id
                     WHERE s.state = 'queued' AND j.cancelled = 0 ORDER BY j.seq, s.idx LIMIT 1",
                    [],
                    |r| {
                        Ok((
                            r.get::<_, String>(0)?,
                            r.get::<_, i64>(1)?,
                            r.get::<_, String>(2)?,
                            r.get::<_, String>(3)?,
                            r.get::<_, Option<String>>(4)?,
                            r.get::<_, Option<String>>(5)?,
                            r.get::<_, Option<i64>>(6)?,
                        ))
                    },
                )
                .optional()?;
            let Some((job_id, index, name, input, scene_id, vocabulary, refine_steps)) = row else { return Ok(None) };
            let scene_id = scene_id.unwrap_or_else(|| crate::scene_store::SceneId::new().to_string());
            tx.execute(
                "UPDATE job_scenes SET state = 'running', scene_id = ?3, attempts = attempts + 1 WHERE job_id = ?1 AND idx = ?2",
                params![job_id, index, scene_id],
            )?;
            Ok(Some(SceneTask {
                job_id,
                index: index as usize,
                name,
                input: PathBuf::from(input),
                scene_id,
                vocabulary: vocabulary.and_then(|v| serde_json::from_str(&v).ok()),
                refine_steps: refine_steps.map(|n| n as usize),
            }))
        })
    }

    fn finish(&self, task: &SceneTask, outcome: &SceneOutcome) -> anyhow::Result<bool> {
        let (state, error, metrics) = match outcome {
            SceneOutcome::Done { metrics } => {
                (JobState::Done, None, metrics.as_ref().map(serde_json::Value::to_string))
            }
            SceneOutcome::Failed { error } => (JobState::Failed, Some(error.as_str()), None),
        };
        let updated = self.write(|tx| {
            tx.execute(
                "UPDATE job_scenes SET state = ?3, error = ?4, metrics = ?5 WHERE job_id = ?1 AND idx = ?2 AND state = 'running'",
                params![task.job_id, task.index as i64, state_name(state), error, metrics],
            )
        })?;
        Ok(updated == 1)
    }

    /// One process a file: its claims hold until it stops.
    fn lease(&self) -> Option<std::time::Duration> {
        None
    }

    fn renew(&self, _task: &SceneTask) -> anyhow::Result<bool> {
        Ok(true)
    }

    fn cancel(&self, job_id: &str) -> anyhow::Result<Option<JobStatus>> {
        self.write(|tx| {
            if tx.execute("UPDATE jobs SET cancelled = 1 WHERE id = ?1", [job_id])? == 0 {
                return Ok(None);
            }
            tx.execute(
                "UPDATE job_scenes SET state = 'cancelled' WHERE job_id = ?1 AND state = 'queued'",
                [job_id],
            )?;
            read_status(tx, job_id)
        })
    }

    fn requeue_interrupted(&self) -> anyhow::Result<usize> {
        self.write(|tx| {
            tx.execute("UPDATE job_scenes SET state = 'queued' WHERE state = 'running'", [])
        })
    }

    fn count_by_state(&self) -> anyhow::Result<Vec<(JobState, usize)>> {
        let conn = self.conn.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut stmt = conn.prepare("SELECT id FROM jobs")?;
        let ids =
            stmt.query_map([], |r| r.get::<_, String>(0))?.collect::<rusqlite::Result<Vec<_>>>()?;
        let mut states = Vec::with_capacity(ids.len());
        for id in ids {
            states.extend(read_status(&conn, &id)?.map(|s| s.state));
        }
        Ok(count_states(states))
    }
}

/// The behaviour every store shares is tested in `super::suite`; here what is SQLite's own.
#[cfg(test)]
mod tests {
    use super::*;

    fn job(id: &str, scenes: usize) -> NewJob {
        NewJob {
            id: id.into(),
            scenes: (0..scenes)
                .map(|i| (format!("s{i}"), PathBuf::from(format!("/in/{i}"))))
                .collect(),
            vocabulary: None,
            refine_steps: None,
        }
    }

    #[test]
    fn a_store_from_before_refine_steps_opens_and_each_job_keeps_its_steps() {
        let dir = tempfile::tempdir().unwrap();
        let db = dir.path().join("jobs.sqlite");
        let old_schema = SCHEMA.replace("    refine_steps INTEGER,\n", "");
        assert_ne!(old_schema, SCHEMA);
        let old = Connection::open(&db).unwrap();
        old.execute_batch(&old_schema).unwrap();
        old.execute("INSERT INTO jobs (id, vocabulary, created_at) VALUES ('old', NULL, 0)", [])
            .unwrap();
        old.execute("INSERT INTO job_scenes (job_id, idx, name, input, state) VALUES ('old', 0, 's0', '/in/0', 'queued')", []).unwrap();
        drop(old);

        let store = SqliteStore::open(&db).unwrap();
        store.create(&NewJob { refine_steps: Some(40), ..job("new", 1) }).unwrap();
        let first = store.claim().unwrap().unwrap();
        assert_eq!((first.job_id.as_str(), first.refine_steps), ("old", None));
        assert!(store.finish(&first, &SceneOutcome::Done { metrics: None }).unwrap());
        let second = store.claim().unwrap().unwrap();
        assert_eq!((second.job_id.as_str(), second.refine_steps), ("new", Some(40)));
        drop(store);
        SqliteStore::open(&db).expect("opens again once the column is there");
    }
}
