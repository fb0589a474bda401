//! Targets across tile seams and at frame edges, clutter, and ArUco.

use std::path::PathBuf;

use gcp_synth::{Clutter, MarkerSpec, SampleFormat, Scene, TargetKind};
use gcp_tagger::pipeline::detect::{ArucoDictionary, MarkerType};

use crate::support::*;

fn marker(id: u32, center: (f64, f64), side: f64, rot: f64) -> MarkerSpec {
    MarkerSpec {
        kind: TargetKind::AprilTag,
        dictionary: "36h11".into(),
        id,
        center,
        side_px: side,
        rotation_deg: rot,
        perspective: 0.02,
    }
}

/// Small tiles (512 px, overlap 133 px) so that many seams cross the frame;
/// markers placed exactly on seams and where tiles overlap twice, and near
/// every frame edge: each found exactly once.
#[test]
fn targets_on_seams_and_edges_are_found_once() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (1600usize, 1200usize);
    let mut opts = options("EPSG:4326", &[MarkerType::AprilTag]);
    opts.frame.tile_size = 512;
    opts.frame.max_target_px = 100;
    let grid = gcp_tagger::pipeline::tiles::TileGrid::new(w, h, 512, opts.frame.overlap());
    let mut markers = Vec::new();
    let mut id = 0;
    // On each vertical seam (a tile's right border) and horizontal seam.
    for &x in &grid.xs[1..] {
        markers.push(marker(
            id,
            (x as f64 + 2.0, 300.0 + 37.0 * id as f64),
            44.0,
            17.0 * id as f64,
        ));
        id += 1;
    }
    for &y in &grid.ys[1..] {
        markers.push(marker(
            id,
            (900.0 + 23.0 * id as f64, y as f64 + 3.0),
            40.0,
            11.0 * id as f64,
        ));
        id += 1;
    }
    // Where four tiles meet.
    markers.push(marker(
        id,
        (grid.xs[1] as f64 + 60.0, grid.ys[1] as f64 + 60.0),
        48.0,
        33.0,
    ));
    id += 1;
    // Near the four frame edges: quiet zone 3 px from the border.
    for (cx, cy) in [
        (30.0, 600.0),
        (w as f64 - 31.0, 500.0),
        (700.0, 30.0),
        (500.0, h as f64 - 31.0),
    ] {
        markers.push(marker(id, (cx, cy), 40.0, 0.0));
        id += 1;
    }
    let scene = Scene {
        width: w,
        height: h,
        seed: 5,
        blur_sigma: 0.8,
        noise_sigma: 3.0,
        gradient: 0.2,
        shadows: 0,
        clutter: Clutter::default(),
        markers,
        printed: Vec::new(),
        motion_blur: (0.0, 0.0),
        tag_shadows: 0.0,
    };
    let (path, truth) = write_scene(dir.path(), "seams.png", &scene, SampleFormat::Png, None);
    let r = run_one(&path, &opts);
    let m = match_truth(&r.targets, &truth);
    assert!(m.missed.is_empty(), "missed {:?}", m.missed);
    assert!(
        m.false_positives.is_empty(),
        "duplicates or false positives {:?}",
        m.false_positives
    );
    assert!(quantile(&m.errors, 0.95) <= 0.3, "{:?}", m.errors);
    assert!(r.targets.iter().all(|t| !t.at_edge));
}

/// Frames full of squares, rings and bars but no target: nothing reported.
#[test]
fn clutter_only_frames_have_no_detections() {
    let dir = tempfile::tempdir().unwrap();
    let scene = |seed: u64| Scene {
        width: 2400,
        height: 1800,
        seed: 900 + seed,
        blur_sigma: 0.8,
        noise_sigma: 3.0,
        gradient: 0.3,
        shadows: 2,
        clutter: Clutter {
            squares: 250,
            circles: 120,
            stripes: 30,
            lookalikes: 0,
        },
        markers: vec![],
        printed: Vec::new(),
        motion_blur: (0.0, 0.0),
        tag_shadows: 0.0,
    };
    let scenes: Vec<(String, Scene)> = (0..3)
        .map(|seed| (format!("clutter{seed}.jpg"), scene(seed)))
        .collect();
    let paths: Vec<PathBuf> = write_scenes(dir.path(), &scenes, SampleFormat::Jpeg)
        .into_iter()
        .map(|(path, _)| path)
        .collect();
    let outcomes = run(
        &paths,
        &options("EPSG:4326", &[MarkerType::AprilTag, MarkerType::Aruco]),
    );
    for (path, outcome) in paths.iter().zip(outcomes) {
        let r = outcome.expect("frame processed");
        assert!(r.targets.is_empty(), "{}: {:?}", path.display(), r.targets);
    }
}

/// ArUco markers of a named dictionary next to AprilTags: each mode reports
/// only its own markers, with the right ids.
#[test]
fn aruco_and_apriltag_in_one_frame() {
    let dir = tempfile::tempdir().unwrap();
    let mut scene = grid_scene(
        1800,
        1400,
        12,
        (34.0, 56.0),
        MarkerType::AprilTag,
        "36h11",
        21,
    );
    for (i, m) in scene.markers.iter_mut().enumerate() {
        if i % 2 == 0 {
            m.kind = TargetKind::Aruco;
            m.dictionary = "5X5_100".into();
            m.id = 40 + i as u32;
        }
    }
    let (path, truth) = write_scene(dir.path(), "mixed.png", &scene, SampleFormat::Png, None);
    let mut opts = options("EPSG:4326", &[MarkerType::AprilTag, MarkerType::Aruco]);
    opts.frame.detector.aruco_dictionary = "5X5_100".parse::<ArucoDictionary>().unwrap();
    let r = run_one(&path, &opts);
    let m = match_truth(&r.targets, &truth);
    assert!(m.missed.is_empty(), "missed {:?}", m.missed);
    assert!(
        m.false_positives.is_empty(),
        "false positives {:?}",
        m.false_positives
    );
    assert!(
        quantile(&m.errors, 0.5) <= 0.1 && quantile(&m.errors, 0.95) <= 0.3,
        "{:?}",
        m.errors
    );
}
