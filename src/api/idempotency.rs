//! `Idempotency-Key` on submissions: a client on a flaky link can retry an
//! upload with the same key and gets the first request's answer (201, the
//! same flight and jobs, `Idempotent-Replayed: true`) without a second
//! job. The key is stored with the jobs in the same transaction; keys are
//! scoped to the client's credentials, and a key reused for a different
//! request (another route or query) is refused.

use crate::error_code::ErrorCode;
use axum::extract::Request;
use axum::http::{header, HeaderMap, HeaderName, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use futures_util::StreamExt;
use md5::{Digest, Md5};

use super::error::ApiError;
use super::views::{FlightSubmitted, FlightView, JobView};
use super::AppState;
use crate::jobs::{IdemKey, IdemRecord};

pub const HEADER: HeaderName = HeaderName::from_static("idempotency-key");
const REPLAYED: HeaderName = HeaderName::from_static("idempotent-replayed");

/// What a replay answers with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Answer {
    /// `POST /v1/jobs`: the job.
    Job,
    /// Flight submissions: the flight and the request's jobs.
    Flight,
}

/// The request's key, if it sent one; a malformed one is a 400.
pub fn key(
    headers: &HeaderMap,
    route: &str,
    query: Option<&str>,
) -> Result<Option<IdemKey>, ApiError> {
    let Some(value) = headers.get(HEADER) else {
        return Ok(None);
    };
    let bad = || {
        ApiError::new(
            ErrorCode::InvalidIdempotencyKey,
            "Idempotency-Key must be 1 to 255 visible ASCII characters (a UUID is a good key)",
        )
        .with_field("Idempotency-Key")
    };
    let value = value.to_str().map_err(|_| bad())?;
    if value.is_empty() || value.len() > 255 || !value.bytes().all(|b| (0x21..=0x7e).contains(&b)) {
        return Err(bad());
    }
    // Scoped to the credentials: one client's key never replays another's.
    let scope: String = headers
        .get(header::AUTHORIZATION)
        .map(|a| {
            Md5::digest(a.as_bytes())
                .iter()
                .map(|b| format!("{b:02x}"))
                .collect()
        })
        .unwrap_or_else(|| "-".into());
    Ok(Some(IdemKey {
        key: format!("{scope}:{value}"),
        request: format!("POST {route}?{}", query.unwrap_or("")),
    }))
}

/// Runs a submission under its key: answers with the recorded result when
/// the key was seen, else runs `submit` (which records the key with its
/// jobs); when another request with the key committed first meanwhile,
/// answers with that one's result.
pub async fn run<F>(
    state: &AppState,
    req: Request,
    route: &str,
    query: Option<&str>,
    answer: Answer,
    submit: impl FnOnce(Request, Option<IdemKey>) -> F,
) -> Result<Response, ApiError>
where
    F: std::future::Future<Output = Result<Response, ApiError>>,
{
    let idem = match key(req.headers(), route, query) {
        Ok(idem) => idem,
        Err(e) => return drained(req, Err(e)).await,
    };
    if let Some(k) = &idem {
        if let Some(answer) = replay(state, k, answer).await.transpose() {
            return drained(req, answer).await;
        }
    }
    match (submit(req, idem.clone()).await, &idem) {
        (Err(e), Some(k)) if e.code == ErrorCode::IdempotencyKeyTaken => {
            replay(state, k, answer).await?.ok_or(e)
        }
        (result, _) => result,
    }
}

/// Reads a request's body to its end (dropping it) before answering, so a
/// client still sending gets the answer instead of a reset connection.
async fn drained(req: Request, answer: Result<Response, ApiError>) -> Result<Response, ApiError> {
    let mut body = req.into_body().into_data_stream();
    while let Some(Ok(_)) = body.next().await {}
    answer
}

/// The first answer for this key, if a request with it was recorded.
pub async fn replay(
    state: &AppState,
    idem: &IdemKey,
    answer: Answer,
) -> Result<Option<Response>, ApiError> {
    let store = state.store.clone();
    let key = idem.key.clone();
    let Some(record) = tokio::task::spawn_blocking(move || store.idempotent(&key))
        .await
        .map_err(|e| ApiError::internal("reading the idempotency key", e))??
    else {
        return Ok(None);
    };
    if record.request != idem.request {
        return Err(ApiError::new(ErrorCode::IdempotencyKeyReused,
            format!(
                "this Idempotency-Key was used for another request ({}); use a new key per submission",
                record.request
            ),
        )
        .with_field("Idempotency-Key"));
    }
    Ok(Some(answer_for(state, &record, answer)?))
}

fn answer_for(state: &AppState, record: &IdemRecord, answer: Answer) -> Result<Response, ApiError> {
    let gone = || {
        ApiError::new(
            ErrorCode::IdempotentResultGone,
            "the submission this Idempotency-Key made has been deleted",
        )
    };
    let mut jobs: Vec<JobView> = Vec::with_capacity(record.jobs.len());
    for id in &record.jobs {
        if let Some(job) = state.store.job(*id)? {
            jobs.push(JobView::new(&job));
        }
    }
    let mut response = match answer {
        Answer::Job => {
            let job = jobs.into_iter().next().ok_or_else(gone)?;
            let location = job.links.self_.clone();
            (
                StatusCode::CREATED,
                [(header::LOCATION, location)],
                Json(job),
            )
                .into_response()
        }
        Answer::Flight => {
            let flight = state.store.flight(record.flight)?.ok_or_else(gone)?;
            let all = state.store.flight_jobs(record.flight)?.unwrap_or_default();
            let body = FlightSubmitted {
                flight: FlightView::new(&flight, &all),
                jobs,
                skipped: Vec::new(),
            };
            let location = body.flight.links.self_.clone();
            (
                StatusCode::CREATED,
                [(header::LOCATION, location)],
                Json(body),
            )
                .into_response()
        }
    };
    response
        .headers_mut()
        .insert(REPLAYED, HeaderValue::from_static("true"));
    Ok(response)
}
