//! Operations routes: liveness, readiness and Prometheus metrics.

use crate::error_code::ErrorCode;
use std::sync::atomic::Ordering;

use axum::extract::State;
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Serialize;

use super::error::{ApiError, Problem};
use super::AppState;

/// A health answer.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct Health {
    /// `ok`.
    pub status: String,
    /// Jobs waiting and running.
    pub queued: usize,
    pub running: usize,
}

/// The process is up and answering.
#[utoipa::path(get, path = "/livez", tag = "operations", security(()),
    responses((status = 200, description = "Alive", body = Health)))]
pub async fn livez(State(state): State<AppState>) -> Json<Health> {
    // Alive whatever the store says; readiness checks the store.
    let stats = state.store.stats().unwrap_or_default();
    Json(Health {
        status: "ok".into(),
        queued: stats.queued,
        running: stats.running,
    })
}

/// The service takes work: the store is open, workers run, and it is not
/// shutting down.
#[utoipa::path(get, path = "/readyz", tag = "operations", security(()),
    responses(
        (status = 200, description = "Ready", body = Health),
        (status = 503, description = "Starting, shutting down, or the job store does not answer", body = Problem, content_type = "application/problem+json"),
    ))]
pub async fn readyz(State(state): State<AppState>) -> Result<Json<Health>, ApiError> {
    if *state.shutdown.borrow() || !state.ready.load(Ordering::SeqCst) {
        return Err(ApiError::new(
            ErrorCode::NotReady,
            "the service is starting or shutting down",
        )
        .with_header(header::RETRY_AFTER, "5"));
    }
    let stats = state.store.stats().map_err(|e| {
        ApiError::new(
            ErrorCode::NotReady,
            format!("the job store does not answer: {e}"),
        )
        .with_header(header::RETRY_AFTER, "5")
    })?;
    Ok(Json(Health {
        status: "ok".into(),
        queued: stats.queued,
        running: stats.running,
    }))
}

/// Prometheus metrics (OpenMetrics text).
#[utoipa::path(get, path = "/metrics", tag = "operations",
    responses((status = 200, description = "Metrics", content_type = "application/openmetrics-text", body = String)))]
pub async fn metrics(State(state): State<AppState>) -> Response {
    let m = &state.metrics;
    if let Ok(stats) = state.store.stats() {
        m.queue_depth.set(stats.queued as i64);
        m.jobs_running.set(stats.running as i64);
    }
    m.budget_in_use_bytes.set(state.budget.in_use() as i64);
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/openmetrics-text; version=1.0.0; charset=utf-8"),
        )],
        m.render(),
    )
        .into_response()
}
