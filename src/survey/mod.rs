//! Surveyed ground control points and what is done with them: parsing a
//! survey file, predicting where each point appears in a frame, matching
//! detections to points, and writing the files photogrammetry software
//! reads. Synchronous and free of HTTP, like the pipeline.
//!
//! - [`parse`]: the survey file (CSV with a header, or whitespace lines).
//! - [`project`]: expected pixel positions (georeference, or camera metadata).
//! - [`matching`]: detections tied to points, deviations, rejections.
//! - [`export`]: gcp_list.txt, Pix4D marks, Metashape markers, GeoJSON, report.

pub mod assign;
pub mod export;
pub mod matching;
pub mod parse;
pub mod project;

use serde::Serialize;

/// Control points constrain the adjustment; check points are kept out of
/// it to measure accuracy.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    Control,
    Check,
}

/// One surveyed point. Coordinates keep the file's text so every export
/// writes exactly what the surveyor measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SurveyPoint {
    pub name: String,
    pub marker_id: Option<u32>,
    /// Easting or longitude.
    pub x: f64,
    /// Northing or latitude.
    pub y: f64,
    pub z: f64,
    #[serde(skip)]
    pub text: [String; 3],
    pub role: Role,
    /// Line of the survey file it came from (1-based).
    pub line: usize,
}

/// A parsed survey: its CRS and its points in file order.
#[derive(Debug, Clone, PartialEq)]
pub struct Survey {
    /// CRS of the coordinates, as given (`EPSG:32611`, a PROJ string, WKT).
    pub crs: String,
    pub geographic: bool,
    pub points: Vec<SurveyPoint>,
    /// Observations a person named (see [`assign`]); empty unless given.
    pub assignments: Vec<assign::Assignment>,
}
