//! World coordinates against an independent GDAL/PROJ computation
//! (`gdaltransform` on the same file), formats and band layouts.

use std::path::Path;
use std::process::Command;

use gcp_synth::{sample_geo, GeoSpec, SampleFormat};
use gcp_tagger::pipeline::detect::MarkerType;

use crate::support::*;

/// `gdaltransform -t_srs CRS file` on OpenCV pixel coordinates (+0.5 for
/// GDAL's corner convention): the reference world coordinates.
fn gdaltransform(file: &Path, crs: &str, pixels: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let input: String = pixels
        .iter()
        .map(|(x, y)| format!("{} {}\n", x + 0.5, y + 0.5))
        .collect();
    let mut child = Command::new("gdaltransform")
        .args(["-t_srs", crs])
        .arg(file)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("gdaltransform (gdal-bin) is installed by scripts/setup.sh");
    use std::io::Write;
    child
        .stdin
        .take()
        .unwrap()
        .write_all(input.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|t| t.parse().unwrap()).collect();
            (v[0], v[1])
        })
        .collect()
}

fn check_world(
    dir: &Path,
    name: &str,
    format: SampleFormat,
    geo: GeoSpec,
    crs: &str,
    tolerance: f64,
) {
    let scene = grid_scene(
        1400,
        1000,
        6,
        (36.0, 50.0),
        MarkerType::AprilTag,
        "36h11",
        7,
    );
    let (path, truth) = write_scene(dir, name, &scene, format, Some(&geo));
    let result = run_one(&path, &options(crs, &[MarkerType::AprilTag]));
    let m = match_truth(&result.targets, &truth);
    assert!(
        m.missed.is_empty() && m.false_positives.is_empty(),
        "{name}: missed {:?} fp {:?}",
        m.missed,
        m.false_positives
    );
    assert!(result.warnings.is_empty(), "{:?}", result.warnings);
    let pixels: Vec<_> = result.targets.iter().map(|t| t.detection.center).collect();
    let expected = gdaltransform(&path, crs, &pixels);
    for (t, e) in result.targets.iter().zip(&expected) {
        let w = t.world.expect("georeferenced");
        assert!(
            (w.0 - e.0).abs() <= tolerance && (w.1 - e.1).abs() <= tolerance,
            "{name} {crs}: {w:?} vs gdaltransform {e:?}"
        );
    }
    // GeoJSON positions are WGS84 lon/lat, checked the same way.
    let lonlat = gdaltransform(&path, "EPSG:4326", &pixels);
    for (t, e) in result.targets.iter().zip(&lonlat) {
        let g = t.lonlat.expect("lon/lat");
        assert!(
            (g.0 - e.0).abs() < 1e-8 && (g.1 - e.1).abs() < 1e-8,
            "{g:?} vs {e:?}"
        );
    }
}

const MM: f64 = 0.001;
/// 1 mm in degrees of latitude (and less of longitude), for geographic CRSs.
const MM_DEG: f64 = 1e-8;

#[test]
fn utm_geotiff_matches_gdaltransform_in_utm_and_wgs84() {
    let dir = tempfile::tempdir().unwrap();
    let geo = sample_geo(0);
    check_world(
        dir.path(),
        "utm.tif",
        SampleFormat::GtiffRgb8,
        geo.clone(),
        "EPSG:32611",
        MM,
    );
    check_world(
        dir.path(),
        "utm2.tif",
        SampleFormat::GtiffRgb8,
        geo,
        "EPSG:4326",
        MM_DEG,
    );
}

/// ED50 / UTM 31N frames reported in WGS84 / UTM 31N: PROJ applies a datum
/// shift of about 100 m; it must be the same shift GDAL applies.
#[test]
fn datum_shift_matches_gdaltransform() {
    let dir = tempfile::tempdir().unwrap();
    let geo = GeoSpec {
        geotransform: [430_000.0, 0.03, 0.0, 4_580_000.0, 0.0, -0.03],
        epsg: 23031,
    };
    check_world(
        dir.path(),
        "ed50.tif",
        SampleFormat::GtiffRgb8,
        geo.clone(),
        "EPSG:32631",
        MM,
    );
    // And the shift really happened (not a same-numbers pass-through).
    let scene = grid_scene(
        1400,
        1000,
        6,
        (36.0, 50.0),
        MarkerType::AprilTag,
        "36h11",
        7,
    );
    let (path, _) = write_scene(
        dir.path(),
        "ed50b.tif",
        &scene,
        SampleFormat::GtiffRgb8,
        Some(&geo),
    );
    let r = run_one(&path, &options("EPSG:32631", &[MarkerType::AprilTag]));
    let t = &r.targets[0];
    let (gx, gy) = (
        430_000.0 + (t.detection.center.0 + 0.5) * 0.03,
        4_580_000.0 - (t.detection.center.1 + 0.5) * 0.03,
    );
    let w = t.world.unwrap();
    assert!(
        dist(w, (gx, gy)) > 50.0,
        "datum shift applied: {w:?} vs ED50 {gx},{gy}"
    );
}

/// 16-bit 4-band multispectral (R, G, B, inverted NIR): the RGB bands are
/// used with one stretch for the frame, and targets are found as in 8 bits.
#[test]
fn sixteen_bit_four_band_geotiff() {
    let dir = tempfile::tempdir().unwrap();
    let geo = sample_geo(0);
    check_world(
        dir.path(),
        "ms16.tif",
        SampleFormat::Gtiff16Rgbn,
        geo,
        "EPSG:32611",
        MM,
    );
    // The same scene as 8-bit PNG and 16-bit RGBN: the same targets, the
    // same centres. (One 32 px tag here, crossed by two shadow edges, is
    // missed in both: a known recall gap for small shadowed tags.)
    let scene = grid_scene(
        2600,
        2200,
        30,
        (30.0, 60.0),
        MarkerType::AprilTag,
        "36h11",
        11,
    );
    let (p16, truth) = write_scene(
        dir.path(),
        "ms16b.tif",
        &scene,
        SampleFormat::Gtiff16Rgbn,
        None,
    );
    let (p8, _) = write_scene(dir.path(), "ms8b.png", &scene, SampleFormat::Png, None);
    let opts = options("EPSG:4326", &[MarkerType::AprilTag]);
    let (r16, r8) = (run_one(&p16, &opts), run_one(&p8, &opts));
    assert_eq!(r16.targets.len(), r8.targets.len());
    assert!(
        r16.targets.len() + 1 >= truth.len(),
        "{} of {}",
        r16.targets.len(),
        truth.len()
    );
    for (a, b) in r16.targets.iter().zip(&r8.targets) {
        assert_eq!(a.detection.marker_id, b.detection.marker_id);
        assert!(
            dist(a.detection.center, b.detection.center) < 0.05,
            "{a:?} vs {b:?}"
        );
    }
    let m = match_truth(&r16.targets, &truth);
    assert!(m.false_positives.is_empty());
    assert!(quantile(&m.errors, 0.5) <= 0.1 && quantile(&m.errors, 0.95) <= 0.3);
}

/// JPEG and grey+alpha PNG without georeference: pixel results, empty world
/// fields, a warning, no error.
#[test]
fn frames_without_georeference_get_pixel_results_and_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let scene = grid_scene(
        1400,
        1000,
        6,
        (36.0, 50.0),
        MarkerType::AprilTag,
        "36h11",
        3,
    );
    for (name, format) in [
        ("plain.jpg", SampleFormat::Jpeg),
        ("alpha.png", SampleFormat::PngGreyAlpha),
    ] {
        let (path, truth) = write_scene(dir.path(), name, &scene, format, None);
        let r = run_one(&path, &options("EPSG:32611", &[MarkerType::AprilTag]));
        let m = match_truth(&r.targets, &truth);
        assert!(
            m.missed.is_empty() && m.false_positives.is_empty(),
            "{name}"
        );
        assert!(quantile(&m.errors, 0.95) <= 0.3, "{name}: {:?}", m.errors);
        assert!(r
            .targets
            .iter()
            .all(|t| t.world.is_none() && t.lonlat.is_none()));
        assert_eq!(r.warnings.len(), 1, "{:?}", r.warnings);
        assert!(
            r.warnings[0].contains("no geotransform"),
            "{:?}",
            r.warnings
        );
    }
}
