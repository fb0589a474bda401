//! Errors as `application/problem+json` (RFC 9457). Every failure path of
//! the API (handlers, extractors, unknown routes, wrong methods, auth) ends
//! here, with a stable machine-readable `code`. Internal details are logged,
//! not returned.

use axum::extract::rejection::{PathRejection, QueryRejection};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde::Serialize;

pub use crate::error_code::ErrorCode;

/// The media type of problem documents.
pub const PROBLEM_JSON: &str = "application/problem+json";

/// A problem document.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Problem {
    /// `urn:gcp-tagger:problem:{code}`.
    #[serde(rename = "type")]
    pub type_: String,
    /// Short summary of the kind of problem (the code's title).
    pub title: String,
    /// HTTP status code.
    pub status: u16,
    /// What went wrong in this request, naming the field, part or file.
    pub detail: String,
    /// Stable machine-readable code; each has one status (see `ErrorCode`).
    pub code: ErrorCode,
    /// The request field or parameter at fault, when there is one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub field: Option<String>,
}

/// An API error: a stable code (which carries the status) and a human
/// detail.
#[derive(Debug, Clone)]
pub struct ApiError {
    pub code: ErrorCode,
    pub detail: String,
    pub field: Option<String>,
    /// Extra headers (`WWW-Authenticate`, `Allow`, `Retry-After`).
    pub headers: Vec<(header::HeaderName, HeaderValue)>,
}

impl ApiError {
    pub fn new(code: ErrorCode, detail: impl Into<String>) -> ApiError {
        ApiError {
            code,
            detail: detail.into(),
            field: None,
            headers: Vec::new(),
        }
    }

    pub fn with_field(mut self, field: impl Into<String>) -> ApiError {
        self.field = Some(field.into());
        self
    }

    pub fn with_header(mut self, name: header::HeaderName, value: &str) -> ApiError {
        if let Ok(v) = HeaderValue::from_str(value) {
            self.headers.push((name, v));
        }
        self
    }

    pub fn not_found(what: &str, id: impl std::fmt::Display) -> ApiError {
        ApiError::new(ErrorCode::NotFound, format!("no {what} {id}"))
    }

    /// A failure of ours: logged with its cause, reported without it.
    pub fn internal(context: &str, cause: impl std::fmt::Display) -> ApiError {
        tracing::error!(error = %cause, "{context}");
        ApiError::new(
            ErrorCode::Internal,
            format!("{context}; the server log has the cause"),
        )
    }

    /// The HTTP status of this error's code.
    pub fn status(&self) -> StatusCode {
        StatusCode::from_u16(self.code.status()).expect("error codes carry valid statuses")
    }

    pub fn problem(&self) -> Problem {
        Problem {
            type_: format!("urn:gcp-tagger:problem:{}", self.code),
            title: self.code.title().to_string(),
            status: self.code.status(),
            detail: self.detail.clone(),
            code: self.code,
            field: self.field.clone(),
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = serde_json::to_vec(&self.problem()).expect("problems serialize");
        let mut response = (
            self.status(),
            [(header::CONTENT_TYPE, HeaderValue::from_static(PROBLEM_JSON))],
            body,
        )
            .into_response();
        for (name, value) in self.headers {
            response.headers_mut().insert(name, value);
        }
        response
    }
}

impl From<PathRejection> for ApiError {
    fn from(r: PathRejection) -> ApiError {
        ApiError::new(
            ErrorCode::InvalidPath,
            format!("bad path parameter: {}", r.body_text()),
        )
    }
}

impl From<QueryRejection> for ApiError {
    fn from(r: QueryRejection) -> ApiError {
        ApiError::new(
            ErrorCode::InvalidQuery,
            format!("bad query string: {}", r.body_text()),
        )
    }
}

impl From<crate::jobs::StoreError> for ApiError {
    fn from(e: crate::jobs::StoreError) -> ApiError {
        match e {
            crate::jobs::StoreError::KeyTaken => ApiError::new(
                ErrorCode::IdempotencyKeyTaken,
                "another request with this Idempotency-Key was recorded first",
            ),
            e @ crate::jobs::StoreError::DuplicateImage(_) => {
                ApiError::new(ErrorCode::DuplicateImage, e.to_string())
            }
            e @ crate::jobs::StoreError::TooManyFrames { .. } => {
                ApiError::new(ErrorCode::TooManyFrames, e.to_string())
            }
            e => ApiError::internal("the job store failed", e),
        }
    }
}

impl From<crate::pipeline::frame::InvalidSetting> for ApiError {
    fn from(e: crate::pipeline::frame::InvalidSetting) -> ApiError {
        ApiError::new(ErrorCode::InvalidParameter, e.to_string()).with_field(e.field)
    }
}

/// Unknown routes.
pub async fn not_found(uri: axum::http::Uri) -> ApiError {
    ApiError::new(ErrorCode::RouteNotFound, format!("no route {}", uri.path()))
}

/// Known routes called with a method they do not take.
pub async fn method_not_allowed(method: axum::http::Method, uri: axum::http::Uri) -> ApiError {
    ApiError::new(
        ErrorCode::MethodNotAllowed,
        format!("{} does not take {method}", uri.path()),
    )
}
