//! Looking at what was found: each detection's chip and each frame's
//! preview (made by the worker, see [`crate::pipeline::pictures`]), the
//! flight's observations as JSON with their chip URLs and reviews, and a
//! reviewer's accept / reject, stored with the job and honoured by every
//! result and export.

use crate::error_code::ErrorCode;
use std::collections::HashMap;

use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::{Deserialize, Serialize};
use uuid::Uuid;

use super::error::{ApiError, Problem};
use super::extract::IdPath;
use super::AppState;
use crate::jobs::results::load_result;
use crate::jobs::review::{self, Reviews, Verdict};
use crate::jobs::{JobRecord, JobState};
use crate::pipeline::frame::FrameResult;
use crate::storage::StoredFileError;

/// One detection as a reviewer sees it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct ObservationView {
    pub job_id: Uuid,
    pub image: String,
    /// The detection's place in its frame's results (from 0): its key in
    /// the chip and review URLs.
    pub index: u32,
    pub marker_type: String,
    pub marker_id: Option<u32>,
    /// Pixel centre (top-left pixel's centre at 0,0).
    pub px_x: f64,
    pub px_y: f64,
    pub size_px: f64,
    pub confidence: f64,
    /// The surveyed point this detection is matched to, when the flight has
    /// a survey and the detection matches one.
    pub gcp_name: Option<String>,
    pub review: Verdict,
    /// A PNG crop around the detection with its outline and centre drawn.
    pub chip_url: String,
    /// PUT `{"verdict": ...}` here to accept or reject it.
    pub review_url: String,
}

/// Every detection of a flight's succeeded frames.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct ObservationList {
    pub flight_id: Uuid,
    /// Sorted by image, then by place in the frame's results.
    pub observations: Vec<ObservationView>,
}

/// A reviewer's word on one detection.
#[derive(Debug, Clone, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ReviewRequest {
    pub verdict: Verdict,
}

fn chip_url(job: Uuid, index: u32) -> String {
    format!("/v1/jobs/{job}/chips/{index}")
}

fn review_url(job: Uuid, index: u32) -> String {
    format!("/v1/jobs/{job}/observations/{index}")
}

fn view(
    job: &JobRecord,
    frame: &FrameResult,
    index: u32,
    reviews: &Reviews,
    names: &HashMap<(String, u64, u64), String>,
) -> ObservationView {
    let t = &frame.targets[index as usize];
    let d = &t.detection;
    ObservationView {
        job_id: job.id,
        image: frame.image.clone(),
        index,
        marker_type: d.marker_type.to_string(),
        marker_id: d.marker_id,
        px_x: d.center.0,
        px_y: d.center.1,
        size_px: d.size_px,
        confidence: d.confidence,
        gcp_name: names
            .get(&(
                frame.image.clone(),
                d.center.0.to_bits(),
                d.center.1.to_bits(),
            ))
            .cloned(),
        review: reviews.verdict(index),
        chip_url: chip_url(job.id, index),
        review_url: review_url(job.id, index),
    }
}

/// Every detection of a flight's succeeded frames, with its chip URL, its
/// review and, when the flight has a survey, the surveyed point it is
/// matched to (rejected detections included, so a rejection can be taken
/// back).
#[utoipa::path(
    get, path = "/v1/flights/{id}/observations", tag = "review",
    params(("id" = Uuid, Path, description = "Flight id")),
    responses(
        (status = 400, description = "Malformed id", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "The detections", body = ObservationList),
        (status = 404, description = "No such flight", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn flight_observations(
    State(state): State<AppState>,
    IdPath(id): IdPath,
) -> Result<Json<ObservationList>, ApiError> {
    let flight = state
        .store
        .flight(id)?
        .ok_or_else(|| ApiError::not_found("flight", id))?;
    let mut jobs: Vec<JobRecord> = state
        .store
        .flight_jobs(id)?
        .unwrap_or_default()
        .into_iter()
        .filter(|j| j.state == JobState::Succeeded)
        .collect();
    jobs.sort_by(|a, b| a.image.cmp(&b.image));
    let inner = state.clone();
    let list = tokio::task::spawn_blocking(move || -> Result<ObservationList, StoredFileError> {
        let mut read = Vec::with_capacity(jobs.len());
        for job in jobs {
            let frame = load_result(&inner.data, job.id)?;
            let reviews = review::load(&inner.data, job.id)?;
            read.push((job, frame, reviews));
        }
        let names = gcp_names(&inner, &flight, &read);
        let mut observations = Vec::new();
        for (job, frame, reviews) in &read {
            for index in 0..frame.targets.len() as u32 {
                observations.push(view(job, frame, index, reviews, &names));
            }
        }
        Ok(ObservationList {
            flight_id: id,
            observations,
        })
    })
    .await
    .map_err(|e| ApiError::internal("listing observations", e))?
    .map_err(|e| ApiError::internal("listing observations", e))?;
    Ok(Json(list))
}

/// The surveyed point each detection matches, keyed by image and centre;
/// empty without a (readable) survey.
fn gcp_names(
    state: &AppState,
    flight: &crate::jobs::FlightRecord,
    read: &[(JobRecord, FrameResult, Reviews)],
) -> HashMap<(String, u64, u64), String> {
    let survey = match crate::jobs::gcp::load_survey(&state.data, flight.id) {
        Ok(Some(stored)) => match stored.parse() {
            Ok(s) => s,
            Err(_) => return HashMap::new(),
        },
        _ => return HashMap::new(),
    };
    let frames: Vec<FrameResult> = read.iter().map(|(_, f, _)| f.clone()).collect();
    crate::jobs::gcp::matched_for(&frames, flight, &survey)
        .observations
        .into_iter()
        .map(|o| ((o.image, o.px.to_bits(), o.py.to_bits()), o.gcp_name))
        .collect()
}

/// The job's record if it succeeded, else the error to answer.
fn succeeded(state: &AppState, id: Uuid) -> Result<JobRecord, ApiError> {
    let job = state
        .store
        .job(id)?
        .ok_or_else(|| ApiError::not_found("job", id))?;
    if job.state != JobState::Succeeded {
        return Err(ApiError::new(
            ErrorCode::JobNotSucceeded,
            format!(
                "job {id} is {}; pictures exist once it has succeeded",
                job.state.as_str()
            ),
        ));
    }
    Ok(job)
}

async fn picture(
    data: &crate::storage::DataDir,
    path: std::path::PathBuf,
    media: &'static str,
    what: String,
) -> Result<Response, ApiError> {
    let (shared, from) = (data.clone(), path.clone());
    tokio::task::spawn_blocking(move || shared.bring_in(&from))
        .await
        .map_err(|e| ApiError::internal("reading a picture", e))?
        .map_err(|e| ApiError::internal("reading a picture from the shared files", e))?;
    match tokio::fs::read(&path).await {
        Ok(bytes) => Ok((
            [
                (header::CONTENT_TYPE, HeaderValue::from_static(media)),
                // A job's pictures never change once it has succeeded.
                (
                    header::CACHE_CONTROL,
                    HeaderValue::from_static("private, max-age=86400, immutable"),
                ),
            ],
            bytes,
        )
            .into_response()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            Err(ApiError::new(ErrorCode::NotFound, format!("no {what}")))
        }
        Err(e) => Err(ApiError::internal("reading a picture", e)),
    }
}

/// One detection's chip: a PNG crop around it (three times its size, at
/// least 96 px, enlarged to at least 128 px by whole pixels) with its
/// fitted outline in yellow and its reported centre as a red cross.
#[utoipa::path(
    get, path = "/v1/jobs/{id}/chips/{index}", tag = "review",
    params(("id" = Uuid, Path, description = "Job id"),
        ("index" = u32, Path, description = "The detection's place in the frame's results, from 0")),
    responses(
        (status = 400, description = "Malformed id or index", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "The chip", content_type = "image/png", body = Vec<u8>),
        (status = 404, description = "No such job or detection", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "The job has not succeeded", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_chip(
    State(state): State<AppState>,
    Path((id, index)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    let (id, index) = job_and_index(&id, &index)?;
    succeeded(&state, id)?;
    let path = state.data.pictures_dir(id).join(format!("{index}.png"));
    picture(
        &state.data,
        path,
        "image/png",
        format!("detection {index} in job {id}"),
    )
    .await
}

/// A frame's preview: reduced to at most 1280 px a side, every detection
/// circled and labelled.
#[utoipa::path(
    get, path = "/v1/jobs/{id}/preview", tag = "review",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 400, description = "Malformed id", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "The preview", content_type = "image/jpeg", body = Vec<u8>),
        (status = 404, description = "No such job", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "The job has not succeeded", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_preview(
    State(state): State<AppState>,
    IdPath(id): IdPath,
) -> Result<Response, ApiError> {
    succeeded(&state, id)?;
    let path = state.data.pictures_dir(id).join("preview.jpg");
    picture(
        &state.data,
        path,
        "image/jpeg",
        format!("preview of job {id}"),
    )
    .await
}

/// Parses the `{id}` and `{index}` of a route.
fn job_and_index(id: &str, index: &str) -> Result<(Uuid, u32), ApiError> {
    let id: Uuid = id.parse().map_err(|_| {
        ApiError::new(
            ErrorCode::InvalidId,
            format!("{id:?} is not a job id (a UUID)"),
        )
        .with_field("id")
    })?;
    let index: u32 = index.parse().map_err(|_| {
        ApiError::new(
            ErrorCode::InvalidIndex,
            format!("{index:?} is not a detection's place in its frame (0, 1, 2, ...)"),
        )
        .with_field("index")
    })?;
    Ok((id, index))
}

/// Serialises reviews' read-modify-write (one server owns the data
/// folder; see `DataDir::open`).
static REVIEW_LOCK: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// Accepts or rejects one detection (`unreviewed` takes the word back).
/// A rejected detection leaves the job's and flight's results and every
/// GCP export; `accepted_only=true` on those keeps the accepted ones only.
#[utoipa::path(
    put, path = "/v1/jobs/{id}/observations/{index}", tag = "review",
    params(("id" = Uuid, Path, description = "Job id"),
        ("index" = u32, Path, description = "The detection's place in the frame's results, from 0")),
    request_body(content = ReviewRequest, content_type = "application/json"),
    responses(
        (status = 400, description = "Malformed id, index or body", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "The detection with its review", body = ObservationView),
        (status = 404, description = "No such job or detection", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "The job has not succeeded", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn put_review(
    State(state): State<AppState>,
    Path((id, index)): Path<(String, String)>,
    body: Bytes,
) -> Result<Json<ObservationView>, ApiError> {
    let (id, index) = job_and_index(&id, &index)?;
    let request: ReviewRequest = serde_json::from_slice(&body).map_err(|e| {
        ApiError::new(ErrorCode::InvalidBody,
            format!(
                "the body must be {{\"verdict\": \"accepted\" | \"rejected\" | \"unreviewed\"}}: {e}"
            ),
        )
        .with_field("verdict")
    })?;
    let job = succeeded(&state, id)?;
    let _guard = REVIEW_LOCK.lock().await;
    let inner = state.clone();
    let answer = tokio::task::spawn_blocking(move || -> Result<ObservationView, ApiError> {
        let frame = load_result(&inner.data, job.id)
            .map_err(|e| ApiError::internal("reading a result", e))?;
        if index as usize >= frame.targets.len() {
            return Err(ApiError::new(
                ErrorCode::NotFound,
                format!(
                    "job {id} has {} detection(s); there is no detection {index}",
                    frame.targets.len()
                ),
            ));
        }
        let mut reviews =
            review::load(&inner.data, id).map_err(|e| ApiError::internal("reading reviews", e))?;
        reviews.set(index, request.verdict);
        review::save(&inner.data, id, &reviews)
            .map_err(|e| ApiError::internal("storing a review", e))?;
        Ok(view(&job, &frame, index, &reviews, &HashMap::new()))
    })
    .await
    .map_err(|e| ApiError::internal("storing a review", e))??;
    Ok(Json(answer))
}
