//! Load benchmark of `gcp-tagger serve`: a 100-frame flight of 4000x3000
//! JPEGs submitted in one request to a server limited to `--max-ram-gb 1`.
//! Prints the throughput (MP/s) next to the command line's on the same
//! frames and limit, the server's peak RSS against its limit, and the
//! latency of status requests made while every worker is busy.
//!
//! Run: `cargo bench --bench load` (frames are generated once into the
//! target folder and reused). Under `cargo test` it does nothing.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde_json::Value;

mod common;
// The integration tests' server helper: a real `serve` process on port 0.
#[path = "../tests/it/server.rs"]
mod server;
use server::Server;

const FRAMES: usize = 100;
const MAX_RAM_GB: &str = "1";

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        println!("load: run with `cargo bench --bench load`");
        return;
    }
    let flight = common::JpegFlight::get("load-frames", FRAMES);
    let megapixels = flight.megapixels();

    let (cli_seconds, cli_rss_kib) = common::run_detect(
        &flight.dir,
        &flight.dir.with_extension("cli.csv"),
        &["--max-ram-gb", MAX_RAM_GB],
    );
    let (server_seconds, peak_rss_kib, latencies) = run_server(&flight.frames);
    let mut ms: Vec<f64> = latencies.iter().map(|d| d.as_secs_f64() * 1e3).collect();
    ms.sort_by(f64::total_cmp);
    let q = |p: f64| ms[((ms.len() - 1) as f64 * p).round() as usize];
    let limit_mib = 1024.0;
    println!("| measure | value |");
    println!("|---|---|");
    println!(
        "| command line, {FRAMES} frames, --max-ram-gb {MAX_RAM_GB} | {:.1} MP/s, peak RSS {:.0} MiB |",
        megapixels / cli_seconds,
        cli_rss_kib as f64 / 1024.0
    );
    println!(
        "| service, one {FRAMES}-frame multipart flight (upload to last result) | {:.1} MP/s ({:.0}% of the command line) |",
        megapixels / server_seconds,
        100.0 * cli_seconds / server_seconds
    );
    println!(
        "| service peak RSS, server + worker processes, at --max-ram-gb {MAX_RAM_GB} | {:.0} MiB of {limit_mib:.0} MiB |",
        peak_rss_kib as f64 / 1024.0
    );
    println!(
        "| status requests while workers are busy: n, p50, p99, max | {}, {:.1} ms, {:.1} ms, {:.1} ms |",
        ms.len(),
        q(0.5),
        q(0.99),
        ms[ms.len() - 1]
    );
}

/// Returns the seconds from the start of the upload to the flight's end,
/// the server's peak RSS in KiB, and the status request latencies.
fn run_server(frames: &[PathBuf]) -> (f64, u64, Vec<Duration>) {
    let data = tempfile::tempdir().expect("temp dir");
    // No rate limit: the poller below asks 50 times a second.
    let server = Server::start(
        &data.path().join("d"),
        &["--max-ram-gb", MAX_RAM_GB, "--rate-limit-per-minute", "0"],
    );
    let start = Instant::now();
    let paths: Vec<&Path> = frames.iter().map(PathBuf::as_path).collect();
    let r = server.post_files("/v1/flights?crs=EPSG:4326", &paths);
    assert_eq!(r.status(), 201);
    let body: Value = r.json().unwrap();
    let flight = body["flight"]["id"].as_str().unwrap().to_string();
    let job = body["jobs"][FRAMES - 1]["id"].as_str().unwrap().to_string();
    eprintln!("uploaded in {:.1} s", start.elapsed().as_secs_f64());

    // Status requests, one every 20 ms, while the flight runs; the RSS of
    // the server and its worker processes, summed, every 100 ms.
    let done = AtomicBool::new(false);
    let tree_peak = std::sync::atomic::AtomicU64::new(0);
    let latencies = std::thread::scope(|s| {
        s.spawn(|| {
            while !done.load(Ordering::SeqCst) {
                tree_peak.fetch_max(tree_rss_kib(server.pid()), Ordering::SeqCst);
                std::thread::sleep(Duration::from_millis(100));
            }
        });
        let poller = s.spawn(|| {
            let mut out = Vec::new();
            while !done.load(Ordering::SeqCst) {
                let t = Instant::now();
                let r = server.get(&format!("/v1/jobs/{job}"));
                assert_eq!(r.status(), 200);
                let _ = r.bytes();
                out.push(t.elapsed());
                std::thread::sleep(Duration::from_millis(20));
            }
            out
        });
        let v = server.wait_flight(&flight);
        assert_eq!(v["jobs"]["succeeded"], FRAMES as u64, "{v}");
        done.store(true, Ordering::SeqCst);
        poller.join().unwrap()
    });
    let seconds = start.elapsed().as_secs_f64();
    let status = std::fs::read_to_string(format!("/proc/{}/status", server.pid())).unwrap();
    let hwm_kib = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap_or(0);
    eprintln!(
        "server VmHWM {} MiB; server + worker processes, sampled peak {} MiB",
        hwm_kib / 1024,
        tree_peak.load(Ordering::SeqCst) / 1024
    );
    (
        seconds,
        tree_peak.load(Ordering::SeqCst).max(hwm_kib),
        latencies,
    )
}

/// VmRSS of `pid` plus that of its child processes, in KiB (children from
/// /proc/PID/task/*/children: no scan of all of /proc).
fn tree_rss_kib(pid: u32) -> u64 {
    let rss = |p: u32| -> u64 {
        std::fs::read_to_string(format!("/proc/{p}/status"))
            .ok()
            .and_then(|s| {
                s.lines()
                    .find_map(|l| l.strip_prefix("VmRSS:"))
                    .and_then(|v| v.split_whitespace().next()?.parse().ok())
            })
            .unwrap_or(0)
    };
    let mut total = rss(pid);
    for task in std::fs::read_dir(format!("/proc/{pid}/task"))
        .into_iter()
        .flatten()
        .flatten()
    {
        let children = std::fs::read_to_string(task.path().join("children")).unwrap_or_default();
        for child in children.split_whitespace().filter_map(|c| c.parse().ok()) {
            total += rss(child);
        }
    }
    total
}
