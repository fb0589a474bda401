//! `/v1/flights/{id}/survey` and `/v1/flights/{id}/exports/{file}`: a
//! flight's surveyed points, and the GCP files made from its detections.

use crate::error_code::ErrorCode;
use axum::body::Bytes;
use axum::extract::{Path, RawQuery, State};
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Serialize;
use uuid::Uuid;

use super::error::{ApiError, Problem};
use super::extract::{ApiQuery, IdPath};
use super::views::{GeoJson, ResultsQuery};
use super::AppState;
use crate::jobs::gcp::{self, StoredSurvey};
use crate::jobs::review::Selection;
use crate::storage::s3::content_type;
use crate::survey::export::{bundle, BUNDLE, FILES};
use crate::survey::{Role, Survey};

/// Largest survey or assignment file accepted.
const MAX_SURVEY_BYTES: usize = 4 << 20;

/// An uploaded text file (`what`: "survey", "assignment file"), at most
/// [`MAX_SURVEY_BYTES`] of UTF-8; `invalid` is the code for other bytes.
fn text_body(body: &Bytes, what: &str, invalid: ErrorCode) -> Result<String, ApiError> {
    if body.len() > MAX_SURVEY_BYTES {
        return Err(ApiError::new(
            ErrorCode::RequestTooLarge,
            format!("a {what} is at most {MAX_SURVEY_BYTES} bytes"),
        ));
    }
    String::from_utf8(body.to_vec())
        .map_err(|e| ApiError::new(invalid, format!("the {what} is not UTF-8 text: {e}")))
}

fn no_survey(id: Uuid) -> ApiError {
    ApiError::new(
        ErrorCode::NoSurvey,
        format!("flight {id} has no survey: PUT /v1/flights/{id}/survey"),
    )
}

/// A flight's survey, as parsed.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct SurveySummary {
    /// CRS of the survey's coordinates.
    pub crs: String,
    pub points: usize,
    pub control: usize,
    pub check: usize,
    /// Points with a marker id (coded targets match by it).
    pub with_marker_id: usize,
    /// Export files, served under `/v1/flights/{id}/exports/`.
    pub exports: Vec<String>,
}

impl SurveySummary {
    fn new(survey: &Survey, flight: Uuid) -> SurveySummary {
        let count = |role| survey.points.iter().filter(|p| p.role == role).count();
        SurveySummary {
            crs: survey.crs.clone(),
            points: survey.points.len(),
            control: count(Role::Control),
            check: count(Role::Check),
            with_marker_id: survey
                .points
                .iter()
                .filter(|p| p.marker_id.is_some())
                .count(),
            exports: FILES
                .iter()
                .map(|f| format!("/v1/flights/{flight}/exports/{f}"))
                .collect(),
        }
    }
}

/// Sets a flight's survey of ground control points: the file as the body
/// (CSV with a header naming name/marker_id/x/y/z/role columns, or
/// whitespace lines `name easting northing elevation [control|check]`),
/// its CRS on a first line like `EPSG:32611` or as `?crs=`. Replaces any
/// survey before. A bad line is a 422 naming the line.
#[utoipa::path(
    put, path = "/v1/flights/{id}/survey", tag = "survey",
    params(("id" = Uuid, Path, description = "Flight id"),
        ("crs" = Option<String>, Query, description = "CRS of the coordinates, when the file's first line does not name one")),
    request_body(content((String = "text/csv"), (String = "text/plain"))),
    responses(
        (status = 200, description = "Survey stored", body = SurveySummary),
        (status = 400, description = "Unknown query parameter", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "No such flight", body = Problem, content_type = "application/problem+json"),
        (status = 413, description = "Survey file too large", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "A bad line or CRS, named", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn put_survey(
    State(state): State<AppState>,
    IdPath(id): IdPath,
    RawQuery(query): RawQuery,
    body: Bytes,
) -> Result<Json<SurveySummary>, ApiError> {
    let mut crs = None;
    for (k, v) in form_urlencoded::parse(query.as_deref().unwrap_or("").as_bytes()) {
        if k != "crs" {
            return Err(ApiError::new(
                ErrorCode::UnknownParameter,
                format!("unknown query parameter {k:?} (known: crs)"),
            )
            .with_field(k.into_owned()));
        }
        crs = Some(v.into_owned());
    }
    if state.store.flight(id)?.is_none() {
        return Err(ApiError::not_found("flight", id));
    }
    let text = text_body(&body, "survey", ErrorCode::InvalidSurvey)?;
    // A new survey starts without assignments: they named the old one's points.
    let stored = StoredSurvey {
        crs,
        text,
        assignments: None,
    };
    let data = state.data.clone();
    tokio::task::spawn_blocking(move || {
        let survey = stored
            .parse()
            .map_err(|e| ApiError::new(ErrorCode::InvalidSurvey, e.0))?;
        gcp::save_survey(&data, id, &stored)
            .map_err(|e| ApiError::internal("storing the survey", e))?;
        Ok(Json(SurveySummary::new(&survey, id)))
    })
    .await
    .map_err(|e| ApiError::internal("storing the survey", e))?
}

/// Observations named by hand, for frames the matcher cannot place (no
/// georeference, no GPS): the body is lines `name,image,px_x,px_y` (a
/// header line is optional); each names the detection nearest that pixel
/// (within 10 px or half its size) as that survey point. Replaces any
/// assignments before; a new survey clears them.
#[utoipa::path(
    put, path = "/v1/flights/{id}/assignments", tag = "survey",
    params(("id" = Uuid, Path, description = "Flight id")),
    request_body(content((String = "text/csv"), (String = "text/plain"))),
    responses(
        (status = 200, description = "Assignments stored", body = AssignmentsSummary),
        (status = 400, description = "Malformed id", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "No such flight, or no survey yet", body = Problem, content_type = "application/problem+json"),
        (status = 413, description = "File too large", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "A bad line, named", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn put_assignments(
    State(state): State<AppState>,
    IdPath(id): IdPath,
    body: Bytes,
) -> Result<Json<AssignmentsSummary>, ApiError> {
    let text = text_body(&body, "assignment file", ErrorCode::InvalidAssignments)?;
    if state.store.flight(id)?.is_none() {
        return Err(ApiError::not_found("flight", id));
    }
    let data = state.data.clone();
    tokio::task::spawn_blocking(move || {
        let mut stored = gcp::load_survey(&data, id)
            .map_err(|e| ApiError::internal("reading the survey", e))?
            .ok_or_else(|| no_survey(id))?;
        stored.assignments = Some(text);
        let survey = stored
            .parse()
            .map_err(|e| ApiError::new(ErrorCode::InvalidAssignments, e.0))?;
        gcp::save_survey(&data, id, &stored)
            .map_err(|e| ApiError::internal("storing the assignments", e))?;
        Ok(Json(AssignmentsSummary {
            assignments: survey.assignments.len(),
        }))
    })
    .await
    .map_err(|e| ApiError::internal("storing the assignments", e))?
}

/// Assignments stored for a flight.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct AssignmentsSummary {
    pub assignments: usize,
}

/// A flight's survey, as parsed.
#[utoipa::path(
    get, path = "/v1/flights/{id}/survey", tag = "survey",
    params(("id" = Uuid, Path, description = "Flight id")),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "The survey", body = SurveySummary),
        (status = 404, description = "No such flight, or no survey", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_survey(
    State(state): State<AppState>,
    IdPath(id): IdPath,
) -> Result<Json<SurveySummary>, ApiError> {
    let survey = flight_survey(&state, id).await?;
    Ok(Json(SurveySummary::new(&survey, id)))
}

async fn flight_survey(state: &AppState, id: Uuid) -> Result<Survey, ApiError> {
    if state.store.flight(id)?.is_none() {
        return Err(ApiError::not_found("flight", id));
    }
    let data = state.data.clone();
    let stored = tokio::task::spawn_blocking(move || gcp::load_survey(&data, id))
        .await
        .map_err(|e| ApiError::internal("reading the survey", e))?
        .map_err(|e| ApiError::internal("reading the survey", e))?
        .ok_or_else(|| no_survey(id))?;
    stored
        .parse()
        .map_err(|e| ApiError::internal("parsing the stored survey", e))
}

/// One GCP file of a flight with a survey: `gcp_list.txt` (OpenDroneMap),
/// `pix4d_marks.csv`, `metashape_markers.xml`, `survey_points.geojson`,
/// `observations.csv` (every detection with its point, deviation and
/// status) or `report.json` (per-point report and every decision), or
/// `exports.zip`, all six in one download. Needs every job ended, or
/// `?partial=true`.
#[utoipa::path(
    get, path = "/v1/flights/{id}/exports/{file}", tag = "survey",
    params(("id" = Uuid, Path, description = "Flight id"),
        ("file" = String, Path, description = "gcp_list.txt, pix4d_marks.csv, metashape_markers.xml, survey_points.geojson, observations.csv, report.json, or exports.zip (all six)"),
        ResultsQuery),
    responses(
        (status = 400, description = "Malformed id or query", body = Problem, content_type = "application/problem+json"),
        (status = 200, description = "The file", content(
            (String = "text/plain"), (String = "text/csv"), (String = "application/xml"),
            (GeoJson = "application/geo+json"), (GeoJson = "application/json"),
            (Vec<u8> = "application/zip"))),
        (status = 404, description = "No such flight, file, or no survey", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "Jobs still queued or running", body = Problem, content_type = "application/problem+json"),
    )
)]
pub async fn get_export(
    State(state): State<AppState>,
    Path((id, file)): Path<(String, String)>,
    ApiQuery(q): ApiQuery<ResultsQuery>,
) -> Result<Response, ApiError> {
    let id: Uuid = id.parse().map_err(|_| ApiError::not_found("flight", &id))?;
    let index = FILES.iter().position(|f| *f == file);
    if index.is_none() && file != BUNDLE {
        return Err(ApiError::new(
            ErrorCode::NotFound,
            format!(
                "no export {file:?}; exports are {} and {BUNDLE} (all of them)",
                FILES.join(", ")
            ),
        ));
    }
    let flight = state
        .store
        .flight(id)?
        .ok_or_else(|| ApiError::not_found("flight", id))?;
    let survey = flight_survey(&state, id).await?;
    let jobs = state.store.flight_jobs(id)?.unwrap_or_default();
    let open = jobs.iter().filter(|j| !j.state.is_terminal()).count();
    if open > 0 && !q.partial.unwrap_or(false) {
        return Err(ApiError::new(ErrorCode::FlightNotFinished,
            format!(
                "{open} of {} jobs have not ended; wait (GET /v1/flights/{id}?wait=60) or ask with partial=true",
                jobs.len()
            ),
        ));
    }
    let selection = Selection::from_accepted_only(q.accepted_only);
    let data = state.data.clone();
    let mut files = tokio::task::spawn_blocking(move || {
        gcp::flight_exports(&data, &flight, &jobs, &survey, selection)
    })
    .await
    .map_err(|e| ApiError::internal("making the exports", e))?
    .map_err(|e| ApiError::internal("making the exports", e))?;
    let (name, bytes, disposition) = match index {
        Some(i) => {
            let (name, text) = files.swap_remove(i);
            (name, text.into_bytes(), "inline")
        }
        None => (BUNDLE, bundle(&files), "attachment"),
    };
    let media = content_type(name);
    let disposition = format!("{disposition}; filename=\"{name}\"");
    Ok((
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(media)),
            (
                header::CONTENT_DISPOSITION,
                HeaderValue::from_str(&disposition).expect("ascii file name"),
            ),
        ],
        bytes,
    )
        .into_response())
}
