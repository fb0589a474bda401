//! `/v1/flights`: many frames in one submission, followed and fetched
//! together.

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
use super::{results, watch, AppState};
use crate::jobs::params::{DetectionQuery, PARAM_KEYS};
use crate::jobs::review::Selection;
use crate::jobs::{FlightRecord, FlightState, IdemKey, JobParams, JobRecord};
use crate::pipeline::output::Format;

/// Keys of an upload's query string besides the detection parameters.
#[derive(Debug, Default)]
pub struct Extras {
    /// `name=`: a raw body's frame name.
    pub name: Option<String>,
    /// `results_to=`: where a new flight's results are written.
    pub results_to: Option<String>,
}

/// Parses and checks the detection parameters of a query string; `extra`
/// names the other keys the route takes. Unknown keys are refused, so a
/// typo never silently falls back to a default.
pub async fn checked_params(
    query: Option<&str>,
    extra: &[&'static str],
) -> Result<(JobParams, Extras), ApiError> {
    let pairs: Vec<(String, String)> = form_urlencoded::parse(query.unwrap_or("").as_bytes())
        .into_owned()
        .collect();
    let mut extras = Extras::default();
    for (k, v) in &pairs {
        if extra.contains(&k.as_str()) {
            match k.as_str() {
                "name" => extras.name = Some(v.clone()),
                "results_to" => extras.results_to = Some(v.clone()),
                _ => {}
            }
        } else if !PARAM_KEYS.contains(&k.as_str()) {
            return Err(ApiError::new(
                ErrorCode::UnknownParameter,
                format!(
                    "unknown query parameter {k:?} (known: {})",
                    [PARAM_KEYS, extra].concat().join(", ")
                ),
            )
            .with_field(k.clone()));
        }
    }
    let params = JobParams::from_pairs(pairs.iter().map(|(k, v)| (k.as_str(), v.as_str())))?;
    // The CRS goes through PROJ (a database lookup): off the async threads.
    let (canonical, _) = tokio::task::spawn_blocking(move || params.check())
        .await
        .map_err(|e| ApiError::internal("checking parameters", e))??;
    Ok((canonical, extras))
}

/// Frames of a flight as a multipart form.
#[derive(utoipa::ToSchema)]
#[allow(dead_code)] // documents the request body
pub struct FlightUpload {
    /// One file part per frame (any field name); each part's file name names the frame.
    #[schema(value_type = Vec<String>, format = Binary)]
    frames: Vec<Vec<u8>>,
}

/// Submits a flight: a multipart form with one file part per frame
/// (`curl -F f=@a.jpg -F f=@b.jpg '.../v1/flights?crs=EPSG:32611'`), or
/// frames in object storage as JSON (`{"sources": ["s3://bucket/flight/"],
/// "results_to": "s3://bucket/out/"}`). Each frame becomes a job; a part or
/// object that is not an image becomes a failed job with the reason, and
/// the other frames go on. Sources are checked before anything is
/// recorded: a missing bucket or object, an empty prefix or refused
/// credentials fail the request.
#[utoipa::path(
    post, path = "/v1/flights", tag = "flights",
    params(DetectionQuery,
        ("Idempotency-Key" = Option<String>, Header, description = "Retry-safe submission: a repeated key answers with the first request's flight and creates nothing"),
        ("results_to" = Option<String>, Query, description = "Multipart uploads: `s3://bucket/prefix/` to write the results to when the flight finishes")),
    request_body(content(
        (FlightUpload = "multipart/form-data"),
        (SourceRequest = "application/json"),
    )),
    responses(
        (status = 201, description = "Flight created; its jobs are queued", body = FlightSubmitted,
            headers(("Location" = String, description = "The flight's URL"))),
        (status = 400, description = "Malformed request", body = Problem, content_type = "application/problem+json"),
        (status = 403, description = "A bucket outside the server's allow-list", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "Two frames of one name", body = Problem, content_type = "application/problem+json"),
        (status = 413, description = "Frame or request too large", body = Problem, content_type = "application/problem+json"),
        (status = 415, description = "Not multipart/form-data or JSON", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Invalid detection parameter; a source that names no bucket, object or image", body = Problem, content_type = "application/problem+json"),
        (status = 502, description = "The object store refused the server's credentials or cannot be reached", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn submit_flight(
    State(state): State<AppState>,
    RawQuery(query): RawQuery,
    req: Request,
) -> Result<Response, ApiError> {
    let (st, q) = (state.clone(), query.clone());
    idempotency::run(
        &state,
        req,
        "/v1/flights",
        query.as_deref(),
        Answer::Flight,
        |req, key| submit_flight_inner(st, q, req, key),
    )
    .await
}

async fn submit_flight_inner(
    state: AppState,
    query: Option<String>,
    req: Request,
    idem: Option<IdemKey>,
) -> Result<Response, ApiError> {
    let (params, extras) = checked_params(query.as_deref(), &["results_to"]).await?;
    let (flight, jobs, skipped) = if sources::is_json(&req) {
        if extras.results_to.is_some() {
            return Err(ApiError::new(
                ErrorCode::UnknownParameter,
                "with a JSON body, results_to goes in the body",
            )
            .with_field("results_to"));
        }
        let sourced = sources::receive(&state, req, true).await?;
        let target = Target::NewFlight(Box::new(params), sourced.results_to);
        let (flight, jobs) = sources::commit(&state, sourced.jobs, target, idem).await?;
        (flight, jobs, sourced.skipped)
    } else {
        let results_to = match extras.results_to {
            Some(raw) => Some(sources::checked_results_to(&state, &raw)?),
            None => None,
        };
        let upload = upload::receive(&state, req, Expect::Many, None).await?;
        let (store, data) = (state.store.clone(), state.data.clone());
        let max = state.limits.max_frames_per_flight;
        let (flight, jobs) = tokio::task::spawn_blocking(move || {
            let target = Target::NewFlight(Box::new(params), results_to);
            upload::commit(&*store, &data, upload, target, idem, max)
        })
        .await
        .map_err(|e| ApiError::internal("recording the flight", e))??;
        (flight, jobs, Vec::new())
    };
    let view = FlightView::new(&flight, &jobs);
    tracing::info!(flight.id = %flight.id, frames = jobs.len(), "flight submitted");
    let body = FlightSubmitted {
        jobs: jobs.iter().map(JobView::new).collect(),
        flight: view,
        skipped,
    };
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, body.flight.links.self_.clone())],
        Json(body),
    )
        .into_response())
}

/// Adds frames to a flight (multipart, or one raw body named by `name=`),
/// with the flight's parameters. Lets a browser upload a large flight in
/// several requests.
#[utoipa::path(
    post, path = "/v1/flights/{id}/frames", tag = "flights",
    params(("id" = Uuid, Path, description = "Flight id"),
        ("name" = Option<String>, Query, description = "Frame name, for a raw body"),
        ("Idempotency-Key" = Option<String>, Header, description = "Retry-safe submission: a repeated key answers with the first request's jobs and creates nothing")),
    request_body(content(
        (FlightUpload = "multipart/form-data"),
        (Vec<u8> = "application/octet-stream"),
        (SourceRequest = "application/json"),
    )),
    responses(
        (status = 201, description = "Jobs created", body = FlightSubmitted,
            headers(("Location" = String, description = "The flight's URL"))),
        (status = 400, description = "Malformed request", body = Problem, content_type = "application/problem+json"),
        (status = 403, description = "A bucket outside the server's allow-list", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "No such flight", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "A frame of that name is in the flight", body = Problem, content_type = "application/problem+json"),
        (status = 413, description = "Frame or request too large", body = Problem, content_type = "application/problem+json"),
        (status = 415, description = "Unsupported body type", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "A source that names no bucket, object or image", body = Problem, content_type = "application/problem+json"),
        (status = 502, description = "The object store refused the server's credentials or cannot be reached", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn add_frames(
    State(state): State<AppState>,
    IdPath(id): IdPath,
    RawQuery(query): RawQuery,
    req: Request,
) -> Result<Response, ApiError> {
    let route = format!("/v1/flights/{id}/frames");
    let (st, q) = (state.clone(), query.clone());
    idempotency::run(
        &state,
        req,
        &route,
        query.as_deref(),
        Answer::Flight,
        |req, key| add_frames_inner(st, id, q, req, key),
    )
    .await
}

async fn add_frames_inner(
    state: AppState,
    id: Uuid,
    query: Option<String>,
    req: Request,
    idem: Option<IdemKey>,
) -> Result<Response, ApiError> {
    let mut name = None;
    for (k, v) in form_urlencoded::parse(query.as_deref().unwrap_or("").as_bytes()) {
        if k != "name" {
            return Err(ApiError::new(
                ErrorCode::UnknownParameter,
                format!(
                    "unknown query parameter {k:?}: frames added to a flight use its parameters"
                ),
            )
            .with_field(k.into_owned()));
        }
        name = Some(v.into_owned());
    }
    if state.store.flight(id)?.is_none() {
        return Err(ApiError::not_found("flight", id));
    }
    if sources::is_json(&req) {
        if name.is_some() {
            return Err(ApiError::new(
                ErrorCode::UnknownParameter,
                "name= is for a raw frame; sources are named by their keys",
            )
            .with_field("name"));
        }
        let sourced = sources::receive(&state, req, false).await?;
        let (flight, jobs) =
            sources::commit(&state, sourced.jobs, Target::Flight(id), idem).await?;
        return Ok(submitted(&state, flight, jobs, sourced.skipped));
    }
    let is_multipart = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.to_ascii_lowercase().starts_with("multipart/"));
    if !is_multipart && name.is_none() {
        return Err(ApiError::new(
            ErrorCode::MissingName,
            "a raw frame added to a flight needs ?name= (names identify frames in results)",
        )
        .with_field("name"));
    }
    let expect = if is_multipart {
        Expect::Many
    } else {
        Expect::One
    };
    let upload = upload::receive(&state, req, expect, name).await?;
    let (store, data) = (state.store.clone(), state.data.clone());
    let max = state.limits.max_frames_per_flight;
    let (flight, jobs) = tokio::task::spawn_blocking(move || {
        upload::commit(&*store, &data, upload, Target::Flight(id), idem, max)
    })
    .await
    .map_err(|e| ApiError::internal("recording the frames", e))??;
    Ok(submitted(&state, flight, jobs, Vec::new()))
}

/// The 201 answer to frames added to a flight.
fn submitted(
    state: &AppState,
    flight: FlightRecord,
    jobs: Vec<JobRecord>,
    skipped: Vec<String>,
) -> Response {
    // The flight's other jobs, as far as the store answers: the frames
    // are recorded either way, so this answer must not fail for a read.
    let all = match state.store.flight_jobs(flight.id) {
        Ok(all) => all.unwrap_or_default(),
        Err(e) => {
            tracing::warn!(error = %e, "cannot read the flight back for the answer");
            jobs.clone()
        }
    };
    let body = FlightSubmitted {
        flight: FlightView::new(&flight, &all),
        jobs: jobs.iter().map(JobView::new).collect(),
        skipped,
    };
    (
        StatusCode::CREATED,
        [(header::LOCATION, body.flight.links.self_.clone())],
        Json(body),
    )
        .into_response()
}

/// Lists flights, oldest first, a page at a time.
#[utoipa::path(
    get, path = "/v1/flights", tag = "flights",
    params(PageQuery),
    responses(
        (status = 200, description = "A page of flights", body = FlightPage),
        (status = 400, description = "Bad query", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn list_flights(
    State(state): State<AppState>,
    ApiQuery(q): ApiQuery<PageQuery>,
) -> Result<Json<FlightPage>, ApiError> {
    let limit = page_limit(q.limit)?;
    let mut flights = state.store.flights(q.after, limit + 1)?;
    let next = (flights.len() > limit).then(|| {
        flights.truncate(limit);
        flights.last().map(|f| f.id)
    });
    let items = flights
        .iter()
        .map(|f| {
            let jobs = state.store.flight_jobs(f.id)?.unwrap_or_default();
            Ok(FlightView::new(f, &jobs))
        })
        .collect::<Result<_, ApiError>>()?;
    Ok(Json(FlightPage {
        items,
        next: next.flatten(),
    }))
}

fn flight_view(state: &AppState, id: Uuid) -> Result<Option<FlightView>, ApiError> {
    let Some(flight) = state.store.flight(id)? else {
        return Ok(None);
    };
    let Some(jobs) = state.store.flight_jobs(id)? else {
        return Ok(None);
    };
    Ok(Some(FlightView::new(&flight, &jobs)))
}

/// A flight's state and job counts; with `wait=N`, answers when every job
/// ended or after N seconds (long-poll).
#[utoipa::path(
    get, path = "/v1/flights/{id}", tag = "flights",
    params(("id" = Uuid, Path, description = "Flight id"), WaitQuery),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "The flight", body = FlightView,
            headers(("Retry-After" = String, description = "0 when a wait= ran out before every job ended: ask again"))),
        (status = 404, description = "No such flight", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_flight(
    State(state): State<AppState>,
    IdPath(id): IdPath,
    ApiQuery(q): ApiQuery<WaitQuery>,
) -> Result<Response, ApiError> {
    let wait = watch::wait_duration(q.wait)?;
    if state.store.flight(id)?.is_none() {
        return Err(ApiError::not_found("flight", id));
    }
    watch::wait_until(&state, wait, || {
        // A store that does not answer ends the wait; the answer below says why.
        flight_view(&state, id).map_or(true, |f| f.is_none_or(|f| f.state == FlightState::Finished))
    })
    .await;
    let view = flight_view(&state, id)?.ok_or_else(|| ApiError::not_found("flight", id))?;
    let finished = view.state == FlightState::Finished;
    Ok(watch::answer(Json(view), wait, finished))
}

/// A flight's jobs in submission order, a page at a time.
#[utoipa::path(
    get, path = "/v1/flights/{id}/jobs", tag = "flights",
    params(("id" = Uuid, Path, description = "Flight id"), PageQuery),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "A page of the flight's jobs", body = JobPage),
        (status = 404, description = "No such flight", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn flight_jobs(
    State(state): State<AppState>,
    IdPath(id): IdPath,
    ApiQuery(q): ApiQuery<PageQuery>,
) -> Result<Json<JobPage>, ApiError> {
    let limit = page_limit(q.limit)?;
    let jobs = state
        .store
        .flight_jobs(id)?
        .ok_or_else(|| ApiError::not_found("flight", id))?;
    let start = match q.after {
        Some(after) => jobs
            .iter()
            .position(|j| j.id == after)
            .map_or(jobs.len(), |i| i + 1),
        None => 0,
    };
    let rest = &jobs[start..];
    let items: Vec<JobView> = rest.iter().take(limit).map(JobView::new).collect();
    let next = (rest.len() > limit)
        .then(|| items.last().map(|j| j.id))
        .flatten();
    Ok(Json(JobPage { items, next }))
}

/// Server-sent events of a flight: a `flight` event with the flight
/// whenever it changes, then `end` once every job ended.
#[utoipa::path(
    get, path = "/v1/flights/{id}/events", tag = "flights",
    params(("id" = Uuid, Path, description = "Flight id")),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "An event stream", content_type = "text/event-stream", body = SseEvent),
        (status = 404, description = "No such flight", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn flight_events(
    State(state): State<AppState>,
    IdPath(id): IdPath,
) -> Result<Response, ApiError> {
    if state.store.flight(id)?.is_none() {
        return Err(ApiError::not_found("flight", id));
    }
    let inner = state.clone();
    Ok(watch::event_stream(state, "flight", move || {
        let view = flight_view(&inner, id).ok()??;
        let json = serde_json::to_string(&view).expect("views serialize");
        Some((json, view.state == FlightState::Finished))
    })
    .into_response())
}

async fn flight_results(
    state: AppState,
    id: Uuid,
    format: Format,
    q: &ResultsQuery,
) -> Result<Response, ApiError> {
    let partial = q.partial.unwrap_or(false);
    let flight = state
        .store
        .flight(id)?
        .ok_or_else(|| ApiError::not_found("flight", id))?;
    let jobs = state.store.flight_jobs(id)?.unwrap_or_default();
    let open = jobs.iter().filter(|j| !j.state.is_terminal()).count();
    if open > 0 && !partial {
        return Err(ApiError::new(ErrorCode::FlightNotFinished,
            format!(
                "{open} of {} jobs are still queued or running; wait (GET /v1/flights/{id}?wait=60) or ask with partial=true",
                jobs.len()
            ),
        ));
    }
    let stem = format!("flight-{id}");
    let selection = Selection::from_accepted_only(q.accepted_only);
    results::render_jobs(&state, jobs, flight.params.crs, format, stem, selection).await
}

/// Targets of every succeeded frame of a flight, sorted by image name, as
/// CSV or GeoJSON by `Accept` (CSV by default). The bytes equal
/// `gcp-tagger detect`'s on the same frames.
#[utoipa::path(
    get, path = "/v1/flights/{id}/results", tag = "results",
    params(("id" = Uuid, Path, description = "Flight id"), ResultsQuery),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "Targets", content(
            (String = "text/csv"), (GeoJson = "application/geo+json"))),
        (status = 404, description = "No such flight", body = Problem, content_type = "application/problem+json"),
        (status = 406, description = "Neither CSV nor GeoJSON acceptable", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "Jobs still queued or running", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_flight_results(
    State(state): State<AppState>,
    IdPath(id): IdPath,
    ApiQuery(q): ApiQuery<ResultsQuery>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let format = results::negotiate(&headers)?;
    flight_results(state, id, format, &q).await
}

/// A flight's targets as CSV.
#[utoipa::path(
    get, path = "/v1/flights/{id}/results.csv", tag = "results",
    params(("id" = Uuid, Path, description = "Flight id"), ResultsQuery),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "Targets", content_type = "text/csv", body = String),
        (status = 404, description = "No such flight", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "Jobs still queued or running", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_flight_results_csv(
    State(state): State<AppState>,
    IdPath(id): IdPath,
    ApiQuery(q): ApiQuery<ResultsQuery>,
) -> Result<Response, ApiError> {
    flight_results(state, id, Format::Csv, &q).await
}

/// A flight's targets as GeoJSON (WGS84 points).
#[utoipa::path(
    get, path = "/v1/flights/{id}/results.geojson", tag = "results",
    params(("id" = Uuid, Path, description = "Flight id"), ResultsQuery),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "Targets", content_type = "application/geo+json", body = GeoJson),
        (status = 404, description = "No such flight", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "Jobs still queued or running", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_flight_results_geojson(
    State(state): State<AppState>,
    IdPath(id): IdPath,
    ApiQuery(q): ApiQuery<ResultsQuery>,
) -> Result<Response, ApiError> {
    flight_results(state, id, Format::GeoJson, &q).await
}

/// Cancels every queued or running job of a flight.
#[utoipa::path(
    post, path = "/v1/flights/{id}/cancel", tag = "flights",
    params(("id" = Uuid, Path, description = "Flight id")),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "The flight after the cancel", body = FlightView),
        (status = 404, description = "No such flight", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn cancel_flight(
    State(state): State<AppState>,
    IdPath(id): IdPath,
) -> Result<Json<FlightView>, ApiError> {
    let store = state.store.clone();
    tokio::task::spawn_blocking(move || store.cancel_flight(id))
        .await
        .map_err(|e| ApiError::internal("canceling", e))??
        .ok_or_else(|| ApiError::not_found("flight", id))?;
    flight_view(&state, id)?
        .map(Json)
        .ok_or_else(|| ApiError::not_found("flight", id))
}

/// Deletes a flight with all its jobs, frames and results (canceling what
/// runs).
#[utoipa::path(
    delete, path = "/v1/flights/{id}", tag = "flights",
    params(("id" = Uuid, Path, description = "Flight id")),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 204, description = "Deleted"),
        (status = 404, description = "No such flight", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn delete_flight(
    State(state): State<AppState>,
    IdPath(id): IdPath,
) -> Result<StatusCode, ApiError> {
    let (store, data) = (state.store.clone(), state.data.clone());
    tokio::task::spawn_blocking(move || {
        let jobs = store.delete_flight(id)?;
        for job in jobs.iter().flatten() {
            data.remove_job_files(job.id, &job.ext);
        }
        if jobs.is_some() {
            data.remove_survey(id);
        }
        Ok::<_, ApiError>(jobs)
    })
    .await
    .map_err(|e| ApiError::internal("deleting", e))??
    .ok_or_else(|| ApiError::not_found("flight", id))?;
    Ok(StatusCode::NO_CONTENT)
}
