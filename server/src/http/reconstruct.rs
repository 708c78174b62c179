//! `POST /v1/reconstruct`: 2–16 photos (multipart `images` parts, optional `vocab` and
//! `refine_steps`) → the reconstruction, stored under a new scene id whose artefacts `scenes`
//! serves.

use std::sync::Arc;

use axum::Json;
use axum::extract::multipart::MultipartRejection;
use axum::extract::{Multipart, State};
use inssplat_proto::api::{ErrorBody, ReconstructResponse};
use inssplat_proto::signature::{MAX_VIEWS, MIN_VIEWS};
use tokio::sync::oneshot;
use utoipa::ToSchema;

use super::upload::{read_parts, refine_steps, vocabulary};
use super::{ApiError, AppState};
use crate::worker::Task;
use inssplat_pipeline::reconstruct::InputImage;

/// The multipart form of `POST /v1/reconstruct` (it describes the form in the OpenAPI
/// document; the handler reads the parts as they stream in).
#[derive(ToSchema)]
#[allow(dead_code)]
pub struct ReconstructForm {
    /// 2–16 photos of one scene (PNG, JPEG or WebP), one `images` part each, in the order they
    /// were taken (registration places a photo that overlaps no other by that order).
    #[schema(value_type = Vec<String>, format = Binary)]
    images: Vec<Vec<u8>>,
    /// Label vocabulary: labels separated by commas or new lines (default: the server's).
    vocab: Option<String>,
    /// Steps of test-time refinement of the Gaussians and cameras against the photos, 0–1000
    /// (about 50 ms a step at 8 views on two cores; default: the server's `--refine-steps`).
    /// The answer's `refinement` gives the input views' PSNR before and after.
    #[schema(minimum = 0, maximum = 1000)]
    refine_steps: Option<usize>,
}

/// Sends `task` to the model workers and waits for its answer.
pub async fn run_task<T>(
    state: &AppState,
    task: Task,
    reply: oneshot::Receiver<Result<T, crate::worker::TaskError>>,
) -> Result<T, ApiError> {
    state.pool.submit(task)?;
    let answer = reply
        .await
        .map_err(|_| ApiError::NotReady("the service stopped before the request ran".into()))?;
    Ok(answer?)
}

/// Reconstruct a scene from 2–16 photos.
#[utoipa::path(
    post,
    path = "/v1/reconstruct",
    tag = "scenes",
    request_body(content = ReconstructForm, content_type = "multipart/form-data"),
    responses(
        (status = 200, description = "The reconstruction; its artefacts stay under /v1/scenes/{scene_id}/", body = ReconstructResponse),
        (status = 400, description = "Unreadable multipart body", body = ErrorBody),
        (status = 401, description = "Missing or wrong API key", body = ErrorBody),
        (status = 413, description = "Body over the size limit", body = ErrorBody),
        (status = 415, description = "Not multipart/form-data", body = ErrorBody),
        (status = 422, description = "Wrong photo count, unknown field, or a photo that cannot be used", body = ErrorBody),
        (status = 429, description = "Queue full; see Retry-After", body = ErrorBody),
        (status = 503, description = "Model not loaded yet", body = ErrorBody),
        (status = 504, description = "Took longer than the request timeout", body = ErrorBody),
    )
)]
pub async fn reconstruct(
    State(state): State<Arc<AppState>>,
    multipart: Result<Multipart, MultipartRejection>,
) -> Result<Json<ReconstructResponse>, ApiError> {
    let parts = read_parts(multipart?, MAX_VIEWS + 3).await?;
    let mut images = Vec::new();
    let mut vocab = None;
    let mut steps = None;
    for part in parts {
        match part.name.as_str() {
            "images" => {
                let name = part
                    .file_name
                    .clone()
                    .filter(|n| !n.is_empty())
                    .unwrap_or_else(|| format!("image {}", images.len()));
                images.push(InputImage { name, bytes: part.bytes.to_vec() });
            }
            "vocab" => vocab = Some(vocabulary(&part)?),
            "refine_steps" => steps = Some(refine_steps(&part)?),
            other => {
                return Err(ApiError::Validation(format!(
                    "unknown form field `{}`: send 2-16 `images` parts and optionally `vocab` and `refine_steps`",
                    other.escape_debug()
                )));
            }
        }
    }
    if !(MIN_VIEWS..=MAX_VIEWS).contains(&images.len()) {
        return Err(ApiError::Validation(format!(
            "{} images given; inssplat needs between {MIN_VIEWS} and {MAX_VIEWS} views of one scene (`images` parts)",
            images.len()
        )));
    }
    let vocabulary = vocab.unwrap_or_else(|| state.default_vocab.clone());
    let (reply, answer) = oneshot::channel();
    let response = run_task(
        &state,
        Task::Reconstruct { images, vocabulary, refine_steps: steps, reply },
        answer,
    )
    .await?;
    Ok(Json(response))
}
