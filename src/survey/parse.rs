//! Survey files as field crews write them:
//!
//! - CSV with a header naming the columns (`name,marker_id,x,y,z,role`;
//!   also `id/label/point`, `easting/lon/longitude`, `northing/lat/latitude`,
//!   `elevation/height/alt`, `type/kind`); comma, semicolon or tab.
//! - Whitespace lines `name easting northing elevation [role]`.
//!
//! An optional first line names the CRS (`EPSG:32611`, `+proj=...`, WKT);
//! a CRS given as a parameter wins. `#` starts a comment. A name made of
//! digits doubles as the marker id when no marker id column is given. Every
//! bad line is an error naming the line.

use crate::pipeline::georef::TargetCrs;

use super::{Role, Survey, SurveyPoint};

/// Why a survey cannot be used; the message names the line.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct SurveyError(pub String);

/// Most points in one survey.
pub const MAX_POINTS: usize = 10_000;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Column {
    Name,
    MarkerId,
    X,
    Y,
    Z,
    Role,
    /// A CRS per row, as GNSS receivers export (every row the same).
    Crs,
    Other,
}

fn column(header: &str) -> Column {
    match header
        .trim()
        .trim_matches('"')
        .to_ascii_lowercase()
        .as_str()
    {
        "name" | "id" | "label" | "point" | "gcp" | "gcp_name" | "point_name" => Column::Name,
        "marker_id" | "marker" | "tag" | "tag_id" | "code" => Column::MarkerId,
        "x" | "e" | "easting" | "lon" | "long" | "longitude" => Column::X,
        "y" | "n" | "northing" | "lat" | "latitude" => Column::Y,
        "z" | "h" | "elevation" | "elev" | "height" | "alt" | "altitude" => Column::Z,
        "role" | "type" | "kind" | "use" => Column::Role,
        "crs" | "srs" | "epsg" | "coordinate_system" => Column::Crs,
        _ => Column::Other,
    }
}

/// The CRS of a survey that names it on every row (a `crs` column): one
/// value throughout (a bare number is an EPSG code), or an error naming
/// the first rows that differ or lack it.
fn column_crs(rows: &[(usize, String)], points: usize) -> Result<String, SurveyError> {
    let Some((first_line, first)) = rows.first() else {
        return Err(SurveyError(
            "the survey names no CRS: give a first line like EPSG:32611, a crs column, or the crs parameter"
                .into(),
        ));
    };
    if rows.len() < points {
        return Err(SurveyError(format!(
            "the survey's crs column is empty on {} of {points} rows: give it on every row, or a first line like EPSG:32611",
            points - rows.len()
        )));
    }
    let normal = |v: &str| {
        let v = v.trim();
        if !v.is_empty() && v.bytes().all(|b| b.is_ascii_digit()) {
            format!("EPSG:{v}")
        } else {
            v.to_string()
        }
    };
    if let Some((line, other)) = rows.iter().find(|(_, v)| normal(v) != normal(first)) {
        return Err(SurveyError(format!(
            "survey lines {first_line} and {line} name different CRSs ({first:?}, {other:?}): one survey, one CRS"
        )));
    }
    Ok(normal(first))
}

fn role(value: &str, line: usize) -> Result<Role, SurveyError> {
    match value.trim().to_ascii_lowercase().as_str() {
        "" | "control" | "gcp" | "c" => Ok(Role::Control),
        "check" | "cp" | "chk" | "checkpoint" | "check_point" => Ok(Role::Check),
        other => Err(SurveyError(format!(
            "survey line {line}: role {other:?} is neither control (gcp) nor check (cp)"
        ))),
    }
}

fn is_crs_line(line: &str) -> bool {
    let l = line.trim().to_ascii_uppercase();
    l.starts_with("EPSG:")
        || l.starts_with("WGS84 UTM ")
        || l.starts_with("+PROJ")
        || l.starts_with("+INIT")
        || [
            "PROJCS[",
            "GEOGCS[",
            "PROJCRS[",
            "GEOGCRS[",
            "COMPOUNDCRS[",
            "COMPD_CS[",
        ]
        .iter()
        .any(|p| l.starts_with(p))
}

/// Parses a survey; `crs` (a parameter) overrides a CRS line in the file.
pub fn parse_survey(text: &str, crs: Option<&str>) -> Result<Survey, SurveyError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim_start_matches('\u{feff}').trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
        .peekable();
    let mut file_crs = None;
    if let Some((_, first)) = lines.peek() {
        if is_crs_line(first) {
            file_crs = Some(first.to_string());
            lines.next();
        }
    }
    let rows: Vec<(usize, &str)> = lines.collect();
    let Some(&(_, first)) = rows.first() else {
        return Err(SurveyError("the survey has no points".into()));
    };
    let delimiter = [',', ';', '\t'].into_iter().find(|d| first.contains(*d));
    let split = |l: &str| -> Vec<String> {
        match delimiter {
            Some(d) => l
                .split(d)
                .map(|f| f.trim().trim_matches('"').to_string())
                .collect(),
            None => l.split_whitespace().map(str::to_string).collect(),
        }
    };
    let first_fields = split(first);
    let has_header = first_fields.len() >= 3 && first_fields[1].parse::<f64>().is_err();
    let (columns, body): (Vec<Column>, &[(usize, &str)]) = if has_header {
        (first_fields.iter().map(|h| column(h)).collect(), &rows[1..])
    } else {
        let cols = vec![Column::Name, Column::X, Column::Y, Column::Z, Column::Role];
        (cols, &rows[..])
    };
    for needed in [Column::Name, Column::X, Column::Y, Column::Z] {
        if !columns.contains(&needed) {
            return Err(SurveyError(format!(
                "survey header {first:?} has no {} column",
                match needed {
                    Column::Name => "name",
                    Column::X => "x/easting/longitude",
                    Column::Y => "y/northing/latitude",
                    _ => "z/elevation",
                }
            )));
        }
    }
    let has_marker_column = columns.contains(&Column::MarkerId);
    let mut points: Vec<SurveyPoint> = Vec::new();
    // The crs column's value on each row that has one.
    let mut row_crs: Vec<(usize, String)> = Vec::new();
    for &(line, text) in body {
        let fields = split(text);
        if fields.len() < 4 || fields.len() > columns.len() {
            return Err(SurveyError(format!(
                "survey line {line}: {} fields, expected {} ({text:?})",
                fields.len(),
                columns.len()
            )));
        }
        let mut point = SurveyPoint {
            name: String::new(),
            marker_id: None,
            x: f64::NAN,
            y: f64::NAN,
            z: f64::NAN,
            text: Default::default(),
            role: Role::Control,
            line,
        };
        for (col, value) in columns.iter().zip(&fields) {
            let coordinate = |what: &str| -> Result<f64, SurveyError> {
                value
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| {
                        SurveyError(format!(
                            "survey line {line}: {what} {value:?} is not a number"
                        ))
                    })
            };
            match col {
                Column::Name => point.name = value.clone(),
                Column::MarkerId if value.is_empty() => {}
                Column::MarkerId => {
                    point.marker_id = Some(value.parse().map_err(|_| {
                        SurveyError(format!(
                            "survey line {line}: marker id {value:?} is not a whole number"
                        ))
                    })?)
                }
                Column::X => (point.x, point.text[0]) = (coordinate("x")?, value.clone()),
                Column::Y => (point.y, point.text[1]) = (coordinate("y")?, value.clone()),
                Column::Z => (point.z, point.text[2]) = (coordinate("z")?, value.clone()),
                Column::Role => point.role = role(value, line)?,
                Column::Crs if value.is_empty() => {}
                Column::Crs => row_crs.push((line, value.clone())),
                Column::Other => {}
            }
        }
        if point.x.is_nan() || point.y.is_nan() || point.z.is_nan() {
            return Err(SurveyError(format!(
                "survey line {line}: a coordinate is missing ({text:?})"
            )));
        }
        if point.name.is_empty()
            || point
                .name
                .chars()
                .any(|c| c.is_whitespace() || c.is_control())
        {
            return Err(SurveyError(format!(
                "survey line {line}: point name {:?} is empty or has spaces (exports are space separated)",
                point.name
            )));
        }
        if !has_marker_column && point.name.bytes().all(|b| b.is_ascii_digit()) {
            point.marker_id = point.name.parse().ok();
        }
        if let Some(other) = points.iter().find(|p| p.name == point.name) {
            return Err(SurveyError(format!(
                "survey line {line}: point {} is already on line {}",
                point.name, other.line
            )));
        }
        if let Some(other) = points
            .iter()
            .find(|p| p.marker_id.is_some() && p.marker_id == point.marker_id)
        {
            return Err(SurveyError(format!(
                "survey line {line}: marker id {} is already point {} (line {})",
                point.marker_id.unwrap_or_default(),
                other.name,
                other.line
            )));
        }
        points.push(point);
        if points.len() > MAX_POINTS {
            return Err(SurveyError(format!("more than {MAX_POINTS} survey points")));
        }
    }
    if points.is_empty() {
        return Err(SurveyError("the survey has no points".into()));
    }
    let crs_text = match (crs, file_crs) {
        (Some(param), _) => param.to_string(),
        (None, Some(line)) => line,
        (None, None) => column_crs(&row_crs, points.len())?,
    };
    let target =
        TargetCrs::parse(&crs_text).map_err(|e| SurveyError(format!("survey CRS: {e}")))?;
    if let Some(p) = points
        .iter()
        .find(|p| target.geographic && (p.y.abs() > 90.0 || p.x.abs() > 180.0))
    {
        return Err(SurveyError(format!(
            "survey line {}: ({}, {}) is not longitude, latitude in {}",
            p.line, p.x, p.y, target.name
        )));
    }
    Ok(Survey {
        crs: target.name,
        geographic: target.geographic,
        points,
        assignments: Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_crs_column_names_the_surveys_crs_when_every_row_agrees() {
        let csv = "name,easting,northing,elevation,crs\n\
                   GCP1,500010.125,4099990.500,101.2,EPSG:32611\n\
                   GCP2,500050,4099950,99.80,EPSG:32611\n";
        let s = parse_survey(csv, None).unwrap();
        assert_eq!((s.crs.as_str(), s.points.len()), ("EPSG:32611", 2));
        let epsg = "name,lat,lon,h,epsg\nA,-33.1,151.2,10,4326\nB,-33.2,151.3,11,4326\n";
        let s = parse_survey(epsg, None).unwrap();
        assert!(s.geographic && s.crs == "EPSG:4326");
        let mixed = csv.replacen("EPSG:32611\n", "EPSG:32612\n", 1);
        let e = parse_survey(&mixed, None).unwrap_err().0;
        assert!(e.contains("lines 2 and 3 name different CRSs"), "{e}");
        let gap = csv.replacen(",EPSG:32611\n", ",\n", 1);
        let e = parse_survey(&gap, None).unwrap_err().0;
        assert!(e.contains("empty on 1 of 2 rows"), "{e}");
        // A parameter or a first line wins over the column.
        let s = parse_survey(&mixed, Some("EPSG:32611")).unwrap();
        assert_eq!(s.crs, "EPSG:32611");
    }

    #[test]
    fn csv_with_a_header_and_whitespace_lines_give_the_same_points() {
        let csv = "EPSG:32611\nname;marker_id;easting;northing;elevation;type\n\
                   GCP1;3;500010.125;4099990.500;101.2;gcp\n\
                   CHK1;;500050;4099950;99.80;check\n";
        let s = parse_survey(csv, None).unwrap();
        assert_eq!(s.crs, "EPSG:32611");
        assert_eq!(s.points.len(), 2);
        assert_eq!(s.points[0].marker_id, Some(3));
        assert_eq!(s.points[0].text[0], "500010.125");
        assert_eq!(s.points[1].role, Role::Check);
        assert_eq!(s.points[1].marker_id, None);
        assert_eq!(s.points[1].text[2], "99.80");

        let ws =
            "# survey 2026-11-22\n7   500010.125 4099990.500 101.2\nB2 500050 4099950 99.8 cp\n";
        let s = parse_survey(ws, Some("EPSG:32611")).unwrap();
        assert_eq!(s.points[0].name, "7");
        assert_eq!(s.points[0].marker_id, Some(7));
        assert_eq!(s.points[1].role, Role::Check);
    }

    #[test]
    fn bad_lines_are_named() {
        let cases = [
            ("EPSG:32611\na 1 2\n", "line 2: 3 fields"),
            ("EPSG:32611\na 1 x 3\n", "line 2: y \"x\" is not a number"),
            (
                "EPSG:32611\na 1 2 3\na 4 5 6\n",
                "line 3: point a is already on line 2",
            ),
            (
                "EPSG:32611\n1 1 2 3\nb 4 5 6 maybe\n",
                "line 3: role \"maybe\"",
            ),
            ("a 1 2 3\n", "names no CRS"),
            (
                "EPSG:4326\na 200 50 3\n",
                "line 2: (200, 50) is not longitude, latitude",
            ),
            ("EPSG:99999999\na 1 2 3\n", "survey CRS"),
            ("EPSG:32611\nname,x,y\n", "no z/elevation column"),
        ];
        for (text, want) in cases {
            let e = parse_survey(text, None).unwrap_err().0;
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }
}
