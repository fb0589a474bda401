//! From detections to GCP files: generated flights with a known survey,
//! georeferenced GeoTIFFs and raw JPEGs carrying EXIF GPS and DJI XMP with
//! a known camera pose. Exports are checked byte for byte against files
//! built here from the detections and the survey, and gcp_list.txt is read
//! back with a reader written here.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use gcp_synth::{
    render, write_drone_meta, write_image, Clutter, DroneMeta, GeoSpec, MarkerSpec, PrintedDesign,
    PrintedSpec, SampleFormat, Scene, TargetKind,
};
use gcp_tagger::survey::export::FILES;
use serde_json::Value;

use crate::server::Server;

const GSD: f64 = 0.05;
const W: usize = 1600;
const H: usize = 1200;

/// A target on the ground: where it is, what it is, and how it is surveyed.
struct Ground {
    /// UTM 11N easting, northing.
    at: (f64, f64),
    /// Coded id, or `None` for a printed crosshair.
    id: Option<u32>,
    /// Survey name, or `None` when it is not in the survey.
    name: Option<&'static str>,
}

const GROUND: [Ground; 8] = [
    Ground {
        at: (500025.0, 4099980.0),
        id: Some(3),
        name: Some("GCP3"),
    },
    Ground {
        at: (500070.0, 4099980.0),
        id: Some(7),
        name: Some("CHK7"),
    },
    Ground {
        at: (500025.0, 4099950.0),
        id: Some(11),
        name: Some("GCP11"),
    },
    Ground {
        at: (500070.0, 4099950.0),
        id: Some(15),
        name: Some("GCP15"),
    },
    Ground {
        at: (500047.0, 4099965.0),
        id: Some(29),
        name: None,
    },
    Ground {
        at: (500040.0, 4099975.0),
        id: None,
        name: Some("P1"),
    },
    Ground {
        at: (500058.0, 4099955.0),
        id: None,
        name: Some("P2"),
    },
    Ground {
        at: (500035.0, 4099945.0),
        id: None,
        name: None,
    },
];

/// The survey: GCP11 was surveyed 3 m east of where it lies (60 px at
/// 5 cm), GCP19 is not in any frame, CHK7 is a check point.
const SURVEY: &str = "EPSG:32611\n\
name,marker_id,easting,northing,elevation,role\n\
GCP3,3,500025.000,4099980.000,101.250,control\n\
CHK7,7,500070.000,4099980.000,100.500,check\n\
GCP11,11,500028.000,4099950.000,99.750,control\n\
GCP15,15,500070.000,4099950.000,100.125,control\n\
P1,,500040.000,4099975.000,100.000,control\n\
P2,,500058.000,4099955.000,100.010,control\n\
GCP19,19,500100.000,4099900.000,98.000,control\n";

/// Top-left corners of the three frames (UTM 11N).
const ORIGINS: [(f64, f64); 3] = [
    (500000.0, 4100000.0),
    (500015.0, 4099995.0),
    (500008.0, 4099990.0),
];

fn pixel(origin: (f64, f64), at: (f64, f64)) -> (f64, f64) {
    ((at.0 - origin.0) / GSD - 0.5, (origin.1 - at.1) / GSD - 0.5)
}

fn scene(width: usize, height: usize, seed: u64) -> Scene {
    Scene {
        width,
        height,
        seed,
        blur_sigma: 0.8,
        noise_sigma: 2.0,
        gradient: 0.2,
        shadows: 0,
        clutter: Clutter::default(),
        markers: Vec::new(),
        printed: Vec::new(),
        motion_blur: (0.0, 0.0),
        tag_shadows: 0.0,
    }
}

fn place(scene: &mut Scene, id: Option<u32>, center: (f64, f64), rotation: f64) {
    match id {
        Some(id) => scene.markers.push(MarkerSpec {
            kind: TargetKind::AprilTag,
            dictionary: "36h11".into(),
            id,
            center,
            side_px: 60.0,
            rotation_deg: rotation,
            perspective: 0.0,
        }),
        None => scene.printed.push(PrintedSpec {
            design: PrintedDesign::Cross {
                bar: 0.2,
                marking: gcp_synth::Marking::None,
            },
            center,
            size_px: 70.0,
            rotation_deg: rotation,
            perspective: 0.0,
            contrast: 1.0,
            shadow: false,
        }),
    }
}

/// Renders the three georeferenced frames; returns their paths.
fn georeferenced_flight(dir: &Path) -> Vec<PathBuf> {
    ORIGINS
        .iter()
        .enumerate()
        .map(|(k, &origin)| {
            let mut s = scene(W, H, 40 + k as u64);
            for (i, g) in GROUND.iter().enumerate() {
                place(&mut s, g.id, pixel(origin, g.at), (i * 37 + k * 11) as f64);
            }
            let (img, _) = render(&s).unwrap();
            let path = dir.join(format!("ortho_{k}.tif"));
            let geo = GeoSpec {
                geotransform: [origin.0, GSD, 0.0, origin.1, 0.0, -GSD],
                epsg: 32611,
            };
            write_image(&path, &img, SampleFormat::GtiffRgb8, Some(&geo)).unwrap();
            path
        })
        .collect()
}

fn detect(frames: &[PathBuf], survey: &Path, out: &Path, extra: &[&str]) {
    std::fs::create_dir_all(out).unwrap();
    let status = Command::new(env!("CARGO_BIN_EXE_gcp-tagger"))
        .arg("detect")
        .args(frames)
        .args([
            "--marker-type",
            "apriltag,crosshair",
            "--min-target-px",
            "30",
            "--quiet",
        ])
        .args(["--output"])
        .arg(out.join("results.csv"))
        .arg("--survey")
        .arg(survey)
        .arg("--exports")
        .arg(out)
        .args(extra)
        .status()
        .unwrap();
    assert!(status.success());
}

/// A results.csv row: image, type, id and the pixel text as written.
struct Row {
    image: String,
    marker_type: String,
    id: Option<u32>,
    px: String,
    py: String,
}

fn rows(csv: &str) -> Vec<Row> {
    csv.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            Row {
                image: f[0].into(),
                marker_type: f[1].into(),
                id: f[2].parse().ok(),
                px: f[3].into(),
                py: f[4].into(),
            }
        })
        .collect()
}

/// Survey coordinates' text by point name.
fn survey_text(survey: &str) -> HashMap<String, (String, String, String, String)> {
    survey
        .lines()
        .skip(2)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[0].into(),
                (f[2].into(), f[3].into(), f[4].into(), f[5].into()),
            )
        })
        .collect()
}

/// One observation of a point in gcp_list.txt: image name, pixel x, y.
type Observation = (String, f64, f64);

/// An OpenDroneMap gcp_list.txt reader: the CRS line, then points and
/// their observations; fails on anything ODM would misread.
fn read_gcp_list(text: &str) -> (String, HashMap<String, Vec<Observation>>) {
    let mut lines = text.lines();
    let crs = lines.next().expect("a CRS line").to_string();
    let mut coords: HashMap<String, String> = HashMap::new();
    let mut obs: HashMap<String, Vec<Observation>> = HashMap::new();
    for line in lines {
        let f: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(f.len(), 7, "{line}");
        for v in &f[..5] {
            v.parse::<f64>().unwrap_or_else(|_| panic!("{v} in {line}"));
        }
        let xyz = f[..3].join(" ");
        let name = f[6].to_string();
        // ODM groups observations of a point by its coordinate text.
        if let Some(before) = coords.insert(name.clone(), xyz.clone()) {
            assert_eq!(before, xyz, "{name} written with two coordinate texts");
        }
        obs.entry(name).or_default().push((
            f[5].to_string(),
            f[3].parse().unwrap(),
            f[4].parse().unwrap(),
        ));
    }
    (crs, obs)
}

#[test]
fn georeferenced_frames_give_byte_exact_gcp_files_from_the_cli_and_the_service() {
    let dir = tempfile::tempdir().unwrap();
    let frames = georeferenced_flight(dir.path());
    let survey_path = dir.path().join("survey.csv");
    std::fs::write(&survey_path, SURVEY).unwrap();
    let out = dir.path().join("exports");
    detect(&frames, &survey_path, &out, &["--crs", "EPSG:32611"]);

    // What the exports must say, from the detections and the survey.
    let results = std::fs::read_to_string(out.join("results.csv")).unwrap();
    let coords = survey_text(SURVEY);
    let mut expected_obs: Vec<(String, String, String, String)> = Vec::new(); // image, name, px, py
    let mut not_in_survey = 0;
    let mut outside = 0;
    let mut unnamed = 0;
    for r in rows(&results) {
        let k: usize = r.image[6..7].parse().unwrap();
        let (px, py): (f64, f64) = (r.px.parse().unwrap(), r.py.parse().unwrap());
        let ground = GROUND
            .iter()
            .min_by(|a, b| {
                let (pa, pb) = (pixel(ORIGINS[k], a.at), pixel(ORIGINS[k], b.at));
                (pa.0 - px)
                    .hypot(pa.1 - py)
                    .total_cmp(&(pb.0 - px).hypot(pb.1 - py))
            })
            .unwrap();
        assert_eq!(ground.id, r.id, "{} {} {}", r.image, r.px, r.py);
        match (ground.name, ground.id) {
            (None, Some(_)) => not_in_survey += 1,
            (None, None) => unnamed += 1,
            (Some("GCP11"), _) => outside += 1,
            (Some(name), _) => expected_obs.push((r.image.clone(), name.into(), r.px, r.py)),
        }
        assert_eq!(
            r.marker_type,
            if ground.id.is_some() {
                "apriltag"
            } else {
                "crosshair"
            }
        );
    }
    assert_eq!((not_in_survey, outside, unnamed), (3, 3, 3), "{results}");
    expected_obs.sort();
    assert_eq!(expected_obs.len(), 15, "5 points x 3 frames");

    let mut gcp_list = String::from("EPSG:32611\n");
    let mut pix4d = String::new();
    for (image, name, px, py) in &expected_obs {
        let (x, y, z, role) = &coords[name];
        if role == "control" {
            gcp_list += &format!("{x} {y} {z} {px} {py} {image} {name}\n");
        }
        let (fx, fy): (f64, f64) = (px.parse().unwrap(), py.parse().unwrap());
        pix4d += &format!("{image},{name},{:.3},{:.3}\n", fx + 0.5, fy + 0.5);
    }
    // Metashape: cameras by label, markers in survey order, projections.
    let images = ["ortho_0", "ortho_1", "ortho_2"];
    let mut xml = String::from(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<document version=\"1.5.0\">\n  <chunk>\n    <cameras>\n",
    );
    for (i, label) in images.iter().enumerate() {
        xml += &format!("      <camera id=\"{i}\" label=\"{label}\"/>\n");
    }
    xml += "    </cameras>\n    <markers>\n";
    let order: Vec<&str> = SURVEY
        .lines()
        .skip(2)
        .map(|l| l.split(',').next().unwrap())
        .collect();
    for (i, name) in order.iter().enumerate() {
        let (x, y, z, role) = &coords[*name];
        xml += &format!(
            "      <marker id=\"{i}\" label=\"{name}\">\n        <reference x=\"{x}\" y=\"{y}\" z=\"{z}\" enabled=\"{}\"/>\n      </marker>\n",
            role == "control"
        );
    }
    xml += "    </markers>\n    <frames>\n      <frame>\n        <markers>\n";
    for (i, name) in order.iter().enumerate() {
        let seen: Vec<_> = expected_obs.iter().filter(|o| o.1 == *name).collect();
        if seen.is_empty() {
            continue;
        }
        xml += &format!("          <marker marker_id=\"{i}\">\n");
        for (image, _, px, py) in seen {
            let camera = images.iter().position(|l| image.starts_with(l)).unwrap();
            let (fx, fy): (f64, f64) = (px.parse().unwrap(), py.parse().unwrap());
            xml += &format!(
                "            <location camera_id=\"{camera}\" pinned=\"true\" x=\"{:.3}\" y=\"{:.3}\"/>\n",
                fx + 0.5,
                fy + 0.5
            );
        }
        xml += "          </marker>\n";
    }
    xml += "        </markers>\n      </frame>\n    </frames>\n    <reference>EPSG:32611</reference>\n  </chunk>\n</document>\n";

    let read = |f: &str| std::fs::read_to_string(out.join(f)).unwrap();
    assert_eq!(read("gcp_list.txt"), gcp_list);
    assert_eq!(read("pix4d_marks.csv"), pix4d);
    assert_eq!(read("metashape_markers.xml"), xml);

    // Read back as ODM would: every observation within a pixel of truth.
    let (crs, obs) = read_gcp_list(&read("gcp_list.txt"));
    assert_eq!(crs, "EPSG:32611");
    assert_eq!(obs.len(), 4, "GCP3, GCP15, P1, P2: {obs:?}");
    for (name, list) in &obs {
        assert_eq!(list.len(), 3, "{name}");
        let g = GROUND
            .iter()
            .find(|g| g.name == Some(name.as_str()))
            .unwrap();
        for (image, x, y) in list {
            let k: usize = image[6..7].parse().unwrap();
            let t = pixel(ORIGINS[k], g.at);
            assert!(
                (x - t.0).hypot(y - t.1) < 0.3,
                "{name} in {image}: {x},{y} vs {t:?}"
            );
        }
    }

    // The report: deviations, rejections with reasons, warnings.
    let report: Value = serde_json::from_str(&read("report.json")).unwrap();
    let point = |name: &str| {
        report["points"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["name"] == name)
            .unwrap()
            .clone()
    };
    assert_eq!(point("GCP3")["observations"], 3);
    assert!(point("GCP3")["max_deviation_px"].as_f64().unwrap() < 1.0);
    assert_eq!(point("CHK7")["role"], "check");
    assert_eq!(point("GCP19")["warnings"][0], "not seen in any image");
    assert_eq!(point("GCP11")["observations"], 0);
    let unmatched = report["unmatched"].as_array().unwrap();
    let codes = |code: &str| unmatched.iter().filter(|u| u["code"] == code).count();
    assert_eq!(
        (
            codes("not_in_survey"),
            codes("outside_tolerance"),
            codes("no_point_nearby")
        ),
        (3, 3, 3)
    );
    let far = unmatched
        .iter()
        .find(|u| u["code"] == "outside_tolerance")
        .unwrap();
    let dev = far["deviation_px"].as_f64().unwrap();
    assert!((dev - 60.0).abs() < 1.0, "GCP11 is 3 m = 60 px off: {dev}");
    assert!(far["reason"].as_str().unwrap().contains("GCP11"));

    let geojson: Value = serde_json::from_str(&read("survey_points.geojson")).unwrap();
    let features = geojson["features"].as_array().unwrap();
    assert_eq!(features.len(), 7);
    let lon = features[0]["geometry"]["coordinates"][0].as_f64().unwrap();
    assert!((lon + 117.0).abs() < 0.01, "WGS84 longitude first: {lon}");
    assert_eq!(features[0]["properties"]["observations"], 3);
    let observations = read("observations.csv");
    assert_eq!(observations.lines().count(), 1 + 15 + 9);

    // The service gives the same bytes for the same frames and survey.
    let data = tempfile::tempdir().unwrap();
    let server = Server::start(&data.path().join("d"), &[]);
    let paths: Vec<&Path> = frames.iter().map(|p| p.as_path()).collect();
    let id = server.post_flight(
        "/v1/flights?crs=EPSG:32611&marker_types=apriltag,crosshair&min_target_px=30",
        &paths,
    );
    let r = server
        .client
        .put(server.url(&format!("/v1/flights/{id}/survey")))
        .body(SURVEY)
        .send()
        .unwrap();
    assert_eq!(r.status(), 200);
    let summary: Value = r.json().unwrap();
    assert_eq!(
        (summary["points"].as_u64(), summary["check"].as_u64()),
        (Some(7), Some(1))
    );
    server.wait_flight(&id);
    assert_eq!(summary["exports"].as_array().unwrap().len(), FILES.len());
    for file in FILES {
        let served = server.get_text(&format!("/v1/flights/{id}/exports/{file}"));
        assert_eq!(served, read(file), "{file}");
    }
    // One download: the six files' bytes, the same archive as the CLI's.
    let r = server.get(&format!("/v1/flights/{id}/exports/exports.zip"));
    assert_eq!(r.headers()["content-type"], "application/zip");
    let zipped = r.bytes().unwrap().to_vec();
    assert_eq!(zipped, std::fs::read(out.join("exports.zip")).unwrap());
    let mut archive = zip::ZipArchive::new(std::io::Cursor::new(zipped)).unwrap();
    assert_eq!(archive.len(), FILES.len());
    for (i, file) in FILES.iter().enumerate() {
        let mut entry = archive.by_index(i).unwrap();
        assert_eq!(entry.name(), *file);
        let mut text = String::new();
        std::io::Read::read_to_string(&mut entry, &mut text).unwrap();
        assert_eq!(text, read(file), "{file} in exports.zip");
    }
    // A bad survey line is named.
    let r = server
        .client
        .put(server.url(&format!("/v1/flights/{id}/survey")))
        .body("EPSG:32611\nA 1 2 3\nB 1 x 3\n")
        .send()
        .unwrap();
    let v = crate::server::problem(r, 422, "invalid_survey");
    assert!(
        v["detail"].as_str().unwrap().contains("survey line 3"),
        "{v}"
    );
}

/// Metres per degree of latitude on the sphere the tests assume.
const M_PER_DEG: f64 = 6_371_008.8 * std::f64::consts::PI / 180.0;

/// A nadir camera's pixel of a ground offset (east, north) in metres,
/// derived by hand: image right is (cos yaw, -sin yaw) on the ground,
/// image up is (sin yaw, cos yaw).
fn nadir_pixel(offset: (f64, f64), yaw_deg: f64, gsd: f64) -> (f64, f64) {
    let (s, c) = yaw_deg.to_radians().sin_cos();
    let (e, n) = offset;
    let (cx, cy) = ((2000.0 - 1.0) / 2.0, (1500.0 - 1.0) / 2.0);
    (cx + (e * c - n * s) / gsd, cy - (e * s + n * c) / gsd)
}

#[test]
fn raw_jpegs_are_matched_through_their_exif_and_xmp_pose() {
    let dir = tempfile::tempdir().unwrap();
    let (lat0, lon0) = (37.0_f64, -117.0_f64);
    let (height, focal_px) = (80.0, 3000.0);
    let gsd = height / focal_px;
    let m_lon = M_PER_DEG * lat0.to_radians().cos();
    // Ground points as offsets (east, north) from the first camera.
    let points: [(&str, Option<u32>, (f64, f64)); 3] = [
        ("5", Some(5), (-10.0, 6.0)),
        ("B", None, (12.0, 9.0)),
        ("C", None, (-12.0, -9.0)),
    ];
    // Two frames: the second 5 m east, turned 35 degrees. Their metadata
    // is off as real metadata is: yaw by 1.5 degrees, position by 2 m.
    let poses = [((0.0, 0.0), 0.0), ((5.0, 0.0), 35.0)];
    let mut frames = Vec::new();
    for (k, &(cam, yaw)) in poses.iter().enumerate() {
        let mut s = scene(2000, 1500, 90 + k as u64);
        for (i, (_, id, at)) in points.iter().enumerate() {
            let offset = (at.0 - cam.0, at.1 - cam.1);
            place(
                &mut s,
                *id,
                nadir_pixel(offset, yaw, gsd),
                (i * 29) as f64 + yaw,
            );
        }
        let (img, _) = render(&s).unwrap();
        let path = dir.path().join(format!("DJI_000{k}.JPG"));
        write_image(&path, &img, SampleFormat::Jpeg, None).unwrap();
        write_drone_meta(
            &path,
            &DroneMeta {
                lat: lat0 + cam.1 / M_PER_DEG,
                lon: lon0 + (cam.0 + 2.0) / m_lon,
                abs_alt_m: 180.0,
                rel_alt_m: height,
                gimbal_yaw_deg: yaw + 1.5,
                gimbal_pitch_deg: -90.0,
                gimbal_roll_deg: 0.0,
                flight_yaw_deg: yaw,
                focal_mm: 8.8,
                focal_plane_px_per_cm: focal_px / 0.88,
            },
        )
        .unwrap();
        frames.push(path);
    }
    let mut survey = String::from("EPSG:4326\n");
    for (name, _, at) in &points {
        survey += &format!(
            "{name} {:.9} {:.9} 100.000\n",
            lon0 + at.0 / m_lon,
            lat0 + at.1 / M_PER_DEG
        );
    }
    let survey_path = dir.path().join("survey.txt");
    std::fs::write(&survey_path, &survey).unwrap();
    let out = dir.path().join("exports");
    detect(&frames, &survey_path, &out, &["--crs", "EPSG:4326"]);

    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let obs = report["observations"].as_array().unwrap();
    assert_eq!(obs.len(), 6, "3 points x 2 frames: {report:#}");
    let devs: Vec<String> = obs.iter().map(|o| o["deviation_px"].to_string()).collect();
    eprintln!(
        "raw JPEG deviations from the EXIF/XMP prediction, px: {}",
        devs.join(", ")
    );
    for o in obs {
        assert_eq!(o["basis"], "camera", "{o}");
        let dev = o["deviation_px"].as_f64().unwrap();
        // 2 m of GPS error is 75 px here; the yaw error adds up to 20.
        assert!((40.0..130.0).contains(&dev), "{o}");
        assert!(o["match_confidence"].as_f64().unwrap() > 0.5, "{o}");
    }
    for frame in report["frames"].as_array().unwrap() {
        assert_eq!(frame["basis"], "camera", "{frame}");
    }
    let names: Vec<&str> = obs
        .iter()
        .map(|o| o["gcp_name"].as_str().unwrap())
        .collect();
    assert_eq!(names.iter().filter(|n| **n == "B").count(), 2);
    // Geographic survey: gcp_list.txt writes longitude first.
    let (crs, list) = read_gcp_list(&std::fs::read_to_string(out.join("gcp_list.txt")).unwrap());
    assert_eq!(crs, "EPSG:4326");
    let first = std::fs::read_to_string(out.join("gcp_list.txt")).unwrap();
    let lon: f64 = first
        .lines()
        .nth(1)
        .unwrap()
        .split(' ')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!((lon + 117.0).abs() < 0.01, "{first}");
    assert_eq!(list.len(), 3);
}

#[test]
fn odm_header_forms_name_the_crs_in_crs_and_in_a_surveys_first_line() {
    let dir = tempfile::tempdir().unwrap();
    let frames = georeferenced_flight(dir.path());
    let run = |form: &str, tag: &str| {
        let survey = SURVEY.replacen("EPSG:32611", form, 1);
        let survey_path = dir.path().join(format!("survey_{tag}.csv"));
        std::fs::write(&survey_path, survey).unwrap();
        let out = dir.path().join(format!("exports_{tag}"));
        detect(&frames, &survey_path, &out, &["--crs", form]);
        let read = |f: &str| std::fs::read_to_string(out.join(f)).unwrap();
        (read("results.csv"), read("gcp_list.txt"))
    };
    let (csv, gcp) = run("EPSG:32611", "epsg");
    assert!(csv.contains(",EPSG:32611,"), "{csv}");
    // The first line of OpenDroneMap's own gcp_list.txt files, and its
    // short form: the same CRS, so the same bytes.
    for (form, tag) in [
        (
            "+proj=utm +zone=11 +ellps=WGS84 +datum=WGS84 +units=m +no_defs",
            "proj",
        ),
        ("WGS84 UTM 11N", "odm"),
    ] {
        let (c, g) = run(form, tag);
        assert_eq!(c, csv, "{form}");
        assert_eq!(g, gcp, "{form}");
    }
    // A GNSS receiver's CSV: no CRS line, a crs column on every row.
    let mut lines = SURVEY.lines().skip(1);
    let mut column = format!("{},crs\n", lines.next().unwrap());
    for row in lines {
        column.push_str(&format!("{row},EPSG:32611\n"));
    }
    let survey_path = dir.path().join("survey_column.csv");
    std::fs::write(&survey_path, column).unwrap();
    let out = dir.path().join("exports_column");
    detect(&frames, &survey_path, &out, &["--crs", "EPSG:32611"]);
    assert_eq!(
        std::fs::read_to_string(out.join("gcp_list.txt")).unwrap(),
        gcp
    );
}

/// A frame with neither georeference nor GPS: printed targets cannot be
/// placed, so they cannot be named; the user hears which frame and why, and
/// names them by hand.
#[test]
fn unplaceable_frames_are_said_and_printed_targets_can_be_assigned_by_hand() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = scene(W, H, 77);
    for (i, g) in GROUND.iter().enumerate() {
        place(&mut s, g.id, pixel(ORIGINS[0], g.at), (i * 37) as f64);
    }
    let (img, _) = render(&s).unwrap();
    let frame = dir.path().join("nogps.jpg");
    write_image(&frame, &img, SampleFormat::Jpeg, None).unwrap();
    let survey_path = dir.path().join("survey.csv");
    std::fs::write(&survey_path, SURVEY).unwrap();
    let frames = vec![frame];

    let run = |extra: &[&str], tag: &str| {
        let out = dir.path().join(tag);
        std::fs::create_dir_all(&out).unwrap();
        let o = Command::new(env!("CARGO_BIN_EXE_gcp-tagger"))
            .arg("detect")
            .args(&frames)
            .args([
                "--marker-type",
                "apriltag,crosshair",
                "--min-target-px",
                "30",
            ])
            .args(["--crs", "EPSG:32611", "--quiet", "--output"])
            .arg(out.join("results.csv"))
            .arg("--survey")
            .arg(&survey_path)
            .arg("--exports")
            .arg(&out)
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let gcp = std::fs::read_to_string(out.join("gcp_list.txt")).unwrap();
        (
            String::from_utf8_lossy(&o.stderr).into_owned(),
            read_gcp_list(&gcp).1,
        )
    };
    let (stderr, obs) = run(&[], "plain");
    assert!(
        stderr.contains("nogps.jpg: 3 printed target(s) cannot be named"),
        "{stderr}"
    );
    // Coded targets still match by id.
    assert!(
        obs.contains_key("GCP3") && obs.contains_key("GCP15"),
        "{obs:?}"
    );
    assert!(!obs.contains_key("P1"));

    // P1 named by a click 3 px off: the detection's own centre is kept.
    let at = pixel(ORIGINS[0], GROUND[5].at);
    let assign = dir.path().join("assign.csv");
    std::fs::write(
        &assign,
        format!(
            "name,image,px_x,px_y\nP1,nogps.jpg,{},{}\n",
            at.0 + 3.0,
            at.1 - 1.0
        ),
    )
    .unwrap();
    let (stderr, obs) = run(&["--assign", assign.to_str().unwrap()], "assigned");
    assert!(
        stderr.contains("2 printed target(s) cannot be named"),
        "{stderr}"
    );
    let p1 = &obs["P1"];
    assert_eq!(p1.len(), 1);
    let (px, py): (f64, f64) = (p1[0].1, p1[0].2);
    assert!((px - at.0).hypot(py - at.1) < 0.5, "{px} {py} vs {at:?}");

    // The service: the warning in the report, the assignment by PUT, and
    // the same gcp_list.txt as the command line's.
    let data = tempfile::tempdir().unwrap();
    let server = Server::start(&data.path().join("d"), &[]);
    let id = server.post_flight(
        "/v1/flights?crs=EPSG:32611&marker_types=apriltag,crosshair&min_target_px=30",
        &[frames[0].as_path()],
    );
    let put = |what: &str, body: String| {
        server
            .client
            .put(server.url(&format!("/v1/flights/{id}/{what}")))
            .body(body)
            .send()
            .unwrap()
    };
    let r = put("assignments", "P1,nogps.jpg,1,2\n".into());
    crate::server::problem(r, 404, "no_survey");
    assert_eq!(put("survey", SURVEY.into()).status(), 200);
    server.wait_flight(&id);
    let report = server.get_json(&format!("/v1/flights/{id}/exports/report.json"));
    let warnings = report["warnings"].to_string();
    assert!(
        warnings.contains("nogps.jpg: 3 printed target(s) cannot be named"),
        "{warnings}"
    );
    let r = put("assignments", "P9,nogps.jpg,1,2\n".into());
    let v = crate::server::problem(r, 422, "invalid_assignments");
    assert!(
        v["detail"].as_str().unwrap().contains("P9 is not a point"),
        "{v}"
    );
    let r = put("assignments", std::fs::read_to_string(&assign).unwrap());
    assert_eq!(r.status(), 200);
    assert_eq!(r.json::<Value>().unwrap()["assignments"], 1);
    let served = server.get_text(&format!("/v1/flights/{id}/exports/gcp_list.txt"));
    let cli = std::fs::read_to_string(dir.path().join("assigned/gcp_list.txt")).unwrap();
    assert_eq!(served, cli);
}
