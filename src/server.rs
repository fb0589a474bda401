//! `gcp-tagger serve`: opens the data folder and job store, starts the
//! worker pool and the HTTP server, and shuts down gracefully on SIGTERM or
//! SIGINT: stop taking requests and jobs, give running jobs the grace
//! period, then stop them and leave them queued for the next start.

use std::future::IntoFuture;
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use tokio::net::TcpListener;
use tokio::time::Instant;

use crate::api::{self, AppState, HttpConfig, UploadLimits};
use crate::config::ServeArgs;
use crate::jobs::fetch::{self, FetchConfig};
use crate::jobs::store::{self, LeaseConfig};
use crate::jobs::{export, retention, PoolConfig, WorkerPool};
use crate::storage::header::PixelLimits;
use crate::storage::s3::S3;
use crate::storage::shared::SharedFiles;
use crate::storage::DataDir;
use crate::telemetry::Metrics;

/// Runs the service until a signal stops it.
pub async fn run(args: ServeArgs) -> anyhow::Result<()> {
    args.validate()?;
    let max_ram_bytes = args.max_ram_bytes()?;
    let mut data = DataDir::open(&args.data_dir)?;
    let s3 = Arc::new(S3::new(args.s3_config()));
    if let Some(url) = &args.shared_files {
        let shared = SharedFiles::new(&s3, url).context("--shared-files")?;
        tracing::info!(
            url = shared.url(),
            "frames and results are shared through the bucket"
        );
        data = data.with_shared(Arc::new(shared));
    }
    let db_path = data.db_path();
    let lease = LeaseConfig {
        lease: std::time::Duration::from_secs(args.lease_secs),
        ..LeaseConfig::default()
    };
    let url = args.store.clone();
    let store = tokio::task::spawn_blocking(move || store::open(url.as_deref(), &db_path, lease))
        .await?
        .context("cannot open the job store")?;
    let metrics = Arc::new(Metrics::new());
    let pool = WorkerPool::start(
        store.clone(),
        data.clone(),
        metrics.clone(),
        &PoolConfig {
            workers: args.workers()?,
            max_ram_bytes,
            pixels: PixelLimits {
                max_pixels: args.max_frame_mp * 1_000_000,
                max_side: args.max_frame_side,
            },
        },
    );
    let (shutdown_tx, shutdown_rx) = tokio::sync::watch::channel(false);
    let ready = Arc::new(AtomicBool::new(false));
    let fetcher = tokio::spawn(fetch::run(
        store.clone(),
        data.clone(),
        s3.clone(),
        FetchConfig {
            concurrency: args.s3_concurrency,
            read_ahead: args.s3_read_ahead,
            max_frame_bytes: args.max_frame_mb << 20,
            pixels: PixelLimits {
                max_pixels: args.max_frame_mp * 1_000_000,
                max_side: args.max_frame_side,
            },
        },
        shutdown_rx.clone(),
    ));
    if args.retention_hours > 0.0 {
        let keep = Duration::from_secs_f64(args.retention_hours * 3600.0);
        tokio::spawn(retention::run(
            store.clone(),
            data.clone(),
            keep,
            shutdown_rx.clone(),
        ));
    }
    let exporter = tokio::spawn(export::run(
        store.clone(),
        data.clone(),
        s3.clone(),
        shutdown_rx.clone(),
    ));
    let state = AppState {
        store: store.clone(),
        data,
        metrics,
        budget: pool.budget().clone(),
        limits: UploadLimits {
            max_frame_bytes: args.max_frame_mb << 20,
            pixels: PixelLimits {
                max_pixels: args.max_frame_mp * 1_000_000,
                max_side: args.max_frame_side,
            },
            min_free_bytes: args.min_free_disk_mb << 20,
            max_request_bytes: args.max_request_mb << 20,
            max_frames_per_request: args.max_frames_per_request,
            max_frames_per_flight: args.max_frames_per_flight,
        },
        shutdown: shutdown_rx.clone(),
        ready: ready.clone(),
        s3,
    };
    let app = api::router(
        state,
        &HttpConfig {
            api_keys: args.api_keys.iter().map(|k| k.trim().to_string()).collect(),
            cors_origins: args.cors_origins.clone(),
            rate_limit_per_minute: args.rate_limit_per_minute,
        },
    );
    let listener = TcpListener::bind(args.listen)
        .await
        .with_context(|| format!("cannot listen on {}", args.listen))?;
    let addr = listener.local_addr()?;
    tracing::info!(%addr, data_dir = %args.data_dir.display(), max_ram_mib = max_ram_bytes >> 20, "listening");
    // Scripts and tests read the address from the first line of stdout.
    println!("gcp-tagger listening on http://{addr}");
    let _ = std::io::stdout().flush();
    ready.store(true, Ordering::SeqCst);

    // The listener stays open through the grace period, so probes see
    // /readyz turn 503 and clients get a 503 for new work, not a refused
    // connection; it closes once the running jobs have ended.
    let (http_stop_tx, mut drained) = tokio::sync::watch::channel(false);
    let mut server = tokio::spawn(
        axum::serve(
            listener,
            app.into_make_service_with_connect_info::<std::net::SocketAddr>(),
        )
        .with_graceful_shutdown(async move {
            let _ = drained.wait_for(|stop| *stop).await;
        })
        .into_future(),
    );
    let signal = tokio::select! {
        s = wait_for_signal() => s,
        r = &mut server => {
            r??;
            anyhow::bail!("the HTTP server stopped on its own");
        }
    };
    tracing::info!(signal, "shutting down: no new requests or jobs");
    ready.store(false, Ordering::SeqCst);
    let _ = shutdown_tx.send(true);
    pool.stop_claiming();

    let grace = Duration::from_secs(args.shutdown_grace_secs);
    let deadline = Instant::now() + grace;
    while store.stats()?.running > 0 && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let left = store.stats()?.running;
    if left > 0 {
        tracing::warn!(
            jobs = left,
            "grace period over: stopping running jobs; they stay queued"
        );
        pool.abort_running();
    }
    let _ = http_stop_tx.send(true);
    // Requests still open (a slow upload) get what is left of the grace.
    let rest = deadline
        .saturating_duration_since(Instant::now())
        .max(Duration::from_secs(1));
    if tokio::time::timeout(rest, server).await.is_err() {
        tracing::warn!("open connections dropped at the end of the grace period");
    }
    tokio::task::spawn_blocking(move || pool.join()).await?;
    // Fetches cut off here start again at the next start; an export
    // in progress finishes (one PUT per file) or is retried then.
    let _ = tokio::time::timeout(Duration::from_secs(5), async {
        let _ = fetcher.await;
        let _ = exporter.await;
    })
    .await;
    tracing::info!("stopped");
    Ok(())
}

async fn wait_for_signal() -> &'static str {
    use tokio::signal::unix::{signal, SignalKind};
    let mut term = signal(SignalKind::terminate()).expect("install SIGTERM handler");
    let mut int = signal(SignalKind::interrupt()).expect("install SIGINT handler");
    tokio::select! {
        _ = term.recv() => "SIGTERM",
        _ = int.recv() => "SIGINT",
    }
}
