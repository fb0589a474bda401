//! Nothing lost: a server killed with SIGKILL mid-flight completes every
//! acknowledged job exactly once after a restart, and a worker process that
//! dies costs its job a retry (or, after three deaths, a clear failure)
//! while the server and the other jobs carry on.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use gcp_synth::{write_image, GreyImage, SampleFormat};
use serde_json::Value;

use crate::server::Server;
use crate::service::{cli_output, flight, CRS};

/// A large flat JPEG: seconds of work for one worker, no targets.
pub(crate) fn big_frame(dir: &Path, name: &str) -> PathBuf {
    let (w, h) = (8000, 6000);
    let img = GreyImage {
        width: w,
        height: h,
        data: (0..w * h).map(|i| 100.0 + (i % 7) as f32).collect(),
    };
    let path = dir.join(name);
    write_image(&path, &img, SampleFormat::Jpeg, None).unwrap();
    path
}

/// The noise frame's query for tests that wait for its job: from 30 px
/// AprilTags are searched once (under it a second time on the linear scale,
/// which on pure noise takes five times the first search).
const NOISE_MODES: &str = "&marker_types=apriltag,crosshair&min_target_px=30";

/// A JPEG of noise: with [`NOISE_MODES`], candidates for one worker of the
/// test build for a while (6000x4000: a second or more, a job that outlasts
/// a few requests; tests that need it longer cancel it rather than wait for
/// it).
fn noise_frame(dir: &Path, (w, h): (usize, usize)) -> PathBuf {
    let mut x = 0x9E37_79B9_7F4A_7C15u64;
    let noise = GreyImage {
        width: w,
        height: h,
        data: (0..w * h)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                (x >> 56) as f32
            })
            .collect(),
    };
    let path = dir.join("noise.jpg");
    write_image(&path, &noise, SampleFormat::Jpeg, None).unwrap();
    path
}

/// Submits `first` then `rest` as a flight (`query` after the CRS) and
/// waits until `first`'s worker process runs; its flight and job ids.
pub(crate) fn flight_with_running_first(
    server: &Server,
    first: &Path,
    rest: &[PathBuf],
    query: &str,
) -> (String, String) {
    let mut upload: Vec<&Path> = vec![first];
    upload.extend(rest.iter().map(|p| p.as_path()));
    let r = server.post_files(&format!("/v1/flights?crs={CRS}{query}"), &upload);
    assert_eq!(r.status(), 201);
    let flight: Value = r.json().unwrap();
    let id = flight["flight"]["id"].as_str().unwrap().to_string();
    let name = first.file_name().unwrap().to_string_lossy();
    let job = job_id(server, &id, &name);
    wait_until("the first frame's worker", || {
        !server.worker_pids(&job).is_empty()
    });
    (id, job)
}

pub(crate) fn jobs_of(server: &Server, flight: &str) -> Vec<Value> {
    server.get_json(&format!("/v1/flights/{flight}/jobs"))["items"]
        .as_array()
        .unwrap()
        .clone()
}

pub(crate) fn job_named<'a>(jobs: &'a [Value], image: &str) -> &'a Value {
    jobs.iter().find(|j| j["image"] == image).unwrap()
}

/// The id of the job of `image` in a flight.
pub(crate) fn job_id(server: &Server, flight: &str, image: &str) -> String {
    job_named(&jobs_of(server, flight), image)["id"]
        .as_str()
        .unwrap()
        .to_string()
}

/// Waits until `f` holds, up to a minute.
pub(crate) fn wait_until(what: &str, mut f: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(120);
    while !f() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn kill_9_mid_flight_then_restart_completes_every_job_once() {
    let frames = &flight().1;
    let dir = tempfile::tempdir().unwrap();
    let big = big_frame(dir.path(), "big_0.jpg");
    let data = dir.path().join("d");
    let mut server = Server::start(&data, &["--workers", "1"]);
    // Kill the server while the big frame's worker runs.
    let (id, big_job) = flight_with_running_first(&server, &big, frames, "");
    let orphan = server.worker_pids(&big_job)[0];
    server.kill9();
    // The worker process dies with the server.
    wait_until("the orphaned worker to die", || {
        !Path::new(&format!("/proc/{orphan}")).exists()
            || std::fs::read_to_string(format!("/proc/{orphan}/stat"))
                .is_ok_and(|s| s.contains(") Z"))
    });

    let server = Server::start(&data, &["--workers", "1"]);
    let done = server.wait_flight(&id);
    assert_eq!(done["jobs"]["succeeded"], 4, "{done}");
    let jobs = jobs_of(&server, &id);
    assert_eq!(jobs.len(), 4, "no job lost or duplicated");
    assert_eq!(job_named(&jobs, "big_0.jpg")["attempts"], 2);
    // Results equal an uninterrupted run of the same frames.
    let csv = server.get_text(&format!("/v1/flights/{id}/results.csv"));
    let mut all: Vec<&Path> = frames.iter().map(|p| p.as_path()).collect();
    all.push(big.as_path());
    assert_eq!(csv, cli_output(&all, "csv"));
}

#[test]
fn a_dying_worker_costs_a_retry_and_three_deaths_fail_the_job() {
    let frames = &flight().1;
    let dir = tempfile::tempdir().unwrap();
    let retried = big_frame(dir.path(), "big_retried.jpg");
    let doomed = big_frame(dir.path(), "big_doomed.jpg");
    let server = Server::start(&dir.path().join("d"), &["--workers", "2"]);
    let mut upload: Vec<&Path> = vec![retried.as_path(), doomed.as_path()];
    upload.extend(frames.iter().map(|p| p.as_path()));
    let id = server.post_flight(&format!("/v1/flights?crs={CRS}"), &upload);

    let kill = |image: &str| {
        let job = job_id(&server, &id, image);
        wait_until(image, || !server.worker_pids(&job).is_empty());
        for pid in server.worker_pids(&job) {
            // SAFETY: kill(2) on a process of this test's server.
            unsafe { libc::kill(pid as i32, libc::SIGKILL) };
        }
    };
    // One death: the job is retried and succeeds.
    kill("big_retried.jpg");
    // Three deaths: the job fails with the reason.
    for attempt in 1..=3 {
        kill("big_doomed.jpg");
        if attempt < 3 {
            wait_until("the doomed job's retry", || {
                job_named(&jobs_of(&server, &id), "big_doomed.jpg")["attempts"] == attempt + 1
            });
        }
    }
    let done = server.wait_flight(&id);
    let jobs = jobs_of(&server, &id);
    let doomed = job_named(&jobs, "big_doomed.jpg");
    assert_eq!(doomed["state"], "failed", "{doomed}");
    assert_eq!(doomed["error"]["code"], "worker_crashed");
    assert_eq!(doomed["attempts"], 3);
    let message = doomed["error"]["message"].as_str().unwrap();
    assert!(message.contains("signal 9"), "{message}");
    let retried = job_named(&jobs, "big_retried.jpg");
    assert_eq!(
        (retried["state"].as_str(), retried["attempts"].as_u64()),
        (Some("succeeded"), Some(2))
    );
    assert_eq!(done["jobs"]["succeeded"], 4, "{done}");
    for f in frames {
        let name = f.file_name().unwrap().to_str().unwrap();
        assert_eq!(job_named(&jobs, name)["attempts"], 1);
    }
    assert_eq!(server.get("/livez").status(), 200);
    // The flat frames have no targets: the results are the small frames'.
    let csv = server.get_text(&format!("/v1/flights/{id}/results.csv?partial=true"));
    let paths: Vec<&Path> = frames.iter().map(|p| p.as_path()).collect();
    assert_eq!(csv, cli_output(&paths, "csv"));
}

#[test]
fn an_idempotency_key_makes_a_retried_upload_create_nothing_new() {
    let frames = &flight().1;
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(&dir.path().join("d"), &[]);
    let post = |path: &str, key: &str| {
        let mut form = reqwest::blocking::multipart::Form::new();
        for f in &frames[..2] {
            form = form.file("frame", f).unwrap();
        }
        server
            .client
            .post(server.url(path))
            .header("Idempotency-Key", key)
            .multipart(form)
            .send()
            .unwrap()
    };
    let path = format!("/v1/flights?crs={CRS}");
    let first = post(&path, "flight-2026-11-22-a");
    assert_eq!(first.status(), 201);
    assert!(first.headers().get("idempotent-replayed").is_none());
    let first: Value = first.json().unwrap();
    let again = post(&path, "flight-2026-11-22-a");
    assert_eq!(again.status(), 201);
    assert_eq!(again.headers()["idempotent-replayed"], "true");
    let again: Value = again.json().unwrap();
    assert_eq!(again["flight"]["id"], first["flight"]["id"]);
    let ids = |v: &Value| -> Vec<String> {
        v["jobs"]
            .as_array()
            .unwrap()
            .iter()
            .map(|j| j["id"].to_string())
            .collect()
    };
    assert_eq!(ids(&again), ids(&first));

    // Concurrent retries of a new key: one flight between them.
    let answers: Vec<Value> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..4)
            .map(|_| s.spawn(|| post(&path, "flight-2026-11-22-b").json::<Value>().unwrap()))
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for a in &answers {
        assert_eq!(a["flight"]["id"], answers[0]["flight"]["id"], "{a}");
    }
    let flights = server.get_json("/v1/flights");
    assert_eq!(flights["items"].as_array().unwrap().len(), 2, "{flights}");

    // The key belongs to its request; a malformed key is refused.
    crate::server::problem(
        post("/v1/flights?crs=EPSG:4326", "flight-2026-11-22-a"),
        422,
        "idempotency_key_reused",
    );
    crate::server::problem(post(&path, "two words"), 400, "invalid_idempotency_key");
    // Single frames too.
    let job = |key: &str| {
        server
            .client
            .post(server.url("/v1/jobs?name=a.tif"))
            .header("Idempotency-Key", key)
            .body(std::fs::read(&frames[0]).unwrap())
            .send()
            .unwrap()
            .json::<Value>()
            .unwrap()
    };
    assert_eq!(job("job-1")["id"], job("job-1")["id"]);
    assert_eq!(
        server.get_json("/v1/jobs")["items"]
            .as_array()
            .unwrap()
            .len(),
        4 + 1
    );
}

#[test]
fn a_second_server_on_the_same_data_folder_refuses_to_start() {
    let frames = &flight().1;
    let dir = tempfile::tempdir().unwrap();
    let big = big_frame(dir.path(), "big_0.jpg");
    let data = dir.path().join("d");
    let server = Server::start(&data, &["--workers", "1"]);
    let (id, _) = flight_with_running_first(&server, &big, frames, "");

    // What a supervisor restarting during the shutdown grace does.
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_gcp-tagger"))
        .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
        .arg(&data)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    while child.try_wait().unwrap().is_none() {
        if Instant::now() > deadline {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("a second server started on the same data folder");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let second = child.wait_with_output().unwrap();
    assert!(!second.status.success());
    let stderr = String::from_utf8_lossy(&second.stderr);
    assert!(
        stderr.contains("in use by another gcp-tagger")
            && stderr.contains(&format!("pid {}", server.pid())),
        "{stderr}"
    );
    assert!(second.stdout.is_empty(), "the second server never listened");

    // The first server's jobs ran once each, untouched by the attempt.
    let done = server.wait_flight(&id);
    assert_eq!(done["jobs"]["succeeded"], 4, "{done}");
    for job in jobs_of(&server, &id) {
        assert_eq!(job["attempts"], 1, "{job}");
    }
}

#[test]
fn a_queued_frame_over_a_lowered_size_limit_fails_when_its_worker_opens_it() {
    let frames = &flight().1;
    let dir = tempfile::tempdir().unwrap();
    let big = big_frame(dir.path(), "big_0.jpg");
    let data = dir.path().join("d");
    let mut server = Server::start(&data, &["--workers", "1"]);
    let (id, _) = flight_with_running_first(&server, &big, frames, "");
    server.kill9();

    // Restarted with a limit under the queued 48 MP frame: the size the
    // worker's decoder opens is checked before any pixel is read.
    let server = Server::start(&data, &["--workers", "1", "--max-frame-mp", "40"]);
    let done = server.wait_flight(&id);
    assert_eq!(done["jobs"]["succeeded"], 3, "{done}");
    let jobs = jobs_of(&server, &id);
    let big = job_named(&jobs, "big_0.jpg");
    assert_eq!(big["error"]["code"], "frame_too_large", "{big}");
    let message = big["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("opens as 8000 x 6000 pixels (48 MP)") && message.contains("40 MP"),
        "{message}"
    );
}

#[test]
fn during_the_shutdown_grace_readiness_is_503_and_new_work_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let big = noise_frame(dir.path(), (6000, 4000));
    let data = dir.path().join("d");
    let mut server = Server::start(&data, &["--workers", "1", "--shutdown-grace-secs", "60"]);
    let (_, big_job) = flight_with_running_first(&server, &big, &[], NOISE_MODES);
    assert_eq!(server.get("/readyz").status(), 200);

    // SIGTERM while the job runs: the listener stays for the grace.
    // SAFETY: kill(2) on our own child's pid.
    unsafe { libc::kill(server.pid() as i32, libc::SIGTERM) };
    wait_until("readiness to turn 503", || {
        server.get("/readyz").status() == 503
    });
    assert_eq!(server.get("/livez").status(), 200);
    let r = server.post_files(&format!("/v1/flights?crs={CRS}"), &[big.as_path()]);
    let v = crate::server::problem(r, 503, "shutting_down");
    assert!(
        v["detail"].as_str().unwrap().contains("shutting down"),
        "{v}"
    );
    // Reads go on: the running job is still there to look at.
    let job = server.get_json(&format!("/v1/jobs/{big_job}"));
    assert_eq!(job["state"], "running", "{job}");
    // The job ends within the grace and the server with it.
    assert!(server.stop().success());
    assert!(
        server.log_text().contains("stopped"),
        "{}",
        server.log_text()
    );
}

#[test]
fn a_full_disk_pauses_jobs_and_they_finish_once_space_returns() {
    let frames = &flight().1;
    let dir = tempfile::tempdir().unwrap();
    let noise = noise_frame(dir.path(), (6000, 4000));
    let data = dir.path().join("d");
    let server =
        Server::start_on_small_disk(&data, 256, &["--workers", "1", "--min-free-disk-mb", "64"]);
    let (id, _) = flight_with_running_first(&server, &noise, frames, NOISE_MODES);

    // Fill the server's disk to the last byte while the job runs.
    let filler = server.own_path(&data.join("filler"));
    {
        let mut f = std::fs::File::create(&filler).unwrap();
        let block = vec![0u8; 1 << 20];
        let full = loop {
            if let Err(e) = std::io::Write::write_all(&mut f, &block) {
                break e;
            }
        };
        assert_eq!(full.raw_os_error(), Some(libc::ENOSPC), "{full}");
    }
    // The job could not store its result: back in the queue, not failed,
    // and nothing else starts while the disk is full.
    wait_until("the job to go back to the queue", || {
        server.log_text().contains("the disk is full")
    });
    std::thread::sleep(Duration::from_secs(3));
    assert_eq!(server.get("/livez").status(), 200);
    for job in jobs_of(&server, &id) {
        assert_ne!(job["state"], "failed", "{job}");
    }

    // Space returns: every job finishes, without a restart.
    std::fs::remove_file(&filler).unwrap();
    let done = server.wait_flight(&id);
    assert_eq!(done["jobs"]["succeeded"], 4, "{done}");
    let jobs = jobs_of(&server, &id);
    assert_eq!(job_named(&jobs, "noise.jpg")["attempts"], 2);
    let results = server.own_path(&data.join("results"));
    let parts: Vec<_> = std::fs::read_dir(&results)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.path().extension().is_some_and(|x| x == "part"))
        .collect();
    assert!(parts.is_empty(), "half-written results left: {parts:?}");
    let csv = server.get_text(&format!("/v1/flights/{id}/results.csv"));
    assert!(csv.lines().count() > 1, "{csv}");
    // Logs back off: a handful of errors, not one per poll.
    let log = server.log_text();
    let errors = log.lines().filter(|l| l.contains("ERROR")).count();
    assert!(errors <= 5, "{errors} error lines:\n{log}");
}

#[test]
fn a_long_poll_that_runs_out_says_to_ask_again() {
    let frames = &flight().1;
    let dir = tempfile::tempdir().unwrap();
    let noise = noise_frame(dir.path(), (8000, 6000));
    let data = dir.path().join("d");
    let server = Server::start(&data, &["--workers", "1"]);
    let upload = [noise.as_path(), frames[0].as_path()];
    // The default search: the longer the noise job, the surer the second
    // frame is still queued (the noise job is canceled, not waited for).
    let r = server.post_files(
        &format!("/v1/flights?crs={CRS}&marker_types=apriltag,crosshair"),
        &upload,
    );
    assert_eq!(r.status(), 201);
    let flight: Value = r.json().unwrap();
    let id = flight["flight"]["id"].as_str().unwrap().to_string();
    // The second frame waits behind the first's seconds of work.
    let queued = job_id(
        &server,
        &id,
        &frames[0].file_name().unwrap().to_string_lossy(),
    );
    let r = server.get(&format!("/v1/jobs/{queued}?wait=1"));
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["retry-after"], "0");
    let r = server.get(&format!("/v1/flights/{id}?wait=1"));
    assert_eq!(r.headers()["retry-after"], "0");
    // Ended: no Retry-After. The noise frame is canceled, not waited for.
    let noise_job = job_id(&server, &id, "noise.jpg");
    let r = server
        .client
        .post(server.url(&format!("/v1/jobs/{noise_job}/cancel")))
        .send()
        .unwrap();
    assert!(r.status().is_success(), "{}", r.status());
    server.wait_flight(&id);
    let r = server.get(&format!("/v1/jobs/{queued}?wait=1"));
    assert!(r.headers().get("retry-after").is_none());
    let r = server.get(&format!("/v1/flights/{id}?wait=5"));
    assert!(r.headers().get("retry-after").is_none());
}
