//! Detections tied to surveyed points.
//!
//! - Coded targets by marker id; a detected id missing from the survey is
//!   rejected (`not_in_survey`).
//! - Every detection with an expected position for its point gets its
//!   `deviation_px`; one farther than the search radius is rejected
//!   (`outside_tolerance`). The radius is `--pixel-tolerance` plus three
//!   standard deviations of the prediction (0 for georeferenced frames,
//!   grown from the metadata's uncertainty for raw frames).
//! - Non-coded targets take the name of the nearest expected position
//!   within its radius, with a match confidence from the distance and from
//!   how far the next candidate is; none in reach leaves them unnamed
//!   (`no_point_nearby`), still reported.
//! - Two detections claiming one point in one frame: the nearer (a coded
//!   one first) keeps it, the other is rejected (`duplicate_claim`) and the
//!   point's report warns.

use serde::Serialize;

use crate::pipeline::frame::FrameResult;
use crate::pipeline::georef::Transformer;

use super::project::{expected_positions, Basis, Expected};
use super::{assign, Role, Survey};

/// Default `pixel_tolerance`: a target's centre on a georeferenced frame
/// lands within a few pixels of its surveyed position; 20 px leaves room
/// for survey and orthorectification error without reaching the next
/// target.
pub const DEFAULT_PIXEL_TOLERANCE: f64 = 20.0;

/// A detection tied to a point.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Observation {
    pub image: String,
    /// Index into the survey's points.
    #[serde(skip)]
    pub point: usize,
    pub gcp_name: String,
    pub marker_type: String,
    pub marker_id: Option<u32>,
    /// OpenCV pixel coordinates (top-left pixel centre at 0,0).
    pub px: f64,
    pub py: f64,
    /// Distance from the point's expected position, when one is known.
    pub deviation_px: Option<f64>,
    /// 1 for a coded id; for non-coded targets from the distance and the
    /// nearest other candidate.
    pub match_confidence: f64,
    pub basis: Option<Basis>,
}

/// A detection not tied to a point, and why.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Unmatched {
    pub image: String,
    pub marker_type: String,
    pub marker_id: Option<u32>,
    pub px: f64,
    pub py: f64,
    /// The point it was compared with, if any.
    pub gcp_name: Option<String>,
    pub deviation_px: Option<f64>,
    /// `not_in_survey`, `outside_tolerance`, `no_point_nearby`,
    /// `duplicate_claim`.
    pub code: &'static str,
    pub reason: String,
}

/// How a frame's expected positions were found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameBasis {
    pub image: String,
    pub basis: Option<Basis>,
    /// Why there are no expected positions, when there are none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// Everything the matcher decided, sorted by image then position.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Matched {
    pub observations: Vec<Observation>,
    pub unmatched: Vec<Unmatched>,
    pub frames: Vec<FrameBasis>,
    /// What a user must hear: frames whose printed targets cannot be
    /// named (and why), assignments that found no detection.
    pub warnings: Vec<String>,
}

/// Matches the targets of `frames` to `survey`'s points.
pub fn match_frames(
    frames: &[FrameResult],
    survey: &Survey,
    tolerance_px: f64,
    transformer: &mut Transformer,
) -> Matched {
    let mut out = Matched::default();
    let mut sorted: Vec<&FrameResult> = frames.iter().collect();
    sorted.sort_by(|a, b| a.image.cmp(&b.image));
    for frame in sorted {
        let expected = match expected_positions(frame, survey, transformer) {
            Ok(e) => {
                out.frames.push(FrameBasis {
                    image: frame.image.clone(),
                    basis: e.iter().flatten().map(|e| e.basis).next(),
                    note: None,
                });
                e
            }
            Err(why) => {
                out.frames.push(FrameBasis {
                    image: frame.image.clone(),
                    basis: None,
                    note: Some(why.to_string()),
                });
                vec![None; survey.points.len()]
            }
        };
        let unnamed_before = out.unmatched.len();
        match_frame(frame, survey, &expected, tolerance_px, &mut out);
        let unnamed = out.unmatched[unnamed_before..]
            .iter()
            .filter(|u| u.code == "no_point_nearby")
            .count();
        if let (Some(note), true) = (&out.frames.last().and_then(|f| f.note.clone()), unnamed > 0) {
            out.warnings.push(format!(
                "{}: {unnamed} printed target(s) cannot be named: {note}; coded targets still match by id, and printed ones can be named in an assignment file (name,image,px_x,px_y)",
                frame.image
            ));
        }
    }
    out.observations.sort_by(|a, b| {
        a.image
            .cmp(&b.image)
            .then(a.py.total_cmp(&b.py))
            .then(a.px.total_cmp(&b.px))
    });
    out.unmatched.sort_by(|a, b| {
        a.image
            .cmp(&b.image)
            .then(a.py.total_cmp(&b.py))
            .then(a.px.total_cmp(&b.px))
    });
    out
}

fn radius(e: &Expected, tolerance: f64) -> f64 {
    tolerance + 3.0 * e.sigma_px
}

fn match_frame(
    frame: &FrameResult,
    survey: &Survey,
    expected: &[Option<Expected>],
    tolerance: f64,
    out: &mut Matched,
) {
    let mut claims: Vec<Observation> = Vec::new();
    // Targets a person named: the detection nearest each assignment.
    let mut assigned: Vec<Option<usize>> = vec![None; frame.targets.len()];
    for a in survey.assignments.iter().filter(|a| a.image == frame.image) {
        let point = survey
            .points
            .iter()
            .position(|p| p.name == a.name)
            .expect("assignments name survey points");
        let nearest = frame
            .targets
            .iter()
            .enumerate()
            .filter(|(i, _)| assigned[*i].is_none())
            .map(|(i, t)| {
                let (x, y) = t.detection.center;
                (i, (x - a.px).hypot(y - a.py), t.detection.size_px)
            })
            .filter(|&(_, dist, size)| dist <= assign::ASSIGN_RADIUS_PX.max(0.5 * size))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        match nearest {
            Some((i, ..)) => assigned[i] = Some(point),
            None => out.warnings.push(format!(
                "{}: assignment line {} ({} at {:.1}, {:.1}) has no detection within {} px",
                frame.image,
                a.line,
                a.name,
                a.px,
                a.py,
                assign::ASSIGN_RADIUS_PX
            )),
        }
    }
    for (index, target) in frame.targets.iter().enumerate() {
        let d = &target.detection;
        let (px, py) = d.center;
        let unmatched =
            |gcp_name: Option<String>, dev: Option<f64>, code, reason: String| Unmatched {
                image: frame.image.clone(),
                marker_type: d.marker_type.as_str().to_string(),
                marker_id: d.marker_id,
                px,
                py,
                gcp_name,
                deviation_px: dev,
                code,
                reason,
            };
        let observation = |point: usize, dev: Option<f64>, confidence: f64, basis| Observation {
            image: frame.image.clone(),
            point,
            gcp_name: survey.points[point].name.clone(),
            marker_type: d.marker_type.as_str().to_string(),
            marker_id: d.marker_id,
            px,
            py,
            deviation_px: dev,
            match_confidence: confidence,
            basis,
        };
        if let Some(point) = assigned[index] {
            let dev = expected[point].map(|e| (px - e.px).hypot(py - e.py));
            claims.push(observation(point, dev, 1.0, None));
            continue;
        }
        if let (true, Some(id)) = (d.marker_type.is_coded(), d.marker_id) {
            let Some(point) = survey.points.iter().position(|p| p.marker_id == Some(id)) else {
                out.unmatched.push(unmatched(
                    None,
                    None,
                    "not_in_survey",
                    format!("marker id {id} is not in the survey"),
                ));
                continue;
            };
            match expected[point] {
                Some(e) => {
                    let dev = (px - e.px).hypot(py - e.py);
                    if dev > radius(&e, tolerance) {
                        out.unmatched.push(unmatched(
                            Some(survey.points[point].name.clone()),
                            Some(dev),
                            "outside_tolerance",
                            format!(
                                "{dev:.1} px from where {} should appear, more than the {:.1} px allowed",
                                survey.points[point].name,
                                radius(&e, tolerance)
                            ),
                        ));
                    } else {
                        claims.push(observation(point, Some(dev), 1.0, Some(e.basis)));
                    }
                }
                None => claims.push(observation(point, None, 1.0, None)),
            }
            continue;
        }
        // Non-coded: the nearest expected position in reach, by distance
        // relative to each point's radius.
        let mut reach: Vec<(f64, usize, f64, Expected)> = expected
            .iter()
            .enumerate()
            .filter_map(|(i, e)| {
                let e = (*e)?;
                let dev = (px - e.px).hypot(py - e.py);
                (dev <= radius(&e, tolerance)).then(|| (dev / radius(&e, tolerance), i, dev, e))
            })
            .collect();
        reach.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        match reach.first() {
            None => out.unmatched.push(unmatched(
                None,
                None,
                "no_point_nearby",
                format!(
                    "no surveyed point is expected within reach ({tolerance:.1} px tolerance{})",
                    if expected.iter().any(Option::is_some) {
                        ""
                    } else {
                        "; the frame gives no expected positions"
                    }
                ),
            )),
            Some(&(rel, point, dev, e)) => {
                let scale = radius(&e, tolerance) / 3.0;
                let mut confidence = (-0.5 * (dev / scale).powi(2)).exp();
                if let Some(&(rel2, ..)) = reach.get(1) {
                    // Ambiguity: the second candidate almost as near.
                    confidence *= ((rel2 - rel) / rel2.max(1e-9)).clamp(0.0, 1.0);
                }
                claims.push(observation(point, Some(dev), confidence, Some(e.basis)));
            }
        }
    }
    // One observation per point and frame: coded first, then nearest.
    claims.sort_by(|a, b| {
        a.point
            .cmp(&b.point)
            .then(b.marker_id.is_some().cmp(&a.marker_id.is_some()))
            .then(
                a.deviation_px
                    .unwrap_or(0.0)
                    .total_cmp(&b.deviation_px.unwrap_or(0.0)),
            )
            .then(a.py.total_cmp(&b.py))
            .then(a.px.total_cmp(&b.px))
    });
    let mut last: Option<usize> = None;
    for claim in claims {
        if last == Some(claim.point) {
            out.unmatched.push(Unmatched {
                image: claim.image,
                marker_type: claim.marker_type,
                marker_id: claim.marker_id,
                px: claim.px,
                py: claim.py,
                reason: format!(
                    "another detection in this frame is taken as {}",
                    claim.gcp_name
                ),
                gcp_name: Some(claim.gcp_name),
                deviation_px: claim.deviation_px,
                code: "duplicate_claim",
            });
            continue;
        }
        last = Some(claim.point);
        out.observations.push(claim);
    }
}

/// What one surveyed point got.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PointReport {
    pub name: String,
    pub marker_id: Option<u32>,
    pub role: Role,
    pub x: f64,
    pub y: f64,
    pub z: f64,
    /// Images with an observation of it, sorted.
    pub images: Vec<String>,
    pub observations: usize,
    pub mean_deviation_px: Option<f64>,
    pub max_deviation_px: Option<f64>,
    pub warnings: Vec<String>,
}

/// Fewer images than this make a point weak in an adjustment.
pub const MIN_IMAGES: usize = 3;

/// Per-point summary with warnings.
pub fn point_reports(survey: &Survey, matched: &Matched) -> Vec<PointReport> {
    survey
        .points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let obs: Vec<&Observation> = matched
                .observations
                .iter()
                .filter(|o| o.point == i)
                .collect();
            let mut images: Vec<String> = obs.iter().map(|o| o.image.clone()).collect();
            images.sort();
            images.dedup();
            let devs: Vec<f64> = obs.iter().filter_map(|o| o.deviation_px).collect();
            let mut warnings = Vec::new();
            if images.is_empty() {
                warnings.push("not seen in any image".to_string());
            } else if images.len() < MIN_IMAGES {
                warnings.push(format!(
                    "seen in {} image{} only (fewer than {MIN_IMAGES})",
                    images.len(),
                    if images.len() == 1 { "" } else { "s" }
                ));
            }
            let mut doubled: Vec<&str> = matched
                .unmatched
                .iter()
                .filter(|u| u.code == "duplicate_claim" && u.gcp_name.as_deref() == Some(&p.name))
                .map(|u| u.image.as_str())
                .collect();
            doubled.dedup();
            for image in doubled {
                warnings.push(format!("{image}: two or more detections claim this point"));
            }
            PointReport {
                name: p.name.clone(),
                marker_id: p.marker_id,
                role: p.role,
                x: p.x,
                y: p.y,
                z: p.z,
                observations: obs.len(),
                images,
                mean_deviation_px: (!devs.is_empty())
                    .then(|| devs.iter().sum::<f64>() / devs.len() as f64),
                max_deviation_px: devs.iter().copied().reduce(f64::max),
                warnings,
            }
        })
        .collect()
}
