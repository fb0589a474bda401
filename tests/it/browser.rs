//! The review page end to end in a real headless browser: Debian's
//! `chromium` driven through `chromedriver` (both installed by
//! `scripts/test-deps.sh`) over the W3C WebDriver protocol, which is JSON
//! over HTTP: the few commands used are below.

use std::net::TcpListener;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use base64::Engine;
use reqwest::blocking::Client;
use serde_json::{json, Value};

use crate::server::Server;
use gcp_synth::{write_flight, FileKind, FlightSpec};

/// A chromedriver process and one browser session on it.
struct Browser {
    driver: Child,
    base: String,
    session: String,
    http: Client,
}

/// A WebDriver element reference.
const ELEMENT: &str = "element-6066-11e4-a52e-4f735466cecf";

impl Browser {
    fn start() -> Browser {
        let port = TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let driver = Command::new("chromedriver")
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromedriver (Debian's chromium-driver; scripts/test-deps.sh installs it)");
        let base = format!("http://127.0.0.1:{port}");
        let http = Client::builder()
            .timeout(Duration::from_secs(60))
            .build()
            .unwrap();
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            let ready = http
                .get(format!("{base}/status"))
                .send()
                .ok()
                .and_then(|r| r.json::<Value>().ok())
                .is_some_and(|v| v["value"]["ready"] == true);
            if ready {
                break;
            }
            assert!(Instant::now() < deadline, "chromedriver did not start");
            std::thread::sleep(Duration::from_millis(100));
        }
        let caps = json!({"capabilities": {"alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": {
                "binary": "/usr/bin/chromium",
                "args": ["--headless=new", "--no-sandbox", "--disable-gpu",
                         "--disable-dev-shm-usage", "--window-size=1400,900"]
            }
        }}});
        let answer: Value = http
            .post(format!("{base}/session"))
            .json(&caps)
            .send()
            .unwrap()
            .json()
            .unwrap();
        let session = answer["value"]["sessionId"]
            .as_str()
            .unwrap_or_else(|| panic!("no browser session: {answer}"))
            .to_string();
        Browser {
            driver,
            base,
            session,
            http,
        }
    }

    fn command(&self, method: &str, path: &str, body: Value) -> Value {
        self.try_command(method, path, body)
            .unwrap_or_else(|e| panic!("WebDriver {path}: {e}"))
    }

    /// A command whose WebDriver error (`no such alert`, ...) is returned.
    fn try_command(&self, method: &str, path: &str, body: Value) -> Result<Value, String> {
        let url = format!("{}/session/{}{path}", self.base, self.session);
        let request = match method {
            "GET" => self.http.get(url),
            "DELETE" => self.http.delete(url),
            _ => self.http.post(url).json(&body),
        };
        let answer: Value = request.send().unwrap().json().unwrap();
        match answer["value"]["error"].as_str() {
            Some(error) => Err(format!("{error}: {}", answer["value"]["message"])),
            None => Ok(answer["value"].clone()),
        }
    }

    /// Answers the page's prompt with `text` once it shows.
    fn answer_prompt(&self, text: &str) -> String {
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            if let Ok(question) = self.try_command("GET", "/alert/text", Value::Null) {
                self.command("POST", "/alert/text", json!({ "text": text }));
                self.command("POST", "/alert/accept", json!({}));
                return question.as_str().unwrap_or_default().to_string();
            }
            assert!(Instant::now() < deadline, "the page asked for nothing");
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn goto(&self, url: &str) {
        self.command("POST", "/url", json!({ "url": url }));
    }

    fn find_all(&self, css: &str) -> Vec<String> {
        self.command(
            "POST",
            "/elements",
            json!({"using": "css selector", "value": css}),
        )
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e[ELEMENT].as_str().unwrap().to_string())
        .collect()
    }

    fn find(&self, css: &str) -> String {
        self.find_all(css)
            .into_iter()
            .next()
            .unwrap_or_else(|| panic!("no element {css}"))
    }

    /// Types `text` into an element (file inputs take paths, one per line).
    fn send_keys(&self, element: &str, text: &str) {
        self.command(
            "POST",
            &format!("/element/{element}/value"),
            json!({ "text": text }),
        );
    }

    fn click(&self, element: &str) {
        self.command("POST", &format!("/element/{element}/click"), json!({}));
    }

    /// Runs an async script; its last argument is the callback.
    fn run_async(&self, script: &str) -> Value {
        self.command(
            "POST",
            "/execute/async",
            json!({"script": script, "args": []}),
        )
    }

    fn run(&self, script: &str) -> Value {
        self.command(
            "POST",
            "/execute/sync",
            json!({"script": script, "args": []}),
        )
    }

    fn screenshot(&self) -> Vec<u8> {
        let b64 = self.command("GET", "/screenshot", Value::Null);
        base64::engine::general_purpose::STANDARD
            .decode(b64.as_str().unwrap())
            .unwrap()
    }

    /// Waits until `script` (a sync script's body) returns true.
    fn wait_for(&self, what: &str, script: &str) {
        let deadline = Instant::now() + Duration::from_secs(60);
        while self.run(script) != Value::Bool(true) {
            assert!(
                Instant::now() < deadline,
                "timed out waiting for {what}; page status: {}",
                self.run("return document.querySelector('#status').textContent")
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self
            .http
            .delete(format!("{}/session/{}", self.base, self.session))
            .send();
        let _ = self.driver.kill();
        let _ = self.driver.wait();
    }
}

/// Truth rows of a generated flight: (image, marker id).
fn truth_ids(dir: &Path) -> Vec<(String, u32)> {
    std::fs::read_to_string(dir.join("truth.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[0].to_string(), f[2].parse().unwrap())
        })
        .collect()
}

#[test]
fn a_reviewer_with_a_key_uploads_frames_rejects_a_detection_and_it_leaves_gcp_list() {
    let tmp = tempfile::tempdir().unwrap();
    let frames = tmp.path().join("frames");
    write_flight(
        &frames,
        &FlightSpec {
            frames: 2,
            width: 1600,
            height: 1200,
            markers: 3,
            kind: FileKind::Jpeg,
            seed: 61,
            hard: false,
        },
    )
    .unwrap();
    let truth = truth_ids(&frames);
    // A survey naming every marker id, for the GCP files.
    let mut survey = String::from("EPSG:32611\nname,marker_id,easting,northing,elevation\n");
    for (i, (_, id)) in truth.iter().enumerate() {
        survey.push_str(&format!(
            "P{id},{id},{},{},10\n",
            500000 + 10 * i,
            3800000 + 7 * i
        ));
    }
    let survey_path = tmp.path().join("survey.csv");
    std::fs::write(&survey_path, survey).unwrap();

    // Keys configured: the page must ask for one and send it as the bearer.
    let key = "review-page-key-0123456789";
    let server = Server::start(
        &tmp.path().join("data"),
        &["--workers", "2", "--api-key", key],
    );
    let get = |path: &str| {
        let r = server
            .client
            .get(server.url(path))
            .bearer_auth(key)
            .send()
            .unwrap();
        assert_eq!(r.status(), 200, "GET {path}");
        r
    };
    let browser = Browser::start();
    browser.goto(&server.url("/"));
    let question = browser.answer_prompt(key);
    assert!(question.contains("API key"), "{question}");
    browser.find("#drop");
    // The marker types this flight has (the defaults include the printed
    // modes, slower and not needed here).
    browser.run("document.querySelector('#marker-types').value = 'apriltag'; return true");
    let paths: Vec<String> = ["frame_0000.jpg", "frame_0001.jpg"]
        .iter()
        .map(|f| frames.join(f).display().to_string())
        .collect();
    browser.send_keys(&browser.find("#frames-input"), &paths.join("\n"));
    // Every tag's chip appears, its image loaded.
    let n = truth.len();
    browser.wait_for(
        "the chips",
        &format!(
            "return document.querySelectorAll('.chip img[data-loaded]').length === {n} \
             && document.querySelector('#flight').dataset.state === 'finished'"
        ),
    );
    browser.send_keys(
        &browser.find("#survey-input"),
        &survey_path.display().to_string(),
    );
    browser.wait_for(
        "the survey's names on the groups",
        "return [...document.querySelectorAll('.group h3')].every(h => h.textContent.startsWith('GCP '))",
    );
    let flight = browser
        .run("return window.gcpTagger.state.flight")
        .as_str()
        .unwrap()
        .to_string();
    assert_eq!(
        server
            .get(&format!("/v1/flights/{flight}/observations"))
            .status(),
        401,
        "the page got in with its key; without one, no"
    );
    let gcp_before = get(&format!("/v1/flights/{flight}/exports/gcp_list.txt"))
        .text()
        .unwrap();
    assert_eq!(gcp_before.lines().count(), 1 + n, "{gcp_before}");

    // Select the second chip by clicking it and reject it from the keyboard.
    let chips = browser.find_all(".chip");
    browser.click(&chips[1]);
    let rejected = browser.run(
        "const c = document.querySelectorAll('.chip')[1]; \
         const o = window.gcpTagger.state.observations[+c.dataset.index]; \
         return [o.image, o.gcp_name, o.px_x]",
    );
    browser.command(
        "POST",
        "/actions",
        json!({"actions": [{"type": "key", "id": "k", "actions": [
            {"type": "keyDown", "value": "r"}, {"type": "keyUp", "value": "r"}]}]}),
    );
    browser.wait_for(
        "the rejection",
        "return document.querySelectorAll('.chip')[1].dataset.review === 'rejected'",
    );
    if let Ok(path) = std::env::var("GCP_TAGGER_SCREENSHOT") {
        std::fs::write(path, browser.screenshot()).unwrap();
    }

    // gcp_list.txt as the page's download button fetches it.
    let gcp_after = browser.run_async(
        "const done = arguments[arguments.length - 1]; \
         window.gcpTagger.fetchExport('exports/gcp_list.txt').then(r => r.text()).then(done, e => done('ERROR ' + e))",
    );
    let gcp_after = gcp_after.as_str().unwrap();
    let (image, name) = (rejected[0].as_str().unwrap(), rejected[1].as_str().unwrap());
    assert_eq!(gcp_after.lines().count(), n, "{gcp_after}");
    assert!(
        !gcp_after
            .lines()
            .any(|l| l.ends_with(&format!(" {image} {name}"))),
        "the rejected {name} in {image} is still in:\n{gcp_after}"
    );
    assert!(
        gcp_before
            .lines()
            .any(|l| l.ends_with(&format!(" {image} {name}"))),
        "{gcp_before}"
    );
    // The review is stored: the API says so after the page is gone.
    drop(browser);
    let observations: Value = get(&format!("/v1/flights/{flight}/observations"))
        .json()
        .unwrap();
    let rejected_now: Vec<&Value> = observations["observations"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|o| o["review"] == "rejected")
        .collect();
    assert_eq!(rejected_now.len(), 1);
    assert_eq!(rejected_now[0]["gcp_name"], name);
}
