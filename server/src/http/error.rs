//! The service's one error type and status table. Every non-2xx answer, including axum's own
//! rejections (bad JSON, wrong content type, a body over the limit, a bad path parameter),
//! unknown routes and wrong methods, is `{"error": "...", "error_type": "..."}`
//! (`proto::api::ErrorBody`).

use axum::Json;
use axum::extract::multipart::{MultipartError, MultipartRejection};
use axum::extract::rejection::{BytesRejection, JsonRejection, PathRejection};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use inssplat_proto::api::ErrorBody;

use crate::worker::{SubmitError, TaskError};

/// An error answer; the message names the input at fault.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// 400: unreadable request (bad JSON syntax, bad multipart, malformed id).
    #[error("{0}")]
    BadRequest(String),
    /// 401: missing or wrong API key (the message never repeats the key sent).
    #[error("a valid API key is required: send `Authorization: Bearer <key>`")]
    Unauthorized,
    #[error("{0}")]
    NotFound(String),
    #[error("{0}")]
    MethodNotAllowed(String),
    #[error("{0}")]
    PayloadTooLarge(String),
    #[error("{0}")]
    UnsupportedMediaType(String),
    /// 422: well-formed but unusable input.
    #[error("{0}")]
    Validation(String),
    /// 429, with `Retry-After`.
    #[error("{message}")]
    Overloaded { message: String, retry_after_s: u64 },
    #[error("{0}")]
    Internal(String),
    /// 503: warming up or shutting down.
    #[error("{0}")]
    NotReady(String),
    #[error("{0}")]
    Timeout(String),
}

impl ApiError {
    pub fn status(&self) -> StatusCode {
        match self {
            Self::BadRequest(_) => StatusCode::BAD_REQUEST,
            Self::Unauthorized => StatusCode::UNAUTHORIZED,
            Self::NotFound(_) => StatusCode::NOT_FOUND,
            Self::MethodNotAllowed(_) => StatusCode::METHOD_NOT_ALLOWED,
            Self::PayloadTooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            Self::UnsupportedMediaType(_) => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            Self::Validation(_) => StatusCode::UNPROCESSABLE_ENTITY,
            Self::Overloaded { .. } => StatusCode::TOO_MANY_REQUESTS,
            Self::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
            Self::NotReady(_) => StatusCode::SERVICE_UNAVAILABLE,
            Self::Timeout(_) => StatusCode::GATEWAY_TIMEOUT,
        }
    }

    /// The snake_case `error_type`.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::BadRequest(_) => "bad_request",
            Self::Unauthorized => "unauthorized",
            Self::NotFound(_) => "not_found",
            Self::MethodNotAllowed(_) => "method_not_allowed",
            Self::PayloadTooLarge(_) => "payload_too_large",
            Self::UnsupportedMediaType(_) => "unsupported_media_type",
            Self::Validation(_) => "validation",
            Self::Overloaded { .. } => "overloaded",
            Self::Internal(_) => "internal",
            Self::NotReady(_) => "not_ready",
            Self::Timeout(_) => "timeout",
        }
    }

    /// An error for an axum rejection with `status`, keeping its message.
    fn from_status(status: StatusCode, message: String) -> Self {
        match status {
            StatusCode::PAYLOAD_TOO_LARGE => Self::PayloadTooLarge(message),
            StatusCode::UNSUPPORTED_MEDIA_TYPE => Self::UnsupportedMediaType(message),
            StatusCode::UNPROCESSABLE_ENTITY => Self::Validation(message),
            s if s.is_client_error() => Self::BadRequest(message),
            _ => Self::Internal(message),
        }
    }

    pub fn internal(e: impl std::fmt::Display) -> Self {
        Self::Internal(e.to_string())
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        if let Self::Internal(message) = &self {
            tracing::error!("internal error: {message}");
        }
        let status = self.status();
        let body = Json(ErrorBody { error: self.to_string(), error_type: self.kind().to_string() });
        match &self {
            Self::Overloaded { retry_after_s, .. } => {
                (status, [(header::RETRY_AFTER, retry_after_s.to_string())], body).into_response()
            }
            Self::Unauthorized => {
                (status, [(header::WWW_AUTHENTICATE, "Bearer".to_string())], body).into_response()
            }
            _ => (status, body).into_response(),
        }
    }
}

impl From<JsonRejection> for ApiError {
    fn from(r: JsonRejection) -> Self {
        Self::from_status(r.status(), r.body_text())
    }
}

impl From<MultipartRejection> for ApiError {
    fn from(r: MultipartRejection) -> Self {
        match r {
            MultipartRejection::InvalidBoundary(_) => Self::UnsupportedMediaType(
                "expected a `multipart/form-data` body with a boundary".into(),
            ),
            other => Self::from_status(other.status(), other.body_text()),
        }
    }
}

impl From<MultipartError> for ApiError {
    fn from(e: MultipartError) -> Self {
        Self::from_status(e.status(), format!("reading the multipart body: {}", e.body_text()))
    }
}

impl From<BytesRejection> for ApiError {
    fn from(r: BytesRejection) -> Self {
        Self::from_status(r.status(), r.body_text())
    }
}

impl From<PathRejection> for ApiError {
    fn from(r: PathRejection) -> Self {
        Self::from_status(r.status(), r.body_text())
    }
}

impl From<SubmitError> for ApiError {
    fn from(e: SubmitError) -> Self {
        match e {
            SubmitError::Overloaded { retry_after_s, .. } => {
                Self::Overloaded { message: e.to_string(), retry_after_s }
            }
            SubmitError::NotReady | SubmitError::Stopped => Self::NotReady(e.to_string()),
        }
    }
}

impl From<TaskError> for ApiError {
    fn from(e: TaskError) -> Self {
        match e {
            TaskError::Invalid(m) => Self::Validation(m),
            TaskError::Unsupported(m) => Self::UnsupportedMediaType(m),
            TaskError::Internal(m) => Self::Internal(m),
        }
    }
}
