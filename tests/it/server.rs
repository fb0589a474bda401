//! A real `gcp-tagger serve` process on 127.0.0.1, port 0, for tests: the
//! address comes from its first stdout line; dropping it sends SIGTERM and
//! waits (SIGKILL if it does not stop).

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use reqwest::blocking::{multipart, Client, Response};
use serde_json::Value;

pub struct Server {
    child: Option<Child>,
    pub base: String,
    pub data: PathBuf,
    pub log: PathBuf,
    pub client: Client,
}

impl Server {
    /// Starts a server on `data` with extra `serve` flags.
    pub fn start(data: &Path, extra: &[&str]) -> Server {
        Server::start_env(data, extra, &[])
    }

    /// Starts a server with extra flags and environment variables.
    pub fn start_env(data: &Path, extra: &[&str], env: &[(&str, &str)]) -> Server {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_gcp-tagger"));
        cmd.args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
            .arg(data)
            .args(extra)
            .envs(env.iter().copied());
        Server::spawn(cmd, data)
    }

    /// Starts a server whose data folder is a tmpfs of `mib` MiB, mounted
    /// in a mount namespace of its own (`unshare -rm`: no privileges
    /// needed, nothing mounted on the host). The test reaches the folder
    /// as the server sees it through [`Server::own_path`].
    pub fn start_on_small_disk(data: &Path, mib: u32, extra: &[&str]) -> Server {
        std::fs::create_dir_all(data).unwrap();
        let mut cmd = Command::new("unshare");
        cmd.args(["-rm", "sh", "-c"])
            .arg(format!(
                "mount -t tmpfs -o size={mib}m tmpfs \"$0\" && exec \"$@\""
            ))
            .arg(data)
            .arg(env!("CARGO_BIN_EXE_gcp-tagger"))
            .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
            .arg(data)
            .args(extra);
        Server::spawn(cmd, data)
    }

    /// `path` as the server process sees it (its own mount namespace).
    pub fn own_path(&self, path: &Path) -> PathBuf {
        PathBuf::from(format!("/proc/{}/root", self.pid())).join(path.strip_prefix("/").unwrap())
    }

    fn spawn(mut cmd: Command, data: &Path) -> Server {
        let log = data.with_extension("log");
        let mut child = cmd
            .env("GCP_TAGGER_LOG", "info")
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .expect("start gcp-tagger serve");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let base = match line.trim().strip_prefix("gcp-tagger listening on ") {
            Some(url) => url.to_string(),
            None => {
                let _ = child.kill();
                panic!(
                    "server did not start: {line:?}\n{}",
                    std::fs::read_to_string(&log).unwrap_or_default()
                );
            }
        };
        Server {
            child: Some(child),
            base,
            data: data.to_path_buf(),
            log,
            client: Client::builder()
                .timeout(Duration::from_secs(120))
                .build()
                .unwrap(),
        }
    }

    /// The server process's id.
    pub fn pid(&self) -> u32 {
        self.child.as_ref().expect("running").id()
    }

    pub fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    pub fn get(&self, path: &str) -> Response {
        self.client.get(self.url(path)).send().unwrap()
    }

    pub fn get_json(&self, path: &str) -> Value {
        let r = self.get(path);
        assert_eq!(r.status(), 200, "GET {path}");
        r.json().unwrap()
    }

    pub fn get_text(&self, path: &str) -> String {
        let r = self.get(path);
        assert_eq!(r.status(), 200, "GET {path}");
        r.text().unwrap()
    }

    /// Uploads files as one multipart request to `path`.
    pub fn post_files(&self, path: &str, files: &[&Path]) -> Response {
        let mut form = multipart::Form::new();
        for f in files {
            form = form.file("frame", f).unwrap();
        }
        self.client
            .post(self.url(path))
            .multipart(form)
            .send()
            .unwrap()
    }

    /// Posts `files` as a new flight (`path` with its query), asserts the
    /// 201 and returns the flight's id.
    pub fn post_flight(&self, path: &str, files: &[&Path]) -> String {
        let r = self.post_files(path, files);
        assert_eq!(r.status(), 201, "POST {path}");
        r.json::<Value>().unwrap()["flight"]["id"]
            .as_str()
            .expect("a flight id")
            .to_string()
    }

    /// Waits for a job to end (long-poll) and returns it.
    pub fn wait_job(&self, id: &str) -> Value {
        self.wait(&format!("/v1/jobs/{id}"), |v| {
            matches!(
                v["state"].as_str(),
                Some("succeeded" | "failed" | "canceled")
            )
        })
    }

    /// Waits for a flight to finish (long-poll) and returns it.
    pub fn wait_flight(&self, id: &str) -> Value {
        self.wait(&format!("/v1/flights/{id}"), |v| v["state"] == "finished")
    }

    fn wait(&self, path: &str, done: impl Fn(&Value) -> bool) -> Value {
        let deadline = Instant::now() + Duration::from_secs(300);
        loop {
            let v = self.get_json(&format!("{path}?wait=30"));
            if done(&v) {
                return v;
            }
            assert!(Instant::now() < deadline, "{path} did not end: {v}");
        }
    }

    /// Kills the process with SIGKILL (no shutdown at all) and reaps it.
    pub fn kill9(&mut self) {
        let mut child = self.child.take().expect("running");
        let _ = child.kill();
        let _ = child.wait();
    }

    /// Pids of the worker processes that have job `job`'s frame open.
    /// Resident memory of the server and its worker processes together,
    /// in KiB (VmRSS of each, from /proc).
    pub fn tree_rss_kib(&self) -> u64 {
        let rss = |pid: u32| -> u64 {
            std::fs::read_to_string(format!("/proc/{pid}/status"))
                .unwrap_or_default()
                .lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .and_then(|v| v.split_whitespace().next()?.parse().ok())
                .unwrap_or(0)
        };
        rss(self.pid()) + self.children().into_iter().map(rss).sum::<u64>()
    }

    /// The server's child processes (its workers), from /proc.
    fn children(&self) -> Vec<u32> {
        let server = self.pid();
        std::fs::read_dir("/proc")
            .unwrap()
            .flatten()
            .filter_map(|entry| entry.file_name().to_string_lossy().parse::<u32>().ok())
            .filter(|pid| {
                let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
                // ppid is the 4th field, after the parenthesised command name.
                stat.rsplit_once(')')
                    .and_then(|(_, rest)| rest.split_whitespace().nth(1))
                    .and_then(|p| p.parse::<u32>().ok())
                    == Some(server)
            })
            .collect()
    }

    pub fn worker_pids(&self, job: &str) -> Vec<u32> {
        self.children()
            .into_iter()
            .filter(|pid| {
                std::fs::read_dir(format!("/proc/{pid}/fd")).is_ok_and(|fds| {
                    fds.flatten().any(|fd| {
                        std::fs::read_link(fd.path())
                            .is_ok_and(|t| t.to_string_lossy().contains(job))
                    })
                })
            })
            .collect()
    }

    /// Sends SIGTERM and waits for the process to end.
    pub fn stop(&mut self) -> ExitStatus {
        let mut child = self.child.take().expect("running");
        // SAFETY: kill(2) on our own child's pid.
        unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            if let Some(status) = child.try_wait().unwrap() {
                return status;
            }
            if Instant::now() > deadline {
                let _ = child.kill();
                return child.wait().unwrap();
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        if self.child.is_some() {
            self.stop();
        }
    }
}

/// Checks a problem+json answer and returns its body.
pub fn problem(r: Response, status: u16, code: &str) -> Value {
    assert_eq!(r.status().as_u16(), status, "status for {code}");
    let ct = r
        .headers()
        .get("content-type")
        .map(|v| v.to_str().unwrap().to_string())
        .unwrap_or_default();
    assert_eq!(ct, "application/problem+json", "content type for {code}");
    let v: Value = r.json().unwrap();
    assert_eq!(v["code"], code, "{v}");
    assert_eq!(v["status"], status);
    assert!(!v["detail"].as_str().unwrap().is_empty());
    v
}
