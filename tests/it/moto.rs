//! A real S3 server for tests and benches: moto_server on a free port of
//! 127.0.0.1 (`scripts/test-deps.sh` installs it), fixtures written with a
//! real S3 client (boto3, through `tests/fixtures/s3_fixture.py`).

use std::io::Write;
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

/// A moto_server on a free port of 127.0.0.1, stopped when dropped.
pub(crate) struct Moto {
    child: Child,
    pub(crate) endpoint: String,
    pub(crate) port: u16,
}

impl Moto {
    /// With `auth`, moto checks signatures and IAM policies after the three
    /// calls that create the test's IAM user.
    pub(crate) fn start(auth: bool) -> Moto {
        let port = TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let mut cmd = Command::new("python3");
        cmd.args(["-m", "moto.server", "-H", "127.0.0.1", "-p"])
            .arg(port.to_string())
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        if auth {
            cmd.env("INITIAL_NO_AUTH_ACTION_COUNT", "3");
        }
        let child = cmd
            .spawn()
            .expect("start moto_server (bash scripts/test-deps.sh installs it)");
        let deadline = Instant::now() + Duration::from_secs(60);
        while TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(Instant::now() < deadline, "moto_server did not start");
            std::thread::sleep(Duration::from_millis(100));
        }
        Moto {
            child,
            endpoint: format!("http://127.0.0.1:{port}"),
            port,
        }
    }

    /// Runs fixture operations with a real S3 client (boto3).
    pub(crate) fn ops(&self, key: &str, secret: &str, ops: Value) -> Value {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/s3_fixture.py");
        let mut child = Command::new("python3")
            .arg(script)
            .args([&self.endpoint, key, secret])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        child
            .stdin
            .take()
            .unwrap()
            .write_all(ops.to_string().as_bytes())
            .unwrap();
        let out = child.wait_with_output().unwrap();
        assert!(
            out.status.success(),
            "s3 fixture failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice(&out.stdout).unwrap()
    }
}

impl Drop for Moto {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Keys for moto without auth (any keys pass).
pub(crate) const KEY: &str = "test-access-key";
pub(crate) const SECRET: &str = "test-secret-key";

pub(crate) fn aws_env<'a>(key: &'a str, secret: &'a str) -> [(&'a str, &'a str); 3] {
    [
        ("AWS_ACCESS_KEY_ID", key),
        ("AWS_SECRET_ACCESS_KEY", secret),
        ("AWS_REGION", "us-east-1"),
    ]
}
