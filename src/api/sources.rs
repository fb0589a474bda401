//! Frames named by `s3://` sources instead of uploaded: a JSON body
//! `{"sources": ["s3://bucket/key", "s3://bucket/prefix/"], "results_to":
//! "s3://bucket/out/"}`. Every source is checked against the object store
//! before anything is recorded (a missing bucket or object, an empty
//! prefix or refused credentials fail the request); each image object then
//! becomes a job that starts `fetching` and is queued once its frame is in
//! the spool (see [`crate::jobs::fetch`]).

use crate::error_code::ErrorCode;
use axum::extract::Request;
use axum::http::header;
use futures_util::StreamExt;
use serde::Deserialize;

use super::error::ApiError;
use super::upload::{self, Target};
use super::AppState;
use crate::jobs::model::JobError;
use crate::jobs::{FlightRecord, IdemKey, JobRecord, NewJob};
use crate::storage::s3::{ObjectRef, S3Error, S3Url};
use crate::storage::spool::sanitize_name;

/// Largest JSON body of a source request.
const MAX_BODY_BYTES: usize = 1 << 20;
/// Sources checked against the object store at once.
const RESOLVE_CONCURRENCY: usize = 8;

/// Frames in object storage, for `POST /v1/flights` and
/// `POST /v1/flights/{id}/frames` with `Content-Type: application/json`.
#[derive(Debug, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SourceRequest {
    /// `s3://bucket/key` for one frame, `s3://bucket/prefix/` (trailing
    /// slash) for every .jpg/.jpeg/.tif/.tiff/.png object under a prefix.
    /// The server's configuration picks the endpoint and credentials.
    pub sources: Vec<String>,
    /// `s3://bucket/prefix/` to write `results.csv` and `results.geojson`
    /// to when the flight finishes (new flights only).
    #[serde(default)]
    pub results_to: Option<String>,
}

/// A checked source request, ready to record.
pub struct Sourced {
    pub jobs: Vec<NewJob>,
    pub skipped: Vec<String>,
    pub results_to: Option<String>,
}

/// True when the request carries a JSON body.
pub fn is_json(req: &Request) -> bool {
    req.headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.split(';').next())
        .is_some_and(|m| {
            let m = m.trim().to_ascii_lowercase();
            m == "application/json" || m.ends_with("+json")
        })
}

/// Reads a source request and checks every source against the store.
pub async fn receive(
    state: &AppState,
    req: Request,
    allow_results_to: bool,
) -> Result<Sourced, ApiError> {
    upload::check_free_space(state).await?;
    let body = axum::body::to_bytes(req.into_body(), MAX_BODY_BYTES)
        .await
        .map_err(|_| {
            ApiError::new(
                ErrorCode::RequestTooLarge,
                format!("a source request is at most {MAX_BODY_BYTES} bytes of JSON"),
            )
        })?;
    let request: SourceRequest = serde_json::from_slice(&body).map_err(|e| {
        ApiError::new(
            ErrorCode::InvalidJson,
            format!(
                "bad source request: {e}; expected {{\"sources\": [\"s3://bucket/key\", ...]}}"
            ),
        )
    })?;
    if request.sources.is_empty() {
        return Err(
            ApiError::new(ErrorCode::InvalidSource, "\"sources\" names no frame")
                .with_field("sources"),
        );
    }
    let results_to =
        match request.results_to {
            Some(_) if !allow_results_to => return Err(ApiError::new(
                ErrorCode::InvalidSource,
                "results_to is set when a flight is created; frames added later use the flight's",
            )
            .with_field("results_to")),
            Some(raw) => Some(checked_results_to(state, &raw)?),
            None => None,
        };
    let mut urls = Vec::with_capacity(request.sources.len());
    for (i, raw) in request.sources.iter().enumerate() {
        urls.push(S3Url::parse(raw).map_err(|e| source_error(e, i))?);
    }
    let s3 = state.s3.clone();
    let resolved: Vec<_> = futures_util::stream::iter(urls.iter().cloned())
        .map(|url| {
            let s3 = s3.clone();
            async move { s3.resolve(&url).await }
        })
        .buffered(RESOLVE_CONCURRENCY)
        .collect()
        .await;
    let limits = &state.limits;
    let mut jobs = Vec::new();
    let mut skipped = Vec::new();
    for (i, (url, found)) in urls.iter().zip(resolved).enumerate() {
        let found = found.map_err(|e| source_error(e, i))?;
        skipped.extend(
            found
                .skipped
                .iter()
                .map(|k| format!("s3://{}/{k}", url.bucket())),
        );
        for object in found.objects {
            if jobs.len() == limits.max_frames_per_request {
                return Err(ApiError::new(
                    ErrorCode::TooManyFrames,
                    format!(
                        "the sources name more than {} frames (--max-frames-per-request)",
                        limits.max_frames_per_request
                    ),
                ));
            }
            jobs.push(new_job(url, object, limits.max_frame_bytes));
        }
    }
    Ok(Sourced {
        jobs,
        skipped,
        results_to,
    })
}

/// Records the jobs of a source request (names unique in the flight).
pub async fn commit(
    state: &AppState,
    jobs: Vec<NewJob>,
    target: Target,
    idem: Option<IdemKey>,
) -> Result<(FlightRecord, Vec<JobRecord>), ApiError> {
    let (store, max) = (state.store.clone(), state.limits.max_frames_per_flight);
    tokio::task::spawn_blocking(move || {
        let names = jobs.iter().map(|j| j.image.as_str());
        upload::check_names(&*store, &target, names, max)?;
        upload::record(&*store, &jobs, target, idem.as_ref(), max)
    })
    .await
    .map_err(|e| ApiError::internal("recording the jobs", e))?
}

/// A job for one object; one too large for a frame is created failed.
fn new_job(url: &S3Url, object: ObjectRef, max_frame_bytes: u64) -> NewJob {
    let name = match url {
        // Under a prefix, the key below it: unique within the prefix.
        S3Url::Prefix { prefix, .. } => {
            let rel = object
                .key
                .strip_prefix(prefix.as_str())
                .unwrap_or(&object.key);
            rel.chars().filter(|c| !c.is_control()).collect()
        }
        S3Url::Object { .. } => sanitize_name(&object.key).unwrap_or_else(|| object.key.clone()),
    };
    let rejected = (object.size > max_frame_bytes).then(|| JobError {
        code: ErrorCode::FrameTooLarge,
        message: S3Error::TooLarge {
            url: object.url(),
            bytes: object.size,
            limit: max_frame_bytes,
        }
        .to_string(),
    });
    NewJob {
        id: uuid::Uuid::now_v7(),
        image: name,
        ext: "none".into(),
        bytes: object.size,
        rejected,
        source: Some((object.url(), object.etag)),
    }
}

/// `results_to` must be a prefix (trailing `/`) in an allowed bucket.
pub fn checked_results_to(state: &AppState, raw: &str) -> Result<String, ApiError> {
    let field = |e: ApiError| e.with_field("results_to");
    match S3Url::parse(raw) {
        Ok(url @ S3Url::Prefix { .. }) => {
            let allowed = &state.s3.config().allowed_buckets;
            if !allowed.is_empty() && !allowed.iter().any(|b| b == url.bucket()) {
                return Err(field(s3_problem(S3Error::BucketNotAllowed(
                    url.bucket().to_string(),
                ))));
            }
            Ok(url.to_string())
        }
        Ok(_) => Err(field(ApiError::new(
            ErrorCode::InvalidSource,
            format!("results_to {raw:?} must be a prefix ending in '/'"),
        ))),
        Err(e) => Err(field(s3_problem(e))),
    }
}

fn source_error(e: S3Error, index: usize) -> ApiError {
    s3_problem(e).with_field(format!("sources[{index}]"))
}

/// The problem for a source that cannot be used: its code carries the
/// status (names the client can fix are 422, 403 outside the allow-list;
/// the store refusing the server's credentials or being unreachable 502).
pub fn s3_problem(e: S3Error) -> ApiError {
    ApiError::new(e.code(), e.to_string())
}
