//! The `gcp-tagger detect` command as a user runs it: exit codes, one-line
//! errors per bad frame, and identical bytes whatever the thread count.

use std::path::Path;
use std::process::{Command, Output};

use gcp_synth::{sample_geo, SampleFormat};
use gcp_tagger::pipeline::detect::MarkerType;

use crate::support::*;

fn detect(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gcp-tagger"))
        .arg("detect")
        .args(args)
        .output()
        .expect("run gcp-tagger")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A folder with two good frames (one georeferenced) and every kind of bad one.
fn flight_with_bad_frames(dir: &Path) {
    let scene = grid_scene(1200, 900, 4, (36.0, 50.0), MarkerType::AprilTag, "36h11", 9);
    let geo = sample_geo(0);
    write_scene(dir, "good.tif", &scene, SampleFormat::GtiffRgb8, Some(&geo));
    let (jpeg, _) = write_scene(dir, "good.jpg", &scene, SampleFormat::Jpeg, None);
    let bytes = std::fs::read(&jpeg).unwrap();
    std::fs::write(dir.join("truncated.jpg"), &bytes[..bytes.len() / 2]).unwrap();
    std::fs::write(dir.join("empty.png"), b"").unwrap();
    std::fs::write(
        dir.join("corrupt.tif"),
        b"II*\0garbage that is not a tiff at all",
    )
    .unwrap();
    std::fs::write(
        dir.join("notes.jpg"),
        b"these are field notes, not an image\n",
    )
    .unwrap();
    let tiny = gcp_synth::GreyImage {
        width: 16,
        height: 16,
        data: vec![0.5; 256],
    };
    gcp_synth::write_image(&dir.join("tiny.png"), &tiny, SampleFormat::Png, None).unwrap();
}

#[test]
fn bad_frames_fail_alone_with_one_clear_line_each() {
    let dir = tempfile::tempdir().unwrap();
    flight_with_bad_frames(dir.path());
    let out = dir.path().join("out.csv");
    let o = detect(&[
        dir.path().to_str().unwrap(),
        "--crs",
        "EPSG:32611",
        "-o",
        out.to_str().unwrap(),
        "-q",
    ]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(3), "some failed: {err}");
    let expect = [
        ("empty.png", "empty file"),
        ("corrupt.tif", "not a supported image"),
        ("notes.jpg", "not a supported image"),
        ("tiny.png", "below the 32 px minimum"),
    ];
    for (file, cause) in expect {
        let line = err
            .lines()
            .find(|l| l.starts_with(&format!("error: {file}:")))
            .unwrap_or_else(|| panic!("no error line for {file}: {err}"));
        assert!(line.contains(cause), "{line}");
    }
    assert!(
        err.contains("warning: good.jpg: frame has no geotransform"),
        "{err}"
    );
    let csv = std::fs::read_to_string(&out).unwrap();
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    // Cut off half-way: the targets of the rows that decode, as in the
    // whole file, and a warning naming the rows.
    let cut_line = err
        .lines()
        .find(|l| l.starts_with("warning: truncated.jpg: partial: rows "))
        .unwrap_or_else(|| panic!("no partial warning: {err}"));
    let cut: f64 = cut_line["warning: truncated.jpg: partial: rows ".len()..]
        .split("..")
        .next()
        .unwrap()
        .parse()
        .unwrap();
    let pixels = |image: &str| -> Vec<String> {
        rows.iter()
            .filter(|r| r.starts_with(&format!("{image},")))
            .map(|r| r.split(',').skip(2).take(3).collect::<Vec<_>>().join(","))
            .collect()
    };
    let (partial, whole) = (pixels("truncated.jpg"), pixels("good.jpg"));
    assert!(!partial.is_empty() && partial.len() < whole.len(), "{csv}");
    for p in &partial {
        assert!(whole.contains(p), "{p} is not a target of the whole frame");
        let y: f64 = p.split(',').nth(2).unwrap().parse().unwrap();
        assert!(y < cut, "{p} below the cut at {cut}");
    }
    assert_eq!(
        rows.iter()
            .filter(|r| r.starts_with("good.tif,apriltag,"))
            .count(),
        4,
        "{csv}"
    );
    assert_eq!(
        rows.iter()
            .filter(|r| r.starts_with("good.jpg,apriltag,"))
            .count(),
        4,
        "{csv}"
    );
    // World fields filled for the GeoTIFF, empty for the JPEG.
    assert!(rows
        .iter()
        .filter(|r| r.starts_with("good.tif"))
        .all(|r| r.split(',').nth(7) == Some("EPSG:32611")));
    assert!(rows
        .iter()
        .filter(|r| r.starts_with("good.jpg"))
        .all(|r| r.split(',').nth(5) == Some("")));
}

#[test]
fn nothing_usable_and_usage_errors_have_their_own_exit_codes() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("a.jpg"), b"not a jpeg").unwrap();
    let out = dir.path().join("out.csv");
    let o = detect(&[
        dir.path().join("a.jpg").to_str().unwrap(),
        "--crs",
        "EPSG:4326",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(4), "{}", stderr(&o));
    assert!(!out.exists(), "nothing written when nothing is usable");

    // An unknown CRS is refused before any frame is read.
    let o = detect(&[
        dir.path().to_str().unwrap(),
        "--crs",
        "EPSG:999999",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    let err = stderr(&o);
    assert!(
        err.starts_with("error: unknown or invalid CRS \"EPSG:999999\""),
        "{err}"
    );
    assert_eq!(err.lines().count(), 1, "one line: {err}");

    let o = detect(&[
        dir.path().to_str().unwrap(),
        "--crs",
        "EPSG:4326",
        "--marker-type",
        "qr",
        "-o",
        "x.csv",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("unknown marker type \"qr\""),
        "{}",
        stderr(&o)
    );
    let o = detect(&[
        dir.path().to_str().unwrap(),
        "--crs",
        "EPSG:4326",
        "--dictionary",
        "9X9_1",
        "-o",
        "x.csv",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("unknown ArUco dictionary"),
        "{}",
        stderr(&o)
    );

    // Target designs: a bad description or an unknown name is one line
    // naming the file and what is wrong, before any frame is read.
    let design = dir.path().join("design.json");
    std::fs::write(
        &design,
        r#"{"name":"club","kind":"cross","bar_width":[0.3,0.1]}"#,
    )
    .unwrap();
    for (arg, says) in [
        (
            design.to_str().unwrap(),
            "bar_width [0.3, 0.1] must satisfy",
        ),
        ("crosss", "neither a preset (cross, checker, bullseye"),
    ] {
        let o = detect(&[
            dir.path().to_str().unwrap(),
            "--crs",
            "EPSG:4326",
            "--target-design",
            arg,
            "-o",
            "x.csv",
        ]);
        assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
        let err = stderr(&o);
        assert!(err.starts_with("error: ") && err.contains(says), "{err}");
        assert!(err.contains(arg), "names the design: {err}");
        assert_eq!(err.lines().count(), 1, "one line: {err}");
    }
}

/// Same input, same bytes, with one worker or two, CSV and GeoJSON.
#[test]
fn output_bytes_do_not_depend_on_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let frames = dir.path().join("frames");
    std::fs::create_dir(&frames).unwrap();
    for i in 0..4u64 {
        let scene = grid_scene(
            1500,
            1100,
            5,
            (34.0, 56.0),
            MarkerType::AprilTag,
            "36h11",
            50 + i,
        );
        // The last frame has no georeference: its targets have no place.
        let geo = sample_geo(i as usize);
        write_scene(
            &frames,
            &format!("f{i}.tif"),
            &scene,
            SampleFormat::GtiffRgb8,
            (i < 3).then_some(&geo),
        );
    }
    let mut outputs = Vec::new();
    for threads in ["1", "2"] {
        for ext in ["csv", "geojson"] {
            let out = dir.path().join(format!("t{threads}.{ext}"));
            let o = detect(&[
                frames.to_str().unwrap(),
                "--crs",
                "EPSG:4326",
                "--threads",
                threads,
                "-o",
                out.to_str().unwrap(),
                "-q",
            ]);
            assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
            outputs.push(std::fs::read(&out).unwrap());
        }
    }
    assert_eq!(
        outputs[0], outputs[2],
        "CSV differs between 1 and 2 threads"
    );
    assert_eq!(
        outputs[1], outputs[3],
        "GeoJSON differs between 1 and 2 threads"
    );
    let csv = String::from_utf8(outputs[0].clone()).unwrap();
    assert_eq!(csv.lines().count(), 1 + 20, "{csv}");

    // The GeoJSON is a valid FeatureCollection of WGS84 points with the
    // projected coordinates in the properties.
    let gj: serde_json::Value = serde_json::from_slice(&outputs[1]).unwrap();
    assert_eq!(gj["type"], "FeatureCollection");
    let features = gj["features"].as_array().unwrap();
    // The unlocated frame's five stay in the CSV, out of the GeoJSON.
    assert_eq!(features.len(), 15);
    assert_eq!(gj["unlocated_targets"], 5);
    for f in features {
        let c = f["geometry"]["coordinates"].as_array().unwrap();
        let (lon, lat) = (c[0].as_f64().unwrap(), c[1].as_f64().unwrap());
        assert!(
            (-117.1..-116.9).contains(&lon) && (37.0..37.1).contains(&lat),
            "{lon} {lat}"
        );
        assert_eq!(f["properties"]["crs"], "EPSG:4326");
        assert_eq!(f["properties"]["world_x"].as_f64().unwrap(), lon);
    }
}

/// A frame that cannot fit the RAM budget is refused with the numbers.
#[test]
fn frame_larger_than_the_budget_is_refused_with_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let scene = grid_scene(1200, 900, 2, (36.0, 50.0), MarkerType::AprilTag, "36h11", 1);
    let (path, _) = write_scene(dir.path(), "f.png", &scene, SampleFormat::Png, None);
    let out = dir.path().join("o.csv");
    // 0.1 GiB leaves ~6 MiB for frames after the process's base footprint.
    let o = detect(&[
        path.to_str().unwrap(),
        "--crs",
        "EPSG:4326",
        "--max-ram-gb",
        "0.1",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(4));
    let err = stderr(&o);
    assert!(
        err.contains("frame needs about") && err.contains("MiB but the RAM budget for frames is"),
        "{err}"
    );
}

/// The configuration reference documents every `serve` flag with its
/// environment variable, checked against `serve --help` itself.
#[test]
fn the_configuration_reference_matches_serve_help() {
    let help = std::process::Command::new(env!("CARGO_BIN_EXE_gcp-tagger"))
        .args(["serve", "--help"])
        .output()
        .expect("serve --help");
    let help = String::from_utf8(help.stdout).unwrap();
    let section = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/docs/configuration.md"
    ))
    .unwrap();
    let mut flags = 0;
    for line in help.lines().map(str::trim) {
        let Some(flag) = line
            .strip_prefix("--")
            .map(|l| l.split([' ', ',']).next().unwrap())
        else {
            continue;
        };
        if flag == "help" {
            continue;
        }
        flags += 1;
        assert!(
            section.contains(&format!("`--{flag}`")),
            "docs/configuration.md lacks --{flag}"
        );
    }
    let mut vars = 0;
    for var in help
        .split("[env: ")
        .skip(1)
        .map(|s| s.split(['=', ']']).next().unwrap())
    {
        vars += 1;
        assert!(
            section.contains(&format!("`{var}`")),
            "docs/configuration.md lacks {var}"
        );
    }
    assert!(flags >= 12 && vars >= 12, "{flags} flags, {vars} variables");
}
