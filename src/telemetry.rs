//! Prometheus metrics of the service (queue, jobs, memory budget, pixels)
//! and of its HTTP side. Workers and handlers record into one [`Metrics`];
//! `/metrics` renders it in the OpenMetrics text format.

use std::sync::atomic::AtomicU64;

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{exponential_buckets, Histogram};
use prometheus_client::registry::Registry;

/// How a job ended: `succeeded`, `failed`, `canceled` or `interrupted`
/// (stopped by shutdown and queued again).
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct OutcomeLabels {
    pub outcome: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct HttpLabels {
    pub method: String,
    /// The matched route template (`/v1/jobs/{id}`), never the raw path, so
    /// the label set stays small.
    pub route: String,
    pub status: u16,
}

/// Every metric of the process.
pub struct Metrics {
    registry: Registry,
    pub queue_depth: Gauge,
    pub jobs_running: Gauge,
    pub jobs_finished: Family<OutcomeLabels, Counter>,
    pub job_duration: Family<OutcomeLabels, Histogram>,
    pub megapixels: Counter<f64, AtomicU64>,
    pub budget_bytes: Gauge,
    pub budget_in_use_bytes: Gauge,
    pub resident_bytes: Gauge,
    pub http_requests: Family<HttpLabels, Counter>,
    pub http_duration: Family<HttpLabels, Histogram>,
}

impl Default for Metrics {
    fn default() -> Self {
        Self::new()
    }
}

impl Metrics {
    pub fn new() -> Metrics {
        let mut registry = Registry::with_prefix("gcp_tagger");
        let queue_depth = Gauge::default();
        registry.register(
            "queue_depth",
            "Jobs waiting for a worker",
            queue_depth.clone(),
        );
        let jobs_running = Gauge::default();
        registry.register("jobs_running", "Jobs running now", jobs_running.clone());
        let jobs_finished = Family::<OutcomeLabels, Counter>::default();
        registry.register("jobs", "Jobs ended, by outcome", jobs_finished.clone());
        // 0.1 s .. ~200 s: a small PNG to a 100 MP frame on one core.
        let job_duration = Family::<OutcomeLabels, Histogram>::new_with_constructor(|| {
            Histogram::new(exponential_buckets(0.1, 2.0, 12))
        });
        registry.register(
            "job_duration_seconds",
            "Time from claim to end of a job",
            job_duration.clone(),
        );
        let megapixels = Counter::<f64, AtomicU64>::default();
        registry.register(
            "megapixels_processed",
            "Megapixels of frames processed to the end",
            megapixels.clone(),
        );
        let budget_bytes = Gauge::default();
        registry.register(
            "memory_budget_bytes",
            "RAM budget for frames (the limit minus the process's base)",
            budget_bytes.clone(),
        );
        let budget_in_use_bytes = Gauge::default();
        registry.register(
            "memory_budget_in_use_bytes",
            "Part of the RAM budget held by running jobs",
            budget_in_use_bytes.clone(),
        );
        let resident_bytes = Gauge::default();
        registry.register(
            "resident_memory_bytes",
            "Resident set size of the process",
            resident_bytes.clone(),
        );
        let http_requests = Family::<HttpLabels, Counter>::default();
        registry.register(
            "http_requests",
            "HTTP requests answered",
            http_requests.clone(),
        );
        // 1 ms .. ~4 s.
        let http_duration = Family::<HttpLabels, Histogram>::new_with_constructor(|| {
            Histogram::new(exponential_buckets(0.001, 2.0, 13))
        });
        registry.register(
            "http_request_duration_seconds",
            "Time to answer an HTTP request (to the first byte of the body)",
            http_duration.clone(),
        );
        Metrics {
            registry,
            queue_depth,
            jobs_running,
            jobs_finished,
            job_duration,
            megapixels,
            budget_bytes,
            budget_in_use_bytes,
            resident_bytes,
            http_requests,
            http_duration,
        }
    }

    /// The OpenMetrics text of every metric.
    pub fn render(&self) -> String {
        self.resident_bytes.set(resident_bytes() as i64);
        let mut out = String::new();
        prometheus_client::encoding::text::encode(&mut out, &self.registry)
            .expect("writing to a String cannot fail");
        out
    }
}

/// Resident set size of this process, from /proc (0 where unavailable).
pub fn resident_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<u64>().ok())
        .map_or(0, |pages| pages * page_size())
}

fn page_size() -> u64 {
    // SAFETY: sysconf has no preconditions.
    let n = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    if n > 0 {
        n as u64
    } else {
        4096
    }
}
