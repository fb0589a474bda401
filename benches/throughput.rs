//! Throughput, peak memory and accuracy of `gcp-tagger detect` on generated
//! flights: 4000x3000 JPEG frames and 8000x6000 JPEG frames.
//!
//! Run: `cargo bench --bench throughput` (frames are generated once into
//! the target folder and reused). Under `cargo test` it does nothing.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use gcp_tagger::synth::{FileKind, FlightSpec};

mod common;
use common::{generate, run_detect};

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
            },
        },
    ];
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
            let (recall, median, p95) = accuracy(&dir.join("truth.csv"), &out);
            println!(
                "| {} x{} | {threads} | {:.1} | {:.0} | {:.1}% | {median:.3} | {p95:.3} |",
                set.name,
                set.spec.frames,
                mp / seconds,
                rss_kib as f64 / 1024.0,
                recall * 100.0
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
}

/// Recall and centre-error quantiles of `out` against `truth` (both CSV,
/// matched by image and id, nearest centre).
fn accuracy(truth: &Path, out: &Path) -> (f64, f64, f64) {
    let read = |p: &Path| -> Vec<(String, String, f64, f64)> {
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
    };
    let mut found: HashMap<(String, String), Vec<(f64, f64)>> = HashMap::new();
    for (img, id, x, y) in read(out) {
        found.entry((img, id)).or_default().push((x, y));
    }
    let truth = read(truth);
    let mut errors: Vec<f64> = truth
        .iter()
        .filter_map(|(img, id, x, y)| {
            found
                .get(&(img.clone(), id.clone()))?
                .iter()
                .map(|(fx, fy)| (fx - x).hypot(fy - y))
                .filter(|d| *d < 5.0)
                .reduce(f64::min)
        })
        .collect();
    errors.sort_by(f64::total_cmp);
    let q = |p: f64| errors[((errors.len() - 1) as f64 * p).round() as usize];
    (errors.len() as f64 / truth.len() as f64, q(0.5), q(0.95))
}
