//! The job store's contract (`src/jobs/store/mod.rs`), checked on both
//! stores: the embedded SQLite file and a real PostgreSQL started for the
//! tests (`crate::postgres`).

use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Barrier};
use std::time::{Duration, Instant};

use gcp_tagger::error_code::ErrorCode;
use gcp_tagger::jobs::model::{JobId, JobState};
use gcp_tagger::jobs::params::JobParams;
use gcp_tagger::jobs::store::{
    Finished, JobFilter, JobStore, LeaseConfig, LeaseState, NewJob, Outcome, PgStore, Progress,
    SqliteStore, StoreError,
};

use crate::postgres::{self, Postgres};

/// Both stores, each fresh, with `lease`; the PostgreSQL one keeps its
/// server alive as long as the store.
struct Stores {
    _dir: tempfile::TempDir,
    _pg: Arc<Postgres>,
    pub list: Vec<(&'static str, Arc<dyn JobStore>)>,
    pub pg_url: String,
}

fn stores(lease: LeaseConfig) -> Stores {
    let dir = tempfile::tempdir().unwrap();
    let pg = postgres::shared();
    let url = pg.database();
    let sqlite: Arc<dyn JobStore> =
        Arc::new(SqliteStore::open_with(&dir.path().join("jobs.sqlite"), lease).unwrap());
    let postgres: Arc<dyn JobStore> = Arc::new(PgStore::connect(&url, lease).unwrap());
    Stores {
        _dir: dir,
        _pg: pg,
        list: vec![("sqlite", sqlite), ("postgres", postgres)],
        pg_url: url,
    }
}

fn frame(image: &str) -> NewJob {
    NewJob {
        id: uuid::Uuid::now_v7(),
        image: image.into(),
        ext: "jpg".into(),
        bytes: 10,
        rejected: None,
        source: None,
    }
}

fn frames(n: usize) -> Vec<NewJob> {
    (0..n).map(|i| frame(&format!("f{i:03}.jpg"))).collect()
}

fn claim(store: &dyn JobStore, wait: Duration) -> Option<gcp_tagger::jobs::store::Claim> {
    store.claim_next(&AtomicBool::new(false), wait).unwrap()
}

fn succeeded() -> Outcome {
    Outcome::Succeeded {
        width: 40,
        height: 30,
        targets: 2,
        warnings: vec!["a warning".into()],
    }
}

#[test]
fn a_claim_is_a_lease_that_expires_into_the_queue_and_fails_on_the_last_attempt() {
    let lease = LeaseConfig {
        lease: Duration::from_millis(600),
        max_attempts: 2,
    };
    // The two stores wait out their leases side by side.
    let stores = stores(lease);
    std::thread::scope(|s| {
        for (name, store) in &stores.list {
            s.spawn(move || leases_expire(name, &**store, lease));
        }
    });
}

fn leases_expire(name: &str, store: &dyn JobStore, lease: LeaseConfig) {
    store
        .create_flight(&JobParams::default(), &frames(1), None, None)
        .unwrap();
    let first = claim(store, Duration::ZERO).expect("a queued job");
    assert_eq!(first.job.attempts, 1, "{name}");
    assert!(
        claim(store, Duration::ZERO).is_none(),
        "{name}: claimed twice"
    );
    // Renewed, it stays this worker's past the lease time.
    let until = Instant::now() + Duration::from_millis(1200);
    while Instant::now() < until {
        let held = store.heartbeat(&first.lease, &Progress::default()).unwrap();
        assert_eq!(held, LeaseState::Held { cancel: false }, "{name}");
        assert!(claim(store, Duration::from_millis(150)).is_none(), "{name}");
    }
    // Not renewed, it goes back to the queue with its attempt counted.
    let second = claim(store, Duration::from_secs(5)).expect("requeued after the lease");
    assert_eq!(
        (second.job.id, second.job.attempts),
        (first.job.id, 2),
        "{name}"
    );
    assert_ne!(second.lease, first.lease, "{name}");
    let stale = store.heartbeat(&first.lease, &Progress::default()).unwrap();
    assert_eq!(stale, LeaseState::Lost, "{name}");
    assert_eq!(
        store.finish(&first.lease, &succeeded()).unwrap(),
        Finished::Lost,
        "{name}: the first worker must not record an end"
    );
    assert_eq!(
        store.job(first.job.id).unwrap().unwrap().state,
        JobState::Running,
        "{name}"
    );
    // The last attempt's lease expires too: the job fails, not queued
    // (a wait of two leases sees it expire).
    assert!(claim(store, 2 * lease.lease).is_none(), "{name}");
    let job = store.job(first.job.id).unwrap().unwrap();
    assert_eq!(job.state, JobState::Failed, "{name}");
    let error = job.error.expect("a reason");
    assert_eq!(error.code, ErrorCode::WorkerCrashed, "{name}");
    assert!(
        error.message.contains("2 attempts"),
        "{name}: {}",
        error.message
    );
    assert_eq!(store.stats().unwrap().running, 0, "{name}");

    // Canceled while its worker is lost: it ends canceled, not queued.
    store
        .create_flight(&JobParams::default(), &frames(1), None, None)
        .unwrap();
    let lost = claim(store, Duration::ZERO).expect("a queued job");
    store.cancel_job(lost.job.id).unwrap();
    assert!(claim(store, 2 * lease.lease).is_none(), "{name}");
    assert_ended_canceled(store, lost.job.id, name);
}

/// The job has ended canceled, its cancel request settled.
fn assert_ended_canceled(store: &dyn JobStore, id: JobId, name: &str) {
    let job = store.job(id).unwrap().unwrap();
    assert_eq!(
        (job.state, job.cancel_requested),
        (JobState::Canceled, false),
        "{name}"
    );
    assert!(job.finished_at.is_some(), "{name}");
}

#[test]
fn progress_and_cancel_travel_with_the_heartbeat() {
    for (name, store) in &stores(LeaseConfig::default()).list {
        let store = &**store;
        let mut changes = store.subscribe();
        let flight = store
            .create_flight(&JobParams::default(), &frames(2), None, None)
            .unwrap();
        let running = claim(store, Duration::ZERO).unwrap();
        let progress = Progress {
            size: Some((4000, 3000)),
            tiles_done: 3,
            tiles_total: 12,
        };
        changes.borrow_and_update();
        let held = store.heartbeat(&running.lease, &progress).unwrap();
        assert_eq!(held, LeaseState::Held { cancel: false }, "{name}");
        wait_changed(&mut changes, name);
        let job = store.job(running.job.id).unwrap().unwrap();
        assert_eq!(
            (job.width, job.height, job.tiles_done, job.tiles_total),
            (Some(4000), Some(3000), 3, 12),
            "{name}"
        );
        let canceled = store.cancel_flight(flight.id).unwrap().unwrap();
        let states: Vec<(JobState, bool)> = canceled
            .iter()
            .map(|j| (j.state, j.cancel_requested))
            .collect();
        assert_eq!(
            states,
            [(JobState::Running, true), (JobState::Canceled, false)],
            "{name}: a queued job ends at once, a running one at its heartbeat"
        );
        let told = store.heartbeat(&running.lease, &progress).unwrap();
        assert_eq!(told, LeaseState::Held { cancel: true }, "{name}");
        let end = store.finish(&running.lease, &Outcome::Canceled).unwrap();
        assert_eq!(end, Finished::Recorded, "{name}");
        assert_ended_canceled(store, running.job.id, name);
    }
}

fn wait_changed(changes: &mut tokio::sync::watch::Receiver<u64>, name: &str) {
    let until = Instant::now() + Duration::from_secs(5);
    while !changes.has_changed().unwrap() {
        assert!(Instant::now() < until, "{name}: no change announced");
        std::thread::sleep(Duration::from_millis(10));
    }
    changes.borrow_and_update();
}

#[test]
fn a_frame_name_is_recorded_once_and_the_limit_holds_under_concurrent_requests() {
    for (name, store) in &stores(LeaseConfig::default()).list {
        let flight = store
            .create_flight(&JobParams::default(), &frames(1), None, None)
            .unwrap();
        for round in 0..3 {
            let image = format!("same-{round}.jpg");
            let barrier = Arc::new(Barrier::new(6));
            let results: Vec<Result<Option<_>, StoreError>> = std::thread::scope(|s| {
                let handles: Vec<_> = (0..6)
                    .map(|_| {
                        let (store, barrier, image) = (store.clone(), barrier.clone(), &image);
                        s.spawn(move || {
                            barrier.wait();
                            store.add_to_flight(flight.id, &[frame(image)], None, 100)
                        })
                    })
                    .collect();
                handles.into_iter().map(|h| h.join().unwrap()).collect()
            });
            let recorded = results.iter().filter(|r| matches!(r, Ok(Some(_)))).count();
            let refused = results
                .iter()
                .filter(|r| matches!(r, Err(StoreError::DuplicateImage(n)) if *n == image))
                .count();
            assert_eq!((recorded, refused), (1, 5), "{name}, round {round}");
        }
        let names = store.flight_images(flight.id).unwrap();
        assert_eq!(
            names,
            ["f000.jpg", "same-0.jpg", "same-1.jpg", "same-2.jpg"],
            "{name}"
        );
        // The limit: two requests of 3 where 5 are left; one passes.
        let results: Vec<_> = std::thread::scope(|s| {
            let barrier = Arc::new(Barrier::new(2));
            let handles: Vec<_> = (0..2)
                .map(|i| {
                    let (store, barrier) = (store.clone(), barrier.clone());
                    s.spawn(move || {
                        let jobs: Vec<NewJob> =
                            (0..3).map(|k| frame(&format!("r{i}-{k}.jpg"))).collect();
                        barrier.wait();
                        store.add_to_flight(flight.id, &jobs, None, 9)
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let passed = results.iter().filter(|r| r.is_ok()).count();
        let over = results
            .iter()
            .filter(|r| matches!(r, Err(StoreError::TooManyFrames { would: 10, max: 9 })))
            .count();
        assert_eq!((passed, over), (1, 1), "{name}: {results:?}");
        assert_eq!(store.flight_images(flight.id).unwrap().len(), 7, "{name}");
        // Twice in one request.
        let twice = store.add_to_flight(flight.id, &[frame("x.jpg"), frame("x.jpg")], None, 99);
        assert!(
            matches!(twice, Err(StoreError::DuplicateImage(_))),
            "{name}"
        );
        assert!(store
            .add_to_flight(uuid::Uuid::now_v7(), &frames(1), None, 9)
            .unwrap()
            .is_none());
    }
}

#[test]
fn concurrent_workers_claim_every_job_once_in_queue_order() {
    for (name, store) in &stores(LeaseConfig::default()).list {
        let flight = store
            .create_flight(&JobParams::default(), &frames(20), None, None)
            .unwrap();
        let claimed: Vec<(JobId, u32)> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..4)
                .map(|_| {
                    let store = store.clone();
                    s.spawn(move || {
                        let mut mine = Vec::new();
                        while let Some(c) = claim(&*store, Duration::from_millis(200)) {
                            let end = store.finish(&c.lease, &succeeded()).unwrap();
                            assert_eq!(end, Finished::Recorded);
                            mine.push((c.job.id, c.job.attempts));
                        }
                        mine
                    })
                })
                .collect();
            handles
                .into_iter()
                .flat_map(|h| h.join().unwrap())
                .collect()
        });
        let mut ids: Vec<JobId> = claimed.iter().map(|c| c.0).collect();
        ids.sort();
        let expected: Vec<JobId> = store
            .flight_jobs(flight.id)
            .unwrap()
            .unwrap()
            .iter()
            .map(|j| j.id)
            .collect();
        assert_eq!(ids, expected, "{name}: every job exactly once");
        assert!(claimed.iter().all(|c| c.1 == 1), "{name}");
        let jobs = store.flight_jobs(flight.id).unwrap().unwrap();
        assert!(
            jobs.iter().all(|j| j.state == JobState::Succeeded
                && j.targets == Some(2)
                && j.warnings == ["a warning"]),
            "{name}"
        );
        // One worker takes them in submission order.
        let later = store
            .create_flight(&JobParams::default(), &frames(3), None, None)
            .unwrap();
        let order: Vec<JobId> = (0..3)
            .map(|_| claim(&**store, Duration::ZERO).unwrap().job.id)
            .collect();
        let submitted: Vec<JobId> = store
            .flight_jobs(later.id)
            .unwrap()
            .unwrap()
            .iter()
            .map(|j| j.id)
            .collect();
        assert_eq!(order, submitted, "{name}");
    }
}

#[test]
fn reads_follow_writes_and_a_deleted_job_is_lost_to_its_worker() {
    for (name, store) in &stores(LeaseConfig::default()).list {
        let store = &**store;
        let mut sourced = frame("s3.tif");
        sourced.source = Some(("s3://b/s3.tif".into(), Some("\"e\"".into())));
        let idem = gcp_tagger::jobs::IdemKey {
            key: "k1".into(),
            request: "POST /v1/flights".into(),
        };
        let flight = store
            .create_flight(
                &JobParams::default(),
                &[frame("a.jpg"), sourced.clone()],
                Some("s3://b/out/".into()),
                Some(&idem),
            )
            .unwrap();
        assert_eq!(store.flight(flight.id).unwrap().unwrap(), flight, "{name}");
        let again = store.create_flight(&JobParams::default(), &frames(1), None, Some(&idem));
        assert!(matches!(again, Err(StoreError::KeyTaken)), "{name}");
        let record = store.idempotent("k1").unwrap().unwrap();
        assert_eq!(record.flight, flight.id, "{name}");
        assert_eq!(record.jobs.len(), 2, "{name}");
        assert!(store.idempotent("nope").unwrap().is_none(), "{name}");
        let stats = store.stats().unwrap();
        assert_eq!(
            (stats.fetching, stats.queued, stats.running),
            (1, 1, 0),
            "{name}"
        );
        assert_eq!(store.to_fetch(5).unwrap()[0].id, sourced.id, "{name}");
        assert!(store.fetched(sourced.id, "tif", 99).unwrap(), "{name}");
        assert!(
            !store.fetched(sourced.id, "tif", 99).unwrap(),
            "{name}: only once"
        );
        assert_eq!(store.stats().unwrap().fetched, 1, "{name}");
        let queued = store
            .jobs(&JobFilter {
                state: Some(JobState::Queued),
                flight: Some(flight.id),
                limit: 10,
                ..JobFilter::default()
            })
            .unwrap();
        assert_eq!(queued.len(), 2, "{name}");
        let page = store
            .jobs(&JobFilter {
                after: Some(queued[0].id),
                limit: 10,
                ..JobFilter::default()
            })
            .unwrap();
        assert_eq!(page.len(), 1, "{name}: the page after the cursor");

        // A running job deleted: its worker hears it has lost the job.
        let running = claim(store, Duration::ZERO).unwrap();
        let removed = store.delete_job(running.job.id).unwrap().unwrap();
        assert_eq!(removed.id, running.job.id, "{name}");
        assert!(store.job(running.job.id).unwrap().is_none(), "{name}");
        let beat = store
            .heartbeat(&running.lease, &Progress::default())
            .unwrap();
        assert_eq!(beat, LeaseState::Lost, "{name}");
        assert_eq!(
            store.finish(&running.lease, &succeeded()).unwrap(),
            Finished::Deleted,
            "{name}"
        );
        // The other one ends: the export is due, then written.
        assert!(store.exports_due().unwrap().is_empty(), "{name}");
        let last = claim(store, Duration::ZERO).unwrap();
        store.finish(&last.lease, &succeeded()).unwrap();
        let due = store.exports_due().unwrap();
        assert_eq!(due.len(), 1, "{name}");
        assert_eq!(due[0].1.len(), 1, "{name}");
        store
            .export_done(flight.id, Err("boom".into()), false)
            .unwrap();
        let export = store.flight(flight.id).unwrap().unwrap().export.unwrap();
        assert_eq!(
            (export.attempts, export.error.as_deref()),
            (1, Some("boom")),
            "{name}"
        );
        store.export_done(flight.id, Ok(()), false).unwrap();
        assert!(store.exports_due().unwrap().is_empty(), "{name}");
        // Expired only once the cutoff is past every end.
        assert!(store.expired_flights(0).unwrap().is_empty(), "{name}");
        let later = gcp_tagger::jobs::model::now_millis() + 1000;
        assert_eq!(store.expired_flights(later).unwrap(), [flight.id], "{name}");
        assert_eq!(store.flights(None, 10).unwrap().len(), 1, "{name}");
        let gone = store.delete_flight(flight.id).unwrap().unwrap();
        assert_eq!(gone.len(), 1, "{name}");
        assert!(store.flight(flight.id).unwrap().is_none(), "{name}");
        assert!(store.flight_jobs(flight.id).unwrap().is_none(), "{name}");
        assert!(store.idempotent("k1").unwrap().is_none(), "{name}");
    }
}

#[test]
fn postgres_schema_is_versioned_and_changes_reach_every_replica() {
    let stores = stores(LeaseConfig::default());
    let url = &stores.pg_url;
    // A second replica on the same database: migrations are not repeated.
    let other = PgStore::connect(url, LeaseConfig::default()).unwrap();
    let pg = postgres::shared();
    assert_eq!(pg.psql(url, "SELECT version FROM schema_version"), "1");
    // A change made through one replica wakes the other's waiters.
    let (_, first) = &stores.list[1];
    let mut changes = other.subscribe();
    changes.borrow_and_update();
    let flight = first
        .create_flight(&JobParams::default(), &frames(1), None, None)
        .unwrap();
    wait_changed(&mut changes, "the other replica");
    let got = other.claim_next(&AtomicBool::new(false), Duration::from_secs(2));
    assert_eq!(got.unwrap().unwrap().job.flight_id, flight.id);
    // A database written by a newer build is refused and left as it is.
    pg.psql(url, "UPDATE schema_version SET version = 9");
    let err = PgStore::connect(url, LeaseConfig::default())
        .err()
        .expect("refused")
        .to_string();
    assert!(err.contains("version 9") && err.contains("newer"), "{err}");
    assert_eq!(pg.psql(url, "SELECT version FROM schema_version"), "9");
}
