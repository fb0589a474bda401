//! Job and flight records: what the store keeps and the API shows.

use crate::error_code::ErrorCode;
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use uuid::Uuid;

use super::params::JobParams;

/// Job ids are UUIDv7: unique without coordination and sortable by time.
pub type JobId = Uuid;
pub type FlightId = Uuid;

/// Where a job is in its life.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    /// Waiting for its frame to arrive from object storage.
    Fetching,
    Queued,
    Running,
    Succeeded,
    Failed,
    Canceled,
}

impl JobState {
    pub const ALL: [JobState; 6] = [
        JobState::Fetching,
        JobState::Queued,
        JobState::Running,
        JobState::Succeeded,
        JobState::Failed,
        JobState::Canceled,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            JobState::Fetching => "fetching",
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Succeeded => "succeeded",
            JobState::Failed => "failed",
            JobState::Canceled => "canceled",
        }
    }

    pub fn parse(s: &str) -> Option<JobState> {
        JobState::ALL.into_iter().find(|st| st.as_str() == s)
    }

    /// No further change will happen.
    pub fn is_terminal(self) -> bool {
        matches!(
            self,
            JobState::Succeeded | JobState::Failed | JobState::Canceled
        )
    }
}

/// Why a job failed: a stable code for machines and a message for people.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct JobError {
    /// Stable machine-readable code, e.g. `unreadable_frame`, `frame_too_large`.
    pub code: ErrorCode,
    pub message: String,
}

/// Milliseconds since the Unix epoch.
pub type Millis = i64;

pub fn now_millis() -> Millis {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as i64)
}

/// One frame's job.
#[derive(Debug, Clone, PartialEq)]
pub struct JobRecord {
    pub id: JobId,
    pub flight_id: FlightId,
    /// Queue order: smaller runs first (submission order across flights).
    pub seq: i64,
    /// The frame's name in results: the uploaded file name, sanitized.
    pub image: String,
    /// File extension of the spooled frame (`jpg`, `tif`, `png`).
    pub ext: String,
    pub bytes: u64,
    pub state: JobState,
    pub created_at: Millis,
    pub started_at: Option<Millis>,
    pub finished_at: Option<Millis>,
    /// Times a worker has claimed the job.
    pub attempts: u32,
    pub error: Option<JobError>,
    /// Frame size, known once a worker opened it.
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// Targets found, once succeeded.
    pub targets: Option<u32>,
    /// Tiles done and in all; kept in memory only.
    pub tiles_done: u32,
    pub tiles_total: u32,
    /// A cancel was asked for while the job was running.
    pub cancel_requested: bool,
    /// `s3://bucket/key` for a frame fetched from object storage.
    pub source: Option<String>,
    /// The object's ETag when the job was submitted (fetches require it).
    pub source_etag: Option<String>,
    /// Conditions of a succeeded frame the user should hear (a frame cut
    /// off part-way, no georeference).
    pub warnings: Vec<String>,
}

/// A submission's group of jobs, sharing one set of parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct FlightRecord {
    pub id: FlightId,
    pub created_at: Millis,
    pub params: JobParams,
    /// Where the flight's results are written when it finishes.
    pub export: Option<Export>,
}

/// Writing a flight's results back to object storage.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, utoipa::ToSchema)]
pub struct Export {
    /// The `s3://bucket/prefix/` the results go to.
    pub to: String,
    pub state: ExportState,
    /// Why the last attempt failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// When the results were last written (milliseconds since the epoch).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub written_at: Option<Millis>,
    pub attempts: u32,
}

impl Export {
    /// Counts an attempt to write the results: written, or failed with the
    /// reason (`give_up` marks it failed for good, else it stays pending).
    pub fn record_attempt(&mut self, result: Result<(), String>, give_up: bool) {
        self.attempts += 1;
        match result {
            Ok(()) => {
                self.state = ExportState::Written;
                self.error = None;
                self.written_at = Some(now_millis());
            }
            Err(e) => {
                self.error = Some(e);
                if give_up {
                    self.state = ExportState::Failed;
                }
            }
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum ExportState {
    /// Written when every job of the flight has ended.
    Pending,
    Written,
    /// Gave up after several attempts; `error` says why.
    Failed,
}

impl ExportState {
    pub fn as_str(self) -> &'static str {
        match self {
            ExportState::Pending => "pending",
            ExportState::Written => "written",
            ExportState::Failed => "failed",
        }
    }

    pub fn parse(s: &str) -> Option<ExportState> {
        [
            ExportState::Pending,
            ExportState::Written,
            ExportState::Failed,
        ]
        .into_iter()
        .find(|st| st.as_str() == s)
    }
}

/// The state of a flight, derived from its jobs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum FlightState {
    /// No job has started yet.
    Queued,
    /// Some jobs are fetching, queued or running, or every job ended and
    /// the results are being written to object storage.
    Running,
    /// Every job ended (succeeded, failed or canceled) and, when asked
    /// for, the results were written to object storage (or that failed).
    Finished,
}

/// Jobs of a flight counted by state.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, utoipa::ToSchema)]
pub struct StateCounts {
    pub fetching: u32,
    pub queued: u32,
    pub running: u32,
    pub succeeded: u32,
    pub failed: u32,
    pub canceled: u32,
}

impl StateCounts {
    pub fn add(&mut self, state: JobState) {
        *match state {
            JobState::Fetching => &mut self.fetching,
            JobState::Queued => &mut self.queued,
            JobState::Running => &mut self.running,
            JobState::Succeeded => &mut self.succeeded,
            JobState::Failed => &mut self.failed,
            JobState::Canceled => &mut self.canceled,
        } += 1;
    }

    pub fn flight_state(&self) -> FlightState {
        if self.fetching + self.queued + self.running == 0 {
            FlightState::Finished
        } else if self.running + self.succeeded + self.failed + self.canceled == 0 {
            FlightState::Queued
        } else {
            FlightState::Running
        }
    }
}
