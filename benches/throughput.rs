//! Throughput, peak memory and accuracy of `gcp-tagger detect` on generated
//! flights: 4000x3000 JPEG frames and 8000x6000 JPEG frames; then AprilTag's
//! hard cases (tags of 18-60 px, motion blur, hard shadows across tags,
//! 16-bit GeoTIFF) side by side with the AprilTag 3 reference detector
//! (pupil-apriltags from PyPI, installed by `scripts/apriltag-peer.sh`)
//! over the same frames in the same run.
//!
//! Run: `cargo bench --bench throughput` (frames are generated once into
//! the target folder and reused). Under `cargo test` it does nothing.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use gcp_synth::{FileKind, FlightSpec};

#[allow(dead_code)] // the service benches' flight
mod common;
use common::{generate, run_detect, run_measured};

struct Set {
    name: &'static str,
    spec: FlightSpec,
}

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        println!("throughput: run with `cargo bench --bench throughput`");
        return;
    }
    let root = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("bench-frames");
    // BENCH_ONLY=pictures or BENCH_ONLY=hard runs that table alone
    // (PEER=off leaves the reference detector out of the hard cases).
    let only = std::env::var("BENCH_ONLY").ok();
    let sets = [
        Set {
            name: "4000x3000 JPEG",
            spec: FlightSpec {
                frames: 12,
                width: 4000,
                height: 3000,
                markers: 8,
                kind: FileKind::Jpeg,
                seed: 11,
                hard: false,
            },
        },
        Set {
            name: "8000x6000 JPEG",
            spec: FlightSpec {
                frames: 3,
                width: 8000,
                height: 6000,
                markers: 12,
                kind: FileKind::Jpeg,
                seed: 12,
                hard: false,
            },
        },
    ];
    match only.as_deref() {
        Some("pictures") => return pictures(&root, &sets[0]),
        Some("hard") => return hard_cases(&root),
        _ => {}
    }
    println!(
        "| frames | threads | MP/s | peak RSS MiB | recall | centre error median px | p95 px |"
    );
    println!("|---|---|---|---|---|---|---|");
    for set in &sets {
        let dir = root.join(format!(
            "{}x{}-{}",
            set.spec.width, set.spec.height, set.spec.frames
        ));
        if !dir.join("truth.csv").exists() {
            eprintln!("generating {} into {}", set.name, dir.display());
            generate(&dir, &set.spec);
        }
        for threads in [1, 2] {
            let out = dir.with_extension(format!("t{threads}.csv"));
            let (seconds, rss_kib) = run_detect(&dir, &out, &["--threads", &threads.to_string()]);
            let mp = (set.spec.width * set.spec.height * set.spec.frames) as f64 / 1e6;
            let s = score(&dir.join("truth.csv"), &out);
            println!(
                "| {} x{} | {threads} | {:.1} | {:.0} | {:.1}% | {:.3} | {:.3} |",
                set.name,
                set.spec.frames,
                mp / seconds,
                rss_kib as f64 / 1024.0,
                100.0 * s.found as f64 / s.truth as f64,
                s.median,
                s.p95
            );
        }
    }

    // Speed of each mode on the same frames (2 threads): detection time
    // depends on the picture (texture, clutter), not on which targets it holds.
    let set = &sets[0];
    let dir = root.join(format!(
        "{}x{}-{}",
        set.spec.width, set.spec.height, set.spec.frames
    ));
    println!();
    println!(
        "| mode ({} x{}, 2 threads) | MP/s | peak RSS MiB |",
        set.name, set.spec.frames
    );
    println!("|---|---|---|");
    for mode in [
        "apriltag",
        "aruco",
        "crosshair",
        "circle",
        "crosshair,circle",
    ] {
        let out = dir.with_extension(format!("{mode}.csv"));
        let (seconds, rss_kib) = run_detect(&dir, &out, &["--threads", "2", "--marker-type", mode]);
        let mp = (set.spec.width * set.spec.height * set.spec.frames) as f64 / 1e6;
        println!(
            "| {mode} | {:.1} | {:.0} |",
            mp / seconds,
            rss_kib as f64 / 1024.0
        );
    }

    pictures(&root, &sets[0]);
    hard_cases(&root);
}

/// What chips and previews add to a flight: `detect` with and without
/// `--chips` on the same frames, 2 threads, best of five runs each
/// (alternating, so a slow spell of the machine hits both).
fn pictures(root: &Path, set: &Set) {
    let dir = root.join(format!(
        "{}x{}-{}",
        set.spec.width, set.spec.height, set.spec.frames
    ));
    if !dir.join("truth.csv").exists() {
        generate(&dir, &set.spec);
    }
    println!();
    println!(
        "| pictures ({} x{}, 2 threads) | without s | with --chips s | added | chips |",
        set.name, set.spec.frames
    );
    println!("|---|---|---|---|---|");
    for mode in ["apriltag", "crosshair"] {
        let chips = dir.with_extension(format!("{mode}.chips"));
        let out = dir.with_extension(format!("{mode}.pictures.csv"));
        let (mut without, mut with) = (f64::MAX, f64::MAX);
        for _ in 0..5 {
            let args = ["--threads", "2", "--marker-type", mode];
            without = without.min(run_detect(&dir, &out, &args).0);
            let _ = std::fs::remove_dir_all(&chips);
            let chips_arg = chips.display().to_string();
            let mut args = args.to_vec();
            args.extend(["--chips", &chips_arg]);
            with = with.min(run_detect(&dir, &out, &args).0);
        }
        let n = std::fs::read_dir(&chips)
            .map(|d| {
                d.filter(|e| {
                    e.as_ref()
                        .is_ok_and(|e| e.file_name().to_string_lossy().ends_with(".png"))
                })
                .count()
            })
            .unwrap_or(0);
        println!(
            "| {mode} | {without:.2} | {with:.2} | {:+.1}% | {n} |",
            100.0 * (with / without - 1.0)
        );
    }
}

/// AprilTag's hard cases, ours against the reference detector at its
/// decimations 2 (its speed setting) and 1 (its best recall), 2 threads each.
fn hard_cases(root: &Path) {
    let sets = [
        Set {
            name: "hard 4000x3000 JPEG",
            spec: FlightSpec {
                frames: 12,
                width: 4000,
                height: 3000,
                markers: 14,
                kind: FileKind::Jpeg,
                seed: 13,
                hard: true,
            },
        },
        Set {
            name: "hard 4000x3000 16-bit GeoTIFF",
            spec: FlightSpec {
                frames: 4,
                width: 4000,
                height: 3000,
                markers: 14,
                kind: FileKind::Gtiff16,
                seed: 14,
                hard: true,
            },
        },
    ];
    let peer = Command::new("bash")
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scripts/apriltag-peer.sh"
        ))
        .output()
        .expect("run scripts/apriltag-peer.sh");
    assert!(peer.status.success(), "scripts/apriltag-peer.sh failed");
    let python = String::from_utf8(peer.stdout).unwrap().trim().to_string();
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/apriltag-peer.py");

    println!();
    println!("| hard set | detector | recall | centre median px | p95 px | wrong ids | false | MP/s | peak RSS MiB |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let mut totals: HashMap<&str, (usize, usize, f64, f64)> = HashMap::new();
    for set in &sets {
        let dir = root.join(format!(
            "hard-{}x{}-{}-{}",
            set.spec.width, set.spec.height, set.spec.frames, set.spec.kind
        ));
        if !dir.join("truth.csv").exists() {
            eprintln!("generating {} into {}", set.name, dir.display());
            generate(&dir, &set.spec);
        }
        let mp = (set.spec.width * set.spec.height * set.spec.frames) as f64 / 1e6;
        let truth = dir.join("truth.csv");
        // Who runs, and the reference detector's decimation.
        let runs = [
            ("gcp-tagger", None),
            ("AprilTag 3, decimate 2", Some("2")),
            ("AprilTag 3, decimate 1", Some("1")),
        ];
        let with_peer = std::env::var("PEER").map_or(true, |v| v != "off");
        for (i, (who, decimate)) in runs.into_iter().enumerate() {
            if decimate.is_some() && !with_peer {
                continue;
            }
            let out = dir.with_extension(format!("hard{i}.csv"));
            let (seconds, rss_kib) = match decimate {
                None => run_detect(&dir, &out, &["--threads", "2"]),
                Some(d) => run_peer(&python, script, &dir, &out, d),
            };
            let s = score(&truth, &out);
            let total = totals.entry(who).or_default();
            total.0 += s.found;
            total.1 += s.truth;
            total.2 += mp;
            total.3 += seconds;
            println!(
                "| {} x{} | {who} | {:.3} | {:.3} | {:.3} | {} | {} | {:.1} | {:.0} |",
                set.name,
                set.spec.frames,
                s.found as f64 / s.truth as f64,
                s.median,
                s.p95,
                s.wrong_ids,
                s.false_positives,
                mp / seconds,
                rss_kib as f64 / 1024.0
            );
        }
    }
    println!();
    let ours = totals["gcp-tagger"];
    for who in [
        "gcp-tagger",
        "AprilTag 3, decimate 2",
        "AprilTag 3, decimate 1",
    ] {
        let Some(&t) = totals.get(who) else { continue };
        println!(
            "{who}: recall {:.3} over all hard frames, {:.1} MP/s; gcp-tagger's speed {:.2}x",
            t.0 as f64 / t.1 as f64,
            t.2 / t.3,
            (ours.2 / ours.3) / (t.2 / t.3)
        );
    }
}

/// The reference detector over `dir` (see scripts/apriltag-peer.py).
fn run_peer(python: &str, script: &str, dir: &Path, out: &Path, decimate: &str) -> (f64, i64) {
    let mut command = Command::new(python);
    command
        .arg(script)
        .arg(dir)
        .arg(out)
        .args(["--decimate", decimate, "--threads", "2"]);
    run_measured(command)
}

/// A detector's output against the truth: a detection within 5 px of a
/// true centre with that id is found (the nearest one), with another id a
/// wrong id; one near no true centre is false.
struct Score {
    truth: usize,
    found: usize,
    median: f64,
    p95: f64,
    wrong_ids: usize,
    false_positives: usize,
}

fn score(truth: &Path, out: &Path) -> Score {
    let truth = read_centres(truth);
    let found = read_centres(out);
    let mut errors = Vec::new();
    for (img, id, x, y) in &truth {
        let best = found
            .iter()
            .filter(|(i, d, _, _)| i == img && d == id)
            .map(|(_, _, fx, fy)| (fx - x).hypot(fy - y))
            .filter(|d| *d < 5.0)
            .reduce(f64::min);
        errors.extend(best);
    }
    let (mut wrong_ids, mut false_positives) = (0, 0);
    for (img, id, fx, fy) in &found {
        let near: Vec<_> = truth
            .iter()
            .filter(|(i, _, x, y)| i == img && (fx - x).hypot(fy - y) < 5.0)
            .collect();
        if near.is_empty() {
            false_positives += 1;
        } else if near.iter().all(|(_, t, _, _)| t != id) {
            wrong_ids += 1;
        }
    }
    errors.sort_by(f64::total_cmp);
    let q = |p: f64| {
        if errors.is_empty() {
            f64::NAN
        } else {
            errors[((errors.len() - 1) as f64 * p).round() as usize]
        }
    };
    Score {
        truth: truth.len(),
        found: errors.len(),
        median: q(0.5),
        p95: q(0.95),
        wrong_ids,
        false_positives,
    }
}

/// (image, id, x, y) of each row of a CSV with image, marker_type,
/// marker_id, px_x, px_y first.
fn read_centres(p: &Path) -> Vec<(String, String, f64, f64)> {
    std::fs::read_to_string(p)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[0].to_string(),
                f[2].to_string(),
                f[3].parse().unwrap(),
                f[4].parse().unwrap(),
            )
        })
        .collect()
}
