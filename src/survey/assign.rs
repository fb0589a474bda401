//! Assignments: a person's word on which detection is which surveyed point,
//! for frames the matcher cannot place (no georeference and no camera
//! pose: printed targets carry no id). One line per observation,
//! `name,image,px_x,px_y` (a header line is optional); the point takes the
//! detection nearest that pixel, within [`ASSIGN_RADIUS_PX`] or half the
//! target's size, so the observation keeps the detector's subpixel centre,
//! not the click.

use serde::Serialize;

use super::parse::SurveyError;
use super::Survey;

/// Farthest a detection may lie from an assignment's pixel (or half the
/// detection's size when larger): a click near a target's centre.
pub const ASSIGN_RADIUS_PX: f64 = 10.0;

/// Longest assignment file, in lines.
const MAX_ASSIGNMENTS: usize = 100_000;

/// One assignment line.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Assignment {
    /// The survey point's name.
    pub name: String,
    pub image: String,
    pub px: f64,
    pub py: f64,
    /// Line of the assignment file (1-based).
    pub line: usize,
}

/// Parses an assignment file against `survey`: every name must be one of
/// its points; an image and pixel may be named once.
pub fn parse_assignments(text: &str, survey: &Survey) -> Result<Vec<Assignment>, SurveyError> {
    let err = |line: usize, what: String| SurveyError(format!("assignment line {line}: {what}"));
    let mut out: Vec<Assignment> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let l = raw.trim_start_matches('\u{feff}').trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = l
            .split([',', ';', '\t'])
            .map(|f| f.trim().trim_matches('"'))
            .collect();
        if fields.len() != 4 {
            return Err(err(
                line,
                format!(
                    "{} fields, expected name,image,px_x,px_y ({l:?})",
                    fields.len()
                ),
            ));
        }
        let (px, py) = (fields[2].parse::<f64>(), fields[3].parse::<f64>());
        let (Ok(px), Ok(py)) = (px, py) else {
            if out.is_empty() && fields[2].parse::<f64>().is_err() && line == first_line(text) {
                // A header line.
                continue;
            }
            return Err(err(
                line,
                format!("pixel ({}, {}) is not two numbers", fields[2], fields[3]),
            ));
        };
        if !(px.is_finite() && py.is_finite()) {
            return Err(err(line, "the pixel is not finite".into()));
        }
        let name = fields[0].to_string();
        if !survey.points.iter().any(|p| p.name == name) {
            return Err(err(line, format!("{name} is not a point of the survey")));
        }
        if let Some(other) = out.iter().find(|a| a.image == fields[1] && a.name == name) {
            return Err(err(
                line,
                format!(
                    "{name} is already assigned in {} (line {})",
                    other.image, other.line
                ),
            ));
        }
        out.push(Assignment {
            name,
            image: fields[1].to_string(),
            px,
            py,
            line,
        });
        if out.len() > MAX_ASSIGNMENTS {
            return Err(SurveyError(format!(
                "more than {MAX_ASSIGNMENTS} assignments"
            )));
        }
    }
    Ok(out)
}

/// The 1-based number of the first line with text.
fn first_line(text: &str) -> usize {
    text.lines()
        .position(|l| !l.trim().is_empty() && !l.trim().starts_with('#'))
        .map_or(0, |i| i + 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::survey::parse::parse_survey;

    #[test]
    fn assignments_name_survey_points_at_pixels() {
        let survey = parse_survey(
            "EPSG:32611\nP1 500000 4100000 10\nP2 500010 4100000 10\n",
            None,
        )
        .unwrap();
        let a = parse_assignments(
            "name,image,px_x,px_y\nP1,DJI_0001.JPG,812.5,402\nP2;DJI_0001.JPG;100;200\n",
            &survey,
        )
        .unwrap();
        assert_eq!(a.len(), 2);
        assert_eq!(
            (a[0].name.as_str(), a[0].px, a[0].py, a[0].line),
            ("P1", 812.5, 402.0, 2)
        );
        for (bad, why) in [
            ("P9,a.jpg,1,2\n", "P9 is not a point of the survey"),
            ("P1,a.jpg,1\n", "3 fields"),
            (
                "P1,a.jpg,1,2\nP1,a.jpg,5,6\n",
                "already assigned in a.jpg (line 1)",
            ),
            (
                "P1,a.jpg,1,2\nP2,a.jpg,x,2\n",
                "line 2: pixel (x, 2) is not two numbers",
            ),
        ] {
            let e = parse_assignments(bad, &survey).unwrap_err().0;
            assert!(e.contains(why), "{bad:?}: {e}");
        }
    }
}
