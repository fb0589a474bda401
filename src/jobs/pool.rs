//! The worker pool: one OS thread per worker (CPU work never touches the
//! async runtime), each claiming the next queued job and running it in a
//! child process (see [`super::isolate`]): the child reads the raster
//! header and estimates its working set, the worker waits for that share
//! of the RAM budget, and the child runs the pipeline under OS limits. A
//! cancel or a stop kills the child; a child that dies puts its job back in
//! the queue, up to [`MAX_ATTEMPTS`] workers.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::pipeline::memory::{RamBudget, BASE_PROCESS_BYTES, MIB};
use crate::storage::header::PixelLimits;
use crate::storage::DataDir;
use crate::telemetry::{Metrics, OutcomeLabels};

use super::isolate::{cpu_limit_secs, ChildLine, Heard, JobChild, JobOrder};
use super::model::{JobError, JobRecord};
use super::store::{Claim, Finished, LeaseState, Outcome, Progress, SharedStore};
use crate::error_code::ErrorCode;

/// How long an idle worker waits before re-checking the stop flag.
const IDLE_WAIT: Duration = Duration::from_millis(250);

/// How often a worker looks at cancel and stop flags while its child runs.
const POLL: Duration = Duration::from_millis(100);

/// Workers a frame may kill before its job fails instead of being retried
/// (the store's claims count the same way).
pub use super::store::MAX_ATTEMPTS;

/// How often a running job's worker renews its lease, reports progress and
/// learns of a cancel.
const HEARTBEAT: Duration = Duration::from_millis(250);

/// Free space on the data folder's disk below which workers start no job:
/// a job needs room for its result file and the store's log (kilobytes to
/// a few MiB). Uploads stop much earlier (`--min-free-disk-mb`).
const MIN_FREE_FOR_JOBS: u64 = 32 * MIB;

/// How often a worker looks at the disk while it is short.
const DISK_WAIT: Duration = Duration::from_secs(1);

/// Retries of an operation that fails for the server's own reasons (a
/// full disk, a store that cannot write): waits double from 0.25 s to
/// 30 s; the failure is logged when it starts and then once a minute, and
/// its end once.
#[derive(Default)]
struct Backoff {
    failures: u32,
    logged: Option<Instant>,
}

impl Backoff {
    /// Records a failure; returns how long to wait before the next try.
    fn failed(&mut self, what: &str, error: &dyn std::fmt::Display) -> Duration {
        self.failures += 1;
        if self
            .logged
            .is_none_or(|at| at.elapsed() >= Duration::from_secs(60))
        {
            tracing::error!(%error, failures = self.failures, "{what}");
            self.logged = Some(Instant::now());
        }
        let wait = IDLE_WAIT.saturating_mul(1 << self.failures.min(7));
        wait.min(Duration::from_secs(30))
    }

    /// Records a success after failures.
    fn recovered(&mut self, what: &str) {
        if self.failures > 0 {
            tracing::info!(failures = self.failures, "{what}");
        }
        *self = Backoff::default();
    }
}

/// Memory a worker process may use beyond its reservation (the estimate
/// runs 20-25 MiB under the measured peak on 8000x6000 frames; the rest
/// is the allocator's slack): its address space (RLIMIT_DATA) is capped
/// there, so a frame that needs more fails itself, not the machine.
const CHILD_HEADROOM_BYTES: u64 = 128 * MIB;

/// Memory of the server process itself (HTTP, upload buffers, the job
/// store, the libraries it links). The load benchmark measured a peak RSS
/// (VmHWM) of 56-58 MiB for it while workers ran 100 frames; the rest is
/// headroom for several uploads streaming at once. Each worker process
/// adds the pipeline's own base ([`BASE_PROCESS_BYTES`]); together, the
/// same benchmark measured 354 MiB for the server and 2 workers on
/// 4000x3000 frames.
pub const SERVICE_BASE_BYTES: u64 = 64 * MIB;

/// Pool settings.
#[derive(Debug, Clone)]
pub struct PoolConfig {
    pub workers: usize,
    /// The whole process's memory limit.
    pub max_ram_bytes: u64,
    /// The frame size limits, checked again on the size the decoder opens
    /// (an upload's header check reads the file as one reader would).
    pub pixels: PixelLimits,
}

/// Running workers and the flags that stop them.
pub struct WorkerPool {
    handles: Vec<JoinHandle<()>>,
    stop_claiming: Arc<AtomicBool>,
    abort: Arc<AtomicBool>,
    budget: Arc<RamBudget>,
    store: SharedStore,
}

impl WorkerPool {
    /// Starts `config.workers` threads on `store`'s queue.
    pub fn start(
        store: SharedStore,
        data: DataDir,
        metrics: Arc<Metrics>,
        config: &PoolConfig,
    ) -> WorkerPool {
        crate::pipeline::init_native();
        // The server, and each worker process's libraries and GDAL cache,
        // come off the limit before frames share the rest.
        let reserved = SERVICE_BASE_BYTES + config.workers.max(1) as u64 * BASE_PROCESS_BYTES;
        let budget = Arc::new(RamBudget::new(
            config.max_ram_bytes.saturating_sub(reserved),
        ));
        if budget.capacity() == 0 {
            tracing::warn!(
                reserved_mib = reserved / MIB,
                "the memory limit leaves nothing for frames: raise --max-ram-gb or lower --workers"
            );
        }
        metrics.budget_bytes.set(budget.capacity() as i64);
        let stop_claiming = Arc::new(AtomicBool::new(false));
        let abort = Arc::new(AtomicBool::new(false));
        let handles = (0..config.workers.max(1))
            .map(|i| {
                let worker = Worker {
                    child: None,
                    store: store.clone(),
                    data: data.clone(),
                    metrics: metrics.clone(),
                    budget: budget.clone(),
                    pixels: config.pixels,
                    stop_claiming: stop_claiming.clone(),
                    abort: abort.clone(),
                };
                std::thread::Builder::new()
                    .name(format!("job-worker-{i}"))
                    .spawn(move || worker.run())
                    .expect("spawn job worker")
            })
            .collect();
        tracing::info!(
            workers = config.workers,
            budget_mib = budget.capacity() / MIB,
            "worker pool started"
        );
        WorkerPool {
            handles,
            stop_claiming,
            abort,
            budget,
            store,
        }
    }

    pub fn budget(&self) -> &Arc<RamBudget> {
        &self.budget
    }

    /// Stops claiming new jobs; running ones go on.
    pub fn stop_claiming(&self) {
        self.stop_claiming.store(true, Ordering::SeqCst);
        self.store.wake_workers();
    }

    /// Stops running jobs at their next tile; they go back to the queue.
    pub fn abort_running(&self) {
        self.abort.store(true, Ordering::SeqCst);
    }

    /// Waits for every worker thread to end (call after [`stop_claiming`]).
    ///
    /// [`stop_claiming`]: WorkerPool::stop_claiming
    pub fn join(self) {
        for handle in self.handles {
            if handle.join().is_err() {
                tracing::error!("a worker thread panicked");
            }
        }
    }
}

/// A running job's heartbeat: when it last went and what it reports.
struct Beat {
    last: Option<Instant>,
    progress: Progress,
    /// Heartbeats the store could not take (logged as other store
    /// failures are: at the start, then once a minute).
    failures: Backoff,
}

impl Beat {
    fn new() -> Beat {
        Beat {
            last: None,
            progress: Progress::default(),
            failures: Backoff::default(),
        }
    }
}

struct Worker {
    /// The worker process, kept between jobs (dropped: killed).
    child: Option<JobChild>,
    store: SharedStore,
    data: DataDir,
    metrics: Arc<Metrics>,
    budget: Arc<RamBudget>,
    pixels: PixelLimits,
    stop_claiming: Arc<AtomicBool>,
    abort: Arc<AtomicBool>,
}

impl Worker {
    fn run(mut self) {
        let mut claims = Backoff::default();
        loop {
            if !self.wait_for_disk() {
                return;
            }
            let claim = match self.store.claim_next(&self.stop_claiming, IDLE_WAIT) {
                Ok(Some(claim)) => {
                    claims.recovered("jobs can be claimed again");
                    claim
                }
                Ok(None) if self.stop_claiming.load(Ordering::SeqCst) => return,
                Ok(None) => continue,
                Err(e) => {
                    std::thread::sleep(claims.failed("cannot claim a job", &e));
                    continue;
                }
            };
            self.run_claim(claim);
        }
    }

    /// Waits while the data folder's disk has less than
    /// [`MIN_FREE_FOR_JOBS`] free (a job started then could not record its
    /// end); false when the pool stops meanwhile.
    fn wait_for_disk(&self) -> bool {
        let mut short = false;
        loop {
            if self.stop_claiming.load(Ordering::SeqCst) {
                return false;
            }
            match self.data.free_bytes() {
                Ok(free) if free < MIN_FREE_FOR_JOBS => {
                    if !short {
                        tracing::warn!(
                            free_mib = free / MIB,
                            "the data folder's disk is full: no job starts until space returns"
                        );
                        short = true;
                    }
                    std::thread::sleep(DISK_WAIT);
                }
                // Room, or no way to tell: the job's own writes will say.
                _ => {
                    if short {
                        tracing::info!("disk space is back: jobs start again");
                    }
                    return true;
                }
            }
        }
    }

    fn run_claim(&mut self, claim: Claim) {
        let job = &claim.job;
        let span = tracing::info_span!("job", job.id = %job.id, image = %job.image);
        let _enter = span.enter();
        let started = Instant::now();
        let Some((outcome, megapixels)) = self.execute(&claim) else {
            tracing::warn!("the job's lease was lost (expired or deleted): another claim runs it");
            return;
        };
        let label = match &outcome {
            Outcome::Succeeded { targets, .. } => {
                tracing::info!(targets, "job succeeded");
                "succeeded"
            }
            Outcome::Failed(e) => {
                tracing::warn!(code = %e.code, error = %e.message, "job failed");
                "failed"
            }
            Outcome::Canceled => "canceled",
            Outcome::Interrupted => "interrupted",
        };
        let labels = OutcomeLabels { outcome: label };
        self.metrics.jobs_finished.get_or_create(&labels).inc();
        self.metrics
            .job_duration
            .get_or_create(&labels)
            .observe(started.elapsed().as_secs_f64());
        if matches!(outcome, Outcome::Succeeded { .. }) {
            self.metrics.megapixels.inc_by(megapixels);
        }
        match self.record_end(&claim, &outcome) {
            // A frame fetched from object storage is still there: the
            // local copy goes once the job has ended, so a long flight
            // does not fill the disk.
            Some(Finished::Recorded)
                if job.source.is_some() && !matches!(outcome, Outcome::Interrupted) =>
            {
                self.data.remove_frame(job.id, &job.ext)
            }
            // Lost: the job's files belong to the claim that has it now.
            Some(Finished::Recorded | Finished::Lost) | None => {}
            // Deleted while it ran: drop what it wrote.
            Some(Finished::Deleted) => self.data.remove_job_files(job.id, &job.ext),
        }
    }

    /// Records a job's end, retrying while the store cannot write (a full
    /// disk: the job must not stay `running` once space returns). When the
    /// server stops meanwhile, the job is put back in the queue in memory
    /// only (the store still says running, which the next start requeues),
    /// so shutdown does not wait for it; None then.
    fn record_end(&self, claim: &Claim, outcome: &Outcome) -> Option<Finished> {
        let mut tries = Backoff::default();
        loop {
            match self.store.finish(&claim.lease, outcome) {
                Ok(changed) => {
                    tries.recovered("the job's end is recorded");
                    return Some(changed);
                }
                Err(e) => {
                    if self.stop_claiming.load(Ordering::SeqCst) {
                        tracing::error!(error = %e, "cannot record the job's end while stopping: it runs again at the next start");
                        self.store.release_unrecorded(&claim.lease);
                        return None;
                    }
                    let wait = tries.failed("cannot record the job's end; retrying", &e);
                    let until = Instant::now() + wait;
                    while Instant::now() < until && !self.stop_claiming.load(Ordering::SeqCst) {
                        std::thread::sleep(POLL);
                    }
                }
            }
        }
    }

    /// Runs a claimed job in a child process (see [`super::isolate`]);
    /// returns its outcome and the frame's megapixels, or `None` if the
    /// lease was lost meanwhile (the child is stopped; nothing to record).
    fn execute(&mut self, claim: &Claim) -> Option<(Outcome, f64)> {
        let job = &claim.job;
        let fail = |code: ErrorCode, message: String| {
            Some((Outcome::Failed(JobError { code, message }), 0.0))
        };
        let frame = self.data.frame_path(job.id, &job.ext);
        let result = self.data.result_path(job.id);
        // Replicas: the frame may have arrived at another one.
        if let Err(e) = self.data.bring_in(&frame) {
            tracing::warn!(error = %e, "cannot bring the frame in from the shared files; the job goes back to the queue");
            std::thread::sleep(DISK_WAIT);
            return Some((Outcome::Interrupted, 0.0));
        }
        if !frame.exists() {
            return fail(
                ErrorCode::Internal,
                "the frame is missing from the data folder (and the shared files)".into(),
            );
        }
        // The worker's process, kept from its last job, or a fresh one.
        let mut child = match self.child.take() {
            Some(child) => child,
            None => match JobChild::spawn() {
                Ok(c) => c,
                Err(e) => {
                    return fail(
                        ErrorCode::Internal,
                        format!("cannot start a worker process: {e}"),
                    )
                }
            },
        };
        let order = JobOrder {
            frame,
            image: job.image.clone(),
            params: claim.params.clone(),
            result,
        };
        if let Err(e) = child.send(&order) {
            // The kept process died while idle: one more try with a new one.
            tracing::warn!(error = %e, "the worker process is gone; starting another");
            child = match JobChild::spawn().and_then(|mut c| c.send(&order).map(|_| c)) {
                Ok(c) => c,
                Err(e) => {
                    return fail(
                        ErrorCode::Internal,
                        format!("cannot start a worker process: {e}"),
                    )
                }
            };
        }
        tracing::debug!(pid = child.pid(), "worker process started");
        let mut megapixels = 0.0;
        let mut warnings = Vec::new();
        let mut permit = None;
        let mut beat = Beat::new();
        loop {
            let heard = child.next_line(POLL);
            if let Some(stop) = self.beat(claim, &mut beat, false) {
                child.kill();
                return stop;
            }
            if self.abort.load(Ordering::SeqCst) && !matches!(heard, Heard::Ended) {
                child.kill();
                return Some((Outcome::Interrupted, 0.0));
            }
            let line = match heard {
                Heard::Line(line) => line,
                Heard::Nothing => continue,
                Heard::Ended => break,
            };
            tracing::debug!(%line, "from the worker process");
            match ChildLine::parse(&line) {
                Some(ChildLine::Header {
                    width,
                    height,
                    need,
                }) => {
                    if let Err(e) = self.pixels.admit(width, height, "opens as") {
                        return fail(ErrorCode::FrameTooLarge, e.to_string());
                    }
                    megapixels = width as f64 * height as f64 / 1e6;
                    beat.progress.size = Some((width, height));
                    // Waiting for memory renews the lease too.
                    loop {
                        if let Some(stop) = self.beat(claim, &mut beat, true) {
                            child.kill();
                            return stop;
                        }
                        match self.budget.acquire_within(need, HEARTBEAT) {
                            Ok(Some(p)) => {
                                permit = Some(p);
                                break;
                            }
                            Ok(None) => {}
                            Err(e) => return fail(ErrorCode::FrameTooLarge, e.to_string()),
                        }
                    }
                    if self.stop_claiming.load(Ordering::SeqCst) {
                        // Shutting down: waiting for memory was the whole run.
                        return Some((Outcome::Interrupted, 0.0));
                    }
                    let data_limit = need + CHILD_HEADROOM_BYTES;
                    if let Err(e) = child.go(data_limit, cpu_limit_secs(width, height)) {
                        tracing::warn!(error = %e, "the worker process did not take its limits");
                    }
                }
                Some(ChildLine::Tile { done, total }) => {
                    beat.progress.tiles_done = done;
                    beat.progress.tiles_total = total;
                }
                Some(ChildLine::Warning { message }) => warnings.push(message),
                Some(ChildLine::Done {
                    targets,
                    width,
                    height,
                }) => {
                    drop(permit);
                    self.child = Some(child);
                    // Replicas: pictures first, then the result that
                    // names them, so a result anyone reads has its pictures.
                    let pictures = self.data.pictures_dir(job.id);
                    let published = (if pictures.exists() {
                        self.data.publish(&pictures)
                    } else {
                        Ok(())
                    })
                    .and_then(|()| self.data.publish(&self.data.result_path(job.id)));
                    if let Err(e) = published {
                        tracing::warn!(error = %e, "cannot write the result to the shared files; the job goes back to the queue");
                        return Some((Outcome::Interrupted, 0.0));
                    }
                    return Some((
                        Outcome::Succeeded {
                            width,
                            height,
                            targets,
                            warnings,
                        },
                        megapixels,
                    ));
                }
                Some(ChildLine::Error { code, message }) => {
                    self.child = Some(child);
                    if code == ErrorCode::NoSpace {
                        // The server's disk, not the frame: the job goes
                        // back to the queue and waits for space.
                        tracing::warn!(%message, "the disk is full: the job goes back to the queue");
                        return Some((Outcome::Interrupted, 0.0));
                    }
                    return fail(code, message);
                }
                None => tracing::warn!(%line, "unexpected line from the worker process"),
            }
        }
        drop(permit);
        if let Some(stop) = self.beat(claim, &mut beat, true) {
            return stop;
        }
        if self.abort.load(Ordering::SeqCst) {
            return Some((Outcome::Interrupted, 0.0));
        }
        let end = child
            .wait_abnormal()
            .unwrap_or_else(|| "ended without a result".into());
        Some(self.crashed(job, &end))
    }

    /// Renews the claim's lease and reports progress, at most every
    /// [`HEARTBEAT`] unless `now`; says how the job stops if it must: a
    /// cancel asked for (`Some(Some(Canceled))`) or the lease lost
    /// (`Some(None)`). A store that cannot answer is logged and the job
    /// goes on (its lease expires if that lasts).
    fn beat(&self, claim: &Claim, beat: &mut Beat, now: bool) -> Option<Option<(Outcome, f64)>> {
        if !now && beat.last.is_some_and(|t| t.elapsed() < HEARTBEAT) {
            return None;
        }
        beat.last = Some(Instant::now());
        let state = match self.store.heartbeat(&claim.lease, &beat.progress) {
            Ok(state) => state,
            Err(e) => {
                beat.failures.failed("cannot renew the job's lease", &e);
                return None;
            }
        };
        beat.failures.recovered("the job's lease is renewed again");
        match state {
            LeaseState::Held { cancel: false } => None,
            LeaseState::Held { cancel: true } => Some(Some((Outcome::Canceled, 0.0))),
            LeaseState::Lost => Some(None),
        }
    }

    /// A worker process died: the job goes back to the queue, or fails
    /// once it has killed [`MAX_ATTEMPTS`] workers.
    fn crashed(&self, job: &JobRecord, end: &str) -> (Outcome, f64) {
        tracing::warn!(attempts = job.attempts, end, "the worker process died");
        if job.attempts >= MAX_ATTEMPTS {
            return (
                Outcome::Failed(JobError {
                    code: ErrorCode::WorkerCrashed,
                    message: format!(
                        "the worker process died on each of {} attempts (last: {end}); the frame is not retried",
                        job.attempts
                    ),
                }),
                0.0,
            );
        }
        (Outcome::Interrupted, 0.0)
    }
}
