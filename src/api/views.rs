//! What the API returns: views of job and flight records with links, and
//! the query types of list and wait requests. These types are the OpenAPI
//! schemas.

use crate::error_code::ErrorCode;
use serde::{Deserialize, Serialize};
use uuid::Uuid;

use crate::jobs::model::{
    Export, ExportState, FlightState, JobError, JobRecord, JobState, Millis, StateCounts,
};
use crate::jobs::{FlightRecord, JobParams};

/// Longest a request may wait for a change (`wait=`), in seconds.
pub const MAX_WAIT_SECS: u64 = 60;
/// Page size of lists, by default and at most.
pub const DEFAULT_LIMIT: usize = 100;
pub const MAX_LIMIT: usize = 1000;

/// RFC 3339 time with milliseconds, UTC.
pub fn timestamp(ms: Millis) -> String {
    let t = std::time::UNIX_EPOCH + std::time::Duration::from_millis(ms.max(0) as u64);
    humantime::format_rfc3339_millis(t).to_string()
}

/// Tiles of a running job.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct Progress {
    pub tiles_done: u32,
    /// 0 until the worker has opened the frame.
    pub tiles_total: u32,
    /// 0.0 .. 1.0; 1.0 once the job ended.
    pub fraction: f64,
}

/// Links to a job's resources.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct JobLinks {
    #[serde(rename = "self")]
    pub self_: String,
    pub flight: String,
    pub events: String,
    pub results_csv: String,
    pub results_geojson: String,
}

/// A job: one frame.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct JobView {
    pub id: Uuid,
    pub flight_id: Uuid,
    /// The frame's name in results (the uploaded file name, sanitized).
    pub image: String,
    pub state: JobState,
    pub progress: Progress,
    /// Bytes of the uploaded frame.
    pub bytes: u64,
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// Targets found (succeeded jobs).
    pub targets: Option<u32>,
    /// Times a worker has started the job.
    pub attempts: u32,
    /// Why the job failed.
    pub error: Option<JobError>,
    /// What a succeeded frame's user should hear: `partial: rows R..H do
    /// not decode ...` for a frame cut off part-way (its targets come from
    /// the rows before the cut), a frame without georeference.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    /// A cancel was asked for and the job stops at its next tile.
    pub cancel_requested: bool,
    /// The `s3://bucket/key` the frame is fetched from (frames submitted as sources).
    pub source: Option<String>,
    pub created_at: String,
    pub started_at: Option<String>,
    pub finished_at: Option<String>,
    pub links: JobLinks,
}

impl JobView {
    pub fn new(j: &JobRecord) -> JobView {
        let fraction = done_fraction(j);
        let base = format!("/v1/jobs/{}", j.id);
        JobView {
            id: j.id,
            flight_id: j.flight_id,
            image: j.image.clone(),
            state: j.state,
            progress: Progress {
                tiles_done: j.tiles_done,
                tiles_total: j.tiles_total,
                fraction,
            },
            bytes: j.bytes,
            width: j.width,
            height: j.height,
            targets: j.targets,
            attempts: j.attempts,
            error: j.error.clone(),
            warnings: j.warnings.clone(),
            cancel_requested: j.cancel_requested,
            source: j.source.clone(),
            created_at: timestamp(j.created_at),
            started_at: j.started_at.map(timestamp),
            finished_at: j.finished_at.map(timestamp),
            links: JobLinks {
                flight: format!("/v1/flights/{}", j.flight_id),
                events: format!("{base}/events"),
                results_csv: format!("{base}/results.csv"),
                results_geojson: format!("{base}/results.geojson"),
                self_: base,
            },
        }
    }
}

/// How much of a job is done, 0.0 .. 1.0 (by tiles while it runs).
fn done_fraction(j: &JobRecord) -> f64 {
    if j.state.is_terminal() {
        1.0
    } else if j.tiles_total > 0 {
        j.tiles_done as f64 / j.tiles_total as f64
    } else {
        0.0
    }
}

/// Links to a flight's resources.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct FlightLinks {
    #[serde(rename = "self")]
    pub self_: String,
    pub jobs: String,
    pub frames: String,
    pub events: String,
    pub results_csv: String,
    pub results_geojson: String,
}

/// A flight: the frames of one submission, sharing parameters.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct FlightView {
    pub id: Uuid,
    pub state: FlightState,
    pub params: JobParams,
    /// Jobs by state.
    pub jobs: StateCounts,
    /// Ended jobs / all jobs, 0.0 .. 1.0 (running jobs count by their tiles).
    pub progress: f64,
    /// Targets found so far in succeeded jobs.
    pub targets: u32,
    pub created_at: String,
    /// When the last job ended, once every job has.
    pub finished_at: Option<String>,
    /// Writing the results to object storage when the flight finishes (if asked for).
    pub export: Option<Export>,
    pub links: FlightLinks,
}

impl FlightView {
    pub fn new(f: &FlightRecord, jobs: &[JobRecord]) -> FlightView {
        let mut counts = StateCounts::default();
        let mut done = 0.0;
        for j in jobs {
            counts.add(j.state);
            done += done_fraction(j);
        }
        let mut state = counts.flight_state();
        // A flight whose results go to object storage has finished once
        // they are there (or the export gave up), so a client that waits
        // for the flight can read them at once.
        if state == FlightState::Finished
            && f.export
                .as_ref()
                .is_some_and(|e| e.state == ExportState::Pending)
        {
            state = FlightState::Running;
        }
        let finished_at = (state == FlightState::Finished)
            .then(|| jobs.iter().filter_map(|j| j.finished_at).max())
            .flatten()
            .map(timestamp);
        let base = format!("/v1/flights/{}", f.id);
        FlightView {
            id: f.id,
            state,
            params: f.params.clone(),
            progress: if jobs.is_empty() {
                1.0
            } else {
                done / jobs.len() as f64
            },
            targets: jobs.iter().filter_map(|j| j.targets).sum(),
            jobs: counts,
            created_at: timestamp(f.created_at),
            finished_at,
            export: f.export.clone(),
            links: FlightLinks {
                jobs: format!("{base}/jobs"),
                frames: format!("{base}/frames"),
                events: format!("{base}/events"),
                results_csv: format!("{base}/results.csv"),
                results_geojson: format!("{base}/results.geojson"),
                self_: base,
            },
        }
    }
}

/// A flight with its jobs, as answered to a submission.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct FlightSubmitted {
    pub flight: FlightView,
    /// The jobs this request created, in the order of its parts (sources: by key).
    pub jobs: Vec<JobView>,
    /// Keys under a submitted prefix that were not taken: not an image by extension.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub skipped: Vec<String>,
}

/// A page of jobs.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct JobPage {
    pub items: Vec<JobView>,
    /// Pass as `after` for the next page; absent on the last page.
    pub next: Option<Uuid>,
}

/// A page of flights.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct FlightPage {
    pub items: Vec<FlightView>,
    pub next: Option<Uuid>,
}

/// Paging and filters of `GET /v1/jobs`.
#[derive(Debug, Clone, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct JobListQuery {
    /// Only jobs of this flight.
    pub flight: Option<Uuid>,
    /// Only jobs in this state.
    pub state: Option<JobState>,
    /// Only jobs after this id (the previous page's `next`).
    pub after: Option<Uuid>,
    /// Page size, 1..=1000 (default 100).
    pub limit: Option<usize>,
}

/// Paging of `GET /v1/flights` and `GET /v1/flights/{id}/jobs`.
#[derive(Debug, Clone, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct PageQuery {
    /// Only items after this id (the previous page's `next`).
    pub after: Option<Uuid>,
    /// Page size, 1..=1000 (default 100).
    pub limit: Option<usize>,
}

/// Long-poll of a job or flight.
#[derive(Debug, Clone, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct WaitQuery {
    /// Seconds to wait for the job (or flight) to end before answering with
    /// its state as it is then; 0..=60, default 0 (answer at once).
    pub wait: Option<u64>,
}

/// Flight results before every job ended.
#[derive(Debug, Clone, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct ResultsQuery {
    /// Answer with the frames finished so far instead of 409 while jobs
    /// are still queued or running.
    pub partial: Option<bool>,
    /// Keep only the detections a reviewer accepted (rejected ones are
    /// always left out).
    pub accepted_only: Option<bool>,
}

/// Checks a page size.
pub fn page_limit(limit: Option<usize>) -> Result<usize, super::error::ApiError> {
    match limit {
        None => Ok(DEFAULT_LIMIT),
        Some(n) if (1..=MAX_LIMIT).contains(&n) => Ok(n),
        Some(n) => Err(super::error::ApiError::new(
            ErrorCode::InvalidQuery,
            format!("limit {n} is outside 1..={MAX_LIMIT}"),
        )
        .with_field("limit")),
    }
}

/// A JSON document (GeoJSON FeatureCollection, or a report object).
#[derive(utoipa::ToSchema)]
#[schema(value_type = Object)]
#[allow(dead_code)] // documents a response body
pub struct GeoJson(serde_json::Value);

/// One server-sent event: `event` names it (`job`, `flight`, `end`) and
/// `data` carries the job's or flight's JSON.
#[derive(utoipa::ToSchema)]
#[allow(dead_code)] // documents a response body
pub struct SseEvent {
    event: String,
    data: String,
    id: Option<String>,
}
