//! The job store: every flight and job, their states and the queue, behind
//! one interface ([`JobStore`]) with two implementations:
//!
//! - [`SqliteStore`]: the embedded default, one file in the data folder,
//!   owned by one process (reads served from memory).
//! - [`PgStore`]: PostgreSQL, shared by any number of replicas: claims
//!   are `FOR UPDATE SKIP LOCKED`, wake-ups `LISTEN/NOTIFY`.
//!
//! The contract both keep (tested on both by `tests/it/store_contract.rs`):
//! - every read can fail (a database is a network away) and says so;
//! - a claim is a **lease**: the worker renews it with [`JobStore::heartbeat`]
//!   while the job runs; a lease not renewed within the store's lease time
//!   puts the job back in the queue (its attempt counted; after
//!   `max_attempts` claims the job fails instead), and the worker that lost
//!   it learns so at its next heartbeat and stops;
//! - cancellation and progress are stored state: a cancel is seen by the
//!   job's worker at its next heartbeat, wherever it runs;
//! - a frame name is recorded once per flight and a flight never holds more
//!   than the limit, decided inside the transaction that records them;
//! - the schema is versioned and each step is taken once.

mod postgres;
mod sqlite;

use std::sync::atomic::AtomicBool;
use std::time::Duration;

use tokio::sync::watch;

use super::model::*;
use super::params::JobParams;

pub use postgres::PgStore;
pub use sqlite::{SqliteStore, SCHEMA_VERSION};

/// Store failures: the database could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("job store: {0}")]
    Db(#[from] rusqlite::Error),
    #[error("job store (PostgreSQL): {0}")]
    Postgres(#[from] tokio_postgres::Error),
    #[error("job store (PostgreSQL): {0}")]
    Pool(String),
    #[error("job store: bad record: {0}")]
    Corrupt(String),
    /// The store was written by a newer build, whose schema steps this one
    /// does not know.
    #[error("its schema is version {found}, newer than this build's {supported}: run a newer gcp-tagger on this data folder")]
    NewerSchema { found: u32, supported: u32 },
    /// Another request with the same Idempotency-Key committed first.
    #[error("job store: idempotency key already used")]
    KeyTaken,
    /// A frame of this name is in the flight already (or twice in the
    /// request): names identify frames in results.
    #[error(
        "{0}: a frame of this name is already in the flight; names identify frames in results"
    )]
    DuplicateImage(String),
    /// The flight would grow past its limit.
    #[error("the flight would hold {would} frames, more than the {max} allowed (--max-frames-per-flight)")]
    TooManyFrames { would: usize, max: usize },
}

/// Claims a job may have before it fails instead of being queued again
/// (a frame that kills its worker, or a worker that stops renewing).
pub const MAX_ATTEMPTS: u32 = 3;

/// How claims behave; the same for both stores.
#[derive(Debug, Clone, Copy)]
pub struct LeaseConfig {
    /// A claim not renewed for this long goes back to the queue.
    pub lease: Duration,
    /// Claims a job may have; a lease that expires on the last one fails
    /// the job instead of queueing it again.
    pub max_attempts: u32,
}

impl Default for LeaseConfig {
    fn default() -> Self {
        LeaseConfig {
            lease: Duration::from_secs(30),
            max_attempts: MAX_ATTEMPTS,
        }
    }
}

/// A client's `Idempotency-Key` and the request it came with.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct IdemKey {
    /// The key, scoped to the client's credentials.
    pub key: String,
    /// Method, route and query of the request, to refuse a key reused for
    /// another request.
    pub request: String,
}

/// What the first request with a key created.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct IdemRecord {
    pub request: String,
    pub flight: FlightId,
    pub jobs: Vec<JobId>,
}

/// A job to create: a frame already in the spool.
#[derive(Debug, Clone)]
pub struct NewJob {
    pub id: JobId,
    pub image: String,
    pub ext: String,
    pub bytes: u64,
    /// Set for uploads refused at submission: the job is created failed.
    pub rejected: Option<JobError>,
    /// For a frame in object storage: its `s3://` URL and ETag. The job
    /// starts `fetching` and is queued once the frame is in the spool.
    pub source: Option<(String, Option<String>)>,
}

impl NewJob {
    /// The state a new job starts in, its error and end time: failed when
    /// refused at submission, fetching when its frame is in object storage,
    /// else queued.
    pub(crate) fn starts(&self, created: Millis) -> (JobState, Option<JobError>, Option<Millis>) {
        match (&self.rejected, &self.source) {
            (Some(e), _) => (JobState::Failed, Some(e.clone()), Some(created)),
            (None, Some(_)) => (JobState::Fetching, None, None),
            (None, None) => (JobState::Queued, None, None),
        }
    }
}

/// A new flight's record; a name twice in `jobs` is refused.
pub(crate) fn new_flight(
    params: &JobParams,
    jobs: &[NewJob],
    export_to: Option<String>,
) -> Result<FlightRecord, StoreError> {
    let mut seen = std::collections::HashSet::new();
    if let Some(job) = jobs.iter().find(|j| !seen.insert(j.image.as_str())) {
        return Err(StoreError::DuplicateImage(job.image.clone()));
    }
    Ok(FlightRecord {
        id: uuid::Uuid::now_v7(),
        created_at: now_millis(),
        params: params.clone(),
        export: export_to.map(|to| Export {
            to,
            state: ExportState::Pending,
            error: None,
            written_at: None,
            attempts: 0,
        }),
    })
}

/// The lease a claim holds: which job, and the token that tells this claim
/// from a later one of the same job.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Lease {
    pub job: JobId,
    pub token: uuid::Uuid,
}

/// A job handed to a worker.
#[derive(Debug, Clone)]
pub struct Claim {
    pub job: JobRecord,
    pub params: JobParams,
    pub lease: Lease,
}

/// What a running job reports with its heartbeat.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Progress {
    /// The frame's size, once its worker opened it.
    pub size: Option<(u32, u32)>,
    pub tiles_done: u32,
    pub tiles_total: u32,
}

/// What a heartbeat tells the worker.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LeaseState {
    /// Still the job's worker; `cancel` when a cancel was asked for.
    Held { cancel: bool },
    /// The lease expired and the job went back to the queue (or was
    /// deleted): stop, record nothing.
    Lost,
}

/// How a claimed job ended.
#[derive(Debug, Clone)]
pub enum Outcome {
    Succeeded {
        width: u32,
        height: u32,
        targets: u32,
        /// What did not stop the frame but the user should hear.
        warnings: Vec<String>,
    },
    Failed(JobError),
    Canceled,
    /// Stopped by shutdown: back to the queue for the next start.
    Interrupted,
}

/// What recording a job's end did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Finished {
    Recorded,
    /// The job was deleted while it ran: its files go too.
    Deleted,
    /// The lease had expired and the job is someone else's now: nothing
    /// was recorded and its files are left to the new claim.
    Lost,
}

/// Filters for listing jobs.
#[derive(Debug, Clone, Default)]
pub struct JobFilter {
    pub flight: Option<FlightId>,
    pub state: Option<JobState>,
    /// Only jobs with an id after this one (pagination cursor).
    pub after: Option<JobId>,
    pub limit: usize,
}

/// Queue figures for metrics and readiness.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct QueueStats {
    pub fetching: usize,
    /// Queued jobs whose frame was fetched from object storage.
    pub fetched: usize,
    pub queued: usize,
    pub running: usize,
}

/// The job store's interface; see the module docs for its contract.
/// Calls block (briefly) and may be made from any thread.
pub trait JobStore: Send + Sync {
    /// A receiver that sees every change (for waiting without polling);
    /// with PostgreSQL, changes made by other replicas too.
    fn subscribe(&self) -> watch::Receiver<u64>;

    /// Records a new flight with its jobs in one transaction.
    /// `export_to` is an `s3://bucket/prefix/` for the results, written
    /// when every job has ended.
    fn create_flight(
        &self,
        params: &JobParams,
        jobs: &[NewJob],
        export_to: Option<String>,
        idem: Option<&IdemKey>,
    ) -> Result<FlightRecord, StoreError>;

    /// Adds jobs to an existing flight; `None` if there is no such flight.
    /// Checked in the transaction that records them, so concurrent
    /// requests cannot both pass: every name new to the flight and once in
    /// `jobs` ([`StoreError::DuplicateImage`]), the flight at most
    /// `max_frames` frames ([`StoreError::TooManyFrames`]).
    fn add_to_flight(
        &self,
        flight: FlightId,
        jobs: &[NewJob],
        idem: Option<&IdemKey>,
        max_frames: usize,
    ) -> Result<Option<Vec<JobRecord>>, StoreError>;

    fn flight(&self, id: FlightId) -> Result<Option<FlightRecord>, StoreError>;

    /// Image names already used in a flight.
    fn flight_images(&self, id: FlightId) -> Result<Vec<String>, StoreError>;

    /// A flight's jobs in submission order; `None` if there is no such flight.
    fn flight_jobs(&self, id: FlightId) -> Result<Option<Vec<JobRecord>>, StoreError>;

    /// Flights whose every job ended before `cutoff` (and whose export, if
    /// any, is no longer pending): due for removal.
    fn expired_flights(&self, cutoff: Millis) -> Result<Vec<FlightId>, StoreError>;

    /// What the first request with `key` created, if one did.
    fn idempotent(&self, key: &str) -> Result<Option<IdemRecord>, StoreError>;

    /// Flights, oldest first, after the cursor.
    fn flights(
        &self,
        after: Option<FlightId>,
        limit: usize,
    ) -> Result<Vec<FlightRecord>, StoreError>;

    fn job(&self, id: JobId) -> Result<Option<JobRecord>, StoreError>;

    /// Jobs matching `filter`, oldest first.
    fn jobs(&self, filter: &JobFilter) -> Result<Vec<JobRecord>, StoreError>;

    fn stats(&self) -> Result<QueueStats, StoreError>;

    /// Waits up to `timeout` for a queued job and leases it. Returns `None`
    /// on timeout or when `stop` is set. Expired leases are reclaimed first.
    fn claim_next(&self, stop: &AtomicBool, timeout: Duration)
        -> Result<Option<Claim>, StoreError>;

    /// Renews a lease and records the job's progress.
    fn heartbeat(&self, lease: &Lease, progress: &Progress) -> Result<LeaseState, StoreError>;

    /// Records how a leased job ended.
    fn finish(&self, lease: &Lease, outcome: &Outcome) -> Result<Finished, StoreError>;

    /// Gives a lease back without recording an end (the store could not
    /// write it, and the server stops): the job is queued again, at once
    /// where the store can, else when the lease expires or at next start.
    fn release_unrecorded(&self, lease: &Lease);

    /// Wakes workers waiting in [`JobStore::claim_next`] (used at shutdown).
    fn wake_workers(&self);

    /// The first `limit` jobs waiting for their frame, in queue order.
    fn to_fetch(&self, limit: usize) -> Result<Vec<JobRecord>, StoreError>;

    /// A fetched frame is in `frames/`: the job joins the worker queue.
    /// Returns `false` if the job was canceled or deleted meanwhile (the
    /// caller removes the frame).
    fn fetched(&self, id: JobId, ext: &str, bytes: u64) -> Result<bool, StoreError>;

    /// A frame could not be fetched: the job fails with the reason.
    fn fetch_failed(&self, id: JobId, error: &JobError) -> Result<(), StoreError>;

    /// Flights whose results are due to be written: export pending and
    /// every job ended.
    fn exports_due(&self) -> Result<Vec<(FlightRecord, Vec<JobRecord>)>, StoreError>;

    /// Records an export attempt: written, or failed with the reason
    /// (`give_up` marks it failed for good, else it stays pending).
    fn export_done(
        &self,
        flight: FlightId,
        result: Result<(), String>,
        give_up: bool,
    ) -> Result<(), StoreError>;

    /// Cancels a job: a queued one at once, a running one at its worker's
    /// next heartbeat. `None` if there is no such job.
    fn cancel_job(&self, id: JobId) -> Result<Option<JobRecord>, StoreError>;

    /// Cancels every unfinished job of a flight; `None` if there is no such
    /// flight.
    fn cancel_flight(&self, id: FlightId) -> Result<Option<Vec<JobRecord>>, StoreError>;

    /// Deletes a job's record (its worker, if it runs, stops at its next
    /// heartbeat); returns the removed record so the caller can remove its
    /// files.
    fn delete_job(&self, id: JobId) -> Result<Option<JobRecord>, StoreError>;

    /// Deletes a flight and all its jobs; returns the removed jobs.
    fn delete_flight(&self, id: FlightId) -> Result<Option<Vec<JobRecord>>, StoreError>;
}

/// The store as the server shares it.
pub type SharedStore = std::sync::Arc<dyn JobStore>;

/// Opens the store a `--store` value names (a PostgreSQL URL), or without
/// one the SQLite file at `sqlite_path`.
pub fn open(
    url: Option<&str>,
    sqlite_path: &std::path::Path,
    lease: LeaseConfig,
) -> Result<SharedStore, StoreError> {
    Ok(match url {
        Some(url) => std::sync::Arc::new(PgStore::connect(url, lease)?),
        None => std::sync::Arc::new(SqliteStore::open_with(sqlite_path, lease)?),
    })
}

/// What a job's record becomes when its end is recorded.
pub(crate) struct Ending {
    pub state: JobState,
    pub finished_at: Option<Millis>,
    pub error: Option<JobError>,
    pub size: Option<(u32, u32)>,
    pub targets: Option<u32>,
    pub warnings: Vec<String>,
}

impl Ending {
    pub fn of(outcome: &Outcome) -> Ending {
        let (state, error, size, targets, warnings) = match outcome {
            Outcome::Succeeded {
                width,
                height,
                targets,
                warnings,
            } => (
                JobState::Succeeded,
                None,
                Some((*width, *height)),
                Some(*targets),
                warnings.clone(),
            ),
            Outcome::Failed(e) => (JobState::Failed, Some(e.clone()), None, None, Vec::new()),
            Outcome::Canceled => (JobState::Canceled, None, None, None, Vec::new()),
            // Back to the queue.
            Outcome::Interrupted => (JobState::Queued, None, None, None, Vec::new()),
        };
        Ending {
            state,
            finished_at: (state != JobState::Queued).then(now_millis),
            error,
            size,
            targets,
            warnings,
        }
    }

    /// The warnings as stored (JSON list), none when empty.
    pub fn warnings_json(&self) -> Option<String> {
        (!self.warnings.is_empty())
            .then(|| serde_json::to_string(&self.warnings).expect("strings serialize"))
    }
}

/// A job's stored error. A code this version no longer has (a store
/// written by another) reads as `internal`, its text kept in the message.
pub(crate) fn stored_error(code: Option<String>, message: Option<String>) -> Option<JobError> {
    let (code, message) = (code?, message?);
    Some(JobError {
        code: code.parse().unwrap_or_else(|_| {
            tracing::warn!(%code, "a stored job error has an unknown code");
            crate::error_code::ErrorCode::Internal
        }),
        message,
    })
}
