//! The HTTP service as clients use it: a real server process on 127.0.0.1
//! and a real HTTP client; frames with known truth; results compared with
//! the truth and with the command line's bytes.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use gcp_synth::{write_flight, FileKind, FlightSpec};
use serde_json::Value;

use crate::server::{problem, Server};

pub(crate) const CRS: &str = "EPSG:32611";

/// Three georeferenced frames with known targets, rendered once.
pub(crate) fn flight() -> &'static (tempfile::TempDir, Vec<PathBuf>) {
    static FLIGHT: OnceLock<(tempfile::TempDir, Vec<PathBuf>)> = OnceLock::new();
    FLIGHT.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let spec = FlightSpec {
            frames: 3,
            width: 1600,
            height: 1200,
            markers: 4,
            kind: FileKind::Gtiff,
            seed: 7,
            hard: false,
        };
        write_flight(dir.path(), &spec).unwrap();
        let frames = (0..3)
            .map(|i| dir.path().join(format!("frame_{i:04}.tif")))
            .collect();
        (dir, frames)
    })
}

/// Truth centres by image and marker id.
fn truth() -> HashMap<(String, u32), (f64, f64)> {
    let text = std::fs::read_to_string(flight().0.path().join("truth.csv")).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                (f[0].to_string(), f[2].parse().unwrap()),
                (f[3].parse().unwrap(), f[4].parse().unwrap()),
            )
        })
        .collect()
}

/// Checks every truth target of `images` is in the CSV within 0.25 px,
/// and nothing else is.
fn assert_csv_matches_truth(csv: &str, images: &[&str]) {
    let truth = truth();
    let mut found = 0;
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let key = (f[0].to_string(), f[2].parse::<u32>().unwrap());
        let t = truth
            .get(&key)
            .unwrap_or_else(|| panic!("false positive {line}"));
        let (x, y): (f64, f64) = (f[3].parse().unwrap(), f[4].parse().unwrap());
        let err = ((x - t.0).powi(2) + (y - t.1).powi(2)).sqrt();
        assert!(err < 0.25, "{line}: {err:.3} px from truth");
        assert_eq!(f[7], CRS);
        found += 1;
    }
    let expected = truth
        .keys()
        .filter(|(i, _)| images.contains(&i.as_str()))
        .count();
    assert_eq!(found, expected, "every target found once:\n{csv}");
}

/// What `gcp-tagger detect` writes for `frames` in `ext` format.
pub(crate) fn cli_output(frames: &[&Path], ext: &str) -> String {
    let out = tempfile::tempdir().unwrap();
    let path = out.path().join(format!("r.{ext}"));
    let status = Command::new(env!("CARGO_BIN_EXE_gcp-tagger"))
        .arg("detect")
        .args(frames)
        .args(["--crs", CRS, "--quiet", "--output"])
        .arg(&path)
        .status()
        .unwrap();
    assert!(status.success());
    std::fs::read_to_string(path).unwrap()
}

fn name(p: &Path) -> String {
    p.file_name().unwrap().to_string_lossy().into_owned()
}

#[test]
fn one_frame_by_raw_body_then_results_equal_the_command_line() {
    let frames = &flight().1;
    let data = tempfile::tempdir().unwrap();
    let server = Server::start(&data.path().join("d"), &[]);
    // As curl --data-binary does it.
    let r = server
        .client
        .post(server.url(&format!("/v1/jobs?crs={CRS}&name=frame_0001.tif")))
        .header("content-type", "image/tiff")
        .body(std::fs::read(&frames[1]).unwrap())
        .send()
        .unwrap();
    assert_eq!(r.status(), 201);
    let location = r.headers()["location"].to_str().unwrap().to_string();
    let job: Value = r.json().unwrap();
    assert_eq!(
        location,
        format!("/v1/jobs/{}", job["id"].as_str().unwrap())
    );
    // A free worker may have claimed it already.
    assert!(
        job["state"] == "queued" || job["state"] == "running",
        "{job}"
    );
    assert_eq!(job["image"], "frame_0001.tif");

    let done = server.wait_job(job["id"].as_str().unwrap());
    assert_eq!(done["state"], "succeeded", "{done}");
    assert_eq!(done["width"], 1600);
    assert_eq!(done["attempts"], 1);
    assert_eq!(done["progress"]["fraction"], 1.0);

    let csv = server.get_text(&format!("{location}/results.csv"));
    assert_csv_matches_truth(&csv, &["frame_0001.tif"]);
    assert_eq!(csv, cli_output(&[&frames[1]], "csv"));
    let geojson = server.get_text(&format!("{location}/results.geojson"));
    assert_eq!(geojson, cli_output(&[&frames[1]], "geojson"));

    // The same results by content negotiation.
    let r = server
        .client
        .get(server.url(&format!("{location}/results")))
        .header("accept", "application/geo+json")
        .send()
        .unwrap();
    assert_eq!(r.headers()["content-type"], "application/geo+json");
    assert_eq!(r.text().unwrap(), geojson);
    let r = server.get(&format!("{location}/results"));
    assert_eq!(r.headers()["content-type"], "text/csv; charset=utf-8");
    assert_eq!(r.text().unwrap(), csv);
}

#[test]
fn a_multipart_flight_keeps_going_past_a_bad_frame_and_equals_the_cli() {
    let frames = &flight().1;
    let data = tempfile::tempdir().unwrap();
    let server = Server::start(&data.path().join("d"), &[]);
    let junk = data.path().join("notes.jpg");
    std::fs::write(&junk, "these are field notes, not a frame").unwrap();
    // Parts deliberately out of name order.
    let parts: Vec<&Path> = vec![&frames[2], &junk, &frames[0], &frames[1]];
    let r = server.post_files(&format!("/v1/flights?crs={CRS}"), &parts);
    assert_eq!(r.status(), 201);
    let body: Value = r.json().unwrap();
    let flight_id = body["flight"]["id"].as_str().unwrap().to_string();
    let jobs = body["jobs"].as_array().unwrap();
    let names: Vec<&str> = jobs.iter().map(|j| j["image"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        [
            "frame_0002.tif",
            "notes.jpg",
            "frame_0000.tif",
            "frame_0001.tif"
        ]
    );
    assert_eq!(jobs[1]["state"], "failed");
    assert_eq!(jobs[1]["error"]["code"], "not_an_image");

    let done = server.wait_flight(&flight_id);
    assert_eq!(done["jobs"]["succeeded"], 3, "{done}");
    assert_eq!(done["jobs"]["failed"], 1);
    assert_eq!(done["targets"], 12);
    let listed = server.get_json(&format!("/v1/flights/{flight_id}/jobs?limit=2"));
    assert_eq!(listed["items"].as_array().unwrap().len(), 2);
    let next = listed["next"].as_str().unwrap();
    let rest = server.get_json(&format!("/v1/flights/{flight_id}/jobs?after={next}"));
    assert_eq!(rest["items"].as_array().unwrap().len(), 2);
    assert!(rest["next"].is_null());

    let csv = server.get_text(&format!("/v1/flights/{flight_id}/results.csv"));
    let all: Vec<String> = frames.iter().map(|p| name(p)).collect();
    let all: Vec<&str> = all.iter().map(String::as_str).collect();
    assert_csv_matches_truth(&csv, &all);
    let paths: Vec<&Path> = frames.iter().map(PathBuf::as_path).collect();
    assert_eq!(csv, cli_output(&paths, "csv"));
    let geojson = server.get_text(&format!("/v1/flights/{flight_id}/results.geojson"));
    assert_eq!(geojson, cli_output(&paths, "geojson"));
}

#[test]
fn concurrent_clients_each_get_their_own_results() {
    let frames = &flight().1;
    let data = tempfile::tempdir().unwrap();
    let server = Server::start(&data.path().join("d"), &["--workers", "2"]);
    let results: Vec<(String, String)> = std::thread::scope(|s| {
        let handles: Vec<_> = frames
            .iter()
            .chain(frames.iter())
            .map(|f| {
                let server = &server;
                s.spawn(move || {
                    let r = server.post_files(&format!("/v1/jobs?crs={CRS}"), &[f.as_path()]);
                    assert_eq!(r.status(), 201);
                    let job: Value = r.json().unwrap();
                    let id = job["id"].as_str().unwrap().to_string();
                    assert_eq!(server.wait_job(&id)["state"], "succeeded");
                    (
                        name(f),
                        server.get_text(&format!("/v1/jobs/{id}/results.csv")),
                    )
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert_eq!(results.len(), 6);
    for (image, csv) in results {
        assert_csv_matches_truth(&csv, &[image.as_str()]);
    }
    let page = server.get_json("/v1/jobs?state=succeeded&limit=1000");
    assert_eq!(page["items"].as_array().unwrap().len(), 6);
}

#[test]
fn canceling_stops_queued_and_running_jobs() {
    let frames = &flight().1;
    let data = tempfile::tempdir().unwrap();
    let server = Server::start(&data.path().join("d"), &["--workers", "1"]);
    // A large frame first (seconds of work, 256 px tiles), so the running
    // job is caught mid-way and the others are still queued.
    let big = crate::durability::big_frame(data.path(), "big.jpg");
    let mut parts: Vec<&Path> = vec![big.as_path()];
    parts.extend(frames.iter().map(PathBuf::as_path));
    let r = server.post_files(
        &format!("/v1/flights?crs={CRS}&tile_size=256&max_target_px=100"),
        &parts,
    );
    let body: Value = r.json().unwrap();
    let flight_id = body["flight"]["id"].as_str().unwrap();
    let first = body["jobs"][0]["id"].as_str().unwrap();
    // Wait until the first job runs, then cancel it.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    // (On a fast machine it may even have ended; the asserts below allow it.)
    while server.get_json(&format!("/v1/jobs/{first}"))["state"] == "queued" {
        assert!(std::time::Instant::now() < deadline);
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let r = server
        .client
        .post(server.url(&format!("/v1/jobs/{first}/cancel")))
        .send()
        .unwrap();
    assert_eq!(r.status(), 200);
    let job = server.wait_job(first);
    assert!(
        job["state"] == "canceled" || job["state"] == "succeeded",
        "a running job ends canceled (or had just finished): {job}"
    );
    let r = server
        .client
        .post(server.url(&format!("/v1/flights/{flight_id}/cancel")))
        .send()
        .unwrap();
    assert_eq!(r.status(), 200);
    let done = server.wait_flight(flight_id);
    assert_eq!(done["state"], "finished");
    assert!(done["jobs"]["canceled"].as_u64().unwrap() >= 2, "{done}");
    let r = server.get(&format!("/v1/jobs/{first}/results.csv"));
    if job["state"] == "canceled" {
        problem(r, 409, "job_not_succeeded");
    }
    // Deleting the flight removes it and its files.
    let r = server
        .client
        .delete(server.url(&format!("/v1/flights/{flight_id}")))
        .send()
        .unwrap();
    assert_eq!(r.status(), 204);
    problem(
        server.get(&format!("/v1/flights/{flight_id}")),
        404,
        "not_found",
    );
    let left = std::fs::read_dir(data.path().join("d/frames"))
        .unwrap()
        .count();
    assert_eq!(left, 0, "frames removed");
}

#[test]
fn bad_requests_get_problem_json_with_stable_codes() {
    let frames = &flight().1;
    let data = tempfile::tempdir().unwrap();
    let server = Server::start(&data.path().join("d"), &["--max-frame-mb", "1"]);
    let small = data.path().join("small.png");
    std::fs::write(&small, b"\x89PNG\r\n\x1a\nnot really").unwrap();
    let c = &server.client;
    let post = |path: &str| c.post(server.url(path));

    // No file part: a text field only.
    let form = reqwest::blocking::multipart::Form::new().text("crs", CRS);
    problem(
        post("/v1/jobs").multipart(form).send().unwrap(),
        400,
        "unexpected_field",
    );
    // No body at all.
    problem(
        post("/v1/jobs")
            .header("content-type", "image/jpeg")
            .send()
            .unwrap(),
        400,
        "empty_frame",
    );
    problem(
        post("/v1/jobs?marker_types=qrcode")
            .body("x")
            .send()
            .unwrap(),
        422,
        "invalid_parameter",
    );
    let p = problem(
        post("/v1/jobs?crs=EPSG:999999").body("x").send().unwrap(),
        422,
        "invalid_parameter",
    );
    assert_eq!(p["field"], "crs");
    // A target design is a preset or inline JSON; never a server path.
    for design in ["star", "%2Fetc%2Fpasswd", "%7B%22name%22%3A%22x%22%7D"] {
        let p = problem(
            post(&format!("/v1/jobs?target_design={design}"))
                .body("x")
                .send()
                .unwrap(),
            422,
            "invalid_parameter",
        );
        assert_eq!(p["field"], "target_design", "{design}");
    }
    problem(
        post("/v1/jobs?tile_size=12").body("x").send().unwrap(),
        422,
        "invalid_parameter",
    );
    problem(
        post("/v1/jobs?markers=aruco").body("x").send().unwrap(),
        400,
        "unknown_parameter",
    );
    let text = data.path().join("readme.txt");
    std::fs::write(&text, "hello").unwrap();
    problem(server.post_files("/v1/jobs", &[&text]), 415, "not_an_image");
    problem(
        server.post_files("/v1/jobs", &[&frames[0]]),
        413,
        "frame_too_large",
    );
    problem(
        server.post_files("/v1/jobs", &[&small, &small]),
        400,
        "expected_one_frame",
    );
    problem(
        server.post_files("/v1/flights", &[&small, &small]),
        409,
        "duplicate_image",
    );
    problem(
        post("/v1/flights")
            .header("content-type", "image/png")
            .body("x")
            .send()
            .unwrap(),
        415,
        "multipart_required",
    );
    // JSON names frames in object storage; broken JSON says so.
    problem(
        post("/v1/jobs")
            .header("content-type", "application/json")
            .body("{")
            .send()
            .unwrap(),
        400,
        "invalid_json",
    );
    problem(
        post("/v1/jobs")
            .header("content-type", "application/x-www-form-urlencoded")
            .body("a=b")
            .send()
            .unwrap(),
        415,
        "unsupported_media_type",
    );
    problem(
        post("/v1/flights")
            .header("content-type", "multipart/form-data; boundary=XYZ")
            .body("--XYZ\r\nContent-Disposition: form-data; name=\"f\"; filename=\"a.jpg\"\r\n\r\nabc")
            .send()
            .unwrap(),
        400,
        "invalid_multipart",
    );
    problem(server.get("/v1/jobs/not-a-uuid"), 400, "invalid_path");
    problem(server.get("/v1/jobs?limit=0"), 400, "invalid_query");
    problem(server.get("/v1/jobs?state=dancing"), 400, "invalid_query");
    problem(server.get("/v1/jobs?wait=1"), 400, "invalid_query");
    problem(
        server.get(&format!("/v1/jobs/{}", uuid_zero())),
        404,
        "not_found",
    );
    problem(server.get("/v2/anything"), 404, "route_not_found");
    problem(
        c.put(server.url("/v1/jobs")).send().unwrap(),
        405,
        "method_not_allowed",
    );
    let r = c
        .get(server.url(&format!("/v1/flights/{}/results", uuid_zero())))
        .header("accept", "image/png")
        .send()
        .unwrap();
    problem(r, 406, "not_acceptable");

    // Nothing above created a job, and the server still works.
    assert_eq!(
        server.get_json("/v1/jobs")["items"]
            .as_array()
            .unwrap()
            .len(),
        0
    );
    assert_eq!(server.get_json("/readyz")["status"], "ok");
}

fn uuid_zero() -> &'static str {
    "00000000-0000-7000-8000-000000000000"
}

#[test]
fn api_keys_guard_every_route_but_health_and_cors_answers_dashboards() {
    let data = tempfile::tempdir().unwrap();
    let key = "k3y-for-the-field-laptop";
    let server = Server::start(
        &data.path().join("d"),
        &[
            "--api-key",
            key,
            "--cors-origin",
            "https://dash.example.org",
        ],
    );
    let c = &server.client;
    assert_eq!(server.get("/livez").status(), 200);
    assert_eq!(server.get("/readyz").status(), 200);
    for path in ["/v1/jobs", "/v1/flights", "/metrics", "/openapi.json"] {
        let r = server.get(path);
        assert_eq!(
            r.headers()["www-authenticate"],
            "Bearer realm=\"gcp-tagger\""
        );
        problem(r, 401, "unauthorized");
    }
    let r = c
        .get(server.url("/v1/jobs"))
        .bearer_auth("wrong-key-wrong-key")
        .send()
        .unwrap();
    problem(r, 401, "unauthorized");
    let r = c
        .get(server.url("/v1/jobs"))
        .bearer_auth(key)
        .send()
        .unwrap();
    assert_eq!(r.status(), 200);

    // A browser's preflight needs no key.
    let r = c
        .request(reqwest::Method::OPTIONS, server.url("/v1/flights"))
        .header("origin", "https://dash.example.org")
        .header("access-control-request-method", "POST")
        .header("access-control-request-headers", "authorization")
        .send()
        .unwrap();
    assert!(r.status().is_success());
    assert_eq!(
        r.headers()["access-control-allow-origin"],
        "https://dash.example.org"
    );
    let r = c
        .get(server.url("/v1/jobs"))
        .bearer_auth(key)
        .header("origin", "https://evil.example.com")
        .send()
        .unwrap();
    assert!(r.headers().get("access-control-allow-origin").is_none());
}

#[test]
fn metrics_events_and_request_ids() {
    let frames = &flight().1;
    let data = tempfile::tempdir().unwrap();
    let server = Server::start(&data.path().join("d"), &[]);
    let r = server.post_files(&format!("/v1/jobs?crs={CRS}"), &[&frames[0]]);
    assert!(r.headers().contains_key("x-request-id"));
    let job: Value = r.json().unwrap();
    let id = job["id"].as_str().unwrap();

    // Server-sent events until the end event.
    let text = server.get_text(&format!("/v1/jobs/{id}/events"));
    let events: Vec<&str> = text
        .lines()
        .filter_map(|l| l.strip_prefix("event: "))
        .collect();
    assert_eq!(events.last(), Some(&"end"), "{text}");
    let last_data = text
        .lines()
        .filter_map(|l| l.strip_prefix("data: "))
        .next_back()
        .unwrap();
    let last: Value = serde_json::from_str(last_data).unwrap();
    assert_eq!(last["state"], "succeeded");

    let metrics = server.get_text("/metrics");
    for needle in [
        "gcp_tagger_jobs_total{outcome=\"succeeded\"} 1",
        "gcp_tagger_queue_depth 0",
        "gcp_tagger_megapixels_processed_total 1.92",
        "gcp_tagger_memory_budget_in_use_bytes 0",
        "gcp_tagger_job_duration_seconds_count{outcome=\"succeeded\"} 1",
        "route=\"/v1/jobs\",status=\"201\"",
    ] {
        assert!(metrics.contains(needle), "{needle} missing from\n{metrics}");
    }
    let docs = server.get_text("/docs/");
    assert!(docs.contains("swagger"), "Swagger UI is served");
    let spec = server.get_json("/openapi.json");
    assert_eq!(spec["info"]["title"], "gcp-tagger");
}

#[test]
fn shutdown_leaves_unfinished_jobs_queued_and_a_restart_completes_them() {
    let frames = &flight().1;
    let data = tempfile::tempdir().unwrap();
    let dir = data.path().join("d");
    let flags = ["--workers", "1", "--shutdown-grace-secs", "0"];
    let mut server = Server::start(&dir, &flags);
    let parts: Vec<&Path> = frames.iter().map(PathBuf::as_path).collect();
    let body: Value = server
        .post_files(
            &format!("/v1/flights?crs={CRS}&tile_size=256&max_target_px=100"),
            &parts,
        )
        .json()
        .unwrap();
    let flight_id = body["flight"]["id"].as_str().unwrap().to_string();
    let status = server.stop();
    assert!(status.success(), "clean exit: {}", server.log_text());
    let log = server.log_text();
    assert!(log.contains("shutting down"), "{log}");
    drop(server);

    let server = Server::start(&dir, &["--workers", "2"]);
    let done = server.wait_flight(&flight_id);
    assert_eq!(done["jobs"]["succeeded"], 3, "{done}");
    let csv = server.get_text(&format!("/v1/flights/{flight_id}/results.csv"));
    let cli = tempfile::tempdir().unwrap();
    let out = cli.path().join("r.csv");
    let status = Command::new(env!("CARGO_BIN_EXE_gcp-tagger"))
        .arg("detect")
        .args(&parts)
        .args([
            "--crs",
            CRS,
            "--quiet",
            "--tile-size",
            "256",
            "--max-target-px",
            "100",
            "--output",
        ])
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    assert_eq!(csv, std::fs::read_to_string(out).unwrap());
}

#[test]
fn a_frame_too_large_for_the_budget_fails_with_the_numbers() {
    let frames = &flight().1;
    let data = tempfile::tempdir().unwrap();
    // 0.14 GiB leaves ~15 MiB for frames; this frame needs ~27 MiB.
    let server = Server::start(&data.path().join("d"), &["--max-ram-gb", "0.14"]);
    let job: Value = server
        .post_files(&format!("/v1/jobs?crs={CRS}"), &[&frames[0]])
        .json()
        .unwrap();
    let done = server.wait_job(job["id"].as_str().unwrap());
    assert_eq!(done["state"], "failed");
    assert_eq!(done["error"]["code"], "frame_too_large");
    let message = done["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("MiB") && message.contains("budget"),
        "{message}"
    );
    assert_eq!(server.get_json("/livez")["status"], "ok");
}

#[test]
fn the_committed_openapi_document_is_current() {
    let committed =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("openapi/openapi.json"))
            .unwrap_or_default();
    let current = gcp_tagger::api::openapi_json();
    assert!(
        committed.trim_end() == current.trim_end(),
        "openapi/openapi.json is stale: regenerate it with \
         `cargo run -- openapi > openapi/openapi.json`"
    );
    // The layers' answers are documented with the routes'.
    let spec: Value = serde_json::from_str(&current).unwrap();
    let upload = &spec["paths"]["/v1/jobs"]["post"]["responses"];
    for code in ["401", "413", "429", "503", "507"] {
        assert!(upload[code].is_object(), "POST /v1/jobs lacks {code}");
    }
    assert!(spec["paths"]["/livez"]["get"]["responses"]["401"].is_null());
}

/// `gcp-tagger probe`, the container's HEALTHCHECK: 0 when the route
/// answers 200, 1 on any other status or when nothing listens.
#[test]
fn the_health_probe_tells_a_live_server_from_a_dead_one() {
    let data = tempfile::tempdir().unwrap();
    let mut server = Server::start(
        &data.path().join("d"),
        &["--api-key", "k3y-for-the-probe-test"],
    );
    let addr = server.base.trim_start_matches("http://").to_string();
    let probe = |path: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_gcp-tagger"))
            .args(["probe", "--addr", &addr, "--path", path])
            .output()
            .expect("run probe")
    };
    assert!(probe("/livez").status.success());
    assert!(probe("/readyz").status.success());
    let refused = probe("/v1/jobs");
    assert_eq!(refused.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("401"),
        "{refused:?}"
    );
    server.stop();
    let dead = probe("/livez");
    assert_eq!(dead.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&dead.stderr).starts_with("error: "));
}

#[test]
fn two_requests_adding_the_same_frame_name_at_once_record_it_once() {
    let dir = tempfile::tempdir().unwrap();
    let frames = dir.path().join("frames");
    write_flight(
        &frames,
        &FlightSpec {
            frames: 1,
            width: 600,
            height: 400,
            markers: 1,
            kind: FileKind::Png,
            seed: 63,
            hard: false,
        },
    )
    .unwrap();
    let first = frames.join("frame_0000.png");
    let server = Server::start(&dir.path().join("data"), &[]);
    let flight = server.post_flight("/v1/flights?crs=EPSG:4326", &[&first]);
    for round in 0..5 {
        // A fresh name each round, sent from two folders at once, as two
        // clients would.
        let name = format!("same{round}.png");
        let paths: Vec<PathBuf> = ["a", "b"]
            .iter()
            .map(|d| {
                let p = dir.path().join(d).join(&name);
                std::fs::create_dir_all(p.parent().unwrap()).unwrap();
                std::fs::copy(&first, &p).unwrap();
                p
            })
            .collect();
        let barrier = std::sync::Barrier::new(2);
        let mut statuses: Vec<u16> = std::thread::scope(|s| {
            let handles: Vec<_> = paths
                .iter()
                .map(|p| {
                    let (server, barrier, flight) = (&server, &barrier, &flight);
                    s.spawn(move || {
                        barrier.wait();
                        server
                            .post_files(&format!("/v1/flights/{flight}/frames"), &[p.as_path()])
                            .status()
                            .as_u16()
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        statuses.sort();
        assert_eq!(statuses, [201, 409], "round {round}");
    }
    let jobs = server.get_json(&format!("/v1/flights/{flight}/jobs"));
    let mut names: Vec<&str> = jobs["items"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j["image"].as_str().unwrap())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "frame_0000.png",
            "same0.png",
            "same1.png",
            "same2.png",
            "same3.png",
            "same4.png"
        ]
    );
}
