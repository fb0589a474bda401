//! Retention: a finished flight's records, frames, results and survey are
//! removed once every job of it ended longer ago than the retention time,
//! so the data folder does not grow without end. Runs at start and then
//! periodically; flights still running, or with results still to write to
//! object storage, are never touched.

use std::time::Duration;

use tokio::sync::watch;

use crate::storage::DataDir;

use super::model::now_millis;
use super::store::SharedStore;

/// Removes the flights that ended more than `keep` ago, every `keep / 2`
/// (between 1 s and 10 min), until `stop`.
pub async fn run(
    store: SharedStore,
    data: DataDir,
    keep: Duration,
    mut stop: watch::Receiver<bool>,
) {
    let every = (keep / 2).clamp(Duration::from_secs(1), Duration::from_secs(600));
    loop {
        let (store, data) = (store.clone(), data.clone());
        let cutoff = now_millis() - keep.as_millis() as i64;
        let swept = tokio::task::spawn_blocking(move || sweep(&*store, &data, cutoff)).await;
        match swept {
            Ok(0) => {}
            Ok(n) => tracing::info!(flights = n, "removed flights past their retention time"),
            Err(e) => tracing::error!(error = %e, "retention sweep failed"),
        }
        tokio::select! {
            _ = stop.wait_for(|s| *s) => break,
            _ = tokio::time::sleep(every) => {}
        }
    }
}

/// Removes every flight that ended before `cutoff`; returns how many.
pub fn sweep(store: &dyn super::store::JobStore, data: &DataDir, cutoff: i64) -> usize {
    let mut removed = 0;
    let expired = store.expired_flights(cutoff).unwrap_or_else(|e| {
        tracing::error!(error = %e, "cannot list the expired flights");
        Vec::new()
    });
    for id in expired {
        match store.delete_flight(id) {
            Ok(Some(jobs)) => {
                for job in &jobs {
                    data.remove_job_files(job.id, &job.ext);
                }
                data.remove_survey(id);
                removed += 1;
            }
            Ok(None) => {}
            Err(e) => {
                tracing::error!(flight.id = %id, error = %e, "cannot remove an expired flight")
            }
        }
    }
    removed
}
