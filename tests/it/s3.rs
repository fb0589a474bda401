//! Frames straight from object storage: a real S3 server on 127.0.0.1
//! (moto_server), fixtures written with a real S3 client (boto3, through
//! `tests/fixtures/s3_fixture.py`), and a real `gcp-tagger serve` reading
//! them with its own S3 client. A fault-injecting TCP proxy between the two
//! cuts or corrupts transfers.

use std::io::{Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::path::{Path, PathBuf};

use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use serde_json::{json, Value};

use crate::server::{problem, Server};
use crate::service::{cli_output, flight, CRS};

use crate::moto::{aws_env, Moto, KEY, SECRET};

fn post_json(server: &Server, path: &str, body: Value) -> reqwest::blocking::Response {
    server
        .client
        .post(server.url(path))
        .json(&body)
        .send()
        .unwrap()
}

fn name(p: &Path) -> String {
    p.file_name().unwrap().to_string_lossy().into_owned()
}

/// Puts the test flight's frames under `bucket/prefix`.
fn put_frames(bucket: &str, prefix: &str, frames: &[PathBuf]) -> Value {
    let mut ops = vec![json!({"op": "bucket", "bucket": bucket})];
    for f in frames {
        ops.push(json!({"op": "put", "bucket": bucket, "key": format!("{prefix}{}", name(f)), "file": f}));
    }
    Value::Array(ops)
}

#[test]
fn a_flight_from_a_prefix_equals_the_upload_and_its_results_are_written_back() {
    let frames = &flight().1;
    let moto = Moto::start(false);
    let mut ops = put_frames("flights", "survey/2026-11-22/", frames);
    let more = ops.as_array_mut().unwrap();
    more.push(json!({"op": "put", "bucket": "flights", "key": "survey/2026-11-22/notes.txt", "text": "pilot notes"}));
    more.push(json!({"op": "put", "bucket": "flights", "key": "survey/other/frame_9999.tif", "text": "not this flight"}));
    more.push(json!({"op": "bucket", "bucket": "results"}));
    moto.ops(KEY, SECRET, ops);

    let data = tempfile::tempdir().unwrap();
    let server = Server::start_env(
        &data.path().join("d"),
        &["--s3-endpoint", &moto.endpoint],
        &aws_env(KEY, SECRET),
    );
    let r = post_json(
        &server,
        &format!("/v1/flights?crs={CRS}"),
        json!({"sources": ["s3://flights/survey/2026-11-22/"], "results_to": "s3://results/runs/1/"}),
    );
    assert_eq!(r.status(), 201);
    let submitted: Value = r.json().unwrap();
    let jobs = submitted["jobs"].as_array().unwrap();
    let names: Vec<&str> = jobs.iter().map(|j| j["image"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        ["frame_0000.tif", "frame_0001.tif", "frame_0002.tif"]
    );
    assert_eq!(
        jobs[1]["source"],
        "s3://flights/survey/2026-11-22/frame_0001.tif"
    );
    assert_eq!(
        submitted["skipped"],
        json!(["s3://flights/survey/2026-11-22/notes.txt"])
    );
    assert_eq!(submitted["flight"]["export"]["state"], "pending");

    let id = submitted["flight"]["id"].as_str().unwrap();
    let done = server.wait_flight(id);
    assert_eq!(done["jobs"]["succeeded"], 3, "{done}");
    assert_eq!(done["export"]["state"], "written", "{done}");
    let paths: Vec<&Path> = frames.iter().map(|p| p.as_path()).collect();
    let csv = server.get_text(&format!("/v1/flights/{id}/results.csv"));
    assert_eq!(csv, cli_output(&paths, "csv"));
    let geojson = server.get_text(&format!("/v1/flights/{id}/results.geojson"));

    // Written back, byte for byte, and read with another S3 client.
    let back = moto.ops(
        KEY,
        SECRET,
        json!([
            {"op": "get", "bucket": "results", "key": "runs/1/results.csv"},
            {"op": "get", "bucket": "results", "key": "runs/1/results.geojson"},
        ]),
    );
    assert_eq!(back[0], csv.as_str());
    assert_eq!(back[1], geojson.as_str());
    let types = moto.ops(
        KEY,
        SECRET,
        json!([
            {"op": "type", "bucket": "results", "key": "runs/1/results.csv"},
            {"op": "type", "bucket": "results", "key": "runs/1/results.geojson"},
        ]),
    );
    assert_eq!(
        types,
        json!(["text/csv; charset=utf-8", "application/geo+json"])
    );
    // Local copies of fetched frames go once their jobs end.
    let left = std::fs::read_dir(data.path().join("d/frames"))
        .unwrap()
        .count();
    assert_eq!(left, 0, "fetched frames left in the data folder");
}

#[test]
fn single_objects_and_sources_that_cannot_work_get_clear_answers() {
    let frames = &flight().1;
    let moto = Moto::start(false);
    let mut ops = put_frames("flights", "f/", &frames[..1]);
    let more = ops.as_array_mut().unwrap();
    more.push(json!({"op": "put", "bucket": "flights", "key": "f/fake.jpg", "text": "<html>not a frame</html>"}));
    more.push(json!({"op": "put", "bucket": "flights", "key": "docs/readme.txt", "text": "no frames here"}));
    more.push(json!({"op": "bucket", "bucket": "private"}));
    moto.ops(KEY, SECRET, ops);

    let data = tempfile::tempdir().unwrap();
    let server = Server::start_env(
        &data.path().join("d"),
        &[
            "--s3-endpoint",
            &moto.endpoint,
            "--s3-allow-bucket",
            "flights,nosuchbucket",
        ],
        &aws_env(KEY, SECRET),
    );
    let flights = "/v1/flights";
    let src = |s: &[&str]| json!({ "sources": s });

    // One object, and one whose content is not an image: the good frame
    // goes on, the other fails its own job with the reason.
    let r = post_json(
        &server,
        &format!("{flights}?crs={CRS}"),
        src(&["s3://flights/f/frame_0000.tif", "s3://flights/f/fake.jpg"]),
    );
    assert_eq!(r.status(), 201);
    let v: Value = r.json().unwrap();
    let id = v["flight"]["id"].as_str().unwrap();
    server.wait_flight(id);
    let jobs = server.get_json(&format!("/v1/flights/{id}/jobs"));
    let jobs = jobs["items"].as_array().unwrap();
    assert_eq!(jobs[0]["image"], "frame_0000.tif");
    assert_eq!(jobs[0]["state"], "succeeded", "{}", jobs[0]);
    assert_eq!(jobs[1]["state"], "failed");
    assert_eq!(jobs[1]["error"]["code"], "not_an_image");
    let message = jobs[1]["error"]["message"].as_str().unwrap();
    assert!(message.contains("s3://flights/f/fake.jpg"), "{message}");
    let csv = server.get_text(&format!("/v1/flights/{id}/results.csv"));
    assert_eq!(csv, cli_output(&[frames[0].as_path()], "csv"));

    // One job from one object, as a single upload would be.
    let r = post_json(
        &server,
        &format!("/v1/jobs?crs={CRS}"),
        src(&["s3://flights/f/frame_0000.tif"]),
    );
    assert_eq!(r.status(), 201);
    let job: Value = r.json().unwrap();
    assert_eq!(job["image"], "frame_0000.tif");
    let done = server.wait_job(job["id"].as_str().unwrap());
    assert_eq!(done["state"], "succeeded", "{done}");
    let v = problem(
        post_json(
            &server,
            &format!("/v1/jobs?crs={CRS}"),
            src(&["s3://flights/f/"]),
        ),
        400,
        "expected_one_frame",
    );
    assert_eq!(v["field"], "sources", "{v}");

    // Sources that cannot work are refused at submission, naming the source;
    // nothing is recorded.
    let before = server.get_json(flights)["items"].as_array().unwrap().len();
    let cases: [(&[&str], u16, &str, &str); 8] = [
        (
            &["s3://flights/f/missing.tif"],
            422,
            "no_such_object",
            "sources[0]",
        ),
        (
            &["s3://flights/f/frame_0000.tif", "s3://nosuchbucket/a.tif"],
            422,
            "no_such_bucket",
            "sources[1]",
        ),
        (&["s3://flights/docs/"], 422, "empty_prefix", "sources[0]"),
        (
            &["s3://flights/nothing-here/"],
            422,
            "empty_prefix",
            "sources[0]",
        ),
        (
            &["s3://private/a.tif"],
            403,
            "bucket_not_allowed",
            "sources[0]",
        ),
        (
            &["https://evil.example/a.tif"],
            422,
            "invalid_source",
            "sources[0]",
        ),
        (
            &["s3://flights/../etc/passwd"],
            422,
            "invalid_source",
            "sources[0]",
        ),
        // A leading empty segment would fetch `secret/canary.jpg`.
        (
            &["s3://flights//secret/canary.jpg"],
            422,
            "invalid_source",
            "sources[0]",
        ),
    ];
    for (sources, status, code, field) in cases {
        let v = problem(post_json(&server, flights, src(sources)), status, code);
        assert_eq!(v["field"], field, "{v}");
    }
    let v = problem(
        post_json(
            &server,
            flights,
            json!({"sources": ["s3://flights/f/"], "results_to": "s3://private/out/"}),
        ),
        403,
        "bucket_not_allowed",
    );
    assert_eq!(v["field"], "results_to");
    let v = problem(
        post_json(
            &server,
            flights,
            json!({"sources": ["s3://flights/f/"], "results_to": "s3://flights/out.csv"}),
        ),
        422,
        "invalid_source",
    );
    assert_eq!(v["field"], "results_to");
    problem(
        post_json(&server, flights, json!({"source": "s3://flights/f/"})),
        400,
        "invalid_json",
    );
    // A second frame of one name in a flight.
    let r = post_json(
        &server,
        &format!("{flights}/{id}/frames"),
        src(&["s3://flights/f/frame_0000.tif"]),
    );
    problem(r, 409, "duplicate_image");
    let after = server.get_json(flights)["items"].as_array().unwrap().len();
    assert_eq!(before, after, "a refused request recorded a flight");
}

#[test]
fn refused_credentials_are_a_clear_bad_gateway_and_good_ones_work() {
    let frames = &flight().1;
    let moto = Moto::start(true);
    let creds = moto.ops("bootstrap", "bootstrap", json!([{"op": "iam_user"}]));
    let (key, secret) = (
        creds[0]["key"].as_str().unwrap().to_string(),
        creds[0]["secret"].as_str().unwrap().to_string(),
    );
    moto.ops(&key, &secret, put_frames("flights", "f/", &frames[..1]));

    let data = tempfile::tempdir().unwrap();
    let wrong = Server::start_env(
        &data.path().join("wrong"),
        &["--s3-endpoint", &moto.endpoint],
        &aws_env(&key, "not-the-secret"),
    );
    let v = problem(
        post_json(
            &wrong,
            "/v1/flights",
            json!({"sources": ["s3://flights/f/frame_0000.tif"]}),
        ),
        502,
        "s3_access_denied",
    );
    let detail = v["detail"].as_str().unwrap();
    assert!(
        detail.contains("refused the server's credentials"),
        "{detail}"
    );
    assert!(detail.contains("403 Forbidden"), "{detail}");
    assert_eq!(v["field"], "sources[0]");
    drop(wrong);

    // The same object with the right keys: moto enforces auth, so this
    // shows the server signs its requests. (Single objects only: moto
    // 5.2 miscomputes signatures of listings with a prefix when auth is
    // on, getmoto/moto#5948.)
    let right = Server::start_env(
        &data.path().join("right"),
        &["--s3-endpoint", &moto.endpoint],
        &aws_env(&key, &secret),
    );
    let r = post_json(
        &right,
        &format!("/v1/flights?crs={CRS}"),
        json!({"sources": ["s3://flights/f/frame_0000.tif"]}),
    );
    assert_eq!(r.status(), 201);
    let v: Value = r.json().unwrap();
    let done = right.wait_flight(v["flight"]["id"].as_str().unwrap());
    assert_eq!(done["jobs"]["succeeded"], 1, "{done}");
}

/// What the proxy does to GETs of one object.
#[derive(Clone, Copy)]
enum Fault {
    /// Closes the connection after this many bytes of the response.
    Cut(u64),
    /// Flips the byte at this offset of the response.
    Corrupt(u64),
}

/// A TCP proxy to moto that injects `fault` into the first `times` GETs of
/// `path` (resumed ones too), forwarding at about 8 MB/s (a slow link).
struct Proxy {
    addr: String,
    stop: Arc<AtomicBool>,
    /// Request lines of GETs of `path`, with whether they asked for a range.
    gets: Arc<Mutex<Vec<(String, bool)>>>,
}

impl Proxy {
    fn start(upstream: u16, path: &str, fault: Fault, times: usize) -> Proxy {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        listener.set_nonblocking(true).unwrap();
        let addr = format!("http://{}", listener.local_addr().unwrap());
        let stop = Arc::new(AtomicBool::new(false));
        let gets = Arc::new(Mutex::new(Vec::new()));
        let left = Arc::new(AtomicUsize::new(times));
        let target = format!("GET {path} ");
        let (stop2, gets2) = (stop.clone(), gets.clone());
        std::thread::spawn(move || {
            while !stop2.load(Ordering::SeqCst) {
                match listener.accept() {
                    Ok((client, _)) => {
                        client.set_nonblocking(false).unwrap();
                        let server = TcpStream::connect(("127.0.0.1", upstream)).unwrap();
                        relay(
                            client,
                            server,
                            target.clone(),
                            fault,
                            left.clone(),
                            gets2.clone(),
                        );
                    }
                    Err(_) => std::thread::sleep(Duration::from_millis(5)),
                }
            }
        });
        Proxy { addr, stop, gets }
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

/// Relays one connection both ways. When the client sends a GET of the
/// target, the fault applies to the response that follows (HTTP/1.1 sends
/// the next request only after the last response, so the response starts
/// at the byte count seen then).
fn relay(
    client: TcpStream,
    server: TcpStream,
    target: String,
    fault: Fault,
    left: Arc<AtomicUsize>,
    gets: Arc<Mutex<Vec<(String, bool)>>>,
) {
    let relayed = Arc::new(AtomicU64::new(0));
    let fault_at = Arc::new(AtomicU64::new(u64::MAX));
    let (mut c_in, mut s_out) = (client.try_clone().unwrap(), server.try_clone().unwrap());
    let (relayed2, fault_at2) = (relayed.clone(), fault_at.clone());
    std::thread::spawn(move || {
        let mut buf = vec![0u8; 64 << 10];
        loop {
            let n = match c_in.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(n) => n,
            };
            let text = String::from_utf8_lossy(&buf[..n]).to_string();
            for line in text.lines().filter(|l| l.starts_with(&target)) {
                let ranged = text.to_ascii_lowercase().contains("\r\nrange:");
                gets.lock().unwrap().push((line.to_string(), ranged));
                let take = left
                    .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| n.checked_sub(1))
                    .is_ok();
                if take {
                    let offset = match fault {
                        Fault::Cut(n) | Fault::Corrupt(n) => n,
                    };
                    fault_at2.store(relayed2.load(Ordering::SeqCst) + offset, Ordering::SeqCst);
                }
            }
            if s_out.write_all(&buf[..n]).is_err() {
                break;
            }
        }
        let _ = s_out.shutdown(Shutdown::Write);
    });
    let (mut s_in, mut c_out) = (server, client);
    std::thread::spawn(move || {
        let mut buf = vec![0u8; 16 << 10];
        loop {
            let n = match s_in.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(n) => n,
            };
            let start = relayed.load(Ordering::SeqCst);
            let at = fault_at.load(Ordering::SeqCst);
            let chunk = &mut buf[..n];
            if at >= start && at < start + n as u64 {
                let i = (at - start) as usize;
                match fault {
                    Fault::Cut(_) => {
                        let _ = c_out.write_all(&chunk[..i]);
                        let _ = c_out.shutdown(Shutdown::Both);
                        let _ = s_in.shutdown(Shutdown::Both);
                        return;
                    }
                    Fault::Corrupt(_) => chunk[i] ^= 0x5a,
                }
            }
            if c_out.write_all(chunk).is_err() {
                break;
            }
            relayed.fetch_add(n as u64, Ordering::SeqCst);
            std::thread::sleep(Duration::from_millis(2));
        }
        let _ = c_out.shutdown(Shutdown::Write);
    });
}

/// Puts two frames under `flights/f/`, puts `fault` on the path to
/// `faulty` and submits the prefix through the proxy; returns what runs
/// (declared in reverse drop order: the server stops first) and the
/// finished flight's id.
fn flight_through_proxy(
    faulty: &str,
    fault: Fault,
    times: usize,
) -> (Moto, Proxy, tempfile::TempDir, Server, String) {
    let frames = &flight().1;
    let moto = Moto::start(false);
    moto.ops(KEY, SECRET, put_frames("flights", "f/", &frames[..2]));
    let proxy = Proxy::start(moto.port, &format!("/flights/f/{faulty}"), fault, times);
    let data = tempfile::tempdir().unwrap();
    let server = Server::start_env(
        &data.path().join("d"),
        &["--s3-endpoint", &proxy.addr],
        &aws_env(KEY, SECRET),
    );
    let r = post_json(
        &server,
        &format!("/v1/flights?crs={CRS}"),
        json!({"sources": ["s3://flights/f/"]}),
    );
    assert_eq!(r.status(), 201);
    let v: Value = r.json().unwrap();
    let id = v["flight"]["id"].as_str().unwrap().to_string();
    server.wait_flight(&id);
    (moto, proxy, data, server, id)
}

#[test]
fn an_interrupted_transfer_resumes_where_it_stopped() {
    // Two cuts in the middle of frame_0001's body.
    let (_moto, proxy, _data, server, id) =
        flight_through_proxy("frame_0001.tif", Fault::Cut(700_000), 2);
    let done = server.get_json(&format!("/v1/flights/{id}"));
    assert_eq!(done["jobs"]["succeeded"], 2, "{done}");
    let paths: Vec<&Path> = flight().1[..2].iter().map(|p| p.as_path()).collect();
    assert_eq!(
        server.get_text(&format!("/v1/flights/{id}/results.csv")),
        cli_output(&paths, "csv")
    );
    let gets = proxy.gets.lock().unwrap().clone();
    assert!(
        gets.len() >= 3 && gets.iter().filter(|g| g.1).count() >= 2,
        "expected two cut transfers resumed by range: {gets:?}"
    );
}

#[test]
fn a_corrupted_transfer_fails_its_job_and_the_others_go_on() {
    let (_moto, _proxy, _data, server, id) =
        flight_through_proxy("frame_0000.tif", Fault::Corrupt(50_000), 1);
    let jobs = server.get_json(&format!("/v1/flights/{id}/jobs"));
    let jobs = jobs["items"].as_array().unwrap();
    assert_eq!(jobs[0]["state"], "failed", "{}", jobs[0]);
    assert_eq!(jobs[0]["error"]["code"], "integrity_check_failed");
    let message = jobs[0]["error"]["message"].as_str().unwrap();
    assert!(message.contains("MD5"), "{message}");
    assert_eq!(jobs[1]["state"], "succeeded", "{}", jobs[1]);
}
