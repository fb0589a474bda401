//! The fetcher: brings frames named by `s3://` sources into the spool
//! ahead of the workers. Jobs wait in `fetching`; a few objects stream at
//! once (`concurrency`), and no more than `read_ahead` fetched frames wait
//! for a worker, so a flight of 800 large frames never fills the disk
//! before the workers get to it. Each object is checked (ETag as at
//! submission, size, MD5 of plain ETags, image by content) before its job
//! is queued; one that cannot be fetched fails its own job with the reason.
//!
//! A fetch cut off by a stop leaves its job `fetching` (the spool is
//! emptied at start) and the next start fetches it again.

use crate::error_code::ErrorCode;
use std::collections::HashSet;
use std::sync::Arc;

use tokio::sync::watch;
use tokio::task::JoinSet;
use tracing::Instrument;

use crate::storage::header::{self, PixelLimits};
use crate::storage::s3::{ObjectRef, S3Url, S3};
use crate::storage::spool::{magic_hex, sniff_image};
use crate::storage::DataDir;

use super::model::{JobError, JobId, JobRecord};
use super::store::SharedStore;

/// Fetcher settings.
#[derive(Debug, Clone)]
pub struct FetchConfig {
    /// Objects streaming at once.
    pub concurrency: usize,
    /// Fetched frames waiting for a worker, at most.
    pub read_ahead: usize,
    pub max_frame_bytes: u64,
    pub pixels: PixelLimits,
}

/// Runs until `stop` turns true.
pub async fn run(
    store: SharedStore,
    data: DataDir,
    s3: Arc<S3>,
    config: FetchConfig,
    mut stop: watch::Receiver<bool>,
) {
    let mut changes = store.subscribe();
    let mut running: JoinSet<JobId> = JoinSet::new();
    let mut in_flight: HashSet<JobId> = HashSet::new();
    loop {
        // A store that does not answer: look again in a second.
        let mut retry = false;
        let waiting = match store.stats() {
            Ok(stats) => stats.fetched + in_flight.len(),
            Err(e) => {
                tracing::warn!(error = %e, "cannot read the queue; trying again in a second");
                retry = true;
                usize::MAX
            }
        };
        let room = config
            .concurrency
            .saturating_sub(in_flight.len())
            .min(config.read_ahead.saturating_sub(waiting));
        if room > 0 {
            let next = store
                .to_fetch(in_flight.len() + room)
                .unwrap_or_else(|e| {
                    tracing::warn!(error = %e, "cannot list the frames to fetch; trying again in a second");
                    retry = true;
                    Vec::new()
                });
            for job in next {
                if !in_flight.insert(job.id) {
                    continue;
                }
                let span = tracing::info_span!(
                    "fetch",
                    job.id = %job.id,
                    source = job.source.as_deref().unwrap_or("")
                );
                let task = FetchTask {
                    store: store.clone(),
                    data: data.clone(),
                    s3: s3.clone(),
                    max_frame_bytes: config.max_frame_bytes,
                    pixels: config.pixels,
                };
                running.spawn(
                    async move {
                        let id = job.id;
                        task.fetch(job).await;
                        id
                    }
                    .instrument(span),
                );
            }
        }
        tokio::select! {
            _ = stop.wait_for(|s| *s) => break,
            Some(done) = running.join_next(), if !running.is_empty() => {
                if let Ok(id) = done {
                    in_flight.remove(&id);
                }
            }
            changed = changes.changed() => {
                if changed.is_err() {
                    break;
                }
            }
            _ = tokio::time::sleep(std::time::Duration::from_secs(1)), if retry => {}
        }
    }
    running.shutdown().await;
}

struct FetchTask {
    store: SharedStore,
    data: DataDir,
    s3: Arc<S3>,
    max_frame_bytes: u64,
    pixels: PixelLimits,
}

impl FetchTask {
    async fn fetch(&self, job: JobRecord) {
        let source = job.source.clone().unwrap_or_default();
        let started = std::time::Instant::now();
        let tmp = self.data.spool_path();
        let outcome = self.fetch_into(&job, &source, &tmp).await;
        let recorded = match outcome {
            Ok((ext, bytes)) => {
                let dest = self.data.frame_path(job.id, ext);
                let placed = match std::fs::rename(&tmp, &dest) {
                    // Replicas: the job may run anywhere.
                    Ok(()) => {
                        let (data, dest) = (self.data.clone(), dest.clone());
                        tokio::task::spawn_blocking(move || data.publish(&dest))
                            .await
                            .unwrap_or_else(|e| Err(std::io::Error::other(e)))
                    }
                    Err(e) => Err(e),
                };
                match placed {
                    Ok(()) => {
                        tracing::info!(
                            bytes,
                            secs = started.elapsed().as_secs_f64(),
                            "frame fetched"
                        );
                        match self.store.fetched(job.id, ext, bytes) {
                            Ok(true) => Ok(()),
                            // Canceled or deleted while it arrived.
                            Ok(false) => {
                                let _ = std::fs::remove_file(&dest);
                                Ok(())
                            }
                            Err(e) => Err(e),
                        }
                    }
                    Err(e) => self.fail(
                        &job,
                        ErrorCode::Internal,
                        format!("cannot move the frame: {e}"),
                    ),
                }
            }
            Err(error) => {
                tracing::warn!(code = %error.code, error = %error.message, "fetch failed");
                self.store.fetch_failed(job.id, &error)
            }
        };
        let _ = std::fs::remove_file(&tmp);
        if let Err(e) = recorded {
            tracing::error!(error = %e, "cannot record a fetch");
        }
    }

    fn fail(
        &self,
        job: &JobRecord,
        code: ErrorCode,
        message: String,
    ) -> Result<(), super::StoreError> {
        self.store.fetch_failed(job.id, &JobError { code, message })
    }

    /// Streams the object into `tmp`; returns its image type and size.
    async fn fetch_into(
        &self,
        job: &JobRecord,
        source: &str,
        tmp: &std::path::Path,
    ) -> Result<(&'static str, u64), JobError> {
        let error = |code: ErrorCode, message: String| JobError { code, message };
        let (bucket, key) = match S3Url::parse(source) {
            Ok(S3Url::Object { bucket, key }) => (bucket, key),
            _ => {
                return Err(error(
                    ErrorCode::InvalidSource,
                    format!("{source:?} names no object"),
                ))
            }
        };
        let object = ObjectRef {
            bucket,
            key,
            size: job.bytes,
            etag: job.source_etag.clone(),
        };
        let (bytes, head) = self
            .s3
            .fetch(&object, tmp, self.max_frame_bytes)
            .await
            .map_err(|e| error(e.code(), e.to_string()))?;
        if bytes == 0 {
            return Err(error(ErrorCode::EmptyFrame, format!("{source} is empty")));
        }
        let ext = sniff_image(&head).ok_or_else(|| {
            error(
                ErrorCode::NotAnImage,
                format!(
                    "{source} is not a JPEG, TIFF or PNG (first bytes: {})",
                    magic_hex(&head)
                ),
            )
        })?;
        // The header's claims, before any image library reads the frame.
        let (path, pixels) = (tmp.to_path_buf(), self.pixels);
        let checked = tokio::task::spawn_blocking(move || header::check(&path, pixels))
            .await
            .map_err(|e| error(ErrorCode::Internal, e.to_string()))?;
        checked.map_err(|e| error(e.code(), format!("{source}: {e}")))?;
        Ok((ext, bytes))
    }
}
