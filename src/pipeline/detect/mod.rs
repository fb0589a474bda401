//! Target detection: one detector per mode behind the [`Detector`] trait, each
//! given an 8-bit grey tile and answering with detections in tile pixels.
//!
//! Detectors hold OpenCV objects that are Send but not Sync: a worker builds
//! its own set per frame with [`build_detectors`] (cheap).

mod fiducial;
pub mod geometry;
pub mod refine;

use std::fmt;
use std::str::FromStr;

use opencv::core::Mat;

pub use fiducial::{marker_bits, AprilTagFamily, ArucoDictionary, FiducialDetector};

/// Why a tile could not be searched.
#[derive(Debug, thiserror::Error)]
#[error("detection failed in tile at ({x}, {y}): {source}")]
pub struct DetectError {
    pub x: usize,
    pub y: usize,
    #[source]
    pub source: opencv::Error,
}

/// Kinds of target a job can ask for.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum MarkerType {
    AprilTag,
    Aruco,
}

impl MarkerType {
    pub const ALL: &'static [MarkerType] = &[MarkerType::AprilTag, MarkerType::Aruco];

    /// The name used on the command line and in outputs.
    pub fn as_str(self) -> &'static str {
        match self {
            MarkerType::AprilTag => "apriltag",
            MarkerType::Aruco => "aruco",
        }
    }
}

impl fmt::Display for MarkerType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for MarkerType {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let wanted = s.trim().to_ascii_lowercase();
        MarkerType::ALL
            .iter()
            .copied()
            .find(|m| m.as_str() == wanted)
            .ok_or_else(|| {
                let names: Vec<_> = MarkerType::ALL.iter().map(|m| m.as_str()).collect();
                format!(
                    "unknown marker type {s:?} (expected one of: {})",
                    names.join(", ")
                )
            })
    }
}

/// Whether subpixel refinement was kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Refinement {
    /// All corners refined.
    Refined,
    /// At least one corner moved implausibly far and was left at its
    /// pixel-level position; the centre is less precise.
    Rejected,
}

impl Refinement {
    pub fn as_str(self) -> &'static str {
        match self {
            Refinement::Refined => "ok",
            Refinement::Rejected => "rejected",
        }
    }
}

/// One target found in one tile, in frame pixel coordinates (OpenCV
/// convention: the centre of the top-left pixel is 0,0).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Detection {
    pub marker_type: MarkerType,
    /// Coded targets' id within their dictionary.
    pub marker_id: Option<u32>,
    pub center: (f64, f64),
    /// Outer corners in the marker's own order (top-left first, clockwise).
    pub corners: [(f64, f64); 4],
    /// Mean side length of the target in pixels.
    pub size_px: f64,
    /// Largest distance a corner moved during subpixel refinement.
    pub refine_shift_px: f64,
    pub refinement: Refinement,
    /// Hamming distance between the bits read and the dictionary's code.
    pub bit_errors: Option<u32>,
    /// How clearly the cells read black or white: the smallest distance of a
    /// cell's mean from the threshold, as a fraction of the black-white
    /// contrast (0 = ambiguous, 0.5 = perfect).
    pub decision_margin: Option<f64>,
    /// Distance from the target to the nearest inner tile border; used only to
    /// pick the best copy when overlapping tiles both see a target (so it is
    /// not stored with results; infinite when no border is a seam).
    #[serde(skip)]
    pub tile_margin: f64,
}

/// A detector for one mode.
pub trait Detector {
    fn marker_type(&self) -> MarkerType;
    /// Searches `tile`, whose top-left pixel is at `origin` in the frame.
    /// `inner_borders` says which tile sides are interior seams (left, top,
    /// right, bottom), for [`Detection::tile_margin`].
    fn detect(
        &mut self,
        tile: &Mat,
        origin: (usize, usize),
        inner_borders: [bool; 4],
    ) -> Result<Vec<Detection>, DetectError>;
}

/// Detection settings shared by all modes of a job.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectorConfig {
    pub modes: Vec<MarkerType>,
    pub aruco_dictionary: ArucoDictionary,
    pub apriltag_family: AprilTagFamily,
    /// Smallest target side, in pixels, that detectors look for.
    pub min_target_px: f64,
    /// Largest corner move accepted from subpixel refinement, in pixels;
    /// `None` scales it with the marker (see `fiducial`).
    pub max_refine_shift_px: Option<f64>,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        DetectorConfig {
            modes: vec![MarkerType::AprilTag],
            aruco_dictionary: ArucoDictionary::default(),
            apriltag_family: AprilTagFamily::default(),
            min_target_px: 16.0,
            max_refine_shift_px: None,
        }
    }
}

/// Builds one detector per requested mode, on the calling thread.
pub fn build_detectors(config: &DetectorConfig) -> opencv::Result<Vec<Box<dyn Detector>>> {
    let mut out: Vec<Box<dyn Detector>> = Vec::new();
    for mode in &config.modes {
        match mode {
            MarkerType::AprilTag => out.push(Box::new(FiducialDetector::new(
                MarkerType::AprilTag,
                config.apriltag_family.opencv_name(),
                config,
            )?)),
            MarkerType::Aruco => out.push(Box::new(FiducialDetector::new(
                MarkerType::Aruco,
                config.aruco_dictionary.opencv_name(),
                config,
            )?)),
        }
    }
    Ok(out)
}
