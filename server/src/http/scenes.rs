//! A stored scene's artefacts (`scene.ply`, `preview.png`, each view's `instances.png` and
//! `labels.png`, query masks) and `POST /v1/scenes/{id}/query`. Path parameters are parsed
//! before any path is built: ids are 32 hex digits, views numbers, query folders and mask
//! names of the form `query` writes, so no parameter can reach outside the scene's folder.

use std::path::{Path as FsPath, PathBuf};
use std::sync::Arc;

use axum::Json;
use axum::extract::rejection::{JsonRejection, PathRejection};
use axum::extract::{Path, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use inssplat_proto::api::{ErrorBody, QueryRequest, QueryResponse};
use tokio::sync::oneshot;

use super::reconstruct::run_task;
use super::{ApiError, AppState};
use crate::scene_store::SceneId;
use crate::worker::Task;

/// Longest query text, in characters.
const MAX_QUERY_CHARS: usize = 500;

/// The folder of the stored scene `id`.
pub(super) fn scene_dir(state: &AppState, id: &str) -> Result<(SceneId, PathBuf), ApiError> {
    let id: SceneId = id.parse().map_err(ApiError::BadRequest)?;
    let dir = state
        .shared
        .scenes
        .open_scene(&id)
        .ok_or_else(|| ApiError::NotFound(format!("no scene {id} (unknown, or expired)")))?;
    Ok((id, dir))
}

/// The file `rel` of scene `id`, with `content_type`.
async fn file(
    state: &AppState,
    id: &str,
    rel: &str,
    content_type: &'static str,
) -> Result<Response, ApiError> {
    let (id, dir) = scene_dir(state, id)?;
    match tokio::fs::read(dir.join(rel)).await {
        Ok(bytes) => Ok(([(header::CONTENT_TYPE, content_type)], bytes).into_response()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            Err(ApiError::NotFound(format!("scene {id} has no {rel}")))
        }
        Err(e) => Err(ApiError::internal(format!("reading {rel} of scene {id}: {e}"))),
    }
}

/// The Gaussians of a scene (binary little-endian 3DGS PLY with inssplat's extras).
#[utoipa::path(get, path = "/v1/scenes/{id}/scene.ply", tag = "scenes",
    params(("id" = String, Path, pattern = "^[0-9a-f]{32}$", description = "Scene id (32 hex digits)")),
    responses((status = 200, description = "PLY file", content_type = "application/octet-stream"),
        (status = 400, description = "Malformed id", body = ErrorBody), (status = 404, description = "No such scene", body = ErrorBody)))]
pub async fn ply(
    State(state): State<Arc<AppState>>,
    id: Result<Path<String>, PathRejection>,
) -> Result<Response, ApiError> {
    file(&state, &id?.0, "scene.ply", "application/octet-stream").await
}

/// Input | depth | instances | labels of every view, one row each.
#[utoipa::path(get, path = "/v1/scenes/{id}/preview.png", tag = "scenes",
    params(("id" = String, Path, pattern = "^[0-9a-f]{32}$", description = "Scene id (32 hex digits)")),
    responses((status = 200, description = "PNG image", content_type = "image/png"),
        (status = 400, description = "Malformed id", body = ErrorBody), (status = 404, description = "No such scene", body = ErrorBody)))]
pub async fn preview(
    State(state): State<Arc<AppState>>,
    id: Result<Path<String>, PathRejection>,
) -> Result<Response, ApiError> {
    file(&state, &id?.0, "preview.png", "image/png").await
}

/// A view's image from `folder` (`instances`, `labels`, `ids` or `depth`).
async fn view_png(
    state: &AppState,
    params: Result<Path<(String, String)>, PathRejection>,
    folder: &str,
) -> Result<Response, ApiError> {
    let Path((id, view)) = params?;
    let view: usize = view.parse().map_err(|_| {
        ApiError::BadRequest(format!("view `{}` is not a view number", view.escape_debug()))
    })?;
    file(state, &id, &format!("{folder}/{view:03}.png"), "image/png").await
}

/// A view's instance map (a colour per instance id, black = none).
#[utoipa::path(get, path = "/v1/scenes/{id}/views/{view}/instances.png", tag = "scenes",
    params(("id" = String, Path, pattern = "^[0-9a-f]{32}$", description = "Scene id"), ("view" = usize, Path, description = "Input view index, from 0")),
    responses((status = 200, description = "PNG image", content_type = "image/png"),
        (status = 400, description = "Malformed id or view", body = ErrorBody), (status = 404, description = "No such scene or view", body = ErrorBody)))]
pub async fn instances_png(
    State(state): State<Arc<AppState>>,
    params: Result<Path<(String, String)>, PathRejection>,
) -> Result<Response, ApiError> {
    view_png(&state, params, "instances").await
}

/// A view's label map (a colour per vocabulary label, black = none).
#[utoipa::path(get, path = "/v1/scenes/{id}/views/{view}/labels.png", tag = "scenes",
    params(("id" = String, Path, pattern = "^[0-9a-f]{32}$", description = "Scene id"), ("view" = usize, Path, description = "Input view index, from 0")),
    responses((status = 200, description = "PNG image", content_type = "image/png"),
        (status = 400, description = "Malformed id or view", body = ErrorBody), (status = 404, description = "No such scene or view", body = ErrorBody)))]
pub async fn labels_png(
    State(state): State<Arc<AppState>>,
    params: Result<Path<(String, String)>, PathRejection>,
) -> Result<Response, ApiError> {
    view_png(&state, params, "labels").await
}

/// A view's instance ids as 16-bit grey (0 = none), at the size of its instance map.
#[utoipa::path(get, path = "/v1/scenes/{id}/views/{view}/ids.png", tag = "scenes",
    params(("id" = String, Path, pattern = "^[0-9a-f]{32}$", description = "Scene id"), ("view" = usize, Path, description = "Input view index, from 0")),
    responses((status = 200, description = "16-bit grey PNG", content_type = "image/png"),
        (status = 400, description = "Malformed id or view", body = ErrorBody), (status = 404, description = "No such scene or view", body = ErrorBody)))]
pub async fn ids_png(
    State(state): State<Arc<AppState>>,
    params: Result<Path<(String, String)>, PathRejection>,
) -> Result<Response, ApiError> {
    view_png(&state, params, "ids").await
}

/// A view's depth along the camera's z axis in millimetres, as 16-bit grey (0 = none), at the
/// size of its instance map: the scene's units, which photos alone do not make metric.
#[utoipa::path(get, path = "/v1/scenes/{id}/views/{view}/depth.png", tag = "scenes",
    params(("id" = String, Path, pattern = "^[0-9a-f]{32}$", description = "Scene id"), ("view" = usize, Path, description = "Input view index, from 0")),
    responses((status = 200, description = "16-bit grey PNG", content_type = "image/png"),
        (status = 400, description = "Malformed id or view", body = ErrorBody), (status = 404, description = "No such scene or view", body = ErrorBody)))]
pub async fn depth_png(
    State(state): State<Arc<AppState>>,
    params: Result<Path<(String, String)>, PathRejection>,
) -> Result<Response, ApiError> {
    view_png(&state, params, "depth").await
}

/// Which instances of the scene the text names, each with its mask in every view.
#[utoipa::path(post, path = "/v1/scenes/{id}/query", tag = "scenes",
    params(("id" = String, Path, pattern = "^[0-9a-f]{32}$", description = "Scene id")),
    request_body = QueryRequest,
    responses((status = 200, description = "Matches, best first (empty with a message when nothing matches)", body = QueryResponse),
        (status = 400, description = "Malformed id or JSON", body = ErrorBody), (status = 404, description = "No such scene", body = ErrorBody),
        (status = 413, description = "Body over the size limit", body = ErrorBody), (status = 415, description = "Not application/json", body = ErrorBody),
        (status = 422, description = "Missing or empty text", body = ErrorBody), (status = 429, description = "Queue full", body = ErrorBody),
        (status = 503, description = "Model not loaded yet", body = ErrorBody)))]
pub async fn query(
    State(state): State<Arc<AppState>>,
    id: Result<Path<String>, PathRejection>,
    body: Result<Json<QueryRequest>, JsonRejection>,
) -> Result<Json<QueryResponse>, ApiError> {
    let (id, dir) = scene_dir(&state, &id?.0)?;
    let text = body?.0.text;
    if text.trim().is_empty() || text.chars().count() > MAX_QUERY_CHARS {
        return Err(ApiError::Validation(format!(
            "`text` must name something, in 1-{MAX_QUERY_CHARS} characters"
        )));
    }
    let (reply, answer) = oneshot::channel();
    let mut response =
        run_task(&state, Task::Query { dir: dir.clone(), text, reply }, answer).await?;
    for mask in response.matches.iter_mut().flat_map(|m| m.masks.iter_mut()) {
        mask.png_url = mask_url(&id, &dir, FsPath::new(&mask.png_url));
    }
    Ok(Json(response))
}

/// The URL of a query mask written at `path` under the scene folder `dir`.
fn mask_url(id: &SceneId, dir: &FsPath, path: &FsPath) -> String {
    let rel = path.strip_prefix(dir).unwrap_or(path);
    let encoded: Vec<String> = rel.iter().map(|c| percent_encode(&c.to_string_lossy())).collect();
    format!("/v1/scenes/{id}/{}", encoded.join("/"))
}

fn percent_encode(s: &str) -> String {
    s.bytes()
        .map(|b| {
            if b.is_ascii_alphanumeric() || b"_-.".contains(&b) {
                char::from(b).to_string()
            } else {
                format!("%{b:02X}")
            }
        })
        .collect()
}

/// Whether `file` is a mask name `query` writes: `id<N>_view<NNN>.png`.
fn is_mask_name(file: &str) -> bool {
    let Some(rest) = file.strip_prefix("id").and_then(|r| r.strip_suffix(".png")) else {
        return false;
    };
    let Some((id, view)) = rest.split_once("_view") else { return false };
    !id.is_empty() && !view.is_empty() && id.bytes().chain(view.bytes()).all(|b| b.is_ascii_digit())
}

/// A query's mask of one instance in one view (white = the instance).
#[utoipa::path(get, path = "/v1/scenes/{id}/query/{slug}/{file}", tag = "scenes",
    params(("id" = String, Path, pattern = "^[0-9a-f]{32}$", description = "Scene id"), ("slug" = String, Path, description = "The query's folder, as in a query answer's png_url"),
        ("file" = String, Path, description = "id<N>_view<NNN>.png")),
    responses((status = 200, description = "PNG mask", content_type = "image/png"),
        (status = 400, description = "Malformed parameter", body = ErrorBody), (status = 404, description = "No such scene or mask", body = ErrorBody)))]
pub async fn query_mask(
    State(state): State<Arc<AppState>>,
    params: Result<Path<(String, String, String)>, PathRejection>,
) -> Result<Response, ApiError> {
    let Path((id, slug, file_name)) = params?;
    if slug.is_empty() || !slug.chars().all(|c| c.is_alphanumeric() || c == '_') {
        return Err(ApiError::BadRequest(format!(
            "`{}` is not a query folder",
            slug.escape_debug()
        )));
    }
    if !is_mask_name(&file_name) {
        return Err(ApiError::BadRequest(format!(
            "`{}` is not a mask name (id<N>_view<NNN>.png)",
            file_name.escape_debug()
        )));
    }
    file(&state, &id, &format!("query/{slug}/{file_name}"), "image/png").await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mask_names_and_urls() {
        assert!(is_mask_name("id3_view007.png"));
        for bad in [
            "id_view1.png",
            "id3_view.png",
            "../id3_view1.png",
            "id3_view1.png.exe",
            "idx_view1.png",
        ] {
            assert!(!is_mask_name(bad), "{bad}");
        }
        let id: SceneId = "0123456789abcdef0123456789abcdef".parse().unwrap();
        let url =
            mask_url(&id, FsPath::new("/d/s"), FsPath::new("/d/s/query/lampe_à/id1_view000.png"));
        assert_eq!(
            url,
            "/v1/scenes/0123456789abcdef0123456789abcdef/query/lampe_%C3%A0/id1_view000.png"
        );
    }
}
