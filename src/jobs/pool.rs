//! The worker pool: one OS thread per worker (CPU work never touches the
//! async runtime), each claiming the next queued job, estimating its working
//! set from the raster header, waiting for that share of the RAM budget, and
//! running the pipeline with a cooperative stop flag checked at every tile.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::pipeline::frame::{detect_frame, FrameError, FrameObserver};
use crate::pipeline::georef::Transformer;
use crate::pipeline::memory::{estimate_frame_bytes, RamBudget, MIB};
use crate::pipeline::raster::{open_frame, RasterError};
use crate::storage::DataDir;
use crate::telemetry::{Metrics, OutcomeLabels};

use super::model::JobError;
use super::store::{Claim, Outcome, Store};

/// How long an idle worker waits before re-checking the stop flag.
const IDLE_WAIT: Duration = Duration::from_millis(250);

/// Memory of the service's async side (HTTP connections, upload buffers,
/// the job store) on top of the pipeline's base. The load benchmark measured
/// 236 MiB peak for the service against 227 MiB for `detect` on the same
/// 100 frames and limit (~9 MiB with one upload); the rest is headroom for
/// several uploads streaming at once (64 KiB-scale buffers each).
pub const SERVICE_BASE_BYTES: u64 = 24 * MIB;

/// Pool settings.
#[derive(Debug, Clone)]
pub struct PoolConfig {
    pub workers: usize,
    /// The whole process's memory limit.
    pub max_ram_bytes: u64,
}

/// Running workers and the flags that stop them.
pub struct WorkerPool {
    handles: Vec<JoinHandle<()>>,
    stop_claiming: Arc<AtomicBool>,
    abort: Arc<AtomicBool>,
    budget: Arc<RamBudget>,
    store: Arc<Store>,
}

impl WorkerPool {
    /// Starts `config.workers` threads on `store`'s queue.
    pub fn start(
        store: Arc<Store>,
        data: DataDir,
        metrics: Arc<Metrics>,
        config: &PoolConfig,
    ) -> WorkerPool {
        crate::pipeline::init_native();
        let budget = Arc::new(RamBudget::for_process_limit(
            config.max_ram_bytes.saturating_sub(SERVICE_BASE_BYTES),
        ));
        metrics.budget_bytes.set(budget.capacity() as i64);
        let stop_claiming = Arc::new(AtomicBool::new(false));
        let abort = Arc::new(AtomicBool::new(false));
        let handles = (0..config.workers.max(1))
            .map(|i| {
                let worker = Worker {
                    store: store.clone(),
                    data: data.clone(),
                    metrics: metrics.clone(),
                    budget: budget.clone(),
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

struct Worker {
    store: Arc<Store>,
    data: DataDir,
    metrics: Arc<Metrics>,
    budget: Arc<RamBudget>,
    stop_claiming: Arc<AtomicBool>,
    abort: Arc<AtomicBool>,
}

impl Worker {
    fn run(self) {
        // PROJ objects are per thread; reuse them across jobs.
        let mut transformer = Transformer::default();
        loop {
            let claim = match self.store.claim_next(&self.stop_claiming, IDLE_WAIT) {
                Ok(Some(claim)) => claim,
                Ok(None) if self.stop_claiming.load(Ordering::SeqCst) => return,
                Ok(None) => continue,
                Err(e) => {
                    tracing::error!(error = %e, "cannot claim a job");
                    std::thread::sleep(IDLE_WAIT);
                    continue;
                }
            };
            self.run_claim(claim, &mut transformer);
        }
    }

    fn run_claim(&self, claim: Claim, transformer: &mut Transformer) {
        let job = &claim.job;
        let span = tracing::info_span!("job", job.id = %job.id, image = %job.image);
        let _enter = span.enter();
        let started = Instant::now();
        let (outcome, megapixels) = self.execute(&claim, transformer);
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
        match self.store.finish(job.id, &outcome) {
            // A frame fetched from object storage is still there: the
            // local copy goes once the job has ended, so a long flight
            // does not fill the disk.
            Ok(true) if job.source.is_some() && !matches!(outcome, Outcome::Interrupted) => {
                self.data.remove_frame(job.id, &job.ext)
            }
            Ok(true) => {}
            // Deleted while it ran: drop what it wrote.
            Ok(false) => self.data.remove_job_files(job.id, &job.ext),
            Err(e) => tracing::error!(error = %e, "cannot record the job's end"),
        }
    }

    /// Runs the pipeline on a claimed job; returns its outcome and the
    /// frame's megapixels.
    fn execute(&self, claim: &Claim, transformer: &mut Transformer) -> (Outcome, f64) {
        let job = &claim.job;
        let fail = |code: &str, message: String| {
            (
                Outcome::Failed(JobError {
                    code: code.into(),
                    message,
                }),
                0.0,
            )
        };
        let options = match claim.params.check() {
            Ok((_, options)) => options,
            Err(e) => return fail("invalid_parameters", e.to_string()),
        };
        let path = self.data.frame_path(job.id, &job.ext);
        let frame = match open_frame(&path) {
            Ok(frame) => frame,
            Err(e) => return fail(raster_code(&e), e.to_string()),
        };
        let header = frame.header().clone();
        let megapixels = (header.width * header.height) as f64 / 1e6;
        self.store.progress(
            job.id,
            Some((header.width as u32, header.height as u32)),
            0,
            0,
        );
        let need = estimate_frame_bytes(&header, options.tile_size);
        let _permit = match self.budget.acquire(need) {
            Ok(permit) => permit,
            Err(e) => return fail("frame_too_large", e.to_string()),
        };
        if self.stop_claiming.load(Ordering::SeqCst) {
            // Shutting down: waiting for memory was the whole run so far.
            return (Outcome::Interrupted, 0.0);
        }
        let observer = JobObserver {
            worker: self,
            claim,
        };
        match detect_frame(frame, &job.image, &options, transformer, &observer) {
            Ok(result) => {
                let bytes = serde_json::to_vec(&result).expect("results serialize");
                if let Err(e) = self
                    .data
                    .write_atomic(&self.data.result_path(job.id), &bytes)
                {
                    return fail("internal", format!("cannot store the result: {e}"));
                }
                (
                    Outcome::Succeeded {
                        width: result.width as u32,
                        height: result.height as u32,
                        targets: result.targets.len() as u32,
                    },
                    megapixels,
                )
            }
            Err(FrameError::Canceled) if claim.cancel.load(Ordering::SeqCst) => {
                (Outcome::Canceled, 0.0)
            }
            Err(FrameError::Canceled) => (Outcome::Interrupted, 0.0),
            Err(FrameError::Raster(e)) => fail(raster_code(&e), e.to_string()),
            Err(FrameError::TooLarge(e)) => fail("frame_too_large", e.to_string()),
            Err(e @ (FrameError::Detect(_) | FrameError::OpenCv(_))) => {
                fail("detection_failed", e.to_string())
            }
        }
    }
}

/// Stable codes for frames that cannot be read.
fn raster_code(e: &RasterError) -> &'static str {
    match e {
        RasterError::Unsupported(_) => "unsupported_frame",
        RasterError::TooSmall { .. } => "frame_too_small",
        RasterError::Bands(_) => "unsupported_bands",
        RasterError::Empty => "empty_frame",
        RasterError::Io(_) | RasterError::RefusedPath(_) | RasterError::Decode { .. } => {
            "unreadable_frame"
        }
    }
}

struct JobObserver<'a> {
    worker: &'a Worker,
    claim: &'a Claim,
}

impl FrameObserver for JobObserver<'_> {
    fn tile_done(&self, done: usize, total: usize) {
        self.worker
            .store
            .progress(self.claim.job.id, None, done as u32, total as u32);
    }

    fn should_stop(&self) -> bool {
        self.claim.cancel.load(Ordering::SeqCst) || self.worker.abort.load(Ordering::SeqCst)
    }
}
