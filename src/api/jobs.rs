//! `/v1/jobs`: one frame in, its state, its results, cancel and delete.

use crate::error_code::ErrorCode;
use axum::extract::{RawQuery, Request, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use uuid::Uuid;

use super::error::{ApiError, Problem};
use super::extract::{ApiQuery, IdPath};
use super::idempotency::{self, Answer};
use super::sources::{self, SourceRequest};
use super::upload::{self, Expect, Target};
use super::views::*;
use super::{flights::checked_params, results, watch, AppState};
use crate::jobs::params::DetectionQuery;
use crate::jobs::review::Selection;
use crate::jobs::IdemKey;
use crate::jobs::{JobFilter, JobRecord, JobState};
use crate::pipeline::output::Format;

/// A frame as a multipart part.
#[derive(utoipa::ToSchema)]
#[allow(dead_code)] // documents the request body
pub struct FrameUpload {
    /// The frame (JPEG, TIFF/GeoTIFF, PNG); the part's file name names it.
    #[schema(value_type = String, format = Binary)]
    frame: Vec<u8>,
}

/// Submits one frame: a raw body (`curl --data-binary @DJI_0001.JPG
/// -H 'Content-Type: image/jpeg' '.../v1/jobs?name=DJI_0001.JPG'`) or a
/// multipart form with one file part (`curl -F frame=@DJI_0001.JPG`).
/// The job belongs to a new flight of one frame.
#[utoipa::path(
    post, path = "/v1/jobs", tag = "jobs",
    params(DetectionQuery,
        ("name" = Option<String>, Query, description = "Name of the frame in results (raw bodies; multipart parts carry their file name)."),
        ("Idempotency-Key" = Option<String>, Header, description = "Retry-safe submission: a repeated key answers with the first request's job and creates nothing")),
    request_body(content(
        (FrameUpload = "multipart/form-data"),
        (Vec<u8> = "application/octet-stream"),
        (Vec<u8> = "image/jpeg"),
        (Vec<u8> = "image/tiff"),
        (Vec<u8> = "image/png"),
        (SourceRequest = "application/json"),
    )),
    responses(
        (status = 201, description = "Job created and queued", body = JobView,
            headers(("Location" = String, description = "The job's URL"))),
        (status = 400, description = "Malformed request", body = Problem, content_type = "application/problem+json"),
        (status = 413, description = "Frame or request too large", body = Problem, content_type = "application/problem+json"),
        (status = 415, description = "Not an image, or an unsupported body type", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Invalid detection parameter", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn submit_job(
    State(state): State<AppState>,
    RawQuery(query): RawQuery,
    req: Request,
) -> Result<Response, ApiError> {
    let (st, q) = (state.clone(), query.clone());
    idempotency::run(
        &state,
        req,
        "/v1/jobs",
        query.as_deref(),
        Answer::Job,
        |req, key| submit_job_inner(st, q, req, key),
    )
    .await
}

async fn submit_job_inner(
    state: AppState,
    query: Option<String>,
    req: Request,
    idem: Option<IdemKey>,
) -> Result<Response, ApiError> {
    let (params, extras) = checked_params(query.as_deref(), &["name"]).await?;
    if sources::is_json(&req) {
        // One frame named in object storage: `{"sources": ["s3://b/key"]}`.
        let sourced = sources::receive(&state, req, false).await?;
        if sourced.jobs.len() != 1 {
            return Err(ApiError::new(
                ErrorCode::ExpectedOneFrame,
                format!(
                    "the sources name {} frames; a job is one frame (POST /v1/flights takes many)",
                    sourced.jobs.len()
                ),
            )
            .with_field("sources"));
        }
        let target = Target::NewFlight(Box::new(params), None);
        let (_, jobs) = sources::commit(&state, sourced.jobs, target, idem).await?;
        return Ok(created(&jobs[0]));
    }
    let upload = upload::receive(&state, req, Expect::One, extras.name).await?;
    if let Some(Err(e)) = upload.parts.first().map(|p| &p.content) {
        return Err(ApiError::new(e.code, e.message.clone()));
    }
    let (store, data) = (state.store.clone(), state.data.clone());
    let (_, jobs) = tokio::task::spawn_blocking(move || {
        upload::commit(
            &*store,
            &data,
            upload,
            Target::NewFlight(Box::new(params), None),
            idem,
            1,
        )
    })
    .await
    .map_err(|e| ApiError::internal("recording the job", e))??;
    Ok(created(&jobs[0]))
}

/// The 201 answer for a submitted job.
fn created(job: &JobRecord) -> Response {
    let view = JobView::new(job);
    tracing::info!(job.id = %view.id, image = %view.image, "job submitted");
    (
        StatusCode::CREATED,
        [(header::LOCATION, view.links.self_.clone())],
        Json(view),
    )
        .into_response()
}

/// Lists jobs, oldest first, filtered by flight and state, a page at a time.
#[utoipa::path(
    get, path = "/v1/jobs", tag = "jobs",
    params(JobListQuery),
    responses(
        (status = 200, description = "A page of jobs", body = JobPage),
        (status = 400, description = "Bad query", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn list_jobs(
    State(state): State<AppState>,
    ApiQuery(q): ApiQuery<JobListQuery>,
) -> Result<Json<JobPage>, ApiError> {
    let limit = page_limit(q.limit)?;
    let items = state.store.jobs(&JobFilter {
        flight: q.flight,
        state: q.state,
        after: q.after,
        limit: limit + 1,
    })?;
    Ok(Json(page(items.iter().map(JobView::new).collect(), limit)))
}

fn page(mut items: Vec<JobView>, limit: usize) -> JobPage {
    let next = (items.len() > limit).then(|| {
        items.truncate(limit);
        items.last().map(|j| j.id)
    });
    JobPage {
        items,
        next: next.flatten(),
    }
}

/// A job's state and progress; with `wait=N`, answers when the job ends or
/// after N seconds, whichever is first (long-poll).
#[utoipa::path(
    get, path = "/v1/jobs/{id}", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id"), WaitQuery),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "The job", body = JobView,
            headers(("Retry-After" = String, description = "0 when a wait= ran out before the job ended: ask again"))),
        (status = 404, description = "No such job", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_job(
    State(state): State<AppState>,
    IdPath(id): IdPath,
    ApiQuery(q): ApiQuery<WaitQuery>,
) -> Result<Response, ApiError> {
    let wait = watch::wait_duration(q.wait)?;
    if state.store.job(id)?.is_none() {
        return Err(ApiError::not_found("job", id));
    }
    watch::wait_until(&state, wait, || {
        // A store that does not answer ends the wait; the answer below says why.
        state
            .store
            .job(id)
            .map_or(true, |j| j.is_none_or(|j| j.state.is_terminal()))
    })
    .await;
    let job = state
        .store
        .job(id)?
        .ok_or_else(|| ApiError::not_found("job", id))?;
    let ended = job.state.is_terminal();
    Ok(watch::answer(Json(JobView::new(&job)), wait, ended))
}

/// Server-sent events of a job: a `job` event with the job whenever it
/// changes, then `end` with its final state.
#[utoipa::path(
    get, path = "/v1/jobs/{id}/events", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "An event stream", content_type = "text/event-stream", body = SseEvent),
        (status = 404, description = "No such job", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn job_events(
    State(state): State<AppState>,
    IdPath(id): IdPath,
) -> Result<Response, ApiError> {
    if state.store.job(id)?.is_none() {
        return Err(ApiError::not_found("job", id));
    }
    let store = state.store.clone();
    Ok(watch::event_stream(state, "job", move || {
        let job = store.job(id).ok()??;
        let json = serde_json::to_string(&JobView::new(&job)).expect("views serialize");
        Some((json, job.state.is_terminal()))
    })
    .into_response())
}

async fn job_results(state: AppState, id: Uuid, format: Format) -> Result<Response, ApiError> {
    let job = state
        .store
        .job(id)?
        .ok_or_else(|| ApiError::not_found("job", id))?;
    if job.state != JobState::Succeeded {
        let why = job
            .error
            .as_ref()
            .map(|e| format!(": {}", e.message))
            .unwrap_or_default();
        return Err(ApiError::new(
            ErrorCode::JobNotSucceeded,
            format!(
                "job {id} is {}{why}; results exist once it succeeded",
                job.state.as_str()
            ),
        ));
    }
    let flight = state
        .store
        .flight(job.flight_id)?
        .ok_or_else(|| ApiError::not_found("job", id))?;
    let stem = format!("job-{id}");
    results::render_jobs(
        &state,
        vec![job],
        flight.params.crs,
        format,
        stem,
        Selection::NotRejected,
    )
    .await
}

/// A succeeded job's targets, as CSV or GeoJSON by the `Accept` header
/// (CSV by default). The bytes equal `gcp-tagger detect`'s for the frame.
#[utoipa::path(
    get, path = "/v1/jobs/{id}/results", tag = "results",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "Targets", content(
            (String = "text/csv"), (GeoJson = "application/geo+json"))),
        (status = 404, description = "No such job", body = Problem, content_type = "application/problem+json"),
        (status = 406, description = "Neither CSV nor GeoJSON acceptable", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "The job has not succeeded", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_job_results(
    State(state): State<AppState>,
    IdPath(id): IdPath,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let format = results::negotiate(&headers)?;
    job_results(state, id, format).await
}

/// A succeeded job's targets as CSV.
#[utoipa::path(
    get, path = "/v1/jobs/{id}/results.csv", tag = "results",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "Targets", content_type = "text/csv", body = String),
        (status = 404, description = "No such job", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "The job has not succeeded", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_job_results_csv(
    State(state): State<AppState>,
    IdPath(id): IdPath,
) -> Result<Response, ApiError> {
    job_results(state, id, Format::Csv).await
}

/// A succeeded job's targets as GeoJSON (WGS84 points).
#[utoipa::path(
    get, path = "/v1/jobs/{id}/results.geojson", tag = "results",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "Targets", content_type = "application/geo+json", body = GeoJson),
        (status = 404, description = "No such job", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "The job has not succeeded", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_job_results_geojson(
    State(state): State<AppState>,
    IdPath(id): IdPath,
) -> Result<Response, ApiError> {
    job_results(state, id, Format::GeoJson).await
}

/// Cancels a job: a queued job at once, a running one at its next tile
/// (`cancel_requested` is true until then). Canceling an ended job changes
/// nothing.
#[utoipa::path(
    post, path = "/v1/jobs/{id}/cancel", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "The job after the cancel", body = JobView),
        (status = 404, description = "No such job", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn cancel_job(
    State(state): State<AppState>,
    IdPath(id): IdPath,
) -> Result<Json<JobView>, ApiError> {
    let store = state.store.clone();
    let job = tokio::task::spawn_blocking(move || store.cancel_job(id))
        .await
        .map_err(|e| ApiError::internal("canceling", e))??
        .ok_or_else(|| ApiError::not_found("job", id))?;
    Ok(Json(JobView::new(&job)))
}

/// Deletes a job, its frame and its results (canceling it if it runs).
#[utoipa::path(
    delete, path = "/v1/jobs/{id}", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 204, description = "Deleted"),
        (status = 404, description = "No such job", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn delete_job(
    State(state): State<AppState>,
    IdPath(id): IdPath,
) -> Result<StatusCode, ApiError> {
    let (store, data) = (state.store.clone(), state.data.clone());
    tokio::task::spawn_blocking(move || {
        let job = store.delete_job(id)?;
        if let Some(job) = &job {
            data.remove_job_files(job.id, &job.ext);
        }
        Ok::<_, ApiError>(job)
    })
    .await
    .map_err(|e| ApiError::internal("deleting", e))??
    .ok_or_else(|| ApiError::not_found("job", id))?;
    Ok(StatusCode::NO_CONTENT)
}
