//! Middleware and fallbacks: the API key check (bearer token, constant-time comparison, the
//! key never logged), the request timeout (504), the access log and request metrics keyed by
//! route template, and JSON answers for unknown routes and wrong methods.

use std::sync::Arc;
use std::time::Instant;

use axum::extract::{MatchedPath, Request, State};
use axum::http::{Method, Uri, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use subtle::ConstantTimeEq;

use super::{ApiError, AppState};

/// Refuses /v1 requests without the configured API key.
pub async fn auth(State(state): State<Arc<AppState>>, req: Request, next: Next) -> Response {
    if let Some(key) = &state.api_key {
        let sent = req
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "));
        let ok = sent.is_some_and(|s| bool::from(s.as_bytes().ct_eq(key.as_bytes())));
        if !ok {
            return ApiError::Unauthorized.into_response();
        }
    }
    next.run(req).await
}

/// Answers 504 when the handler takes longer than the configured timeout (the work it
/// queued is then dropped before it starts, its requester being gone).
pub async fn timeout(State(state): State<Arc<AppState>>, req: Request, next: Next) -> Response {
    let limit = state.request_timeout;
    match tokio::time::timeout(limit, next.run(req)).await {
        Ok(response) => response,
        Err(_) => ApiError::Timeout(format!("the request took longer than {} s", limit.as_secs()))
            .into_response(),
    }
}

/// Logs each request and counts it under its route template.
pub async fn observe(State(state): State<Arc<AppState>>, req: Request, next: Next) -> Response {
    let start = Instant::now();
    let method = req.method().clone();
    let route =
        req.extensions().get::<MatchedPath>().map_or("unmatched", MatchedPath::as_str).to_string();
    let response = next.run(req).await;
    record(&state, &method, &route, &response, start);
    response
}

fn record(state: &AppState, method: &Method, route: &str, response: &Response, start: Instant) {
    let seconds = start.elapsed().as_secs_f64();
    let status = response.status().as_u16();
    state.shared.metrics.record_request(method.as_str(), route, status, seconds);
    tracing::info!("{method} {route} {status} {:.1} ms", seconds * 1e3);
}

pub async fn not_found(State(state): State<Arc<AppState>>, method: Method, uri: Uri) -> Response {
    let start = Instant::now();
    let path: String = uri.path().chars().take(200).collect();
    let response =
        ApiError::NotFound(format!("no route {method} {}", path.escape_debug())).into_response();
    record(&state, &method, "unmatched", &response, start);
    response
}

pub async fn method_not_allowed(method: Method, uri: Uri) -> ApiError {
    let path: String = uri.path().chars().take(200).collect();
    ApiError::MethodNotAllowed(format!("{method} is not allowed on {}", path.escape_debug()))
}
