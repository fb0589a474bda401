//! The shared job store: PostgreSQL, for replicas that share one queue.
//!
//! Every read and write goes to the database (no state is kept in the
//! process beyond the last progress each lease reported). Claims take the
//! oldest queued job with `FOR UPDATE SKIP LOCKED`, so replicas never take
//! the same job; a lease and a cancel request are columns of the job;
//! times of leases come from the database's clock, so replicas' clocks do
//! not matter. Every change sends `NOTIFY gcp_tagger`; one listening
//! connection per process turns those into wake-ups for waiting workers and
//! into the change counter long-polls and event streams wait on, whichever
//! replica made the change.
//!
//! The calls are blocking (the [`JobStore`] interface): each runs on this
//! store's own small tokio runtime and the caller waits for its answer, so
//! they may be made from worker threads and from async handlers alike.

use std::collections::HashMap;
use std::future::Future;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use deadpool_postgres::{GenericClient, Manager, ManagerConfig, Pool, RecyclingMethod};
use tokio::sync::watch;
use tokio_postgres::{NoTls, Row};

use super::sqlite::lease_expired_error;
use super::*;
use crate::background::Background;

/// The database's clock in milliseconds since the epoch.
const NOW_MS: &str = "(extract(epoch from clock_timestamp()) * 1000)::bigint";

/// The channel every change is announced on.
const CHANNEL: &str = "gcp_tagger";

/// Columns of a job, in the order [`job_from_row`] reads them.
const JOB_COLS: &str = "seq, id, flight_id, image, ext, bytes, state, created_at, started_at,
    finished_at, attempts, error_code, error_message, width, height, targets, source,
    source_etag, warnings, tiles_done, tiles_total, cancel_requested";

/// Columns of a flight, in the order [`flight_from_row`] reads them.
const FLIGHT_COLS: &str = "id, created_at, params, export_to, export_state, export_error,
    export_written_at, export_attempts";

/// How long a waiting worker sleeps at most before looking again (other
/// replicas' expired leases, a lost listening connection).
const POLL: Duration = Duration::from_secs(1);

/// The schema, step by step; a step is never changed once shipped.
const MIGRATIONS: [(&str, &str); 1] = [(
    "flights, jobs with leases, and idempotency keys",
    "CREATE TABLE flights (
        id UUID PRIMARY KEY,
        created_at BIGINT NOT NULL,
        params TEXT NOT NULL,
        export_to TEXT,
        export_state TEXT,
        export_error TEXT,
        export_written_at BIGINT,
        export_attempts INTEGER NOT NULL DEFAULT 0
    );
    CREATE TABLE jobs (
        seq BIGSERIAL PRIMARY KEY,
        id UUID NOT NULL UNIQUE,
        flight_id UUID NOT NULL REFERENCES flights(id) ON DELETE CASCADE,
        image TEXT NOT NULL,
        ext TEXT NOT NULL,
        bytes BIGINT NOT NULL,
        state TEXT NOT NULL,
        created_at BIGINT NOT NULL,
        started_at BIGINT,
        finished_at BIGINT,
        attempts INTEGER NOT NULL DEFAULT 0,
        error_code TEXT,
        error_message TEXT,
        width INTEGER,
        height INTEGER,
        targets INTEGER,
        source TEXT,
        source_etag TEXT,
        warnings TEXT,
        lease_token UUID,
        lease_until BIGINT,
        cancel_requested BOOLEAN NOT NULL DEFAULT FALSE,
        tiles_done INTEGER NOT NULL DEFAULT 0,
        tiles_total INTEGER NOT NULL DEFAULT 0,
        UNIQUE (flight_id, image)
    );
    CREATE INDEX jobs_flight ON jobs(flight_id, seq);
    CREATE INDEX jobs_state ON jobs(state, seq);
    CREATE TABLE idempotency (
        key TEXT PRIMARY KEY,
        request TEXT NOT NULL,
        flight_id UUID NOT NULL REFERENCES flights(id) ON DELETE CASCADE,
        job_ids TEXT NOT NULL,
        created_at BIGINT NOT NULL
    );",
)];

/// The schema version this build writes.
pub const PG_SCHEMA_VERSION: u32 = MIGRATIONS.len() as u32;

/// Wake-ups for workers waiting in `claim_next`: a counter bumped on every
/// announced change.
#[derive(Default)]
struct Wake {
    generation: Mutex<u64>,
    cond: Condvar,
}

impl Wake {
    fn bump(&self) {
        *self.generation.lock().expect("wake lock") += 1;
        self.cond.notify_all();
    }
}

/// The PostgreSQL job store; share it in an `Arc`.
pub struct PgStore {
    lease: LeaseConfig,
    /// The calls block, from worker threads and handlers.
    rt: Background,
    pool: Pool,
    changed: watch::Sender<u64>,
    wake: Arc<Wake>,
    /// The last progress each running lease reported from this process
    /// (to announce only changes).
    reported: Mutex<HashMap<JobId, Progress>>,
}

fn pool_error(e: impl std::fmt::Display) -> StoreError {
    StoreError::Pool(e.to_string())
}

impl PgStore {
    /// Connects to the database at `url` (`postgres://user@host/db`),
    /// takes its schema to this build's version and starts listening for
    /// changes.
    pub fn connect(url: &str, lease: LeaseConfig) -> Result<PgStore, StoreError> {
        let config: tokio_postgres::Config = url.parse()?;
        let rt = Background::new("pg-store").map_err(pool_error)?;
        let manager = Manager::from_config(
            config.clone(),
            NoTls,
            ManagerConfig {
                recycling_method: RecyclingMethod::Fast,
            },
        );
        let pool = Pool::builder(manager)
            .max_size(8)
            .build()
            .map_err(pool_error)?;
        let (changed, _) = watch::channel(0);
        let wake = Arc::new(Wake::default());
        let store = PgStore {
            lease,
            rt,
            pool,
            changed,
            wake,
            reported: Mutex::new(HashMap::new()),
        };
        let pool = store.pool.clone();
        store.run(async move {
            let mut client = pool.get().await.map_err(pool_error)?;
            migrate(&mut client).await
        })?;
        store.listen(config)?;
        tracing::info!(version = PG_SCHEMA_VERSION, "PostgreSQL job store ready");
        Ok(store)
    }

    /// Runs `f` on the store's runtime and waits for its answer.
    fn run<T: Send + 'static>(
        &self,
        f: impl Future<Output = Result<T, StoreError>> + Send + 'static,
    ) -> Result<T, StoreError> {
        self.rt
            .run(f)
            .ok_or_else(|| pool_error("the store's runtime stopped"))?
    }

    /// Runs `f` with a pooled connection.
    fn with<T, F, Fut>(&self, f: F) -> Result<T, StoreError>
    where
        T: Send + 'static,
        F: FnOnce(deadpool_postgres::Object) -> Fut + Send + 'static,
        Fut: Future<Output = Result<T, StoreError>> + Send,
    {
        let pool = self.pool.clone();
        self.run(async move {
            let client = pool.get().await.map_err(pool_error)?;
            f(client).await
        })
    }

    /// Starts the listening connection: every `NOTIFY` bumps the change
    /// counter and wakes workers. A lost connection is made again (after a
    /// bump, since changes may have been missed meanwhile).
    fn listen(&self, config: tokio_postgres::Config) -> Result<(), StoreError> {
        let changed = self.changed.clone();
        let wake = self.wake.clone();
        let (ready_tx, ready_rx) = std::sync::mpsc::sync_channel::<Result<(), StoreError>>(1);
        self.rt.spawn(async move {
            let mut ready = Some(ready_tx);
            loop {
                match listen_once(&config, &changed, &wake, &mut ready).await {
                    Ok(()) => tracing::warn!("the job store's listening connection closed"),
                    Err(e) => {
                        if let Some(tx) = ready.take() {
                            let _ = tx.send(Err(e));
                            return;
                        }
                        tracing::warn!(error = %e, "the job store's listening connection failed");
                    }
                }
                changed.send_modify(|v| *v = v.wrapping_add(1));
                wake.bump();
                tokio::time::sleep(POLL).await;
            }
        });
        ready_rx
            .recv()
            .map_err(|_| pool_error("the listening connection did not start"))?
    }

    fn announce_local(&self) {
        // The NOTIFY comes back through the listener too; bumping here makes
        // this process's own waiters see the change without that round trip.
        self.changed.send_modify(|v| *v = v.wrapping_add(1));
        self.wake.bump();
    }
}

async fn listen_once(
    config: &tokio_postgres::Config,
    changed: &watch::Sender<u64>,
    wake: &Wake,
    ready: &mut Option<std::sync::mpsc::SyncSender<Result<(), StoreError>>>,
) -> Result<(), StoreError> {
    let (client, mut connection) = config.connect(NoTls).await?;
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let driver = tokio::spawn(async move {
        loop {
            let message = std::future::poll_fn(|cx| connection.poll_message(cx)).await;
            match message {
                Some(Ok(m)) => {
                    if tx.send(Ok(m)).is_err() {
                        return;
                    }
                }
                Some(Err(e)) => {
                    let _ = tx.send(Err(e));
                    return;
                }
                None => return,
            }
        }
    });
    client.batch_execute(&format!("LISTEN {CHANNEL}")).await?;
    if let Some(tx) = ready.take() {
        let _ = tx.send(Ok(()));
    }
    let result = loop {
        match rx.recv().await {
            Some(Ok(tokio_postgres::AsyncMessage::Notification(_))) => {
                changed.send_modify(|v| *v = v.wrapping_add(1));
                wake.bump();
            }
            Some(Ok(_)) => {}
            Some(Err(e)) => break Err(e.into()),
            None => break Ok(()),
        }
    };
    driver.abort();
    drop(client);
    result
}

/// Takes the database to [`PG_SCHEMA_VERSION`], one transaction per step,
/// under an advisory lock (replicas starting together migrate once).
async fn migrate(client: &mut deadpool_postgres::Object) -> Result<(), StoreError> {
    let tx = client.transaction().await?;
    tx.batch_execute(
        "SELECT pg_advisory_xact_lock(7426011);
         CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL)",
    )
    .await?;
    let at: i32 = match tx
        .query_opt("SELECT version FROM schema_version", &[])
        .await?
    {
        Some(row) => row.get(0),
        None => {
            tx.execute("INSERT INTO schema_version VALUES (0)", &[])
                .await?;
            0
        }
    };
    let at = at as u32;
    if at > PG_SCHEMA_VERSION {
        return Err(StoreError::NewerSchema {
            found: at,
            supported: PG_SCHEMA_VERSION,
        });
    }
    for (version, (what, sql)) in (1u32..).zip(MIGRATIONS.iter()).skip(at as usize) {
        tx.batch_execute(sql).await?;
        tx.execute(
            "UPDATE schema_version SET version = $1",
            &[&(version as i32)],
        )
        .await?;
        tracing::info!(version, what, "job store schema migrated");
    }
    tx.commit().await?;
    Ok(())
}

fn job_from_row(r: &Row) -> Result<JobRecord, StoreError> {
    let state_name: String = r.get(6);
    Ok(JobRecord {
        seq: r.get(0),
        id: r.get(1),
        flight_id: r.get(2),
        image: r.get(3),
        ext: r.get(4),
        bytes: r.get::<_, i64>(5) as u64,
        state: JobState::parse(&state_name)
            .ok_or_else(|| StoreError::Corrupt(format!("job state {state_name:?}")))?,
        created_at: r.get(7),
        started_at: r.get(8),
        finished_at: r.get(9),
        attempts: r.get::<_, i32>(10) as u32,
        error: stored_error(r.get(11), r.get(12)),
        width: r.get::<_, Option<i32>>(13).map(|v| v as u32),
        height: r.get::<_, Option<i32>>(14).map(|v| v as u32),
        targets: r.get::<_, Option<i32>>(15).map(|v| v as u32),
        source: r.get(16),
        source_etag: r.get(17),
        warnings: r
            .get::<_, Option<String>>(18)
            .and_then(|t| serde_json::from_str(&t).ok())
            .unwrap_or_default(),
        tiles_done: r.get::<_, i32>(19) as u32,
        tiles_total: r.get::<_, i32>(20) as u32,
        cancel_requested: r.get(21),
    })
}

fn flight_from_row(r: &Row) -> Result<FlightRecord, StoreError> {
    let id: FlightId = r.get(0);
    let params: JobParams = serde_json::from_str(r.get::<_, &str>(2))
        .map_err(|e| StoreError::Corrupt(format!("flight {id} params: {e}")))?;
    let export = match r.get::<_, Option<String>>(3) {
        None => None,
        Some(to) => {
            let name: String = r.get::<_, Option<String>>(4).unwrap_or_default();
            Some(Export {
                to,
                state: ExportState::parse(&name)
                    .ok_or_else(|| StoreError::Corrupt(format!("export state {name:?}")))?,
                error: r.get(5),
                written_at: r.get(6),
                attempts: r.get::<_, i32>(7) as u32,
            })
        }
    };
    Ok(FlightRecord {
        id,
        created_at: r.get(1),
        params,
        export,
    })
}

fn jobs_from_rows(rows: &[Row]) -> Result<Vec<JobRecord>, StoreError> {
    rows.iter().map(job_from_row).collect()
}

async fn notify(c: &impl GenericClient) -> Result<(), StoreError> {
    c.batch_execute(&format!("NOTIFY {CHANNEL}")).await?;
    Ok(())
}

async fn insert_jobs(
    tx: &deadpool_postgres::Transaction<'_>,
    flight: FlightId,
    jobs: &[NewJob],
) -> Result<Vec<JobRecord>, StoreError> {
    let created = now_millis();
    let mut out = Vec::with_capacity(jobs.len());
    for new in jobs {
        let (state, error, finished) = new.starts(created);
        let (source, source_etag) = new.source.clone().unzip();
        let source_etag = source_etag.flatten();
        let row = tx
            .query_one(
                &format!(
                    "INSERT INTO jobs (id, flight_id, image, ext, bytes, state, created_at,
                         finished_at, error_code, error_message, source, source_etag)
                     VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12)
                     RETURNING {JOB_COLS}"
                ),
                &[
                    &new.id,
                    &flight,
                    &new.image,
                    &new.ext,
                    &(new.bytes as i64),
                    &state.as_str(),
                    &created,
                    &finished,
                    &error.as_ref().map(|e| e.code.as_str()),
                    &error.as_ref().map(|e| e.message.clone()),
                    &source,
                    &source_etag,
                ],
            )
            .await
            .map_err(|e| unique_image(e, &new.image))?;
        out.push(job_from_row(&row)?);
    }
    Ok(out)
}

/// A repeat of (flight, image) refused by the database itself.
fn unique_image(e: tokio_postgres::Error, image: &str) -> StoreError {
    if e.code() == Some(&tokio_postgres::error::SqlState::UNIQUE_VIOLATION) {
        StoreError::DuplicateImage(image.to_string())
    } else {
        e.into()
    }
}

async fn insert_idem(
    tx: &deadpool_postgres::Transaction<'_>,
    idem: Option<&IdemKey>,
    flight: FlightId,
    jobs: &[JobRecord],
) -> Result<(), StoreError> {
    let Some(idem) = idem else { return Ok(()) };
    let ids: Vec<String> = jobs.iter().map(|j| j.id.to_string()).collect();
    let inserted = tx
        .execute(
            "INSERT INTO idempotency (key, request, flight_id, job_ids, created_at)
             VALUES ($1, $2, $3, $4, $5) ON CONFLICT (key) DO NOTHING",
            &[
                &idem.key,
                &idem.request,
                &flight,
                &serde_json::to_string(&ids).expect("ids serialize"),
                &now_millis(),
            ],
        )
        .await?;
    if inserted == 0 {
        return Err(StoreError::KeyTaken);
    }
    Ok(())
}

/// Puts jobs whose lease expired back in the queue, or fails them on their
/// last attempt; true if any was.
async fn reap_expired(
    client: &mut deadpool_postgres::Object,
    max_attempts: u32,
) -> Result<bool, StoreError> {
    let tx = client.transaction().await?;
    let rows = tx
        .query(
            &format!(
                "SELECT id, attempts, cancel_requested FROM jobs
                 WHERE state = 'running' AND lease_until < {NOW_MS}
                 FOR UPDATE SKIP LOCKED"
            ),
            &[],
        )
        .await?;
    for row in &rows {
        let id: JobId = row.get(0);
        let attempts = row.get::<_, i32>(1) as u32;
        if row.get::<_, bool>(2) {
            // Canceled while its worker was lost: it ends canceled.
            tx.execute(
                "UPDATE jobs SET state = 'canceled', finished_at = $2, lease_token = NULL,
                     lease_until = NULL, cancel_requested = FALSE
                 WHERE id = $1",
                &[&id, &now_millis()],
            )
            .await?;
        } else if attempts >= max_attempts {
            let error = lease_expired_error(attempts);
            tx.execute(
                "UPDATE jobs SET state = 'failed', finished_at = $2, error_code = $3,
                     error_message = $4, lease_token = NULL, lease_until = NULL
                 WHERE id = $1",
                &[&id, &now_millis(), &error.code.as_str(), &error.message],
            )
            .await?;
        } else {
            tx.execute(
                "UPDATE jobs SET state = 'queued', started_at = NULL, lease_token = NULL,
                     lease_until = NULL, cancel_requested = FALSE
                 WHERE id = $1",
                &[&id],
            )
            .await?;
        }
        tracing::warn!(job.id = %id, "a job's lease expired: its worker stopped renewing it");
    }
    if !rows.is_empty() {
        notify(&tx).await?;
    }
    tx.commit().await?;
    Ok(!rows.is_empty())
}

/// Cancels one job inside `tx`: a queued or fetching one at once, a running
/// one by its stored request.
async fn cancel_in(
    tx: &deadpool_postgres::Transaction<'_>,
    id: JobId,
) -> Result<Option<JobRecord>, StoreError> {
    let Some(row) = tx
        .query_opt(
            &format!("SELECT {JOB_COLS} FROM jobs WHERE id = $1 FOR UPDATE"),
            &[&id],
        )
        .await?
    else {
        return Ok(None);
    };
    let job = job_from_row(&row)?;
    match job.state {
        JobState::Queued | JobState::Fetching => {
            tx.execute(
                "UPDATE jobs SET state = 'canceled', finished_at = $2 WHERE id = $1",
                &[&id, &now_millis()],
            )
            .await?
        }
        JobState::Running => {
            tx.execute(
                "UPDATE jobs SET cancel_requested = TRUE WHERE id = $1",
                &[&id],
            )
            .await?
        }
        _ => return Ok(Some(job)),
    };
    let row = tx
        .query_one(
            &format!("SELECT {JOB_COLS} FROM jobs WHERE id = $1"),
            &[&id],
        )
        .await?;
    Ok(Some(job_from_row(&row)?))
}

impl JobStore for PgStore {
    fn subscribe(&self) -> watch::Receiver<u64> {
        self.changed.subscribe()
    }

    fn create_flight(
        &self,
        params: &JobParams,
        jobs: &[NewJob],
        export_to: Option<String>,
        idem: Option<&IdemKey>,
    ) -> Result<FlightRecord, StoreError> {
        let flight = new_flight(params, jobs, export_to)?;
        let (record, jobs, idem) = (flight.clone(), jobs.to_vec(), idem.cloned());
        self.with(move |mut c| async move {
            let tx = c.transaction().await?;
            tx.execute(
                "INSERT INTO flights (id, created_at, params, export_to, export_state)
                 VALUES ($1, $2, $3, $4, $5)",
                &[
                    &record.id,
                    &record.created_at,
                    &serde_json::to_string(&record.params).expect("params serialize"),
                    &record.export.as_ref().map(|e| e.to.clone()),
                    &record.export.as_ref().map(|e| e.state.as_str()),
                ],
            )
            .await?;
            let records = insert_jobs(&tx, record.id, &jobs).await?;
            insert_idem(&tx, idem.as_ref(), record.id, &records).await?;
            notify(&tx).await?;
            tx.commit().await?;
            Ok(())
        })?;
        self.announce_local();
        Ok(flight)
    }

    fn add_to_flight(
        &self,
        flight: FlightId,
        jobs: &[NewJob],
        idem: Option<&IdemKey>,
        max_frames: usize,
    ) -> Result<Option<Vec<JobRecord>>, StoreError> {
        let (jobs, idem) = (jobs.to_vec(), idem.cloned());
        let out = self.with(move |mut c| async move {
            let tx = c.transaction().await?;
            // The flight's row lock orders concurrent additions to it.
            if tx
                .query_opt("SELECT 1 FROM flights WHERE id = $1 FOR UPDATE", &[&flight])
                .await?
                .is_none()
            {
                return Ok(None);
            }
            let mut names: std::collections::HashSet<String> = tx
                .query("SELECT image FROM jobs WHERE flight_id = $1", &[&flight])
                .await?
                .iter()
                .map(|r| r.get(0))
                .collect();
            let would = names.len() + jobs.len();
            if would > max_frames {
                return Err(StoreError::TooManyFrames {
                    would,
                    max: max_frames,
                });
            }
            for job in &jobs {
                if !names.insert(job.image.clone()) {
                    return Err(StoreError::DuplicateImage(job.image.clone()));
                }
            }
            let records = insert_jobs(&tx, flight, &jobs).await?;
            insert_idem(&tx, idem.as_ref(), flight, &records).await?;
            // New frames mean new results: write them again at the end.
            tx.execute(
                "UPDATE flights SET export_state = 'pending', export_attempts = 0,
                     export_error = NULL
                 WHERE id = $1 AND export_to IS NOT NULL",
                &[&flight],
            )
            .await?;
            notify(&tx).await?;
            tx.commit().await?;
            Ok(Some(records))
        })?;
        if out.is_some() {
            self.announce_local();
        }
        Ok(out)
    }

    fn flight(&self, id: FlightId) -> Result<Option<FlightRecord>, StoreError> {
        self.with(move |c| async move {
            c.query_opt(
                &format!("SELECT {FLIGHT_COLS} FROM flights WHERE id = $1"),
                &[&id],
            )
            .await?
            .map(|r| flight_from_row(&r))
            .transpose()
        })
    }

    fn flight_images(&self, id: FlightId) -> Result<Vec<String>, StoreError> {
        self.with(move |c| async move {
            Ok(c.query(
                "SELECT image FROM jobs WHERE flight_id = $1 ORDER BY seq",
                &[&id],
            )
            .await?
            .iter()
            .map(|r| r.get(0))
            .collect())
        })
    }

    fn flight_jobs(&self, id: FlightId) -> Result<Option<Vec<JobRecord>>, StoreError> {
        self.with(move |mut c| async move {
            let tx = c.build_transaction().read_only(true).start().await?;
            if tx
                .query_opt("SELECT 1 FROM flights WHERE id = $1", &[&id])
                .await?
                .is_none()
            {
                return Ok(None);
            }
            let rows = tx
                .query(
                    &format!("SELECT {JOB_COLS} FROM jobs WHERE flight_id = $1 ORDER BY seq"),
                    &[&id],
                )
                .await?;
            Ok(Some(jobs_from_rows(&rows)?))
        })
    }

    fn expired_flights(&self, cutoff: Millis) -> Result<Vec<FlightId>, StoreError> {
        self.with(move |c| async move {
            Ok(c.query(
                "SELECT f.id FROM flights f
                 WHERE (f.export_state IS NULL OR f.export_state <> 'pending')
                   AND NOT EXISTS (SELECT 1 FROM jobs j WHERE j.flight_id = f.id
                       AND (j.state NOT IN ('succeeded', 'failed', 'canceled')
                            OR j.finished_at IS NULL OR j.finished_at >= $1))
                   AND (EXISTS (SELECT 1 FROM jobs j WHERE j.flight_id = f.id)
                        OR f.created_at < $1)
                 ORDER BY f.id",
                &[&cutoff],
            )
            .await?
            .iter()
            .map(|r| r.get(0))
            .collect())
        })
    }

    fn idempotent(&self, key: &str) -> Result<Option<IdemRecord>, StoreError> {
        let key = key.to_string();
        self.with(move |c| async move {
            let Some(row) = c
                .query_opt(
                    "SELECT request, flight_id, job_ids FROM idempotency WHERE key = $1",
                    &[&key],
                )
                .await?
            else {
                return Ok(None);
            };
            let ids: Vec<uuid::Uuid> = serde_json::from_str(row.get::<_, &str>(2))
                .map_err(|e| StoreError::Corrupt(format!("idempotency job ids: {e}")))?;
            Ok(Some(IdemRecord {
                request: row.get(0),
                flight: row.get(1),
                jobs: ids,
            }))
        })
    }

    fn flights(
        &self,
        after: Option<FlightId>,
        limit: usize,
    ) -> Result<Vec<FlightRecord>, StoreError> {
        self.with(move |c| async move {
            let rows = c
                .query(
                    &format!(
                        "SELECT {FLIGHT_COLS} FROM flights WHERE ($1::uuid IS NULL OR id > $1)
                         ORDER BY id LIMIT $2"
                    ),
                    &[&after, &(limit.min(i64::MAX as usize) as i64)],
                )
                .await?;
            rows.iter().map(flight_from_row).collect()
        })
    }

    fn job(&self, id: JobId) -> Result<Option<JobRecord>, StoreError> {
        self.with(move |c| async move {
            c.query_opt(
                &format!("SELECT {JOB_COLS} FROM jobs WHERE id = $1"),
                &[&id],
            )
            .await?
            .map(|r| job_from_row(&r))
            .transpose()
        })
    }

    fn jobs(&self, filter: &JobFilter) -> Result<Vec<JobRecord>, StoreError> {
        let filter = filter.clone();
        self.with(move |c| async move {
            let rows = c
                .query(
                    &format!(
                        "SELECT {JOB_COLS} FROM jobs
                         WHERE ($1::uuid IS NULL OR id > $1)
                           AND ($2::uuid IS NULL OR flight_id = $2)
                           AND ($3::text IS NULL OR state = $3)
                         ORDER BY id LIMIT $4"
                    ),
                    &[
                        &filter.after,
                        &filter.flight,
                        &filter.state.map(|s| s.as_str()),
                        &(filter.limit.min(i64::MAX as usize) as i64),
                    ],
                )
                .await?;
            jobs_from_rows(&rows)
        })
    }

    fn stats(&self) -> Result<QueueStats, StoreError> {
        self.with(move |c| async move {
            let mut stats = QueueStats::default();
            for row in c
                .query(
                    "SELECT state, source IS NOT NULL, count(*) FROM jobs
                     WHERE state IN ('fetching', 'queued', 'running') GROUP BY 1, 2",
                    &[],
                )
                .await?
            {
                let n = row.get::<_, i64>(2) as usize;
                match (row.get::<_, &str>(0), row.get::<_, bool>(1)) {
                    ("fetching", _) => stats.fetching += n,
                    ("queued", sourced) => {
                        stats.queued += n;
                        if sourced {
                            stats.fetched += n;
                        }
                    }
                    _ => stats.running += n,
                }
            }
            Ok(stats)
        })
    }

    fn claim_next(
        &self,
        stop: &AtomicBool,
        timeout: Duration,
    ) -> Result<Option<Claim>, StoreError> {
        let deadline = Instant::now() + timeout;
        let (lease_ms, max_attempts) =
            (self.lease.lease.as_millis() as i64, self.lease.max_attempts);
        loop {
            let seen = *self.wake.generation.lock().expect("wake lock");
            if stop.load(Ordering::SeqCst) {
                return Ok(None);
            }
            let token = uuid::Uuid::new_v4();
            let claimed = self.with(move |mut c| async move {
                reap_expired(&mut c, max_attempts).await?;
                let tx = c.transaction().await?;
                let Some(row) = tx
                    .query_opt(
                        &format!(
                            "UPDATE jobs SET state = 'running', started_at = {NOW_MS},
                                 attempts = attempts + 1, lease_token = $1,
                                 lease_until = {NOW_MS} + $2, cancel_requested = FALSE,
                                 tiles_done = 0, tiles_total = 0
                             WHERE seq = (SELECT seq FROM jobs WHERE state = 'queued'
                                          ORDER BY seq FOR UPDATE SKIP LOCKED LIMIT 1)
                             RETURNING {JOB_COLS}"
                        ),
                        &[&token, &lease_ms],
                    )
                    .await?
                else {
                    return Ok(None);
                };
                let job = job_from_row(&row)?;
                let params: String = tx
                    .query_one(
                        "SELECT params FROM flights WHERE id = $1",
                        &[&job.flight_id],
                    )
                    .await?
                    .get(0);
                let params: JobParams = serde_json::from_str(&params).map_err(|e| {
                    StoreError::Corrupt(format!("flight {} params: {e}", job.flight_id))
                })?;
                notify(&tx).await?;
                tx.commit().await?;
                Ok(Some((job, params)))
            })?;
            if let Some((job, params)) = claimed {
                self.announce_local();
                let lease = Lease { job: job.id, token };
                return Ok(Some(Claim { job, params, lease }));
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            let wait = (deadline - now).min(POLL);
            let generation = self.wake.generation.lock().expect("wake lock");
            let _ = self
                .wake
                .cond
                .wait_timeout_while(generation, wait, |g| {
                    *g == seen && !stop.load(Ordering::SeqCst)
                })
                .expect("wake lock");
        }
    }

    fn heartbeat(&self, lease: &Lease, progress: &Progress) -> Result<LeaseState, StoreError> {
        let (lease_copy, p) = (*lease, *progress);
        let lease_ms = self.lease.lease.as_millis() as i64;
        let changed = self
            .reported
            .lock()
            .expect("reported lock")
            .insert(lease.job, p)
            != Some(p);
        let state = self.with(move |c| async move {
            let (w, h) = p.size.unzip();
            let row = c
                .query_opt(
                    &format!(
                        "UPDATE jobs SET lease_until = {NOW_MS} + $3,
                             width = COALESCE($4, width), height = COALESCE($5, height),
                             tiles_done = $6, tiles_total = $7
                         WHERE id = $1 AND lease_token = $2 AND state = 'running'
                         RETURNING cancel_requested"
                    ),
                    &[
                        &lease_copy.job,
                        &lease_copy.token,
                        &lease_ms,
                        &w.map(|v| v as i32),
                        &h.map(|v| v as i32),
                        &(p.tiles_done as i32),
                        &(p.tiles_total as i32),
                    ],
                )
                .await?;
            if changed && row.is_some() {
                notify(&c).await?;
            }
            Ok(match row {
                Some(r) => LeaseState::Held { cancel: r.get(0) },
                None => LeaseState::Lost,
            })
        })?;
        if state == LeaseState::Lost {
            self.reported
                .lock()
                .expect("reported lock")
                .remove(&lease.job);
        }
        Ok(state)
    }

    fn finish(&self, lease: &Lease, outcome: &Outcome) -> Result<Finished, StoreError> {
        let lease_copy = *lease;
        let end = Ending::of(outcome);
        self.reported
            .lock()
            .expect("reported lock")
            .remove(&lease.job);
        let finished = self.with(move |mut c| async move {
            let tx = c.transaction().await?;
            let Some(row) = tx
                .query_opt(
                    "SELECT lease_token, state FROM jobs WHERE id = $1 FOR UPDATE",
                    &[&lease_copy.job],
                )
                .await?
            else {
                return Ok(Finished::Deleted);
            };
            let (token, state): (Option<uuid::Uuid>, String) = (row.get(0), row.get(1));
            if token != Some(lease_copy.token) || state != "running" {
                return Ok(Finished::Lost);
            }
            tx.execute(
                "UPDATE jobs SET state = $2, finished_at = $3, error_code = $4, error_message = $5,
                     width = COALESCE($6, width), height = COALESCE($7, height), targets = $8,
                     started_at = CASE WHEN $2 = 'queued' THEN NULL ELSE started_at END,
                     warnings = $9, lease_token = NULL, lease_until = NULL,
                     cancel_requested = FALSE
                 WHERE id = $1",
                &[
                    &lease_copy.job,
                    &end.state.as_str(),
                    &end.finished_at,
                    &end.error.as_ref().map(|e| e.code.as_str()),
                    &end.error.as_ref().map(|e| e.message.clone()),
                    &end.size.map(|s| s.0 as i32),
                    &end.size.map(|s| s.1 as i32),
                    &end.targets.map(|t| t as i32),
                    &end.warnings_json(),
                ],
            )
            .await?;
            notify(&tx).await?;
            tx.commit().await?;
            Ok(Finished::Recorded)
        })?;
        if finished == Finished::Recorded {
            self.announce_local();
        }
        Ok(finished)
    }

    fn release_unrecorded(&self, lease: &Lease) {
        self.reported
            .lock()
            .expect("reported lock")
            .remove(&lease.job);
        let lease = *lease;
        let released = self.with(move |c| async move {
            c.execute(
                "UPDATE jobs SET state = 'queued', started_at = NULL, lease_token = NULL,
                     lease_until = NULL
                 WHERE id = $1 AND lease_token = $2 AND state = 'running'",
                &[&lease.job, &lease.token],
            )
            .await?;
            notify(&c).await
        });
        if let Err(e) = released {
            tracing::warn!(error = %e, "cannot give the job back: it runs again when its lease expires");
        }
    }

    fn wake_workers(&self) {
        self.wake.bump();
    }

    fn to_fetch(&self, limit: usize) -> Result<Vec<JobRecord>, StoreError> {
        self.with(move |c| async move {
            let rows = c
                .query(
                    &format!(
                        "SELECT {JOB_COLS} FROM jobs WHERE state = 'fetching' ORDER BY seq LIMIT $1"
                    ),
                    &[&(limit.min(i64::MAX as usize) as i64)],
                )
                .await?;
            jobs_from_rows(&rows)
        })
    }

    fn fetched(&self, id: JobId, ext: &str, bytes: u64) -> Result<bool, StoreError> {
        let ext = ext.to_string();
        let queued = self.with(move |c| async move {
            let n = c
                .execute(
                    "UPDATE jobs SET state = 'queued', ext = $2, bytes = $3
                     WHERE id = $1 AND state = 'fetching'",
                    &[&id, &ext, &(bytes as i64)],
                )
                .await?;
            if n == 1 {
                notify(&c).await?;
            }
            Ok(n == 1)
        })?;
        if queued {
            self.announce_local();
        }
        Ok(queued)
    }

    fn fetch_failed(&self, id: JobId, error: &JobError) -> Result<(), StoreError> {
        let error = error.clone();
        self.with(move |c| async move {
            let n = c
                .execute(
                    "UPDATE jobs SET state = 'failed', finished_at = $2, error_code = $3,
                         error_message = $4
                     WHERE id = $1 AND state = 'fetching'",
                    &[&id, &now_millis(), &error.code.as_str(), &error.message],
                )
                .await?;
            if n == 1 {
                notify(&c).await?;
            }
            Ok(())
        })?;
        self.announce_local();
        Ok(())
    }

    fn exports_due(&self) -> Result<Vec<(FlightRecord, Vec<JobRecord>)>, StoreError> {
        self.with(move |mut c| async move {
            let tx = c.build_transaction().read_only(true).start().await?;
            let flights = tx
                .query(
                    &format!(
                        "SELECT {FLIGHT_COLS} FROM flights f WHERE export_state = 'pending'
                           AND NOT EXISTS (SELECT 1 FROM jobs j WHERE j.flight_id = f.id
                               AND j.state NOT IN ('succeeded', 'failed', 'canceled'))
                         ORDER BY id"
                    ),
                    &[],
                )
                .await?;
            let mut due = Vec::with_capacity(flights.len());
            for row in &flights {
                let flight = flight_from_row(row)?;
                let jobs = tx
                    .query(
                        &format!("SELECT {JOB_COLS} FROM jobs WHERE flight_id = $1 ORDER BY seq"),
                        &[&flight.id],
                    )
                    .await?;
                due.push((flight, jobs_from_rows(&jobs)?));
            }
            Ok(due)
        })
    }

    fn export_done(
        &self,
        flight: FlightId,
        result: Result<(), String>,
        give_up: bool,
    ) -> Result<(), StoreError> {
        self.with(move |mut c| async move {
            let tx = c.transaction().await?;
            let Some(row) = tx
                .query_opt(
                    &format!("SELECT {FLIGHT_COLS} FROM flights WHERE id = $1 FOR UPDATE"),
                    &[&flight],
                )
                .await?
            else {
                return Ok(());
            };
            let Some(mut export) = flight_from_row(&row)?.export else {
                return Ok(());
            };
            export.record_attempt(result, give_up);
            tx.execute(
                "UPDATE flights SET export_state = $2, export_error = $3, export_written_at = $4,
                     export_attempts = $5 WHERE id = $1",
                &[
                    &flight,
                    &export.state.as_str(),
                    &export.error,
                    &export.written_at,
                    &(export.attempts as i32),
                ],
            )
            .await?;
            notify(&tx).await?;
            tx.commit().await?;
            Ok(())
        })?;
        self.announce_local();
        Ok(())
    }

    fn cancel_job(&self, id: JobId) -> Result<Option<JobRecord>, StoreError> {
        let out = self.with(move |mut c| async move {
            let tx = c.transaction().await?;
            let job = cancel_in(&tx, id).await?;
            notify(&tx).await?;
            tx.commit().await?;
            Ok(job)
        })?;
        self.announce_local();
        Ok(out)
    }

    fn cancel_flight(&self, id: FlightId) -> Result<Option<Vec<JobRecord>>, StoreError> {
        let out = self.with(move |mut c| async move {
            let tx = c.transaction().await?;
            if tx
                .query_opt("SELECT 1 FROM flights WHERE id = $1 FOR UPDATE", &[&id])
                .await?
                .is_none()
            {
                return Ok(None);
            }
            let ids: Vec<JobId> = tx
                .query(
                    "SELECT id FROM jobs WHERE flight_id = $1 ORDER BY seq",
                    &[&id],
                )
                .await?
                .iter()
                .map(|r| r.get(0))
                .collect();
            let mut out = Vec::with_capacity(ids.len());
            for job in ids {
                out.extend(cancel_in(&tx, job).await?);
            }
            notify(&tx).await?;
            tx.commit().await?;
            Ok(Some(out))
        })?;
        self.announce_local();
        Ok(out)
    }

    fn delete_job(&self, id: JobId) -> Result<Option<JobRecord>, StoreError> {
        let out = self.with(move |c| async move {
            let row = c
                .query_opt(
                    &format!("DELETE FROM jobs WHERE id = $1 RETURNING {JOB_COLS}"),
                    &[&id],
                )
                .await?;
            notify(&c).await?;
            row.map(|r| job_from_row(&r)).transpose()
        })?;
        self.announce_local();
        Ok(out)
    }

    fn delete_flight(&self, id: FlightId) -> Result<Option<Vec<JobRecord>>, StoreError> {
        let out = self.with(move |mut c| async move {
            let tx = c.transaction().await?;
            let rows = tx
                .query(
                    &format!(
                        "SELECT {JOB_COLS} FROM jobs WHERE flight_id = $1 ORDER BY seq FOR UPDATE"
                    ),
                    &[&id],
                )
                .await?;
            let jobs = jobs_from_rows(&rows)?;
            if tx
                .execute("DELETE FROM flights WHERE id = $1", &[&id])
                .await?
                == 0
            {
                return Ok(None);
            }
            notify(&tx).await?;
            tx.commit().await?;
            Ok(Some(jobs))
        })?;
        self.announce_local();
        Ok(out)
    }
}
