//! Helpers shared by the benchmarks.

use std::path::Path;
use std::process::Command;

use gcp_tagger::synth::FlightSpec;

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
        .status()
        .expect("run gcp-tagger sample");
    assert!(status.success(), "sample generation failed");
}
