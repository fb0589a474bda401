//! Configuration of `gcp-tagger serve`: every flag also readable from a
//! `GCP_TAGGER_*` environment variable, with defaults that serve a local
//! data folder and need no external service.

use std::net::SocketAddr;
use std::path::PathBuf;

use clap::Args;

use crate::pipeline::memory::default_max_ram_bytes;
use crate::storage::s3::S3Config;

/// Flags of `serve`.
#[derive(Args, Debug, Clone)]
pub struct ServeArgs {
    /// Address to listen on; port 0 picks a free port (the bound address is printed and logged).
    #[arg(long, env = "GCP_TAGGER_LISTEN", default_value = "127.0.0.1:8080")]
    pub listen: SocketAddr,
    /// Folder for the job store, uploaded frames and results (created if missing).
    #[arg(long, env = "GCP_TAGGER_DATA_DIR", default_value = "gcp-tagger-data")]
    pub data_dir: PathBuf,
    /// The job store: `postgres://user:password@host/db` for one queue shared by several replicas; default: SQLite in the data folder.
    #[arg(long, env = "GCP_TAGGER_STORE")]
    pub store: Option<String>,
    /// With `--store postgres://...`: the bucket and prefix (`s3://bucket/prefix/`) where frames, results, reviews and surveys live, so any replica can run any job and serve any result (through the S3 settings below).
    #[arg(long, env = "GCP_TAGGER_SHARED_FILES")]
    pub shared_files: Option<String>,
    /// Seconds a job's claim lasts without a heartbeat from its worker (sent every 0.25 s) before the job is queued again.
    #[arg(long, env = "GCP_TAGGER_LEASE_SECS", default_value_t = 30)]
    pub lease_secs: u64,
    /// Memory limit for the whole process, in GiB (default: half of the machine's or container's memory).
    #[arg(long, env = "GCP_TAGGER_MAX_RAM_GB")]
    pub max_ram_gb: Option<f64>,
    /// Jobs run at once at most (default: number of cores); the RAM budget may allow fewer.
    #[arg(long, env = "GCP_TAGGER_WORKERS")]
    pub workers: Option<usize>,
    /// Largest frame accepted, in MiB.
    #[arg(long, env = "GCP_TAGGER_MAX_FRAME_MB", default_value_t = 512)]
    pub max_frame_mb: u64,
    /// Largest request body accepted (a whole flight upload), in MiB.
    #[arg(long, env = "GCP_TAGGER_MAX_REQUEST_MB", default_value_t = 16384)]
    pub max_request_mb: u64,
    /// Most frames in one request.
    #[arg(
        long,
        env = "GCP_TAGGER_MAX_FRAMES_PER_REQUEST",
        default_value_t = 2000
    )]
    pub max_frames_per_request: usize,
    /// Most frames one flight may hold, across all its requests.
    #[arg(
        long,
        env = "GCP_TAGGER_MAX_FRAMES_PER_FLIGHT",
        default_value_t = 20000
    )]
    pub max_frames_per_flight: usize,
    /// Bearer API keys, comma separated; when set, every route but /livez and /readyz needs one.
    #[arg(
        long = "api-key",
        env = "GCP_TAGGER_API_KEYS",
        value_delimiter = ',',
        hide_env_values = true
    )]
    pub api_keys: Vec<String>,
    /// Origins allowed to call the API from browsers (CORS), comma separated; `*` allows any.
    #[arg(
        long = "cors-origin",
        env = "GCP_TAGGER_CORS_ORIGINS",
        value_delimiter = ','
    )]
    pub cors_origins: Vec<String>,
    /// On SIGTERM/SIGINT, seconds running jobs get to finish before they are stopped and left queued.
    #[arg(long, env = "GCP_TAGGER_SHUTDOWN_GRACE_SECS", default_value_t = 30)]
    pub shutdown_grace_secs: u64,
    /// Finished flights (records, frames, results) are removed this many hours after their last job ended; 0 keeps them forever.
    #[arg(long, env = "GCP_TAGGER_RETENTION_HOURS", default_value_t = 168.0)]
    pub retention_hours: f64,
    /// Requests per minute one client (API key, else IP address) may make; 0 turns the limit off.
    #[arg(long, env = "GCP_TAGGER_RATE_LIMIT_PER_MINUTE", default_value_t = 1200)]
    pub rate_limit_per_minute: u32,
    /// Most pixels a frame's header may claim, in megapixels (checked before decoding).
    #[arg(long, env = "GCP_TAGGER_MAX_FRAME_MP", default_value_t = 400)]
    pub max_frame_mp: u64,
    /// Longest side a frame's header may claim, in pixels.
    #[arg(long, env = "GCP_TAGGER_MAX_FRAME_SIDE", default_value_t = 60000)]
    pub max_frame_side: u32,
    /// Uploads are refused with 507 while the data folder's disk has less free, in MiB; running work goes on.
    #[arg(long, env = "GCP_TAGGER_MIN_FREE_DISK_MB", default_value_t = 1024)]
    pub min_free_disk_mb: u64,
    /// S3-compatible endpoint for s3:// sources (MinIO, Ceph), e.g. http://127.0.0.1:9000 (default: AWS_ENDPOINT_URL, else AWS).
    #[arg(long, env = "GCP_TAGGER_S3_ENDPOINT")]
    pub s3_endpoint: Option<String>,
    /// S3 region (default: AWS_REGION / AWS_DEFAULT_REGION, else us-east-1).
    #[arg(long, env = "GCP_TAGGER_S3_REGION")]
    pub s3_region: Option<String>,
    /// Buckets clients may name in s3:// sources and results_to, comma separated (default: any bucket at the endpoint).
    #[arg(
        long = "s3-allow-bucket",
        env = "GCP_TAGGER_S3_ALLOW_BUCKETS",
        value_delimiter = ','
    )]
    pub s3_allow_buckets: Vec<String>,
    /// Objects downloaded at once.
    #[arg(long, env = "GCP_TAGGER_S3_CONCURRENCY", default_value_t = 4)]
    pub s3_concurrency: usize,
    /// Fetched frames that may wait in the spool for a worker.
    #[arg(long, env = "GCP_TAGGER_S3_READ_AHEAD", default_value_t = 8)]
    pub s3_read_ahead: usize,
    /// Longest one object download may take, in seconds (100 MB at 100 kB/s fits).
    #[arg(long, env = "GCP_TAGGER_S3_TIMEOUT_SECS", default_value_t = 1800)]
    pub s3_timeout_secs: u64,
    /// Skip the MD5 check of downloads against plain ETags (for stores whose ETags are not MD5s, e.g. SSE-KMS).
    #[arg(long, env = "GCP_TAGGER_S3_NO_MD5_CHECK")]
    pub s3_no_md5_check: bool,
}

/// A setting of `serve` that cannot work.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct ConfigError(pub String);

impl ServeArgs {
    /// The S3 client settings.
    pub fn s3_config(&self) -> S3Config {
        S3Config {
            endpoint: self.s3_endpoint.clone(),
            region: self.s3_region.clone(),
            allowed_buckets: self
                .s3_allow_buckets
                .iter()
                .map(|b| b.trim().to_string())
                .filter(|b| !b.is_empty())
                .collect(),
            verify_md5: !self.s3_no_md5_check,
            request_timeout_secs: self.s3_timeout_secs,
        }
    }

    /// The process memory limit in bytes.
    pub fn max_ram_bytes(&self) -> Result<u64, ConfigError> {
        match self.max_ram_gb {
            Some(gb) if gb.is_finite() && gb > 0.0 => Ok((gb * (1u64 << 30) as f64) as u64),
            Some(gb) => Err(ConfigError(format!(
                "--max-ram-gb must be positive, got {gb}"
            ))),
            None => Ok(default_max_ram_bytes()),
        }
    }

    pub fn workers(&self) -> Result<usize, ConfigError> {
        match self.workers {
            Some(0) => Err(ConfigError("--workers must be at least 1".into())),
            Some(n) => Ok(n),
            None => Ok(std::thread::available_parallelism().map_or(1, |n| n.get())),
        }
    }

    /// Checks what clap cannot: non-empty keys, sane limits.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.max_ram_bytes()?;
        self.workers()?;
        if self.api_keys.iter().any(|k| k.trim().len() < 16) {
            return Err(ConfigError(
                "--api-key: every key needs at least 16 characters".into(),
            ));
        }
        if self.max_frame_mb == 0 || self.max_request_mb < self.max_frame_mb {
            return Err(ConfigError(
                "--max-frame-mb must be positive and at most --max-request-mb".into(),
            ));
        }
        if !(self.retention_hours.is_finite() && self.retention_hours >= 0.0) {
            return Err(ConfigError(format!(
                "--retention-hours must be 0 or positive, got {}",
                self.retention_hours
            )));
        }
        if let Some(url) = &self.store {
            if !(url.starts_with("postgres://") || url.starts_with("postgresql://")) {
                return Err(ConfigError(
                    "--store must be a postgres:// or postgresql:// URL (leave it out for the embedded SQLite store)".into(),
                ));
            }
        }
        match (&self.store, &self.shared_files) {
            (Some(_), None) => {
                return Err(ConfigError(
                    "--store postgres://... needs --shared-files s3://bucket/prefix/: replicas keep frames and results there".into(),
                ))
            }
            (None, Some(_)) => {
                return Err(ConfigError(
                    "--shared-files is for replicas sharing a --store postgres://...; the embedded store keeps files in --data-dir".into(),
                ))
            }
            (Some(_), Some(url)) if !(url.starts_with("s3://") && url.ends_with('/')) => {
                return Err(ConfigError(format!(
                    "--shared-files must be s3://bucket/prefix/ (ending in '/'), got {url:?}"
                )))
            }
            _ => {}
        }
        if self.lease_secs < 2 {
            return Err(ConfigError(format!(
                "--lease-secs must be at least 2 (workers renew every 0.25 s), got {}",
                self.lease_secs
            )));
        }
        if self.s3_concurrency == 0 || self.s3_read_ahead == 0 || self.s3_timeout_secs == 0 {
            return Err(ConfigError(
                "--s3-concurrency, --s3-read-ahead and --s3-timeout-secs must be positive".into(),
            ));
        }
        if let Some(e) = &self.s3_endpoint {
            if !(e.starts_with("http://") || e.starts_with("https://")) {
                return Err(ConfigError(format!(
                    "--s3-endpoint must be an http:// or https:// URL, got {e:?}"
                )));
            }
        }
        if self.max_frames_per_request == 0 {
            return Err(ConfigError(
                "--max-frames-per-request must be positive".into(),
            ));
        }
        Ok(())
    }
}
