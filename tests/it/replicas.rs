//! Replicas sharing one queue: `serve` processes on one PostgreSQL (a real
//! server, `crate::postgres`) and one bucket (moto's S3 server).

use std::path::{Path, PathBuf};

use serde_json::{json, Value};

use crate::durability::{big_frame, flight_with_running_first, job_named, jobs_of, wait_until};
use crate::moto::{aws_env, Moto, KEY, SECRET};
use crate::postgres;
use crate::server::Server;
use crate::service::{cli_output, flight, CRS};

const BUCKET: &str = "fleet";

/// A replica on `store` with its own data folder `dir/name`.
fn replica(dir: &Path, name: &str, store: &str, moto: &Moto, extra: &[&str]) -> Server {
    let mut args = vec![
        "--store",
        store,
        "--shared-files",
        "s3://fleet/shared/",
        "--s3-endpoint",
        &moto.endpoint,
        "--workers",
        "1",
        "--log-json",
    ];
    args.extend_from_slice(extra);
    Server::start_env(&dir.join(name), &args, &aws_env(KEY, SECRET))
}

/// Job ids a replica's log (JSON lines) says it ran to success.
fn succeeded_in(server: &Server) -> Vec<String> {
    server
        .log_text()
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter(|l| l["fields"]["message"] == "job succeeded")
        .filter_map(|l| Some(l["span"]["job.id"].as_str()?.to_string()))
        .collect()
}

/// `n` frames named `f00.tif`.. (copies of the test flight's three).
fn frames(dir: &Path, n: usize) -> Vec<PathBuf> {
    let source = &flight().1;
    (0..n)
        .map(|i| {
            let path = dir.join(format!("f{i:02}.tif"));
            std::fs::copy(&source[i % source.len()], &path).unwrap();
            path
        })
        .collect()
}

#[test]
fn two_replicas_share_one_queue_run_each_job_once_and_serve_each_others_results() {
    let pg = postgres::shared();
    let store = pg.database();
    let moto = Moto::start(false);
    moto.ops(KEY, SECRET, json!([{"op": "bucket", "bucket": BUCKET}]));
    let dir = tempfile::tempdir().unwrap();
    let a = replica(dir.path(), "a", &store, &moto, &[]);
    let b = replica(dir.path(), "b", &store, &moto, &[]);
    let frames = frames(dir.path(), 20);
    let paths: Vec<&Path> = frames.iter().map(|p| p.as_path()).collect();

    let id = a.post_flight(&format!("/v1/flights?crs={CRS}"), &paths);
    // Followed on the other replica: its event stream hears every change
    // (progress made on either) and ends with the flight.
    let text = b.get_text(&format!("/v1/flights/{id}/events"));
    let events: Vec<&str> = text
        .lines()
        .filter_map(|l| l.strip_prefix("event: "))
        .collect();
    assert_eq!(events.last(), Some(&"end"), "{text}");
    assert!(events.len() > 3, "{text}");
    // And its long-poll.
    let done = b.wait_flight(&id);
    assert_eq!(done["jobs"]["succeeded"], 20, "{done}");
    let jobs = jobs_of(&b, &id);
    assert!(jobs.iter().all(|j| j["attempts"] == 1), "{jobs:?}");

    let (ran_a, ran_b) = (succeeded_in(&a), succeeded_in(&b));
    assert!(
        !ran_a.is_empty() && !ran_b.is_empty(),
        "both replicas run jobs: {} and {}",
        ran_a.len(),
        ran_b.len()
    );
    let mut all: Vec<String> = ran_a.iter().chain(&ran_b).cloned().collect();
    all.sort();
    let mut ids: Vec<String> = jobs
        .iter()
        .map(|j| j["id"].as_str().unwrap().to_string())
        .collect();
    ids.sort();
    assert_eq!(all, ids, "every job ran exactly once");

    // Results from the replica the frames were not sent to, equal to the CLI's.
    let csv = b.get_text(&format!("/v1/flights/{id}/results.csv"));
    assert_eq!(csv, cli_output(&paths, "csv"));
    // And a chip and a preview of a job the other replica ran.
    let from_a = &ran_a[0];
    let chip = b.get(&format!("/v1/jobs/{from_a}/chips/0"));
    assert_eq!(chip.status(), 200);
    assert!(chip.bytes().unwrap().starts_with(b"\x89PNG"));
    assert_eq!(b.get(&format!("/v1/jobs/{from_a}/preview")).status(), 200);
    // Deleted through one replica: gone from the other and the bucket.
    assert_eq!(
        a.client
            .delete(a.url(&format!("/v1/flights/{id}")))
            .send()
            .unwrap()
            .status(),
        204
    );
    assert_eq!(b.get(&format!("/v1/flights/{id}")).status(), 404);
    let listed = moto.ops(KEY, SECRET, json!([{"op": "list", "bucket": BUCKET}]));
    assert_eq!(listed[0], json!([]), "{listed}");
}

#[test]
fn a_replica_killed_mid_job_loses_its_lease_and_the_other_finishes_the_job() {
    let pg = postgres::shared();
    let store = pg.database();
    let moto = Moto::start(false);
    moto.ops(KEY, SECRET, json!([{"op": "bucket", "bucket": BUCKET}]));
    let dir = tempfile::tempdir().unwrap();
    let big = big_frame(dir.path(), "big_0.jpg");
    let rest = frames(dir.path(), 3);
    let lease = ["--lease-secs", "2"];
    let mut a = replica(dir.path(), "a", &store, &moto, &lease);
    let (id, big_job) = flight_with_running_first(&a, &big, &rest, "");
    let b = replica(dir.path(), "b", &store, &moto, &lease);
    a.kill9();

    let done = b.wait_flight(&id);
    assert_eq!(done["jobs"]["succeeded"], 4, "{done}");
    let jobs = jobs_of(&b, &id);
    assert_eq!(jobs.len(), 4, "no job lost or duplicated");
    assert_eq!(job_named(&jobs, "big_0.jpg")["attempts"], 2);
    let ran_b = succeeded_in(&b);
    assert_eq!(
        ran_b.iter().filter(|j| **j == big_job).count(),
        1,
        "the killed replica's job ran to its end once, on the other"
    );
    assert!(!succeeded_in(&a).contains(&big_job));
    wait_until("the expired lease to be logged", || {
        b.log_text().contains("lease expired")
    });
    let mut all: Vec<&Path> = vec![big.as_path()];
    all.extend(rest.iter().map(|p| p.as_path()));
    let csv = b.get_text(&format!("/v1/flights/{id}/results.csv"));
    assert_eq!(csv, cli_output(&all, "csv"));
}
