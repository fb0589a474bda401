//! Shared helpers: render frames with known truth, run the pipeline, and
//! match detections to truth.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

use gcp_synth::{
    render, write_image, Clutter, GeoSpec, Grid, MarkerSpec, Rng, SampleFormat, Scene, Truth,
};
use gcp_tagger::pipeline::batch::{run_batch, BatchOptions, FrameInput, FrameOutcome};
use gcp_tagger::pipeline::detect::{DetectorConfig, MarkerType};
use gcp_tagger::pipeline::frame::{FrameOptions, FrameResult, Target};
use gcp_tagger::pipeline::georef::TargetCrs;

/// Default options for a pipeline run in tests.
pub fn options(crs: &str, modes: &[MarkerType]) -> BatchOptions {
    BatchOptions {
        frame: FrameOptions {
            detector: DetectorConfig {
                modes: modes.to_vec(),
                ..DetectorConfig::default()
            },
            tile_size: gcp_tagger::pipeline::frame::default_tile_size(modes),
            max_target_px: 200,
            crs: TargetCrs::parse(crs).expect("valid test CRS"),
        },
        threads: 2,
        max_ram_bytes: 2 << 30,
        chips: None,
    }
}

/// Runs the pipeline on `paths` (named by file name).
pub fn run(paths: &[PathBuf], options: &BatchOptions) -> Vec<FrameOutcome> {
    let inputs: Vec<FrameInput> = paths
        .iter()
        .map(|p| FrameInput {
            path: p.clone(),
            name: p.file_name().unwrap().to_string_lossy().into_owned(),
        })
        .collect();
    run_batch(&inputs, options, &|_, _| {})
}

pub fn run_one(path: &Path, options: &BatchOptions) -> FrameResult {
    run(&[path.to_path_buf()], options)
        .pop()
        .unwrap()
        .expect("frame processed")
}

/// Renders `scene` and writes it to `dir/name`.
pub fn write_scene(
    dir: &Path,
    name: &str,
    scene: &Scene,
    format: SampleFormat,
    geo: Option<&GeoSpec>,
) -> (PathBuf, Vec<Truth>) {
    let (img, truth) = render(scene).expect("render");
    let path = dir.join(name);
    write_image(&path, &img, format, geo).expect("write frame");
    (path, truth)
}

/// Renders each `(name, scene)` side by side (a thread each) and writes it
/// to `dir/name`, in order.
pub fn write_scenes(
    dir: &Path,
    scenes: &[(String, Scene)],
    format: SampleFormat,
) -> Vec<(PathBuf, Vec<Truth>)> {
    std::thread::scope(|s| {
        let renders: Vec<_> = scenes
            .iter()
            .map(|(name, scene)| s.spawn(move || write_scene(dir, name, scene, format, None)))
            .collect();
        renders.into_iter().map(|r| r.join().unwrap()).collect()
    })
}

/// A scene of `count` markers with sides in `sides`, on a grid with random
/// jitter, rotation and mild perspective; moderate blur and noise.
pub fn grid_scene(
    width: usize,
    height: usize,
    count: usize,
    sides: (f64, f64),
    marker_type: MarkerType,
    dictionary: &str,
    seed: u64,
) -> Scene {
    let mut rng = Rng::new(seed);
    let grid = Grid::new(width, height, count);
    let markers = (0..count)
        .map(|i| MarkerSpec {
            kind: kind(marker_type),
            dictionary: dictionary.to_string(),
            id: (i as u32 * 3 + 1) % 30,
            center: grid.position(i, 0.15, &mut rng),
            side_px: rng.range(sides.0, sides.1),
            rotation_deg: rng.range(0.0, 360.0),
            perspective: rng.range(0.0, 0.05),
        })
        .collect();
    Scene {
        width,
        height,
        seed,
        blur_sigma: 0.8,
        noise_sigma: 3.0,
        gradient: 0.3,
        shadows: 2,
        clutter: Clutter {
            squares: 15,
            circles: 10,
            stripes: 4,
            lookalikes: 0,
        },
        markers,
        printed: Vec::new(),
        motion_blur: (0.0, 0.0),
        tag_shadows: 0.0,
    }
}

/// Centre errors of the detections matched to truth, plus unmatched truth
/// and detections that match no truth (wrong id or false positive).
pub struct Matching {
    pub errors: Vec<f64>,
    pub missed: Vec<Truth>,
    pub false_positives: Vec<Target>,
}

/// The generator's name for a detection mode.
pub fn kind(mode: MarkerType) -> gcp_synth::TargetKind {
    mode.as_str()
        .parse()
        .expect("the generator draws every mode")
}

pub fn match_truth(targets: &[Target], truth: &[Truth]) -> Matching {
    let mut used = vec![false; targets.len()];
    let mut errors = Vec::new();
    let mut missed = Vec::new();
    for t in truth {
        let best = targets
            .iter()
            .enumerate()
            .filter(|(i, d)| {
                !used[*i]
                    && kind(d.detection.marker_type) == t.kind
                    && (d.detection.marker_id == Some(t.id) || !d.detection.marker_type.is_coded())
                    && dist(d.detection.center, t.center) < t.side_px / 2.0
            })
            .min_by(|a, b| {
                dist(a.1.detection.center, t.center)
                    .total_cmp(&dist(b.1.detection.center, t.center))
            });
        match best {
            Some((i, d)) => {
                used[i] = true;
                errors.push(dist(d.detection.center, t.center));
            }
            None => missed.push(t.clone()),
        }
    }
    let false_positives = targets
        .iter()
        .zip(&used)
        .filter(|(_, u)| !**u)
        .map(|(t, _)| t.clone())
        .collect();
    Matching {
        errors,
        missed,
        false_positives,
    }
}

pub fn dist(a: (f64, f64), b: (f64, f64)) -> f64 {
    (a.0 - b.0).hypot(a.1 - b.1)
}

/// The p-quantile (0..=1) of `v`, nearest rank.
pub fn quantile(v: &[f64], p: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[((s.len() - 1) as f64 * p).round() as usize]
}
