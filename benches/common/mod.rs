//! Helpers shared by the benchmarks.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use gcp_synth::{FileKind, FlightSpec};

/// A flight of the service benches: 4000x3000 JPEG frames of eight coded
/// markers each (seed 21), rendered once into the target folder and reused.
pub struct JpegFlight {
    pub spec: FlightSpec,
    pub dir: PathBuf,
    pub frames: Vec<PathBuf>,
}

impl JpegFlight {
    /// `count` frames in `CARGO_TARGET_TMPDIR/folder`, rendered if missing.
    pub fn get(folder: &str, count: usize) -> JpegFlight {
        let spec = FlightSpec {
            frames: count,
            width: 4000,
            height: 3000,
            markers: 8,
            kind: FileKind::Jpeg,
            seed: 21,
            hard: false,
        };
        let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(folder);
        if !dir.join("truth.csv").exists() {
            eprintln!("generating {count} frames into {}", dir.display());
            generate(&dir, &spec);
        }
        let frames = (0..count)
            .map(|i| dir.join(format!("frame_{i:04}.jpg")))
            .collect();
        JpegFlight { spec, dir, frames }
    }

    /// The flight's size in megapixels.
    pub fn megapixels(&self) -> f64 {
        (self.spec.width * self.spec.height * self.frames.len()) as f64 / 1e6
    }
}

/// Renders frames in a separate process: Linux carries a process's peak RSS
/// across fork+exec into its children's rusage, so rendering 8000x6000
/// frames in the benchmark process would inflate every figure it measures.
pub fn generate(dir: &Path, spec: &FlightSpec) {
    let status = Command::new(env!("CARGO_BIN_EXE_gcp-tagger"))
        .arg("sample")
        .arg("--out")
        .arg(dir)
        .args([
            "--frames",
            &spec.frames.to_string(),
            "--width",
            &spec.width.to_string(),
        ])
        .args([
            "--height",
            &spec.height.to_string(),
            "--markers",
            &spec.markers.to_string(),
        ])
        .args([
            "--kind",
            &spec.kind.to_string(),
            "--seed",
            &spec.seed.to_string(),
        ])
        .args(spec.hard.then_some("--hard"))
        .status()
        .expect("run gcp-tagger sample");
    assert!(status.success(), "sample generation failed");
}

/// Runs `gcp-tagger detect DIR --crs EPSG:4326 --quiet EXTRA... --output OUT`
/// (the release binary); returns wall seconds and the child's peak RSS in
/// KiB (from wait4's rusage).
pub fn run_detect(dir: &Path, out: &Path, extra: &[&str]) -> (f64, i64) {
    let mut command = Command::new(env!("CARGO_BIN_EXE_gcp-tagger"));
    command
        .arg("detect")
        .arg(dir)
        .args(["--crs", "EPSG:4326", "--quiet"])
        .args(extra)
        .arg("--output")
        .arg(out);
    run_measured(command)
}

/// Runs `command`; returns wall seconds and the child's peak RSS in KiB
/// (from wait4's rusage). Panics when it fails.
pub fn run_measured(mut command: Command) -> (f64, i64) {
    let start = Instant::now();
    // Reaped by wait4 below (which also gives the peak RSS), not wait().
    #[allow(clippy::zombie_processes)]
    let child = command.spawn().expect("spawn");
    let mut status = 0;
    // SAFETY: plain libc call on our own child's pid with valid out-pointers.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = unsafe { libc::wait4(child.id() as i32, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as i32, "wait4");
    assert_eq!(status, 0, "{command:?} failed");
    (start.elapsed().as_secs_f64(), usage.ru_maxrss)
}
