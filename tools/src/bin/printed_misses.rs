//! Development aid for the printed-target detectors: renders the frames of
//! `tests/it/printed.rs`, runs the pipeline, and prints every missed target
//! with its conditions and why the detector rejected the candidates near it.
//!
//!     cargo run --release -p gcp-tools --bin printed_misses -- crosshair 300 4
//!
//! `EXPECT_PX=60` narrows the size range as a survey's target size and GSD
//! would (60 px x/÷ 1.5); `RMS=1` prints every hit, `BOARD=1` the board's
//! sides of imprecise ones, `ACCEPTED=1` every candidate the detector
//! accepted (as clutter frames always do) and each target's centre, size
//! and design (`TRUTH` lines; candidates are in tile coordinates, tiles
//! starting 352 px apart on these frames), `LIFTED=1` the reason of each
//! rejected candidate's second look (shadow lifted) next to its first's,
//! `MISSCROP=1` a crop of each missed target (`/tmp/crops/miss*.png`),
//! `TRUTHCROP=1` (with `ACCEPTED=1`) of every target; `DESIGN=cross,checker`
//! (preset names or JSON files) runs the design detector; `FRAMES=dir`
//! keeps the frames; `SIZES=120,190` draws targets of those sizes (px,
//! default 40-120), `TARGETS=20` that many per frame (default 30),
//! `MAXPX=400` sets `--max-target-px` (default 200); on clutter,
//! `ONLY=circle` (or `crosshair`) runs that mode alone.

use std::collections::BTreeMap;
use std::io::BufRead;
use std::sync::Mutex;

use gcp_synth::{clutter_scene, printed_scene, render_with_lookalikes, write_image, SampleFormat};
use gcp_synth::{dist, GreyImage};
use gcp_tagger::pipeline::batch::{run_batch, BatchOptions, FrameInput};
use gcp_tagger::pipeline::detect::{DetectorConfig, MarkerType};
use gcp_tagger::pipeline::frame::FrameOptions;
use gcp_tagger::pipeline::georef::TargetCrs;

/// Writes a 3x enlarged crop of `img` around `c` to /tmp/crops/`name`.png.
fn crop(img: &GreyImage, c: (f64, f64), half: usize, name: &str) {
    let x0 = (c.0 as i64 - half as i64).clamp(0, (img.width - 2 * half) as i64) as usize;
    let y0 = (c.1 as i64 - half as i64).clamp(0, (img.height - 2 * half) as i64) as usize;
    let side = 6 * half;
    let mut data = vec![0f32; side * side];
    for y in 0..side {
        for x in 0..side {
            data[y * side + x] = img.data[(y0 + y / 3) * img.width + x0 + x / 3];
        }
    }
    // Mark the centre with a small plus of alternating grey.
    let (cx, cy) = (
        (3.0 * (c.0 - x0 as f64)) as i64,
        (3.0 * (c.1 - y0 as f64)) as i64,
    );
    for d in -4i64..=4 {
        for (x, y) in [(cx + d, cy), (cx, cy + d)] {
            if (0..side as i64).contains(&x) && (0..side as i64).contains(&y) {
                data[y as usize * side + x as usize] = if d % 2 == 0 { 1.0 } else { 0.0 };
            }
        }
    }
    let out = GreyImage {
        width: side,
        height: side,
        data,
    };
    std::fs::create_dir_all("/tmp/crops").unwrap();
    write_image(
        std::path::Path::new(&format!("/tmp/crops/{name}.png")),
        &out,
        SampleFormat::Png,
        None,
    )
    .unwrap();
}

/// The generator's name for a detection mode.
fn kind(mode: MarkerType) -> gcp_synth::TargetKind {
    mode.as_str()
        .parse()
        .expect("the generator draws every mode")
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let clutter = args.get(1).is_some_and(|a| a == "clutter");
    let mode: MarkerType = if clutter {
        MarkerType::Crosshair
    } else {
        args.get(1).map_or("crosshair", |s| s).parse().unwrap()
    };
    let seed0: u64 = args.get(2).map_or(300, |s| s.parse().unwrap());
    let frames: u64 = args.get(3).map_or(4, |s| s.parse().unwrap());
    let dir = tempfile::tempdir().unwrap();
    let log_path = dir.path().join("trace.json");
    let log = std::fs::File::create(&log_path).unwrap();
    tracing_subscriber::fmt()
        .json()
        .with_env_filter("gcp_tagger::pipeline::detect=trace")
        .with_writer(Mutex::new(log))
        .init();
    let expect_m = std::env::var("EXPECT_PX")
        .ok()
        .map(|px| px.parse::<f64>().expect("EXPECT_PX: a number") / 100.0);
    let options = BatchOptions {
        frame: FrameOptions {
            detector: DetectorConfig {
                modes: if clutter {
                    match std::env::var("ONLY") {
                        Ok(m) => vec![m.parse().expect("ONLY: crosshair or circle")],
                        Err(_) => vec![MarkerType::Crosshair, MarkerType::Circle],
                    }
                } else {
                    vec![mode]
                },
                min_target_px: 40.0,
                // As a survey narrows it: targets expected at EXPECT_PX px
                // (a size in metres over a GSD of 1 cm).
                target_size_m: expect_m,
                gsd_cm: expect_m.map(|_| 1.0),
                // DESIGN=cross,checker (preset names or JSON files): look
                // for those designs, found from their description.
                designs: std::env::var("DESIGN")
                    .ok()
                    .map(|list| {
                        list.split(',')
                            .map(|d| {
                                gcp_tagger::pipeline::detect::TargetDesign::from_name_or_file(d)
                                    .expect("DESIGN")
                            })
                            .collect()
                    })
                    .unwrap_or_default(),
                ..DetectorConfig::default()
            },
            tile_size: gcp_tagger::pipeline::frame::PRINTED_TILE_SIZE,
            max_target_px: std::env::var("MAXPX").map_or(200, |v| v.parse().expect("MAXPX")),
            crs: TargetCrs::parse("EPSG:4326").unwrap(),
        },
        threads: 1,
        max_ram_bytes: 2 << 30,
        chips: None,
    };
    // SIZES=lo,hi: target sizes in px (default 40-120); TARGETS=n per frame.
    let sizes = std::env::var("SIZES").map_or((40.0, 120.0), |v| {
        let (lo, hi) = v.split_once(',').expect("SIZES=lo,hi");
        (lo.parse().expect("SIZES"), hi.parse().expect("SIZES"))
    });
    let targets: usize = std::env::var("TARGETS").map_or(30, |v| v.parse().expect("TARGETS"));
    let (mut total, mut missed) = (0, 0);
    let mut errors: [Vec<f64>; 2] = Default::default();
    for seed in seed0..seed0 + frames {
        let scene = if clutter {
            clutter_scene(2400, 1800, 700 + seed)
        } else {
            printed_scene(2400, 1800, targets, kind(mode), sizes, seed)
        };
        let (img, truth, lookalikes) = render_with_lookalikes(&scene).unwrap();
        if let Ok(dir) = std::env::var("FRAMES") {
            // FRAMES=dir: keep each frame, to run the CLI on.
            let path = std::path::Path::new(&dir).join(format!("frame{seed}.png"));
            write_image(&path, &img, SampleFormat::Png, None).unwrap();
        }
        let path = dir.path().join(format!("{mode}{seed}.png"));
        write_image(&path, &img, SampleFormat::Png, None).unwrap();
        std::fs::write(&log_path, b"").unwrap();
        let input = FrameInput {
            path: path.clone(),
            name: "f".into(),
        };
        let result = run_batch(&[input], &options, &|_, _| {})
            .pop()
            .unwrap()
            .unwrap();
        let reasons: Vec<(f64, f64, f64, String)> =
            std::io::BufReader::new(std::fs::File::open(&log_path).unwrap())
                .lines()
                .filter_map(|l| {
                    let v: serde_json::Value = serde_json::from_str(&l.ok()?).ok()?;
                    let f = &v["fields"];
                    Some((
                        f["x"].as_f64()?,
                        f["y"].as_f64()?,
                        f["size"].as_f64().unwrap_or(0.0),
                        match f["lifted"].as_str() {
                            Some(l) if std::env::var("LIFTED").is_ok() => {
                                format!("{} / lifted: {l}", f["why"].as_str()?)
                            }
                            _ => f["why"].as_str()?.to_string(),
                        },
                    ))
                })
                .collect();
        eprintln!(
            "seed {seed}: blur {:.2} motion {:?} noise {:.1}",
            scene.blur_sigma, scene.motion_blur, scene.noise_sigma
        );
        if clutter || std::env::var("ACCEPTED").is_ok() {
            for l in std::fs::read_to_string(&log_path).unwrap().lines() {
                if l.contains("accepted") {
                    eprintln!("  {l}");
                }
            }
        }
        if clutter {
            for (i, d) in result.targets.iter().enumerate() {
                let d = &d.detection;
                // The nearest look-alike painted over the detection, or
                // none: ground, clutter squares or stripes.
                let under = lookalikes
                    .iter()
                    .filter(|l| l.covers(d.center))
                    .min_by(|a, b| dist(a.center, d.center).total_cmp(&dist(b.center, d.center)))
                    .map_or("none".to_string(), |l| format!("{:?}", l.kind));
                eprintln!(
                    "  FP {} at ({:.1},{:.1}) size {:.1} confidence {:.2} rms {:?} on {under}",
                    d.marker_type, d.center.0, d.center.1, d.size_px, d.confidence, d.fit_rms_px
                );
                crop(
                    &img,
                    d.center,
                    (1.5 * d.size_px) as usize,
                    &format!("fp{seed}_{i}"),
                );
            }
        }
        for t in &truth {
            if std::env::var("ACCEPTED").is_ok() {
                eprintln!(
                    "  TRUTH {:.2} {:.2} {:.1} {:?}",
                    t.center.0, t.center.1, t.side_px, scene.printed[t.id as usize].design
                );
                if std::env::var("TRUTHCROP").is_ok() {
                    crop(
                        &img,
                        t.center,
                        (1.5 * t.side_px) as usize,
                        &format!("truth{seed}_{}", t.id),
                    );
                }
            }
            total += 1;
            let hit = result.targets.iter().find(|d| {
                let c = d.detection.center;
                (c.0 - t.center.0).hypot(c.1 - t.center.1) < t.side_px / 2.0
            });
            let spec = &scene.printed[t.id as usize];
            match hit {
                Some(d) => {
                    let c = d.detection.center;
                    let e = (c.0 - t.center.0).hypot(c.1 - t.center.1);
                    if std::env::var("RMS").is_ok() {
                        eprintln!(
                            "HIT rms {:.3} conf {:.2} size {:.1} of {:.1} err {e:.3} {:?}",
                            d.detection.fit_rms_px.unwrap_or(0.0),
                            d.detection.confidence,
                            d.detection.size_px,
                            spec.size_px,
                            spec.design
                        );
                    }
                    errors[(t.id % 2) as usize].push(e);
                    if e > 0.3 {
                        eprintln!(
                            "  imprecise {:?} size {:.0} err {e:.3} contrast {:.2} shadow {} persp {:.3} rms {:?} at ({:.2}, {:.2}) found ({:.2}, {:.2})",
                            spec.design, spec.size_px, spec.contrast, spec.shadow, spec.perspective, d.detection.fit_rms_px,
                            t.center.0, t.center.1, c.0, c.1
                        );
                        if std::env::var("BOARD").is_ok() {
                            let h = gcp_synth::Homography::from_unit_square(&t.corners);
                            let b = [(-0.5, -0.5), (1.5, -0.5), (1.5, 1.5), (-0.5, 1.5)]
                                .map(|p| h.apply(p));
                            for k in 0..4 {
                                let (p, q) = (b[k], b[(k + 1) % 4]);
                                let d = (q.0 - p.0, q.1 - p.1);
                                let l = d.0.hypot(d.1);
                                let n = (-d.1 / l, d.0 / l);
                                let dist =
                                    ((p.0 - t.center.0) * n.0 + (p.1 - t.center.1) * n.1).abs();
                                eprintln!(
                                    "    truth side dist {dist:.2} normal {:.2}",
                                    n.1.atan2(n.0).to_degrees().rem_euclid(180.0)
                                );
                            }
                            eprintln!(
                                "    truth centre {:.2},{:.2} found {:.2},{:.2}",
                                t.center.0, t.center.1, c.0, c.1
                            );
                            crop(
                                &img,
                                t.center,
                                (1.5 * t.side_px) as usize,
                                &format!("imprecise{seed}_{}", t.id),
                            );
                        }
                    }
                }
                None => {
                    missed += 1;
                    if std::env::var("MISSCROP").is_ok() {
                        crop(
                            &img,
                            t.center,
                            (1.5 * t.side_px) as usize,
                            &format!("miss{seed}_{}", t.id),
                        );
                    }
                    let mut why: BTreeMap<String, usize> = BTreeMap::new();
                    let mut each = Vec::new();
                    for (x, y, size, w) in &reasons {
                        let d = (x - t.center.0).hypot(y - t.center.1);
                        if d < t.side_px / 2.0 {
                            *why.entry(w.clone()).or_default() += 1;
                            if d < 0.08 * t.side_px {
                                each.push(format!("{w} (off {d:.1}, size {size:.0})"));
                            }
                        }
                    }

                    eprintln!(
                        "  MISS {:?} at ({:.0},{:.0}) size {:.0} rot {:.0} contrast {:.2} shadow {} persp {:.3}: {why:?}",
                        spec.design, t.center.0, t.center.1, spec.size_px, spec.rotation_deg, spec.contrast, spec.shadow, spec.perspective
                    );
                    eprintln!("    near centre: {}", each.join("; "));
                }
            }
        }
    }
    for (k, e) in errors.iter_mut().enumerate() {
        e.sort_by(f64::total_cmp);
        if !e.is_empty() {
            let q = |p: f64| e[((e.len() - 1) as f64 * p).round() as usize];
            // Truth ids alternate the two designs of the mode.
            eprintln!(
                "  design {k}: {} found of {}, median {:.3} px, p95 {:.3} px",
                e.len(),
                (total + 1 - k) / 2,
                q(0.5),
                q(0.95)
            );
        }
    }
    eprintln!("{mode}: {} of {total} found", total - missed);
}
