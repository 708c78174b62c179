//! Batch jobs over HTTP: `POST /v1/jobs` (photo sets as multipart parts named by scene, or a
//! tar/zip of scene folders as an `archive` part or the whole body) stores the upload and
//! queues the job; `GET /v1/jobs/{id}` is its status with every scene's progress, result and
//! metrics; `GET /v1/jobs/{id}/events` streams that status as server-sent events whenever it
//! changes, ending when the job does; `DELETE /v1/jobs/{id}` cancels what has not started.

use std::convert::Infallible;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use axum::Json;
use axum::body::Bytes;
use axum::extract::rejection::PathRejection;
use axum::extract::{FromRequest, Multipart, Path, Request, State};
use axum::http::{StatusCode, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use futures_util::Stream;
use inssplat_proto::api::{ErrorBody, JobAccepted, JobState, JobStatus};
use tokio::sync::broadcast;
use utoipa::ToSchema;

use super::upload::{Part, read_parts, refine_steps, vocabulary};
use super::{ApiError, AppState};
use crate::jobs::intake::{self, ArchiveKind, IntakeError, Photo};
use crate::jobs::{JobStore, NewJob};
use crate::scene_store::is_id;

/// The multipart form of `POST /v1/jobs` (for the OpenAPI document). Either photo sets, as
/// file parts whose field name is the scene's name (2–16 per scene), or one `archive`.
#[derive(ToSchema)]
#[allow(dead_code)]
pub struct JobForm {
    /// A tar or zip of scene folders: folders of photos, or dataset scenes (a
    /// `transforms.json` with an eval split makes the job score the scene).
    #[schema(value_type = Option<String>, format = Binary)]
    archive: Option<Vec<u8>>,
    /// Label vocabulary for the photo-set scenes (labels separated by commas or new lines).
    vocab: Option<String>,
    /// Steps of test-time refinement of every scene against its photos, 0–1000 (default: the
    /// server's `--refine-steps`).
    #[schema(minimum = 0, maximum = 1000)]
    refine_steps: Option<usize>,
}

/// Most form parts in a job upload.
const MAX_PARTS: usize = intake::MAX_SCENES * 16 + 2;

/// What a job upload holds.
enum Upload {
    Sets(Vec<(String, Vec<Photo>)>),
    Archive(Bytes),
}

/// The settings a multipart job upload may send beside its scenes.
#[derive(Default)]
struct Options {
    vocabulary: Option<Vec<String>>,
    refine_steps: Option<usize>,
}

fn job_id(id: Result<Path<String>, PathRejection>) -> Result<String, ApiError> {
    let id = id?.0;
    if is_id(&id) {
        Ok(id)
    } else {
        Err(ApiError::BadRequest(format!(
            "`{}` is not a job id (32 lower-case hex digits)",
            id.escape_debug()
        )))
    }
}

/// Runs a job-store call off the async threads.
async fn with_store<T: Send + 'static>(
    state: &AppState,
    f: impl FnOnce(&dyn JobStore) -> anyhow::Result<T> + Send + 'static,
) -> Result<T, ApiError> {
    let store = state.shared.jobs.clone();
    tokio::task::spawn_blocking(move || f(store.as_ref()))
        .await
        .map_err(ApiError::internal)?
        .map_err(|e| ApiError::internal(format!("job store: {e:#}")))
}

fn sets_from_parts(parts: Vec<Part>) -> Result<(Upload, Options), ApiError> {
    let mut sets: Vec<(String, Vec<Photo>)> = Vec::new();
    let mut archive = None;
    let mut options = Options::default();
    for part in parts {
        match part.name.as_str() {
            "vocab" => options.vocabulary = Some(vocabulary(&part)?),
            "refine_steps" => options.refine_steps = Some(refine_steps(&part)?),
            "archive" => archive = Some(part.bytes),
            name if intake::valid_scene_name(name) => {
                let photo = Photo {
                    file_name: part.file_name.unwrap_or_else(|| name.to_string()),
                    bytes: part.bytes.to_vec(),
                };
                match sets.iter_mut().find(|(n, _)| n == name) {
                    Some((_, photos)) => photos.push(photo),
                    None => sets.push((name.to_string(), vec![photo])),
                }
            }
            other => {
                return Err(ApiError::Validation(format!(
                    "form field `{}`: a scene name is 1-64 of A-Z a-z 0-9 _ . - (or send `archive` / `vocab` / `refine_steps`)",
                    other.escape_debug()
                )));
            }
        }
    }
    match archive {
        Some(_) if !sets.is_empty() => {
            Err(ApiError::Validation("send either photo sets or an `archive`, not both".into()))
        }
        Some(bytes) => Ok((Upload::Archive(bytes), options)),
        None => Ok((Upload::Sets(sets), options)),
    }
}

/// Submit a batch of scenes.
#[utoipa::path(post, path = "/v1/jobs", tag = "jobs",
    request_body(content(
        (JobForm = "multipart/form-data"),
        (Vec<u8> = "application/x-tar"),
        (Vec<u8> = "application/zip"),
    )),
    responses((status = 202, description = "Job queued", body = JobAccepted),
        (status = 400, description = "Unreadable body", body = ErrorBody), (status = 401, description = "Missing or wrong API key", body = ErrorBody),
        (status = 413, description = "Body over the size limit", body = ErrorBody), (status = 415, description = "Unsupported content type", body = ErrorBody),
        (status = 422, description = "No scenes, a bad scene, or a bad archive", body = ErrorBody)))]
pub async fn submit(
    State(state): State<Arc<AppState>>,
    req: Request,
) -> Result<Response, ApiError> {
    let content_type = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_ascii_lowercase();
    let (upload, options) = if content_type.starts_with("multipart/form-data") {
        let multipart = Multipart::from_request(req, &()).await?;
        sets_from_parts(read_parts(multipart, MAX_PARTS).await?)?
    } else if [
        "application/x-tar",
        "application/tar",
        "application/zip",
        "application/octet-stream",
    ]
    .iter()
    .any(|t| content_type.starts_with(t))
    {
        (Upload::Archive(Bytes::from_request(req, &()).await?), Options::default())
    } else {
        return Err(ApiError::UnsupportedMediaType(format!(
            "content type `{}`: send multipart/form-data, application/x-tar or application/zip",
            content_type.escape_debug()
        )));
    };
    let id = crate::scene_store::SceneId::new().to_string();
    let dest = state.data_dir.join("jobs").join(&id);
    let max_unpacked = (state.max_body_bytes as u64).saturating_mul(4);
    let job = {
        let (id, dest) = (id.clone(), dest.clone());
        tokio::task::spawn_blocking(move || -> Result<NewJob, IntakeError> {
            let scenes = match upload {
                Upload::Sets(sets) => intake::write_photo_sets(sets, &dest)?,
                Upload::Archive(bytes) => {
                    let kind = ArchiveKind::sniff(&bytes).ok_or_else(|| {
                        IntakeError::Invalid("the archive is neither a tar nor a zip file".into())
                    })?;
                    intake::unpack_archive(&bytes, kind, &dest, max_unpacked)?
                }
            };
            Ok(NewJob {
                id,
                scenes,
                vocabulary: options.vocabulary,
                refine_steps: options.refine_steps,
            })
        })
        .await
        .map_err(ApiError::internal)?
    };
    let job = match job {
        Ok(job) => job,
        Err(e) => {
            remove_upload(dest).await;
            return Err(match e {
                IntakeError::Invalid(m) => ApiError::Validation(m),
                IntakeError::Io(e) => ApiError::internal(format!("storing the upload: {e}")),
            });
        }
    };
    let accepted = JobAccepted {
        job_id: id.clone(),
        scenes: job.scenes.iter().map(|(n, _)| n.clone()).collect(),
    };
    if let Err(e) = with_store(&state, move |s| s.create(&job)).await {
        remove_upload(dest).await;
        return Err(e);
    }
    tracing::info!("job {id}: {} scene(s) queued", accepted.scenes.len());
    Ok((StatusCode::ACCEPTED, [(header::LOCATION, format!("/v1/jobs/{id}"))], Json(accepted))
        .into_response())
}

async fn remove_upload(dest: PathBuf) {
    if let Err(e) = tokio::fs::remove_dir_all(&dest).await
        && e.kind() != std::io::ErrorKind::NotFound
    {
        tracing::warn!("cannot remove {}: {e}", dest.display());
    }
}

async fn current(state: &AppState, id: String) -> Result<JobStatus, ApiError> {
    let missing = format!("no job {id}");
    with_store(state, move |s| s.status(&id)).await?.ok_or(ApiError::NotFound(missing))
}

/// A job's status and every scene's progress, result (scene id) and metrics.
#[utoipa::path(get, path = "/v1/jobs/{id}", tag = "jobs",
    params(("id" = String, Path, pattern = "^[0-9a-f]{32}$", description = "Job id (32 hex digits)")),
    responses((status = 200, description = "Status", body = JobStatus),
        (status = 400, description = "Malformed id", body = ErrorBody), (status = 404, description = "No such job", body = ErrorBody)))]
pub async fn status(
    State(state): State<Arc<AppState>>,
    id: Result<Path<String>, PathRejection>,
) -> Result<Json<JobStatus>, ApiError> {
    Ok(Json(current(&state, job_id(id)?).await?))
}

/// Cancel the job's scenes that have not started (a running one finishes).
#[utoipa::path(delete, path = "/v1/jobs/{id}", tag = "jobs",
    params(("id" = String, Path, pattern = "^[0-9a-f]{32}$", description = "Job id (32 hex digits)")),
    responses((status = 200, description = "Status after cancelling", body = JobStatus),
        (status = 400, description = "Malformed id", body = ErrorBody), (status = 404, description = "No such job", body = ErrorBody)))]
pub async fn cancel(
    State(state): State<Arc<AppState>>,
    id: Result<Path<String>, PathRejection>,
) -> Result<Json<JobStatus>, ApiError> {
    let id = job_id(id)?;
    let missing = format!("no job {id}");
    let status =
        with_store(&state, move |s| s.cancel(&id)).await?.ok_or(ApiError::NotFound(missing))?;
    let _ = state.shared.job_events.send(status.job_id.clone());
    Ok(Json(status))
}

fn finished(s: &JobStatus) -> bool {
    matches!(s.state, JobState::Done | JobState::Failed | JobState::Cancelled)
}

/// How often an event stream reads the job's status without news of a change: a replica
/// sharing a PostgreSQL store with others hears only of its own scenes.
const POLL: Duration = Duration::from_secs(1);

/// Stream state: what was last sent, and whether the stream is over.
struct Watch {
    state: Arc<AppState>,
    id: String,
    events: broadcast::Receiver<String>,
    last: Option<JobStatus>,
    pending: Option<JobStatus>,
}

impl Watch {
    /// The next status that differs from the last one sent; `None` when the job has ended or
    /// the service is stopping.
    async fn next(&mut self) -> Option<JobStatus> {
        if let Some(s) = self.pending.take() {
            return Some(s);
        }
        if self.last.as_ref().is_some_and(finished) {
            return None;
        }
        let mut shutdown = self.state.shutdown.clone();
        loop {
            let changed = tokio::select! {
                e = self.events.recv() => match e {
                    Ok(job) => job == self.id,
                    Err(broadcast::error::RecvError::Lagged(_)) => true,
                    Err(broadcast::error::RecvError::Closed) => return None,
                },
                _ = shutdown.wait_for(|stop| *stop) => return None,
                // Other replicas sharing the store announce nothing here: read it anyway.
                _ = tokio::time::sleep(POLL) => true,
            };
            if !changed {
                continue;
            }
            let status = current(&self.state, self.id.clone()).await.ok()?;
            if self.last.as_ref() != Some(&status) {
                return Some(status);
            }
        }
    }
}

/// The job's status as server-sent events (`event: status`, JSON data) each time it changes
/// (on this replica at once, on others sharing the job store within a second); the stream ends
/// after the job does.
#[utoipa::path(get, path = "/v1/jobs/{id}/events", tag = "jobs",
    params(("id" = String, Path, pattern = "^[0-9a-f]{32}$", description = "Job id (32 hex digits)")),
    responses((status = 200, description = "text/event-stream of JobStatus", content_type = "text/event-stream", body = JobStatus),
        (status = 400, description = "Malformed id", body = ErrorBody), (status = 404, description = "No such job", body = ErrorBody)))]
pub async fn events(
    State(state): State<Arc<AppState>>,
    id: Result<Path<String>, PathRejection>,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    let id = job_id(id)?;
    let events = state.shared.job_events.subscribe();
    let first = current(&state, id.clone()).await?;
    let watch = Watch { state, id, events, last: None, pending: Some(first) };
    let stream = futures_util::stream::unfold(watch, |mut w| async move {
        let status = w.next().await?;
        let event = Event::default()
            .event("status")
            .json_data(&status)
            .unwrap_or_else(|_| Event::default().event("status"));
        w.last = Some(status);
        Some((Ok(event), w))
    });
    Ok(Sse::new(stream).keep_alive(KeepAlive::default()))
}
