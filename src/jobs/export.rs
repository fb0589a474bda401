//! Writing a finished flight's results back to object storage: when every
//! job of a flight with `results_to` has ended, `results.csv` and
//! `results.geojson` (the same bytes as the API's), and with a survey the
//! GCP files (`gcp_list.txt` and the rest), are written under that prefix. A failed write is retried with backoff, and after
//! [`MAX_ATTEMPTS`] the export is marked failed with the reason, shown on
//! the flight. Export state is in the store, so a restart finishes what a
//! stop interrupted.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::watch;
use tokio::time::Instant;

use crate::pipeline::output::Format;
use crate::storage::s3::{S3Error, S3Url, S3};
use crate::storage::{DataDir, StoredFileError};
use crate::survey::export::ProjectionError;
use crate::survey::parse::SurveyError;

use super::gcp;
use super::model::{FlightId, FlightRecord, JobRecord};
use super::results::load_frames;
use super::review::Selection;
use super::store::SharedStore;
use crate::pipeline::georef::{GeorefError, TargetCrs};
use crate::pipeline::output::render;

/// Attempts before an export is marked failed.
pub const MAX_ATTEMPTS: u32 = 5;

/// Runs until `stop` turns true.
pub async fn run(store: SharedStore, data: DataDir, s3: Arc<S3>, mut stop: watch::Receiver<bool>) {
    let mut changes = store.subscribe();
    let mut not_before: HashMap<FlightId, Instant> = HashMap::new();
    loop {
        let now = Instant::now();
        let mut retry = None;
        let due = store.exports_due().unwrap_or_else(|e| {
            tracing::warn!(error = %e, "cannot list the exports due; trying again in a second");
            retry = Some(now + Duration::from_secs(1));
            Vec::new()
        });
        for (flight, jobs) in due {
            if not_before.get(&flight.id).is_some_and(|t| *t > now) {
                continue;
            }
            let result = export(&data, &s3, &flight, jobs)
                .await
                .map_err(|e| e.to_string());
            let attempts = flight.export.as_ref().map_or(0, |e| e.attempts) + 1;
            match &result {
                Ok(()) => {
                    tracing::info!(flight.id = %flight.id, "results written to object storage");
                    not_before.remove(&flight.id);
                }
                Err(e) => {
                    tracing::warn!(flight.id = %flight.id, attempts, error = %e, "cannot write results");
                    let backoff = Duration::from_secs(2u64.pow(attempts.min(6)));
                    not_before.insert(flight.id, Instant::now() + backoff);
                }
            }
            if let Err(e) = store.export_done(flight.id, result, attempts >= MAX_ATTEMPTS) {
                tracing::error!(error = %e, "cannot record an export");
            }
        }
        let wake = not_before.values().copied().chain(retry).min();
        tokio::select! {
            _ = stop.wait_for(|s| *s) => break,
            changed = changes.changed() => {
                if changed.is_err() {
                    break;
                }
            }
            _ = sleep_until(wake) => {}
        }
    }
}

async fn sleep_until(at: Option<Instant>) {
    match at {
        Some(at) => tokio::time::sleep_until(at).await,
        None => std::future::pending().await,
    }
}

/// Renders both formats and writes them under the flight's prefix.
async fn export(
    data: &DataDir,
    s3: &S3,
    flight: &FlightRecord,
    jobs: Vec<JobRecord>,
) -> Result<(), WriteBackError> {
    let to = flight
        .export
        .as_ref()
        .map(|e| e.to.clone())
        .unwrap_or_default();
    let Ok(S3Url::Prefix { bucket, prefix }) = S3Url::parse(&to) else {
        return Err(WriteBackError::NotAPrefix(to));
    };
    let (data, flight) = (data.clone(), flight.clone());
    let files = tokio::task::spawn_blocking(move || {
        // The stored results are read once for every file.
        let frames = load_frames(&data, &jobs, Selection::NotRejected)?;
        let crs = TargetCrs::parse(&flight.params.crs).map_err(WriteBackError::Crs)?;
        let mut files = vec![
            ("results.csv", render(Format::Csv, &frames, &crs)),
            ("results.geojson", render(Format::GeoJson, &frames, &crs)),
        ];
        if let Some(stored) = gcp::load_survey(&data, flight.id)? {
            let survey = stored.parse().map_err(WriteBackError::Survey)?;
            files.extend(gcp::exports_for(&frames, &flight, &survey)?);
        }
        Ok::<_, WriteBackError>(files)
    })
    .await
    .map_err(|e| WriteBackError::Rendering(e.to_string()))??;
    for (name, text) in files {
        s3.put(&bucket, &format!("{prefix}{name}"), text.into_bytes())
            .await?;
    }
    Ok(())
}

/// Why a flight's results could not be written back (kept on the flight as
/// its export's last error, and retried with a back-off).
#[derive(Debug, thiserror::Error)]
enum WriteBackError {
    #[error("{0:?} is not an s3://bucket/prefix/")]
    NotAPrefix(String),
    #[error(transparent)]
    Stored(#[from] StoredFileError),
    #[error("stored CRS: {0}")]
    Crs(GeorefError),
    #[error("stored survey: {0}")]
    Survey(SurveyError),
    #[error(transparent)]
    Projection(#[from] ProjectionError),
    #[error("rendering results: {0}")]
    Rendering(String),
    #[error(transparent)]
    S3(#[from] S3Error),
}
