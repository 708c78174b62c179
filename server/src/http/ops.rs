//! Operational endpoints: liveness (`/health`), readiness once the model is warm (`/ready`,
//! 503 before), Prometheus metrics (`/metrics`) and the OpenAPI document (`/openapi.json`;
//! `page` serves `/docs`, which renders it).

use std::sync::Arc;

use axum::Json;
use axum::extract::State;
use axum::http::header;
use axum::response::{IntoResponse, Response};
use inssplat_proto::api::{ErrorBody, ServiceStatus};
use utoipa::OpenApi;

use super::openapi::ApiDoc;
use super::{ApiError, AppState};
use crate::metrics::Gauges;

/// The process is up (the model may still be loading).
#[utoipa::path(get, path = "/health", tag = "service", responses((status = 200, description = "Up", body = ServiceStatus)))]
pub async fn health(State(state): State<Arc<AppState>>) -> Json<ServiceStatus> {
    let status = if state.pool.model_version().is_some() { "ok" } else { "warming_up" };
    Json(ServiceStatus {
        status: status.into(),
        model_version: state.pool.model_version().map(str::to_string),
    })
}

/// The model is loaded and warmed up: requests will be served.
#[utoipa::path(get, path = "/ready", tag = "service",
    responses((status = 200, description = "Ready", body = ServiceStatus), (status = 503, description = "Still loading", body = ErrorBody)))]
pub async fn ready(State(state): State<Arc<AppState>>) -> Result<Json<ServiceStatus>, ApiError> {
    match state.pool.model_version() {
        Some(v) => {
            Ok(Json(ServiceStatus { status: "ready".into(), model_version: Some(v.to_string()) }))
        }
        None => Err(ApiError::NotReady("the model is still loading".into())),
    }
}

/// Prometheus metrics: requests, latencies per route and per pipeline stage, queue depth,
/// jobs by state, stored scene bytes.
#[utoipa::path(get, path = "/metrics", tag = "service",
    responses((status = 200, description = "Prometheus text format", content_type = "text/plain")))]
pub async fn metrics(State(state): State<Arc<AppState>>) -> Result<Response, ApiError> {
    let shared = state.shared.clone();
    let (jobs_by_state, scene_bytes) = tokio::task::spawn_blocking(move || {
        (shared.jobs.count_by_state(), shared.scenes.total_bytes())
    })
    .await
    .map_err(ApiError::internal)?;
    let gauges = Gauges {
        queue_depth: state.pool.queue_depth(),
        queue_capacity: state.pool.queue_capacity(),
        jobs_by_state: jobs_by_state
            .map_err(|e| ApiError::internal(format!("job store: {e:#}")))?,
        scene_bytes,
        ready: state.pool.model_version().is_some(),
    };
    let text = state.shared.metrics.render(&gauges);
    Ok(([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], text).into_response())
}

/// The OpenAPI 3.1 document of this service.
#[utoipa::path(get, path = "/openapi.json", tag = "service",
    responses((status = 200, description = "OpenAPI document", content_type = "application/json")))]
pub async fn openapi() -> Json<utoipa::openapi::OpenApi> {
    Json(ApiDoc::openapi())
}
