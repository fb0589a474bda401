//! The embedded job store: SQLite in the data folder, owned by one process.
//!
//! Reads are served from memory (status requests stay fast while workers
//! write); every submission and state change is first committed to SQLite
//! in WAL mode, so a restart finds the queue as it was. Leases, progress
//! (tiles done) and cancel requests of running jobs live in memory: they
//! concern only this process's workers, and a restart queues every job that
//! was running. Writers hold the database lock while they update memory, so
//! memory always follows the database's order.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use rusqlite::{params, Connection};
use tokio::sync::watch;

use super::*;
use crate::error_code::ErrorCode;

#[derive(Default)]
struct State {
    jobs: BTreeMap<JobId, JobRecord>,
    flights: BTreeMap<FlightId, FlightRecord>,
    /// Jobs of each flight, in submission order.
    flight_jobs: HashMap<FlightId, Vec<JobId>>,
    /// Queued jobs by queue order.
    queue: BTreeSet<(i64, JobId)>,
    /// Jobs waiting for their frame from object storage, in queue order.
    fetching: BTreeSet<(i64, JobId)>,
    /// Leases of running jobs.
    leases: HashMap<JobId, Held>,
    running: usize,
}

/// A running job's lease, as this process holds it.
struct Held {
    token: uuid::Uuid,
    until: Instant,
}

/// The SQLite job store; share it in an `Arc`.
pub struct SqliteStore {
    lease: LeaseConfig,
    db: Mutex<Connection>,
    state: Mutex<State>,
    /// Signalled when a job is queued (workers wait on it).
    work: Condvar,
    /// Bumped on every change (long-polls and event streams wait on it).
    changed: watch::Sender<u64>,
}

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS flights (
    id TEXT PRIMARY KEY,
    created_at INTEGER NOT NULL,
    params TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS jobs (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    id TEXT NOT NULL UNIQUE,
    flight_id TEXT NOT NULL REFERENCES flights(id) ON DELETE CASCADE,
    image TEXT NOT NULL,
    ext TEXT NOT NULL,
    bytes INTEGER NOT NULL,
    state TEXT NOT NULL,
    created_at INTEGER NOT NULL,
    started_at INTEGER,
    finished_at INTEGER,
    attempts INTEGER NOT NULL DEFAULT 0,
    error_code TEXT,
    error_message TEXT,
    width INTEGER,
    height INTEGER,
    targets INTEGER
);
CREATE INDEX IF NOT EXISTS jobs_flight ON jobs(flight_id);
-- Later steps: see MIGRATIONS.
CREATE TABLE IF NOT EXISTS idempotency (
    key TEXT PRIMARY KEY,
    request TEXT NOT NULL,
    flight_id TEXT NOT NULL REFERENCES flights(id) ON DELETE CASCADE,
    job_ids TEXT NOT NULL,
    created_at INTEGER NOT NULL
);
";

/// Columns added after the first release: (table, column, type). Opening
/// an older data folder adds them.
const ADDED_COLUMNS: [(&str, &str, &str); 8] = [
    ("jobs", "source", "TEXT"),
    ("jobs", "warnings", "TEXT"),
    ("jobs", "source_etag", "TEXT"),
    ("flights", "export_to", "TEXT"),
    ("flights", "export_state", "TEXT"),
    ("flights", "export_error", "TEXT"),
    ("flights", "export_written_at", "INTEGER"),
    ("flights", "export_attempts", "INTEGER NOT NULL DEFAULT 0"),
];

/// One step of the schema, run inside its own transaction.
type Step = fn(&Connection) -> Result<(), StoreError>;

/// The store's schema, step by step: a store records the last step it
/// took in SQLite's `user_version`, and opening it takes the steps after
/// that, each in one transaction. Every step is safe on a store that
/// already has part of it (a data folder from before the steps were
/// numbered is at version 0 whatever columns it holds). Add a step; never
/// change one that has shipped.
const MIGRATIONS: [(&str, Step); 3] = [
    ("flights, jobs and idempotency keys", |c| {
        c.execute_batch(SCHEMA)?;
        Ok(())
    }),
    (
        "S3 sources, warnings and the flight's export",
        add_missing_columns,
    ),
    ("one frame per name in a flight", unique_frame_names),
];

/// The schema version this build writes: the number of [`MIGRATIONS`].
pub const SCHEMA_VERSION: u32 = MIGRATIONS.len() as u32;

/// Takes the store at `conn` to [`SCHEMA_VERSION`]; refuses a store written
/// by a newer build (its steps are unknown here).
fn migrate(conn: &mut Connection) -> Result<(), StoreError> {
    let at: u32 = conn.pragma_query_value(None, "user_version", |r| r.get(0))?;
    if at > SCHEMA_VERSION {
        return Err(StoreError::NewerSchema {
            found: at,
            supported: SCHEMA_VERSION,
        });
    }
    for (version, (what, step)) in (1u32..).zip(MIGRATIONS.iter()).skip(at as usize) {
        let tx = conn.transaction()?;
        step(&tx)?;
        tx.pragma_update(None, "user_version", version)?;
        tx.commit()?;
        tracing::info!(version, what, "job store schema migrated");
    }
    Ok(())
}

/// One frame per name in a flight, enforced by the database too. A store
/// written before this index may hold duplicates: it opens, they stay, and
/// new ones are still refused by `add_to_flight`.
fn unique_frame_names(conn: &Connection) -> Result<(), StoreError> {
    if let Err(e) = conn.execute_batch(
        "CREATE UNIQUE INDEX IF NOT EXISTS jobs_flight_image ON jobs(flight_id, image)",
    ) {
        tracing::warn!(error = %e, "frame names repeat within a flight in this store; new repeats are refused");
    }
    Ok(())
}

fn add_missing_columns(conn: &Connection) -> Result<(), StoreError> {
    for (table, column, kind) in ADDED_COLUMNS {
        let mut stmt = conn.prepare(&format!("PRAGMA table_info({table})"))?;
        let names: Vec<String> = stmt
            .query_map([], |r| r.get::<_, String>(1))?
            .collect::<Result<_, _>>()?;
        if !names.iter().any(|n| n == column) {
            conn.execute_batch(&format!("ALTER TABLE {table} ADD COLUMN {column} {kind}"))?;
        }
    }
    Ok(())
}

impl SqliteStore {
    /// Opens (or creates) the store at `path` with the default leases.
    pub fn open(path: &Path) -> Result<SqliteStore, StoreError> {
        SqliteStore::open_with(path, LeaseConfig::default())
    }

    /// Opens (or creates) the store at `path` and loads it. Jobs that were
    /// running when the process stopped go back to the queue.
    pub fn open_with(path: &Path, lease: LeaseConfig) -> Result<SqliteStore, StoreError> {
        let mut conn = Connection::open(path)?;
        // WAL: readers never block the writer; FULL: a commit is on disk
        // before the client hears "created".
        conn.pragma_update(None, "journal_mode", "WAL")?;
        conn.pragma_update(None, "synchronous", "FULL")?;
        conn.pragma_update(None, "foreign_keys", "ON")?;
        conn.busy_timeout(Duration::from_secs(5))?;
        migrate(&mut conn)?;
        let requeued = conn.execute(
            "UPDATE jobs SET state = 'queued', started_at = NULL WHERE state = 'running'",
            [],
        )?;
        if requeued > 0 {
            tracing::info!(
                requeued,
                "jobs interrupted by the last stop are queued again"
            );
        }
        let state = load(&conn)?;
        tracing::info!(
            flights = state.flights.len(),
            jobs = state.jobs.len(),
            queued = state.queue.len(),
            "job store loaded"
        );
        Ok(SqliteStore {
            lease,
            db: Mutex::new(conn),
            state: Mutex::new(state),
            work: Condvar::new(),
            changed: watch::channel(0).0,
        })
    }

    fn db(&self) -> MutexGuard<'_, Connection> {
        self.db.lock().expect("store db lock")
    }

    fn state(&self) -> MutexGuard<'_, State> {
        self.state.lock().expect("store state lock")
    }

    fn notify(&self) {
        self.changed.send_modify(|v| *v = v.wrapping_add(1));
    }

    /// Puts jobs whose lease expired back in the queue, or fails them on
    /// their last attempt. Called with both locks held.
    fn reap_expired(&self, db: &Connection, state: &mut State) -> Result<(), StoreError> {
        let now = Instant::now();
        let expired: Vec<JobId> = state
            .leases
            .iter()
            .filter(|(_, held)| held.until <= now)
            .map(|(id, _)| *id)
            .collect();
        for id in expired {
            state.leases.remove(&id);
            state.running -= 1;
            let job = state.jobs.get_mut(&id).expect("leased job exists");
            if job.cancel_requested {
                // Canceled while its worker was lost: it ends canceled.
                let finished = now_millis();
                db.execute(
                    "UPDATE jobs SET state = 'canceled', finished_at = ?2 WHERE id = ?1",
                    params![id.to_string(), finished],
                )?;
                job.state = JobState::Canceled;
                job.finished_at = Some(finished);
                job.cancel_requested = false;
            } else if job.attempts >= self.lease.max_attempts {
                let error = lease_expired_error(job.attempts);
                let finished = now_millis();
                db.execute(
                    "UPDATE jobs SET state = 'failed', finished_at = ?2, error_code = ?3,
                         error_message = ?4 WHERE id = ?1",
                    params![id.to_string(), finished, error.code.as_str(), error.message],
                )?;
                job.state = JobState::Failed;
                job.finished_at = Some(finished);
                job.error = Some(error);
            } else {
                db.execute(
                    "UPDATE jobs SET state = 'queued', started_at = NULL WHERE id = ?1",
                    params![id.to_string()],
                )?;
                job.state = JobState::Queued;
                job.started_at = None;
                let seq = job.seq;
                state.queue.insert((seq, id));
            }
            tracing::warn!(job.id = %id, "a job's lease expired: its worker stopped renewing it");
        }
        Ok(())
    }
}

impl JobStore for SqliteStore {
    /// A receiver that sees every change (for waiting without polling).
    fn subscribe(&self) -> watch::Receiver<u64> {
        self.changed.subscribe()
    }

    /// Records a new flight with its jobs in one transaction.
    /// `export_to` is an `s3://bucket/prefix/` for the results, written
    /// when every job has ended.
    fn create_flight(
        &self,
        params: &JobParams,
        jobs: &[NewJob],
        export_to: Option<String>,
        idem: Option<&IdemKey>,
    ) -> Result<FlightRecord, StoreError> {
        let flight = new_flight(params, jobs, export_to)?;
        let mut db = self.db();
        let tx = db.transaction()?;
        tx.execute(
            "INSERT INTO flights (id, created_at, params, export_to, export_state)
             VALUES (?1, ?2, ?3, ?4, ?5)",
            params![
                flight.id.to_string(),
                flight.created_at,
                serde_json::to_string(params).expect("params serialize"),
                flight.export.as_ref().map(|e| e.to.clone()),
                flight.export.as_ref().map(|e| e.state.as_str()),
            ],
        )?;
        let records = insert_jobs(&tx, flight.id, jobs)?;
        insert_idem(&tx, idem, flight.id, &records)?;
        tx.commit()?;
        let mut state = self.state();
        state.flights.insert(flight.id, flight.clone());
        state.flight_jobs.insert(flight.id, Vec::new());
        add_jobs(&mut state, records);
        drop(state);
        self.work.notify_all();
        self.notify();
        Ok(flight)
    }

    /// Adds jobs to an existing flight; `None` if there is no such flight.
    /// Checked under the store's lock, so concurrent requests cannot both
    /// pass: every name new to the flight and once in `jobs`
    /// ([`StoreError::DuplicateImage`]), the flight at most `max_frames`
    /// frames ([`StoreError::TooManyFrames`]).
    fn add_to_flight(
        &self,
        flight: FlightId,
        jobs: &[NewJob],
        idem: Option<&IdemKey>,
        max_frames: usize,
    ) -> Result<Option<Vec<JobRecord>>, StoreError> {
        let mut db = self.db();
        if !self.state().flights.contains_key(&flight) {
            return Ok(None);
        }
        let mut names: std::collections::HashSet<String> =
            images_of(&self.state(), flight).into_iter().collect();
        let would = names.len() + jobs.len();
        if would > max_frames {
            return Err(StoreError::TooManyFrames {
                would,
                max: max_frames,
            });
        }
        for job in jobs {
            if !names.insert(job.image.clone()) {
                return Err(StoreError::DuplicateImage(job.image.clone()));
            }
        }
        let tx = db.transaction()?;
        let records = insert_jobs(&tx, flight, jobs)?;
        insert_idem(&tx, idem, flight, &records)?;
        // New frames mean new results: write them again at the end.
        tx.execute(
            "UPDATE flights SET export_state = 'pending', export_attempts = 0, export_error = NULL
             WHERE id = ?1 AND export_to IS NOT NULL",
            params![flight.to_string()],
        )?;
        tx.commit()?;
        let mut state = self.state();
        if let Some(export) = state
            .flights
            .get_mut(&flight)
            .and_then(|f| f.export.as_mut())
        {
            export.state = ExportState::Pending;
            export.attempts = 0;
            export.error = None;
        }
        add_jobs(&mut state, records.clone());
        drop(state);
        self.work.notify_all();
        self.notify();
        Ok(Some(records))
    }

    fn flight(&self, id: FlightId) -> Result<Option<FlightRecord>, StoreError> {
        Ok(self.state().flights.get(&id).cloned())
    }

    /// Image names already used in a flight.
    fn flight_images(&self, id: FlightId) -> Result<Vec<String>, StoreError> {
        let state = self.state();
        Ok(images_of(&state, id))
    }

    /// A flight's jobs in submission order.
    fn flight_jobs(&self, id: FlightId) -> Result<Option<Vec<JobRecord>>, StoreError> {
        let state = self.state();
        Ok(state
            .flight_jobs
            .get(&id)
            .map(|ids| ids.iter().map(|j| state.jobs[j].clone()).collect()))
    }

    /// Flights whose every job ended before `cutoff` (and whose export, if
    /// any, is no longer pending): due for removal.
    fn expired_flights(&self, cutoff: Millis) -> Result<Vec<FlightId>, StoreError> {
        let state = self.state();
        Ok(state
            .flights
            .values()
            .filter(|f| {
                f.export
                    .as_ref()
                    .is_none_or(|e| e.state != ExportState::Pending)
            })
            .filter(|f| {
                let jobs = &state.flight_jobs[&f.id];
                let ended = jobs
                    .iter()
                    .map(|j| &state.jobs[j])
                    .all(|j| j.state.is_terminal() && j.finished_at.is_some_and(|t| t < cutoff));
                ended && (!jobs.is_empty() || f.created_at < cutoff)
            })
            .map(|f| f.id)
            .collect())
    }

    /// What the first request with `key` created, if one did.
    fn idempotent(&self, key: &str) -> Result<Option<IdemRecord>, StoreError> {
        let db = self.db();
        let row = db.query_row(
            "SELECT request, flight_id, job_ids FROM idempotency WHERE key = ?1",
            params![key],
            |r| {
                Ok((
                    r.get::<_, String>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, String>(2)?,
                ))
            },
        );
        let (request, flight, jobs) = match row {
            Ok(row) => row,
            Err(rusqlite::Error::QueryReturnedNoRows) => return Ok(None),
            Err(e) => return Err(e.into()),
        };
        let ids: Vec<String> = serde_json::from_str(&jobs)
            .map_err(|e| StoreError::Corrupt(format!("idempotency job ids: {e}")))?;
        Ok(Some(IdemRecord {
            request,
            flight: parse_id(&flight)?,
            jobs: ids.iter().map(|i| parse_id(i)).collect::<Result<_, _>>()?,
        }))
    }

    /// Flights, oldest first, after the cursor.
    fn flights(
        &self,
        after: Option<FlightId>,
        limit: usize,
    ) -> Result<Vec<FlightRecord>, StoreError> {
        let state = self.state();
        let start = after.map_or(std::ops::Bound::Unbounded, std::ops::Bound::Excluded);
        Ok(state
            .flights
            .range((start, std::ops::Bound::Unbounded))
            .take(limit)
            .map(|(_, f)| f.clone())
            .collect())
    }

    fn job(&self, id: JobId) -> Result<Option<JobRecord>, StoreError> {
        Ok(self.state().jobs.get(&id).cloned())
    }

    /// Jobs matching `filter`, oldest first.
    fn jobs(&self, filter: &JobFilter) -> Result<Vec<JobRecord>, StoreError> {
        let state = self.state();
        let start = filter
            .after
            .map_or(std::ops::Bound::Unbounded, std::ops::Bound::Excluded);
        Ok(state
            .jobs
            .range((start, std::ops::Bound::Unbounded))
            .map(|(_, j)| j)
            .filter(|j| filter.flight.is_none_or(|f| j.flight_id == f))
            .filter(|j| filter.state.is_none_or(|s| j.state == s))
            .take(filter.limit)
            .cloned()
            .collect())
    }

    fn stats(&self) -> Result<QueueStats, StoreError> {
        let state = self.state();
        let fetched = state
            .queue
            .iter()
            .filter(|(_, id)| state.jobs[id].source.is_some())
            .count();
        Ok(QueueStats {
            fetching: state.fetching.len(),
            fetched,
            queued: state.queue.len(),
            running: state.running,
        })
    }

    /// Waits up to `timeout` for a queued job and marks it running. Returns
    /// `None` on timeout or when `stop` is set.
    fn claim_next(
        &self,
        stop: &AtomicBool,
        timeout: Duration,
    ) -> Result<Option<Claim>, StoreError> {
        let deadline = Instant::now() + timeout;
        loop {
            {
                let db = self.db();
                let mut state = self.state();
                self.reap_expired(&db, &mut state)?;
                if stop.load(Ordering::SeqCst) {
                    return Ok(None);
                }
                if let Some(&(seq, id)) = state.queue.first() {
                    let started = now_millis();
                    db.execute(
                        "UPDATE jobs SET state = 'running', started_at = ?2, attempts = attempts + 1
                         WHERE id = ?1",
                        params![id.to_string(), started],
                    )?;
                    state.queue.remove(&(seq, id));
                    state.running += 1;
                    let lease = Lease {
                        job: id,
                        token: uuid::Uuid::new_v4(),
                    };
                    let until = Instant::now() + self.lease.lease;
                    state.leases.insert(
                        id,
                        Held {
                            token: lease.token,
                            until,
                        },
                    );
                    let job = state.jobs.get_mut(&id).expect("queued job exists");
                    job.state = JobState::Running;
                    job.started_at = Some(started);
                    job.attempts += 1;
                    job.tiles_done = 0;
                    job.tiles_total = 0;
                    job.cancel_requested = false;
                    let job = job.clone();
                    let params = state.flights[&job.flight_id].params.clone();
                    drop(state);
                    drop(db);
                    self.notify();
                    return Ok(Some(Claim { job, params, lease }));
                }
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            // Wait for work, the next lease to expire, or the deadline.
            let state = self.state();
            let wake = state
                .leases
                .values()
                .map(|h| h.until)
                .min()
                .map_or(deadline, |e| e.clamp(now, deadline));
            let _ = self
                .work
                .wait_timeout_while(state, wake - now, |s| {
                    s.queue.is_empty() && !stop.load(Ordering::SeqCst)
                })
                .expect("store state lock");
        }
    }

    fn heartbeat(&self, lease: &Lease, progress: &Progress) -> Result<LeaseState, StoreError> {
        let mut state = self.state();
        match state.leases.get_mut(&lease.job) {
            Some(held) if held.token == lease.token => {
                held.until = Instant::now() + self.lease.lease;
            }
            _ => return Ok(LeaseState::Lost),
        }
        let job = state.jobs.get_mut(&lease.job).expect("leased job exists");
        let before = (job.width, job.height, job.tiles_done, job.tiles_total);
        if let Some((w, h)) = progress.size {
            job.width = Some(w);
            job.height = Some(h);
        }
        job.tiles_done = progress.tiles_done;
        job.tiles_total = progress.tiles_total;
        let cancel = job.cancel_requested;
        let changed = before != (job.width, job.height, job.tiles_done, job.tiles_total);
        drop(state);
        if changed {
            self.notify();
        }
        Ok(LeaseState::Held { cancel })
    }

    /// The first `limit` jobs waiting for their frame, in queue order.
    fn to_fetch(&self, limit: usize) -> Result<Vec<JobRecord>, StoreError> {
        let state = self.state();
        Ok(state
            .fetching
            .iter()
            .take(limit)
            .map(|(_, id)| state.jobs[id].clone())
            .collect())
    }

    /// A fetched frame is in `frames/`: the job joins the worker queue.
    /// Returns `false` if the job was canceled or deleted meanwhile (the
    /// caller removes the frame).
    fn fetched(&self, id: JobId, ext: &str, bytes: u64) -> Result<bool, StoreError> {
        let db = self.db();
        let mut state = self.state();
        let Some(job) = state.jobs.get(&id) else {
            return Ok(false);
        };
        if job.state != JobState::Fetching {
            return Ok(false);
        }
        let seq = job.seq;
        db.execute(
            "UPDATE jobs SET state = 'queued', ext = ?2, bytes = ?3 WHERE id = ?1",
            params![id.to_string(), ext, bytes as i64],
        )?;
        state.fetching.remove(&(seq, id));
        state.queue.insert((seq, id));
        let job = state.jobs.get_mut(&id).expect("job exists");
        job.state = JobState::Queued;
        job.ext = ext.to_string();
        job.bytes = bytes;
        drop(state);
        drop(db);
        self.work.notify_all();
        self.notify();
        Ok(true)
    }

    /// A frame could not be fetched: the job fails with the reason.
    fn fetch_failed(&self, id: JobId, error: &JobError) -> Result<(), StoreError> {
        let db = self.db();
        let mut state = self.state();
        let Some(job) = state.jobs.get(&id) else {
            return Ok(());
        };
        if job.state != JobState::Fetching {
            return Ok(());
        }
        let (seq, now) = (job.seq, now_millis());
        db.execute(
            "UPDATE jobs SET state = 'failed', finished_at = ?2, error_code = ?3, error_message = ?4
             WHERE id = ?1",
            params![id.to_string(), now, error.code.as_str(), error.message],
        )?;
        state.fetching.remove(&(seq, id));
        let job = state.jobs.get_mut(&id).expect("job exists");
        job.state = JobState::Failed;
        job.finished_at = Some(now);
        job.error = Some(error.clone());
        drop(state);
        drop(db);
        self.notify();
        Ok(())
    }

    /// Flights whose results are due to be written: export pending and
    /// every job ended.
    fn exports_due(&self) -> Result<Vec<(FlightRecord, Vec<JobRecord>)>, StoreError> {
        let state = self.state();
        let mut due = Vec::new();
        for flight in state.flights.values() {
            if flight.export.as_ref().map(|e| e.state) != Some(ExportState::Pending) {
                continue;
            }
            let jobs: Vec<JobRecord> = state.flight_jobs[&flight.id]
                .iter()
                .map(|id| state.jobs[id].clone())
                .collect();
            if jobs.iter().all(|j| j.state.is_terminal()) {
                due.push((flight.clone(), jobs));
            }
        }
        Ok(due)
    }

    /// Records an export attempt: written, or failed with the reason
    /// (`give_up` marks it failed for good, else it stays pending).
    fn export_done(
        &self,
        flight: FlightId,
        result: Result<(), String>,
        give_up: bool,
    ) -> Result<(), StoreError> {
        let db = self.db();
        let mut state = self.state();
        let Some(export) = state
            .flights
            .get_mut(&flight)
            .and_then(|f| f.export.as_mut())
        else {
            return Ok(());
        };
        export.record_attempt(result, give_up);
        db.execute(
            "UPDATE flights SET export_state = ?2, export_error = ?3, export_written_at = ?4,
                 export_attempts = ?5 WHERE id = ?1",
            params![
                flight.to_string(),
                export.state.as_str(),
                export.error,
                export.written_at,
                export.attempts
            ],
        )?;
        drop(state);
        drop(db);
        self.notify();
        Ok(())
    }

    /// Wakes workers waiting in [`JobStore::claim_next`] (used at shutdown).
    fn wake_workers(&self) {
        let _state = self.state();
        self.work.notify_all();
    }

    /// Puts the job back in the queue in memory only: the store still says
    /// running, which the next start requeues. For a server that stops
    /// while its disk is full.
    fn release_unrecorded(&self, lease: &Lease) {
        let mut state = self.state();
        if state.leases.get(&lease.job).map(|h| h.token) != Some(lease.token) {
            return;
        }
        state.leases.remove(&lease.job);
        let job = state.jobs.get_mut(&lease.job).expect("leased job exists");
        job.state = JobState::Queued;
        job.started_at = None;
        let seq = job.seq;
        state.queue.insert((seq, lease.job));
        state.running -= 1;
    }

    fn finish(&self, lease: &Lease, outcome: &Outcome) -> Result<Finished, StoreError> {
        let db = self.db();
        let id = lease.job;
        {
            let state = self.state();
            if !state.jobs.contains_key(&id) {
                // Deleted while running; the running count was settled by delete.
                return Ok(Finished::Deleted);
            }
            if state.leases.get(&id).map(|h| h.token) != Some(lease.token) {
                return Ok(Finished::Lost);
            }
        }
        let end = Ending::of(outcome);
        let (state_name, finished_at) = (end.state, end.finished_at);
        db.execute(
            "UPDATE jobs SET state = ?2, finished_at = ?3, error_code = ?4, error_message = ?5,
                 width = COALESCE(?6, width), height = COALESCE(?7, height), targets = ?8,
                 started_at = CASE WHEN ?2 = 'queued' THEN NULL ELSE started_at END,
                 warnings = ?9
             WHERE id = ?1",
            params![
                id.to_string(),
                end.state.as_str(),
                end.finished_at,
                end.error.as_ref().map(|e| e.code.as_str()),
                end.error.as_ref().map(|e| e.message.clone()),
                end.size.map(|s| s.0),
                end.size.map(|s| s.1),
                end.targets,
                end.warnings_json(),
            ],
        )?;
        let (error, size, targets, warnings) = (end.error, end.size, end.targets, end.warnings);
        let mut state = self.state();
        state.leases.remove(&id);
        let job = state
            .jobs
            .get_mut(&id)
            .expect("checked above under the db lock");
        job.state = state_name;
        job.finished_at = finished_at;
        job.error = error;
        job.cancel_requested = false;
        if let Some((w, h)) = size {
            job.width = Some(w);
            job.height = Some(h);
        }
        job.targets = targets;
        job.warnings = warnings;
        let seq = job.seq;
        if state_name == JobState::Queued {
            job.started_at = None;
            state.queue.insert((seq, id));
        }
        state.running -= 1;
        drop(state);
        drop(db);
        if state_name == JobState::Queued {
            self.work.notify_all();
        }
        self.notify();
        Ok(Finished::Recorded)
    }

    /// Cancels a job: a queued one at once, a running one at its next heartbeat.
    /// `None` if there is no such job.
    fn cancel_job(&self, id: JobId) -> Result<Option<JobRecord>, StoreError> {
        let db = self.db();
        let mut state = self.state();
        let Some(job) = state.jobs.get(&id).cloned() else {
            return Ok(None);
        };
        let out = cancel_locked(&db, &mut state, &job)?;
        drop(state);
        drop(db);
        self.notify();
        Ok(Some(out))
    }

    /// Cancels every unfinished job of a flight; `None` if there is no such
    /// flight.
    fn cancel_flight(&self, id: FlightId) -> Result<Option<Vec<JobRecord>>, StoreError> {
        let db = self.db();
        let mut state = self.state();
        let Some(ids) = state.flight_jobs.get(&id).cloned() else {
            return Ok(None);
        };
        let mut out = Vec::with_capacity(ids.len());
        for job_id in ids {
            let job = state.jobs[&job_id].clone();
            out.push(cancel_locked(&db, &mut state, &job)?);
        }
        drop(state);
        drop(db);
        self.notify();
        Ok(Some(out))
    }

    /// Deletes a job's record (cancelling it if it runs); returns the
    /// removed record so the caller can remove its files.
    fn delete_job(&self, id: JobId) -> Result<Option<JobRecord>, StoreError> {
        let db = self.db();
        let mut state = self.state();
        let Some(job) = state.jobs.get(&id).cloned() else {
            return Ok(None);
        };
        db.execute("DELETE FROM jobs WHERE id = ?1", params![id.to_string()])?;
        remove_locked(&mut state, &job);
        if let Some(ids) = state.flight_jobs.get_mut(&job.flight_id) {
            ids.retain(|j| *j != id);
        }
        drop(state);
        drop(db);
        self.notify();
        Ok(Some(job))
    }

    /// Deletes a flight and all its jobs; returns the removed jobs.
    fn delete_flight(&self, id: FlightId) -> Result<Option<Vec<JobRecord>>, StoreError> {
        let db = self.db();
        let mut state = self.state();
        if !state.flights.contains_key(&id) {
            return Ok(None);
        }
        db.execute("DELETE FROM flights WHERE id = ?1", params![id.to_string()])?;
        let ids = state.flight_jobs.remove(&id).unwrap_or_default();
        state.flights.remove(&id);
        let mut out = Vec::with_capacity(ids.len());
        for job_id in ids {
            let job = state.jobs[&job_id].clone();
            remove_locked(&mut state, &job);
            out.push(job);
        }
        drop(state);
        drop(db);
        self.notify();
        Ok(Some(out))
    }
}

/// Image names already used in a flight.
fn images_of(state: &State, id: FlightId) -> Vec<String> {
    state
        .flight_jobs
        .get(&id)
        .map(|ids| ids.iter().map(|j| state.jobs[j].image.clone()).collect())
        .unwrap_or_default()
}

/// Why a job whose lease expired on its last attempt failed.
pub(super) fn lease_expired_error(attempts: u32) -> JobError {
    JobError {
        code: ErrorCode::WorkerCrashed,
        message: format!(
            "its worker stopped renewing its claim on each of {attempts} attempts; the frame is not retried"
        ),
    }
}

/// Records an idempotency key with what its request created; a key taken
/// by a request that committed first is [`StoreError::KeyTaken`].
fn insert_idem(
    tx: &rusqlite::Transaction<'_>,
    idem: Option<&IdemKey>,
    flight: FlightId,
    jobs: &[JobRecord],
) -> Result<(), StoreError> {
    let Some(idem) = idem else { return Ok(()) };
    let ids: Vec<String> = jobs.iter().map(|j| j.id.to_string()).collect();
    let inserted = tx.execute(
        "INSERT INTO idempotency (key, request, flight_id, job_ids, created_at)
         VALUES (?1, ?2, ?3, ?4, ?5) ON CONFLICT (key) DO NOTHING",
        params![
            idem.key,
            idem.request,
            flight.to_string(),
            serde_json::to_string(&ids).expect("ids serialize"),
            now_millis()
        ],
    )?;
    if inserted == 0 {
        return Err(StoreError::KeyTaken);
    }
    Ok(())
}

fn insert_jobs(
    tx: &rusqlite::Transaction<'_>,
    flight: FlightId,
    jobs: &[NewJob],
) -> Result<Vec<JobRecord>, StoreError> {
    let created = now_millis();
    let mut out = Vec::with_capacity(jobs.len());
    for new in jobs {
        let (state, error, finished) = new.starts(created);
        let (source, source_etag) = new.source.clone().unzip();
        let source_etag = source_etag.flatten();
        tx.execute(
            "INSERT INTO jobs (id, flight_id, image, ext, bytes, state, created_at, finished_at,
                 error_code, error_message, source, source_etag)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12)",
            params![
                new.id.to_string(),
                flight.to_string(),
                new.image,
                new.ext,
                new.bytes as i64,
                state.as_str(),
                created,
                finished,
                error.as_ref().map(|e| e.code.as_str()),
                error.as_ref().map(|e| e.message.clone()),
                source,
                source_etag,
            ],
        )?;
        out.push(JobRecord {
            id: new.id,
            flight_id: flight,
            seq: tx.last_insert_rowid(),
            image: new.image.clone(),
            ext: new.ext.clone(),
            bytes: new.bytes,
            state,
            created_at: created,
            started_at: None,
            finished_at: finished,
            attempts: 0,
            error,
            width: None,
            height: None,
            targets: None,
            tiles_done: 0,
            tiles_total: 0,
            cancel_requested: false,
            source,
            source_etag,
            warnings: Vec::new(),
        });
    }
    Ok(out)
}

fn add_jobs(state: &mut State, records: Vec<JobRecord>) {
    for job in records {
        match job.state {
            JobState::Queued => {
                state.queue.insert((job.seq, job.id));
            }
            JobState::Fetching => {
                state.fetching.insert((job.seq, job.id));
            }
            _ => {}
        }
        state
            .flight_jobs
            .entry(job.flight_id)
            .or_default()
            .push(job.id);
        state.jobs.insert(job.id, job);
    }
}

fn cancel_locked(
    db: &Connection,
    state: &mut State,
    job: &JobRecord,
) -> Result<JobRecord, StoreError> {
    match job.state {
        JobState::Queued | JobState::Fetching => {
            let now = now_millis();
            db.execute(
                "UPDATE jobs SET state = 'canceled', finished_at = ?2 WHERE id = ?1",
                params![job.id.to_string(), now],
            )?;
            state.queue.remove(&(job.seq, job.id));
            state.fetching.remove(&(job.seq, job.id));
            let rec = state.jobs.get_mut(&job.id).expect("job exists");
            rec.state = JobState::Canceled;
            rec.finished_at = Some(now);
            Ok(rec.clone())
        }
        JobState::Running => {
            let rec = state.jobs.get_mut(&job.id).expect("job exists");
            rec.cancel_requested = true;
            Ok(rec.clone())
        }
        _ => Ok(job.clone()),
    }
}

fn remove_locked(state: &mut State, job: &JobRecord) {
    state.queue.remove(&(job.seq, job.id));
    state.fetching.remove(&(job.seq, job.id));
    if state.leases.remove(&job.id).is_some() {
        state.running -= 1;
    }
    state.jobs.remove(&job.id);
}

fn load(conn: &Connection) -> Result<State, StoreError> {
    let mut state = State::default();
    let mut stmt = conn.prepare(
        "SELECT id, created_at, params, export_to, export_state, export_error, export_written_at,
                export_attempts
         FROM flights",
    )?;
    let mut rows = stmt.query([])?;
    while let Some(r) = rows.next()? {
        let id = parse_id(&r.get::<_, String>(0)?)?;
        let params: JobParams = serde_json::from_str(&r.get::<_, String>(2)?)
            .map_err(|e| StoreError::Corrupt(format!("flight {id} params: {e}")))?;
        let export = match r.get::<_, Option<String>>(3)? {
            None => None,
            Some(to) => {
                let name: String = r.get::<_, Option<String>>(4)?.unwrap_or_default();
                Some(Export {
                    to,
                    state: ExportState::parse(&name)
                        .ok_or_else(|| StoreError::Corrupt(format!("export state {name:?}")))?,
                    error: r.get(5)?,
                    written_at: r.get(6)?,
                    attempts: r.get(7)?,
                })
            }
        };
        state.flights.insert(
            id,
            FlightRecord {
                id,
                created_at: r.get(1)?,
                params,
                export,
            },
        );
        state.flight_jobs.insert(id, Vec::new());
    }
    let mut stmt = conn.prepare(
        "SELECT seq, id, flight_id, image, ext, bytes, state, created_at, started_at, finished_at,
                attempts, error_code, error_message, width, height, targets, source, source_etag,
                warnings
         FROM jobs ORDER BY seq",
    )?;
    let mut rows = stmt.query([])?;
    let mut records = Vec::new();
    while let Some(r) = rows.next()? {
        let state_name: String = r.get(6)?;
        let error = stored_error(r.get(11)?, r.get(12)?);
        records.push(JobRecord {
            seq: r.get(0)?,
            id: parse_id(&r.get::<_, String>(1)?)?,
            flight_id: parse_id(&r.get::<_, String>(2)?)?,
            image: r.get(3)?,
            ext: r.get(4)?,
            bytes: r.get::<_, i64>(5)? as u64,
            state: JobState::parse(&state_name)
                .ok_or_else(|| StoreError::Corrupt(format!("job state {state_name:?}")))?,
            created_at: r.get(7)?,
            started_at: r.get(8)?,
            finished_at: r.get(9)?,
            attempts: r.get(10)?,
            error,
            width: r.get(13)?,
            height: r.get(14)?,
            targets: r.get(15)?,
            tiles_done: 0,
            tiles_total: 0,
            cancel_requested: false,
            source: r.get(16)?,
            source_etag: r.get(17)?,
            warnings: r
                .get::<_, Option<String>>(18)?
                .and_then(|t| serde_json::from_str(&t).ok())
                .unwrap_or_default(),
        });
    }
    add_jobs(&mut state, records);
    Ok(state)
}

fn parse_id(s: &str) -> Result<uuid::Uuid, StoreError> {
    s.parse()
        .map_err(|_| StoreError::Corrupt(format!("id {s:?}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sourced(image: &str) -> NewJob {
        NewJob {
            id: uuid::Uuid::now_v7(),
            image: image.into(),
            ext: "none".into(),
            bytes: 10,
            rejected: None,
            source: Some((format!("s3://b/{image}"), Some("\"etag\"".into()))),
        }
    }

    #[test]
    fn fetching_jobs_survive_a_restart_and_join_the_queue_once_fetched() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("jobs.sqlite");
        let (a, b) = (sourced("a.tif"), sourced("b.tif"));
        let store = SqliteStore::open(&path).unwrap();
        let flight = store
            .create_flight(
                &JobParams::default(),
                &[a.clone(), b.clone()],
                Some("s3://b/out/".into()),
                None,
            )
            .unwrap();
        assert_eq!(store.stats().unwrap().fetching, 2);
        assert_eq!(store.stats().unwrap().queued, 0);
        drop(store);

        let store = SqliteStore::open(&path).unwrap();
        let waiting: Vec<JobId> = store.to_fetch(10).unwrap().iter().map(|j| j.id).collect();
        assert_eq!(waiting, [a.id, b.id]);
        let job = store.job(a.id).unwrap().unwrap();
        assert_eq!(job.source.as_deref(), Some("s3://b/a.tif"));
        assert_eq!(job.source_etag.as_deref(), Some("\"etag\""));
        assert!(store.fetched(a.id, "tif", 12).unwrap());
        let error = JobError {
            code: crate::error_code::ErrorCode::NoSuchObject,
            message: "gone".into(),
        };
        store.fetch_failed(b.id, &error).unwrap();
        // A second answer for the same fetch changes nothing.
        assert!(!store.fetched(a.id, "tif", 12).unwrap());
        let stats = store.stats().unwrap();
        assert_eq!((stats.fetching, stats.queued, stats.fetched), (0, 1, 1));
        let stop = AtomicBool::new(false);
        let claim = store
            .claim_next(&stop, Duration::from_millis(10))
            .unwrap()
            .unwrap();
        assert_eq!((claim.job.id, claim.job.ext.as_str()), (a.id, "tif"));
        assert!(store.exports_due().unwrap().is_empty(), "a job still runs");
        let done = Outcome::Succeeded {
            width: 1,
            height: 1,
            targets: 0,
            warnings: vec!["partial: rows 1..2 do not decode".into()],
        };
        assert_eq!(
            store.finish(&claim.lease, &done).unwrap(),
            Finished::Recorded
        );
        let due = store.exports_due().unwrap();
        assert_eq!(due.len(), 1);
        assert_eq!(due[0].0.id, flight.id);
        store.export_done(flight.id, Ok(()), false).unwrap();
        drop(store);

        let store = SqliteStore::open(&path).unwrap();
        let export = store.flight(flight.id).unwrap().unwrap().export.unwrap();
        assert_eq!((export.state, export.attempts), (ExportState::Written, 1));
        // A succeeded job's warnings survive a restart.
        assert_eq!(
            store.job(a.id).unwrap().unwrap().warnings,
            ["partial: rows 1..2 do not decode"]
        );
        assert_eq!(store.job(b.id).unwrap().unwrap().error, Some(error));
    }

    #[test]
    fn a_name_is_recorded_once_per_flight_and_the_limit_holds_in_the_store() {
        let dir = tempfile::tempdir().unwrap();
        let store = SqliteStore::open(&dir.path().join("jobs.sqlite")).unwrap();
        let flight = store
            .create_flight(&JobParams::default(), &[sourced("a.tif")], None, None)
            .unwrap();
        let dup = store.add_to_flight(flight.id, &[sourced("a.tif")], None, 10);
        assert!(matches!(dup, Err(StoreError::DuplicateImage(n)) if n == "a.tif"));
        let twice = store.add_to_flight(flight.id, &[sourced("b.tif"), sourced("b.tif")], None, 10);
        assert!(matches!(twice, Err(StoreError::DuplicateImage(n)) if n == "b.tif"));
        let many = store.add_to_flight(flight.id, &[sourced("c.tif"), sourced("d.tif")], None, 2);
        assert!(matches!(
            many,
            Err(StoreError::TooManyFrames { would: 3, max: 2 })
        ));
        assert_eq!(store.flight_images(flight.id).unwrap(), ["a.tif"]);
        store
            .add_to_flight(flight.id, &[sourced("b.tif")], None, 2)
            .unwrap()
            .unwrap();
        assert_eq!(store.flight_jobs(flight.id).unwrap().unwrap().len(), 2);
        // The database refuses a repeat on its own too.
        let db = store.db();
        let insert = db.execute(
            "INSERT INTO jobs (id, flight_id, image, ext, bytes, state, created_at)
             VALUES (?1, ?2, 'a.tif', 'tif', 5, 'queued', 1)",
            params![uuid::Uuid::now_v7().to_string(), flight.id.to_string()],
        );
        assert!(insert.is_err());
    }

    #[test]
    fn a_data_folder_from_before_s3_sources_opens_with_its_jobs() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("jobs.sqlite");
        let conn = Connection::open(&path).unwrap();
        conn.execute_batch(SCHEMA).unwrap();
        conn.execute(
            "INSERT INTO flights (id, created_at, params) VALUES (?1, 1, ?2)",
            params![
                uuid::Uuid::nil().to_string(),
                serde_json::to_string(&JobParams::default()).unwrap()
            ],
        )
        .unwrap();
        conn.execute(
            "INSERT INTO jobs (id, flight_id, image, ext, bytes, state, created_at)
             VALUES (?1, ?2, 'a.tif', 'tif', 5, 'queued', 1)",
            params![
                uuid::Uuid::now_v7().to_string(),
                uuid::Uuid::nil().to_string()
            ],
        )
        .unwrap();
        drop(conn);
        let store = SqliteStore::open(&path).unwrap();
        assert_eq!(store.stats().unwrap().queued, 1);
        assert_eq!(
            store.flight(uuid::Uuid::nil()).unwrap().unwrap().export,
            None
        );
        drop(store);
        // Migrated to this build's version, which a second open keeps.
        let version = |path: &Path| -> u32 {
            Connection::open(path)
                .unwrap()
                .pragma_query_value(None, "user_version", |r| r.get(0))
                .unwrap()
        };
        assert_eq!(version(&path), SCHEMA_VERSION);
        SqliteStore::open(&path).unwrap();
        assert_eq!(version(&path), SCHEMA_VERSION);
    }

    #[test]
    fn a_store_from_a_newer_build_is_refused_and_left_as_it_is() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("jobs.sqlite");
        drop(SqliteStore::open(&path).unwrap());
        let conn = Connection::open(&path).unwrap();
        conn.pragma_update(None, "user_version", SCHEMA_VERSION + 1)
            .unwrap();
        drop(conn);
        let err = SqliteStore::open(&path).err().expect("refused").to_string();
        assert!(
            err.contains(&format!("version {}", SCHEMA_VERSION + 1))
                && err.contains("newer than this build"),
            "{err}"
        );
        let conn = Connection::open(&path).unwrap();
        let v: u32 = conn
            .pragma_query_value(None, "user_version", |r| r.get(0))
            .unwrap();
        assert_eq!(v, SCHEMA_VERSION + 1);
    }
}
