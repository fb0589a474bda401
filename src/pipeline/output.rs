//! Result writers: CSV and GeoJSON (RFC 7946), byte-for-byte deterministic.
//! Rows follow frame order as given (callers sort frames by name), then the
//! frame's own order (type, id, y, x); numbers have fixed decimal places.

use std::fmt::Write as _;
use std::str::FromStr;

use super::frame::{FrameResult, Target};
use super::georef::TargetCrs;

/// Decimal places: pixels to 1/1000 px; metres to 0.1 mm; degrees to ~0.1 mm.
const PX_DECIMALS: usize = 3;
const METRE_DECIMALS: usize = 4;
const DEGREE_DECIMALS: usize = 9;

/// The CSV header; every column is computed for every row or left empty
/// where it does not apply (world fields of frames without georeference,
/// bit errors and decision margin of printed targets, fit RMS of coded ones).
pub const CSV_HEADER: &str = "image,marker_type,marker_id,px_x,px_y,world_x,world_y,crs,size_px,refine_shift_px,refinement,bit_errors,decision_margin,fit_rms_px,confidence,at_edge";

/// Output formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Csv,
    GeoJson,
}

impl Format {
    /// Picks the format from a file name's extension.
    pub fn from_path(path: &std::path::Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        ext.parse().ok()
    }
}

impl FromStr for Format {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "csv" => Ok(Format::Csv),
            "geojson" | "json" => Ok(Format::GeoJson),
            other => Err(format!(
                "unknown output format {other:?} (expected csv or geojson)"
            )),
        }
    }
}

/// Renders frames in `format`.
pub fn render(format: Format, frames: &[FrameResult], crs: &TargetCrs) -> String {
    match format {
        Format::Csv => to_csv(frames, crs),
        Format::GeoJson => to_geojson(frames, crs),
    }
}

fn world_decimals(crs: &TargetCrs) -> usize {
    if crs.geographic {
        DEGREE_DECIMALS
    } else {
        METRE_DECIMALS
    }
}

/// CSV text (RFC 4180 quoting, `\n` line ends).
pub fn to_csv(frames: &[FrameResult], crs: &TargetCrs) -> String {
    let wd = world_decimals(crs);
    let mut out = String::with_capacity(256 * frames.len());
    out.push_str(CSV_HEADER);
    out.push('\n');
    for frame in frames {
        for t in &frame.targets {
            let d = &t.detection;
            let (wx, wy, crs_name) = match t.world {
                Some((x, y)) => (
                    format!("{x:.wd$}"),
                    format!("{y:.wd$}"),
                    csv_field(&crs.name),
                ),
                None => (String::new(), String::new(), String::new()),
            };
            let _ = writeln!(
                out,
                "{},{},{},{:.p$},{:.p$},{},{},{},{:.2},{:.3},{},{},{},{},{:.3},{}",
                csv_text(&frame.image),
                d.marker_type,
                opt(d.marker_id),
                d.center.0,
                d.center.1,
                wx,
                wy,
                crs_name,
                d.size_px,
                d.refine_shift_px,
                d.refinement.as_str(),
                opt(d.bit_errors),
                d.decision_margin
                    .map(|m| format!("{m:.3}"))
                    .unwrap_or_default(),
                d.fit_rms_px.map(|m| format!("{m:.3}")).unwrap_or_default(),
                d.confidence,
                t.at_edge,
                p = PX_DECIMALS,
            );
        }
    }
    out
}

fn opt<T: std::fmt::Display>(v: Option<T>) -> String {
    v.map(|v| v.to_string()).unwrap_or_default()
}

/// Quotes a CSV field when it holds a comma, quote or line break.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// A client-chosen text (a frame's or a GCP's name) as a CSV field: one
/// that starts like a formula (`=`, `+`, `-`, `@`, tab or carriage return)
/// gets a leading `'` so a spreadsheet shows it instead of running it
/// (OWASP, "CSV Injection"), then quoted as any field.
pub fn csv_text(s: &str) -> String {
    if s.starts_with(['=', '+', '-', '@', '\t', '\r']) {
        csv_field(&format!("'{s}"))
    } else {
        csv_field(s)
    }
}

/// A GeoJSON FeatureCollection in WGS84 lon/lat of the targets that have a
/// place. Targets of frames without a georeference stay out (many GIS
/// tools drop null geometries silently, or refuse the file); they are in
/// the CSV and JSON results, and the collection counts them in the foreign
/// member `unlocated_targets` (RFC 7946 §6.1).
pub fn to_geojson(frames: &[FrameResult], crs: &TargetCrs) -> String {
    let unlocated = frames
        .iter()
        .flat_map(|f| &f.targets)
        .filter(|t| t.lonlat.is_none())
        .count();
    let mut out = format!(
        "{{\"type\":\"FeatureCollection\",\"unlocated_targets\":{unlocated},\"features\":["
    );
    let mut first = true;
    for frame in frames {
        for t in frame.targets.iter().filter(|t| t.lonlat.is_some()) {
            if !first {
                out.push(',');
            }
            first = false;
            out.push('\n');
            feature(&mut out, &frame.image, t, crs);
        }
    }
    out.push_str("\n]}\n");
    out
}

fn feature(out: &mut String, image: &str, t: &Target, crs: &TargetCrs) {
    let d = &t.detection;
    let wd = world_decimals(crs);
    let json = |s: &str| serde_json::to_string(s).expect("strings serialize");
    let (lon, lat) = t.lonlat.expect("only located targets are features");
    let geometry = format!(
        "{{\"type\":\"Point\",\"coordinates\":[{lon:.dd$},{lat:.dd$}]}}",
        dd = DEGREE_DECIMALS
    );
    let mut props = vec![
        format!("\"image\":{}", json(image)),
        format!("\"marker_type\":{}", json(d.marker_type.as_str())),
    ];
    if let Some(id) = d.marker_id {
        props.push(format!("\"marker_id\":{id}"));
    }
    props.push(format!(
        "\"px_x\":{:.p$},\"px_y\":{:.p$}",
        d.center.0,
        d.center.1,
        p = PX_DECIMALS
    ));
    if let Some((x, y)) = t.world {
        props.push(format!(
            "\"world_x\":{x:.wd$},\"world_y\":{y:.wd$},\"crs\":{}",
            json(&crs.name)
        ));
    }
    props.push(format!(
        "\"size_px\":{:.2},\"refine_shift_px\":{:.3},\"refinement\":{}",
        d.size_px,
        d.refine_shift_px,
        json(d.refinement.as_str())
    ));
    if let Some(b) = d.bit_errors {
        props.push(format!("\"bit_errors\":{b}"));
    }
    if let Some(m) = d.decision_margin {
        props.push(format!("\"decision_margin\":{m:.3}"));
    }
    if let Some(m) = d.fit_rms_px {
        props.push(format!("\"fit_rms_px\":{m:.3}"));
    }
    props.push(format!("\"confidence\":{:.3}", d.confidence));
    props.push(format!("\"at_edge\":{}", t.at_edge));
    let _ = write!(
        out,
        "{{\"type\":\"Feature\",\"geometry\":{geometry},\"properties\":{{{}}}}}",
        props.join(",")
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_that_start_like_formulas_are_shown_not_run() {
        assert_eq!(csv_text("DJI_0001.JPG"), "DJI_0001.JPG");
        assert_eq!(
            csv_text("=HYPERLINK(\"http://x\",\"a\").jpg"),
            "\"'=HYPERLINK(\"\"http://x\"\",\"\"a\"\").jpg\""
        );
        assert_eq!(csv_text("+1.jpg"), "'+1.jpg");
        assert_eq!(csv_text("-2+3.jpg"), "'-2+3.jpg");
        assert_eq!(csv_text("@SUM(A1).jpg"), "'@SUM(A1).jpg");
        assert_eq!(csv_text("a,b.jpg"), "\"a,b.jpg\"");
    }
}
