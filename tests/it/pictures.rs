//! Chips and previews from the user's side: `detect --chips DIR` on
//! generated frames, the pictures read back with GDAL and the drawn centre
//! found in them.

use std::process::Command;

use gcp_synth::{write_flight, FileKind, FlightSpec};
use gcp_tagger::pipeline::frame::Target;
use gcp_tagger::pipeline::pictures::{chip_window, chip_zoom, Crop};

/// Pixels of the pure red the centre is drawn in: (column, row).
fn red_pixels(path: &std::path::Path) -> (usize, usize, Vec<(usize, usize)>) {
    let ds = gdal::Dataset::open(path).unwrap();
    let (w, h) = ds.raster_size();
    let band = |i| {
        ds.rasterband(i)
            .unwrap()
            .read_as::<u8>((0, 0), (w, h), (w, h), None)
            .unwrap()
            .data()
            .to_vec()
    };
    let (r, g, b) = (band(1), band(2), band(3));
    let red = (0..w * h)
        .filter(|&i| r[i] > 200 && g[i] < 60 && b[i] < 60)
        .map(|i| (i % w, i / w))
        .collect();
    (w, h, red)
}

/// The most common value and how often it comes.
fn mode(values: impl Iterator<Item = usize>) -> (usize, usize) {
    let mut counts = std::collections::BTreeMap::new();
    for v in values {
        *counts.entry(v).or_insert(0usize) += 1;
    }
    counts
        .into_iter()
        .max_by_key(|&(v, n)| (n, std::cmp::Reverse(v)))
        .unwrap()
}

#[test]
fn each_chip_draws_its_centre_on_the_reported_centre_and_the_preview_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    let frames = tmp.path().join("frames");
    write_flight(
        &frames,
        &FlightSpec {
            frames: 2,
            width: 1600,
            height: 1200,
            markers: 4,
            kind: FileKind::Png,
            seed: 62,
            hard: false,
        },
    )
    .unwrap();
    let chips = tmp.path().join("chips");
    let o = Command::new(env!("CARGO_BIN_EXE_gcp-tagger"))
        .args([
            "detect",
            "--marker-type",
            "aruco,apriltag",
            "--crs",
            "EPSG:4326",
            "-q",
        ])
        .arg(&frames)
        .arg("-o")
        .arg(tmp.path().join("out.csv"))
        .arg("--chips")
        .arg(&chips)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The detections as the pipeline reports them, in the results' order.
    let options = crate::support::options(
        "EPSG:4326",
        &[
            gcp_tagger::pipeline::detect::MarkerType::Aruco,
            gcp_tagger::pipeline::detect::MarkerType::AprilTag,
        ],
    );
    let mut checked = 0;
    for image in ["frame_0000.png", "frame_0001.png"] {
        let result = crate::support::run_one(&frames.join(image), &options);
        assert!(!result.targets.is_empty());
        assert!(chips.join(format!("{image}.preview.jpg")).is_file());
        assert!(!chips
            .join(format!("{image}.{}.png", result.targets.len()))
            .exists());
        for (i, Target { detection: d, .. }) in result.targets.iter().enumerate() {
            let path = chips.join(format!("{image}.{i}.png"));
            let (w, h, red) = red_pixels(&path);
            let (x0, y0, side) = chip_window(d);
            let zoom = chip_zoom(side);
            assert_eq!((w, h), (side * zoom, side * zoom));
            // The cross's horizontal arms fill one row, its vertical arms
            // one column: where they lie is the drawn centre.
            let (row, n_row) = mode(red.iter().map(|p| p.1));
            let (col, n_col) = mode(red.iter().map(|p| p.0));
            assert!(
                n_row >= 12 && n_col >= 12,
                "{}: no cross drawn",
                path.display()
            );
            let crop = Crop {
                x0,
                y0,
                side,
                grey: Vec::new(),
            };
            let want = gcp_tagger::pipeline::pictures::to_chip(&crop, zoom, d.center);
            // Within the drawing's own pixel: half a chip pixel, 0.5 / zoom
            // frame pixels.
            assert!(
                (col as f64 - want.0).abs() <= 0.51 && (row as f64 - want.1).abs() <= 0.51,
                "{}: cross at ({col}, {row}), centre at ({:.2}, {:.2})",
                path.display(),
                want.0,
                want.1
            );
            checked += 1;
        }
    }
    assert!(checked >= 6, "only {checked} chips");
}
