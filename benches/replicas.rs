//! Replicas on one queue: the same flight run by one `serve` replica and by
//! two, each with one worker, on one PostgreSQL (initdb'd for the run) and
//! one bucket (moto_server). Prints the throughput of each and their ratio.
//!
//! Run: `cargo bench --bench replicas` (frames like the load bench's,
//! generated once into the target folder). Under `cargo test` it does
//! nothing.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde_json::json;

#[allow(dead_code)]
mod common;
#[path = "../tests/it/moto.rs"]
#[allow(dead_code)]
mod moto;
#[path = "../tests/it/postgres.rs"]
#[allow(dead_code)]
mod postgres;
#[path = "../tests/it/server.rs"]
mod server;

use moto::{aws_env, Moto, KEY, SECRET};
use server::Server;

const FRAMES: usize = 24;

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        println!("replicas: run with `cargo bench --bench replicas`");
        return;
    }
    let flight = common::JpegFlight::get("replica-frames", FRAMES);
    let megapixels = flight.megapixels();
    let pg = postgres::Postgres::start();
    let moto = Moto::start(false);
    moto.ops(KEY, SECRET, json!([{"op": "bucket", "bucket": "bench"}]));

    let modes = std::env::var("MODES").unwrap_or_else(|_| "apriltag;crosshair".into());
    println!("| marker types | 1 replica | 2 replicas | ratio |");
    println!("|---|---|---|---|");
    for mode in modes.split(';') {
        let one = run(&pg, &moto, &flight.frames, 1, mode);
        let two = run(&pg, &moto, &flight.frames, 2, mode);
        println!(
            "| {mode} | {:.1} MP/s | {:.1} MP/s | {:.2}x |",
            megapixels / one,
            megapixels / two,
            one / two
        );
    }
    println!(
        "\n{FRAMES} frames of {}x{} JPEG in one multipart request to the first replica, \
         timed to the flight's end; each replica `--workers 1`, one PostgreSQL, one bucket \
         (moto), on this machine ({} cores).",
        flight.spec.width,
        flight.spec.height,
        std::thread::available_parallelism().map_or(0, |n| n.get())
    );
}

/// Seconds from the upload's start to the flight's end with `n` replicas.
fn run(pg: &postgres::Postgres, moto: &Moto, frames: &[PathBuf], n: usize, mode: &str) -> f64 {
    let store = pg.database();
    let data = tempfile::tempdir().unwrap();
    let prefix = format!("s3://bench/{}/", uuid_like(&store));
    let replicas: Vec<Server> = (0..n)
        .map(|i| {
            Server::start_env(
                &data.path().join(format!("r{i}")),
                &[
                    "--store",
                    &store,
                    "--shared-files",
                    &prefix,
                    "--s3-endpoint",
                    &moto.endpoint,
                    "--workers",
                    "1",
                ],
                &aws_env(KEY, SECRET),
            )
        })
        .collect();
    let paths: Vec<&Path> = frames.iter().map(|p| p.as_path()).collect();
    let started = Instant::now();
    let id = replicas[0].post_flight(
        &format!("/v1/flights?crs=EPSG:32633&marker_types={mode}"),
        &paths,
    );
    let uploaded = started.elapsed().as_secs_f64();
    let done = replicas[0].wait_flight(&id);
    let seconds = started.elapsed().as_secs_f64();
    eprintln!("{mode}, {n} replica(s): upload answered after {uploaded:.1} s, flight done after {seconds:.1} s");
    assert_eq!(done["jobs"]["succeeded"], FRAMES, "{done}");
    seconds
}

/// The database's name, to keep each run's files apart in the bucket.
fn uuid_like(url: &str) -> String {
    url.rsplit('/').next().unwrap_or("run").to_string()
}
