//! Files photogrammetry software reads, from a survey and the matcher's
//! decisions. Every writer is deterministic: observations sorted by image
//! then point, fixed decimals, `\n` line ends.
//!
//! Pixel conventions: OpenDroneMap's `gcp_list.txt` uses OpenCV's (top-left
//! pixel centre at 0,0), as detections do. Pix4D marks and Metashape put
//! the origin at the image's top-left corner, so their coordinates are
//! 0.5 px larger.

use std::fmt::Write;

use serde_json::json;

use crate::pipeline::georef::{GeorefError, Transformer, WGS84};
use crate::pipeline::output::csv_text;

use super::matching::{point_reports, Matched, Observation, PointReport};
use super::{Role, Survey};

/// The export files, by the name they are served and written under.
pub const FILES: [&str; 6] = [
    "gcp_list.txt",
    "pix4d_marks.csv",
    "metashape_markers.xml",
    "survey_points.geojson",
    "observations.csv",
    "report.json",
];

/// The one-download bundle of every export file.
pub const BUNDLE: &str = "exports.zip";

/// The export files in one zip archive, in [`FILES`] order, deflated, with
/// a fixed date and mode: the same files give the same bytes.
pub fn bundle(files: &[(&str, String)]) -> Vec<u8> {
    use std::io::Write;
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let options = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated)
        .last_modified_time(zip::DateTime::default())
        .unix_permissions(0o644);
    for (name, text) in files {
        zip.start_file(*name, options)
            .and_then(|()| zip.write_all(text.as_bytes()).map_err(Into::into))
            .expect("writing to memory");
    }
    zip.finish().expect("writing to memory").into_inner()
}

/// Observations sorted by image, then point name.
fn sorted<'a>(matched: &'a Matched, role: Option<Role>, survey: &Survey) -> Vec<&'a Observation> {
    let mut obs: Vec<&Observation> = matched
        .observations
        .iter()
        .filter(|o| role.is_none_or(|r| survey.points[o.point].role == r))
        .collect();
    obs.sort_by(|a, b| a.image.cmp(&b.image).then(a.gcp_name.cmp(&b.gcp_name)));
    obs
}

/// OpenDroneMap `gcp_list.txt`: the CRS line, then `geo_x geo_y geo_z im_x
/// im_y image_name gcp_name` for every observation of a control point.
/// Coordinates are the survey file's own text, so every observation of a
/// point carries byte-identical coordinates (ODM groups by that text);
/// x is easting or longitude.
pub fn gcp_list(survey: &Survey, matched: &Matched) -> String {
    let mut out = format!("{}\n", odm_crs(&survey.crs));
    for o in sorted(matched, Some(Role::Control), survey) {
        let p = &survey.points[o.point];
        let _ = writeln!(
            out,
            "{} {} {} {:.3} {:.3} {} {}",
            p.text[0], p.text[1], p.text[2], o.px, o.py, o.image, p.name
        );
    }
    out
}

/// The CRS line ODM reads: `EPSG:n` when the CRS has one, else a PROJ
/// string as given (WKT goes through unchanged: ODM reads that too).
fn odm_crs(crs: &str) -> String {
    let t = crs.trim();
    if t.len() > 5 && t[..5].eq_ignore_ascii_case("EPSG:") {
        format!("EPSG:{}", &t[5..])
    } else {
        t.replace('\n', " ")
    }
}

/// Pix4D marks: `image,label,x,y`, corner-origin pixels, control and check
/// points alike (Pix4D tells them apart by its own GCP table).
pub fn pix4d_marks(survey: &Survey, matched: &Matched) -> String {
    let mut out = String::new();
    for o in sorted(matched, None, survey) {
        let _ = writeln!(
            out,
            "{},{},{:.3},{:.3}",
            o.image,
            o.gcp_name,
            o.px + 0.5,
            o.py + 0.5
        );
    }
    out
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Metashape markers (File > Import > Import Markers): cameras by label
/// (the image name without its extension), markers with their reference
/// coordinates (check points with the reference disabled), and one pinned
/// projection per observation, corner-origin pixels.
pub fn metashape_markers(survey: &Survey, matched: &Matched) -> String {
    let obs = sorted(matched, None, survey);
    let mut images: Vec<&str> = obs.iter().map(|o| o.image.as_str()).collect();
    images.sort();
    images.dedup();
    let mut out = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    out.push_str("<document version=\"1.5.0\">\n  <chunk>\n    <cameras>\n");
    for (id, image) in images.iter().enumerate() {
        let label = image.rsplit_once('.').map_or(*image, |(stem, _)| stem);
        let _ = writeln!(
            out,
            "      <camera id=\"{id}\" label=\"{}\"/>",
            xml_escape(label)
        );
    }
    out.push_str("    </cameras>\n    <markers>\n");
    for (id, p) in survey.points.iter().enumerate() {
        let _ = writeln!(
            out,
            "      <marker id=\"{id}\" label=\"{}\">\n        <reference x=\"{}\" y=\"{}\" z=\"{}\" enabled=\"{}\"/>\n      </marker>",
            xml_escape(&p.name),
            p.text[0],
            p.text[1],
            p.text[2],
            p.role == Role::Control
        );
    }
    out.push_str("    </markers>\n    <frames>\n      <frame>\n        <markers>\n");
    for (id, _) in survey.points.iter().enumerate() {
        let mine: Vec<&&Observation> = obs.iter().filter(|o| o.point == id).collect();
        if mine.is_empty() {
            continue;
        }
        let _ = writeln!(out, "          <marker marker_id=\"{id}\">");
        for o in mine {
            let camera = images.iter().position(|i| *i == o.image).unwrap_or(0);
            let _ = writeln!(
                out,
                "            <location camera_id=\"{camera}\" pinned=\"true\" x=\"{:.3}\" y=\"{:.3}\"/>",
                o.px + 0.5,
                o.py + 0.5
            );
        }
        out.push_str("          </marker>\n");
    }
    let _ = write!(
        out,
        "        </markers>\n      </frame>\n    </frames>\n    <reference>{}</reference>\n  </chunk>\n</document>\n",
        xml_escape(&odm_crs(&survey.crs))
    );
    out
}

/// The survey's points could not be brought to WGS84 (for the GeoJSON).
#[derive(Debug, thiserror::Error)]
#[error("survey to WGS84: {0}")]
pub struct ProjectionError(#[from] GeorefError);

/// Survey points as GeoJSON (WGS84 longitude, latitude) with their
/// observation counts, deviations and warnings.
pub fn survey_geojson(
    survey: &Survey,
    reports: &[PointReport],
    transformer: &mut Transformer,
) -> Result<String, ProjectionError> {
    let mut lonlat: Vec<(f64, f64)> = survey.points.iter().map(|p| (p.x, p.y)).collect();
    transformer.transform(&survey.crs, WGS84, &mut lonlat)?;
    let features: Vec<serde_json::Value> = survey
        .points
        .iter()
        .zip(reports)
        .zip(&lonlat)
        .map(|((p, r), &(lon, lat))| {
            json!({
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": [round(lon, 9), round(lat, 9), p.z]},
                "properties": {
                    "name": p.name,
                    "marker_id": p.marker_id,
                    "role": p.role,
                    "x": p.x, "y": p.y, "z": p.z,
                    "crs": survey.crs,
                    "observations": r.observations,
                    "images": r.images,
                    "mean_deviation_px": r.mean_deviation_px.map(|d| round(d, 3)),
                    "max_deviation_px": r.max_deviation_px.map(|d| round(d, 3)),
                    "warnings": r.warnings,
                }
            })
        })
        .collect();
    let doc = json!({"type": "FeatureCollection", "features": features});
    Ok(serde_json::to_string_pretty(&doc).expect("json") + "\n")
}

fn round(v: f64, decimals: i32) -> f64 {
    let f = 10f64.powi(decimals);
    (v * f).round() / f
}

/// Every detection with what became of it: `image,marker_type,marker_id,
/// px,py,gcp_name,role,deviation_px,match_confidence,status,reason`.
pub fn observations_csv(survey: &Survey, matched: &Matched) -> String {
    let mut rows: Vec<(String, f64, f64, String)> = Vec::new();
    let num = |v: Option<f64>| v.map(|d| format!("{d:.3}")).unwrap_or_default();
    let id = |v: Option<u32>| v.map(|i| i.to_string()).unwrap_or_default();
    for o in &matched.observations {
        let role = match survey.points[o.point].role {
            Role::Control => "control",
            Role::Check => "check",
        };
        rows.push((
            o.image.clone(),
            o.py,
            o.px,
            format!(
                "{},{},{},{:.3},{:.3},{},{role},{},{:.3},matched,",
                csv_text(&o.image),
                o.marker_type,
                id(o.marker_id),
                o.px,
                o.py,
                csv_text(&o.gcp_name),
                num(o.deviation_px),
                o.match_confidence
            ),
        ));
    }
    for u in &matched.unmatched {
        rows.push((
            u.image.clone(),
            u.py,
            u.px,
            format!(
                "{},{},{},{:.3},{:.3},{},,{},,{},{}",
                csv_text(&u.image),
                u.marker_type,
                id(u.marker_id),
                u.px,
                u.py,
                csv_text(u.gcp_name.as_deref().unwrap_or("")),
                num(u.deviation_px),
                u.code,
                csv_text(&u.reason)
            ),
        ));
    }
    rows.sort_by(|a, b| {
        a.0.cmp(&b.0)
            .then(a.1.total_cmp(&b.1))
            .then(a.2.total_cmp(&b.2))
    });
    let mut out = String::from(
        "image,marker_type,marker_id,px,py,gcp_name,role,deviation_px,match_confidence,status,reason\n",
    );
    for (_, _, _, row) in rows {
        out.push_str(&row);
        out.push('\n');
    }
    out
}

/// Rounds pixel figures to 0.001 px and confidences to 0.0001 throughout a
/// report, so it reads cleanly and is the same bytes wherever it is made.
fn round_figures(v: &mut serde_json::Value) {
    match v {
        serde_json::Value::Object(map) => {
            for (key, value) in map.iter_mut() {
                let decimals = match key.as_str() {
                    "px" | "py" | "deviation_px" | "mean_deviation_px" | "max_deviation_px" => 3,
                    "match_confidence" => 4,
                    _ => {
                        round_figures(value);
                        continue;
                    }
                };
                if let Some(f) = value.as_f64() {
                    *value = json!(round(f, decimals));
                }
            }
        }
        serde_json::Value::Array(items) => items.iter_mut().for_each(round_figures),
        _ => {}
    }
}

/// The per-point report with every decision, as JSON.
pub fn report_json(
    survey: &Survey,
    matched: &Matched,
    reports: &[PointReport],
    tolerance_px: f64,
) -> String {
    let mut doc = json!({
        "survey_crs": survey.crs,
        "pixel_tolerance": tolerance_px,
        "points": reports,
        "frames": matched.frames,
        "observations": matched.observations,
        "unmatched": matched.unmatched,
        "warnings": matched.warnings,
    });
    round_figures(&mut doc);
    serde_json::to_string_pretty(&doc).expect("json") + "\n"
}

/// All export files for a matched flight, in [`FILES`] order.
pub fn all(
    survey: &Survey,
    matched: &Matched,
    tolerance_px: f64,
    transformer: &mut Transformer,
) -> Result<Vec<(&'static str, String)>, ProjectionError> {
    let reports = point_reports(survey, matched);
    Ok(vec![
        (FILES[0], gcp_list(survey, matched)),
        (FILES[1], pix4d_marks(survey, matched)),
        (FILES[2], metashape_markers(survey, matched)),
        (FILES[3], survey_geojson(survey, &reports, transformer)?),
        (FILES[4], observations_csv(survey, matched)),
        (
            FILES[5],
            report_json(survey, matched, &reports, tolerance_px),
        ),
    ])
}
