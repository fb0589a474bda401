//! Real aerial photos: `../shared/real/copr-dev`, twenty 4272x2848 photos of
//! printed crosses on sand with every sighting listed (`targets.csv`, good to
//! about 1 px). Run as a new user would, `--marker-type crosshair` and the
//! default options (every built-in crosshair design), nothing chosen for
//! this set.

use std::path::PathBuf;

use gcp_tagger::pipeline::detect::MarkerType;

use crate::support::*;

fn real_set() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/real/copr-dev");
    assert!(
        dir.join("targets.csv").is_file(),
        "the real set is expected at {} (the shared folder beside the clone)",
        dir.display()
    );
    dir
}

/// (image, x, y) of every listed sighting.
fn sightings(dir: &std::path::Path) -> Vec<(String, f64, f64)> {
    let text = std::fs::read_to_string(dir.join("targets.csv")).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[0].to_string(),
                f[1].parse().unwrap(),
                f[2].parse().unwrap(),
            )
        })
        .collect()
}

fn real_photos(dir: &std::path::Path) -> Vec<PathBuf> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(dir.join("images"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    paths.sort();
    assert_eq!(paths.len(), 20);
    paths
}

/// The photos hold no AprilTag: the default family and the two whose
/// codes a random quad reads most easily (16h5, Circle21h7, see
/// `corrected_bits`) find nothing among the sand, shrubs and crosses.
#[test]
fn real_photos_without_apriltags_give_no_apriltag() {
    let dir = real_set();
    let paths = real_photos(&dir);
    for family in ["36h11", "16h5", "Circle21h7"] {
        let mut opts = options("EPSG:32611", &[MarkerType::AprilTag]);
        opts.frame.detector.apriltag_family = family.parse().unwrap();
        let found: Vec<String> = run(&paths, &opts)
            .into_iter()
            .flat_map(|o| {
                let frame = o.expect("frame processed");
                let image = frame.image.clone();
                frame
                    .targets
                    .iter()
                    .map(move |t| format!("{image} {:?}", t.detection.center))
                    .collect::<Vec<_>>()
            })
            .collect();
        assert!(found.is_empty(), "{family}: {found:?}");
    }
}

/// At least 32 of the 33 sightings found within 3 px, at most one false
/// detection over the twenty photos.
#[test]
fn printed_crosses_on_real_photos_are_found_with_the_default_options() {
    let dir = real_set();
    let truth = sightings(&dir);
    assert_eq!(truth.len(), 33);
    let paths = real_photos(&dir);
    let opts = options("EPSG:32611", &[MarkerType::Crosshair]);
    let outcomes = run(&paths, &opts);
    let mut found: Vec<(String, (f64, f64))> = Vec::new();
    for outcome in outcomes {
        let frame = outcome.expect("frame processed");
        for t in &frame.targets {
            found.push((frame.image.clone(), t.detection.center));
        }
    }
    let hits = truth
        .iter()
        .filter(|(img, x, y)| {
            found
                .iter()
                .any(|(i, c)| i == img && dist(*c, (*x, *y)) <= 3.0)
        })
        .count();
    let false_detections: Vec<_> = found
        .iter()
        .filter(|(i, c)| {
            !truth
                .iter()
                .any(|(img, x, y)| img == i && dist(*c, (*x, *y)) <= 3.0)
        })
        .collect();
    eprintln!(
        "real set: {hits} of {} sightings within 3 px, {} false: {false_detections:?}",
        truth.len(),
        false_detections.len()
    );
    assert!(hits >= 32, "{hits} of 33 sightings found");
    assert!(false_detections.len() <= 1, "false: {false_detections:?}");
}

/// The same design through the service: a real photo uploaded with
/// `target_design=cross` gives the command line's bytes, with its three
/// sightings among them.
#[test]
fn the_service_finds_the_same_crosses_from_the_design() {
    let dir = real_set();
    let photo = dir.join("images/IMG_0052.jpg");
    let data = tempfile::tempdir().unwrap();
    let server = crate::server::Server::start(&data.path().join("d"), &[]);
    let r = server
        .client
        .post(server.url(
            "/v1/jobs?crs=EPSG:32611&marker_types=crosshair&target_design=cross&name=IMG_0052.jpg",
        ))
        .header("content-type", "image/jpeg")
        .body(std::fs::read(&photo).unwrap())
        .send()
        .unwrap();
    assert_eq!(r.status(), 201);
    let job: serde_json::Value = r.json().unwrap();
    let id = job["id"].as_str().unwrap();
    let done = server.wait_job(id);
    assert_eq!(done["state"], "succeeded", "{done}");
    let csv = server.get_text(&format!("/v1/jobs/{id}/results.csv"));

    let out = data.path().join("cli.csv");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_gcp-tagger"))
        .args(["detect", photo.to_str().unwrap(), "--crs", "EPSG:32611"])
        .args([
            "--marker-type",
            "crosshair",
            "--target-design",
            "cross",
            "-q",
            "-o",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(csv, std::fs::read_to_string(&out).unwrap());

    let truth: Vec<_> = sightings(&dir)
        .into_iter()
        .filter(|(img, _, _)| img == "IMG_0052.jpg")
        .collect();
    assert_eq!(truth.len(), 3);
    let centres: Vec<(f64, f64)> = csv
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[3].parse().unwrap(), f[4].parse().unwrap())
        })
        .collect();
    for (_, x, y) in &truth {
        assert!(
            centres.iter().any(|c| dist(*c, (*x, *y)) <= 3.0),
            "({x}, {y}) not in {csv}"
        );
    }
}
