//! Target detection: one detector per mode behind the [`Detector`] trait, each
//! given an 8-bit grey tile and answering with detections in tile pixels.
//!
//! Detectors hold OpenCV objects that are Send but not Sync: a worker builds
//! its own set per frame with [`build_detectors`] (cheap).

mod apriltag;
mod arcs;
mod blobs;
mod circle;
pub mod design;
mod fiducial;
mod found;
pub mod geometry;
mod harmonic;
mod modelfit;
mod printed;
mod profile;
pub mod refine;
mod shadow;
#[cfg(test)]
mod test_image;

use std::fmt;
use std::str::FromStr;

use opencv::core::Mat;

pub use apriltag::{tag_cells, AprilTagDetector, AprilTagFamily, TagCells, TagCellsError};
pub use circle::CircleDetector;
pub use design::TargetDesign;
pub use fiducial::{ArucoDictionary, FiducialDetector};
pub use printed::PrintedDetector;

/// Why a tile could not be searched.
#[derive(Debug, thiserror::Error)]
#[error("detection failed in tile at ({x}, {y}): {source}")]
pub struct DetectError {
    pub x: usize,
    pub y: usize,
    #[source]
    pub source: opencv::Error,
}

impl DetectError {
    /// Wraps OpenCV errors of the tile whose top-left pixel is `origin`.
    pub fn at(origin: (usize, usize)) -> impl Fn(opencv::Error) -> DetectError + Copy {
        move |source| DetectError {
            x: origin.0,
            y: origin.1,
            source,
        }
    }
}

/// Kinds of target a job can ask for.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum MarkerType {
    AprilTag,
    Aruco,
    /// Printed, no code: a white cross on a black square, or a 2x2 checker.
    Crosshair,
    /// Printed, no code: a bullseye, or a disc on a square board.
    Circle,
}

impl MarkerType {
    pub const ALL: &'static [MarkerType] = &[
        MarkerType::AprilTag,
        MarkerType::Aruco,
        MarkerType::Crosshair,
        MarkerType::Circle,
    ];

    /// The name used on the command line and in outputs.
    pub fn as_str(self) -> &'static str {
        match self {
            MarkerType::AprilTag => "apriltag",
            MarkerType::Aruco => "aruco",
            MarkerType::Crosshair => "crosshair",
            MarkerType::Circle => "circle",
        }
    }

    /// Whether the target carries an id.
    pub fn is_coded(self) -> bool {
        matches!(self, MarkerType::AprilTag | MarkerType::Aruco)
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
    /// Hamming distance between the bits read and the dictionary's code
    /// (AprilTag: the bits libapriltag corrected).
    pub bit_errors: Option<u32>,
    /// How clearly the cells read black or white. AprilTag: libapriltag's
    /// `decision_margin`, the mean distance of the data bits' grey from
    /// their threshold on its search scale (0-255). ArUco: the smallest
    /// distance of a cell's mean from the threshold, as a fraction of the
    /// black-white contrast (0 = ambiguous, 0.5 = perfect).
    pub decision_margin: Option<f64>,
    /// Printed targets: RMS distance, in pixels, of the subpixel edge points
    /// from the fitted lines or ellipse.
    pub fit_rms_px: Option<f64>,
    /// How sure the detector is, 0..1: for coded targets from the decision
    /// margin, bit errors and refinement; for printed targets from the share
    /// of profiles that found their edge, the fit residual, the contrast and
    /// (crosshair) the symmetry of the arms.
    pub confidence: f64,
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
    /// Printed targets' physical size in metres (square side, outer
    /// diameter); with the ground sample distance it narrows the size range.
    pub target_size_m: Option<f64>,
    /// Expected ground sample distance in cm per pixel; `None` takes it from
    /// the frame's georeference when that is in metres.
    pub gsd_cm: Option<f64>,
    /// Printed designs to look for, found from their description; none
    /// of a mode's kind means that mode's presets (`crosshair`: the `cross`
    /// and `checker` presets).
    pub designs: Vec<TargetDesign>,
}

/// Target sizes, in pixels, a detector accepts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SizeRange {
    pub min_px: f64,
    pub max_px: f64,
    /// How far around a candidate its structure is followed (an arm to
    /// its end): the largest target the frame is searched for, not
    /// narrowed by the expected size, so a narrower range only rejects
    /// sizes and never changes what a candidate's surroundings show.
    pub reach_px: f64,
}

/// The ground sample distance varies across a frame and a flight (terrain
/// height, tilt): the expected size in pixels is trusted to this factor.
pub const GSD_SIZE_TOLERANCE: f64 = 1.5;

/// Factors a measured size may fall below the range's least size and rise
/// above its largest: the measurement's own error with a margin. Each
/// detector measures size its own way and has its own slack.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SizeSlack {
    pub below: f64,
    pub above: f64,
}

impl SizeRange {
    /// The range for a frame: `min_target_px..=max_target_px`, narrowed to
    /// the expected size (x/÷ [`GSD_SIZE_TOLERANCE`]) when the physical
    /// target size and the GSD (given, or else `frame_gsd_m`) are known.
    pub fn for_frame(
        config: &DetectorConfig,
        max_target_px: f64,
        frame_gsd_m: Option<f64>,
    ) -> SizeRange {
        let mut range = SizeRange {
            min_px: config.min_target_px,
            max_px: max_target_px,
            reach_px: max_target_px,
        };
        let gsd_m = config.gsd_cm.map(|g| g / 100.0).or(frame_gsd_m);
        if let (Some(size), Some(gsd)) = (config.target_size_m, gsd_m) {
            let expected = size / gsd;
            range.min_px = range.min_px.max(expected / GSD_SIZE_TOLERANCE);
            range.max_px = range.max_px.min(expected * GSD_SIZE_TOLERANCE);
        }
        range
    }

    /// Whether a size measured with the given slack fits.
    pub fn accepts(&self, size_px: f64, slack: SizeSlack) -> bool {
        size_px >= self.min_px / slack.below && size_px <= self.max_px * slack.above
    }
}

impl Default for DetectorConfig {
    fn default() -> Self {
        DetectorConfig {
            modes: vec![MarkerType::AprilTag],
            aruco_dictionary: ArucoDictionary::default(),
            apriltag_family: AprilTagFamily::default(),
            min_target_px: 16.0,
            max_refine_shift_px: None,
            target_size_m: None,
            gsd_cm: None,
            designs: Vec::new(),
        }
    }
}

/// The designs a printed-target mode looks for: those given of its kind,
/// or else every built-in design of the mode (`crosshair`: a cross, marked
/// or not, and a 2x2 checker; `circle`: bullseyes and discs).
fn designs_of(config: &DetectorConfig, mode: MarkerType) -> Vec<TargetDesign> {
    let own: Vec<TargetDesign> = config
        .designs
        .iter()
        .filter(|d| d.marker_type() == mode)
        .cloned()
        .collect();
    if !own.is_empty() {
        return own;
    }
    design::presets()
        .into_iter()
        .filter(|d| d.marker_type() == mode)
        .collect()
}

/// Builds one detector per requested mode, on the calling thread.
pub fn build_detectors(
    config: &DetectorConfig,
    sizes: SizeRange,
) -> opencv::Result<Vec<Box<dyn Detector>>> {
    let mut out: Vec<Box<dyn Detector>> = Vec::new();
    for mode in &config.modes {
        match mode {
            MarkerType::AprilTag => out.push(Box::new(AprilTagDetector::new(
                config.apriltag_family,
                config,
            ))),
            MarkerType::Aruco => out.push(Box::new(FiducialDetector::new(
                config.aruco_dictionary,
                config,
            )?)),
            MarkerType::Crosshair => out.push(Box::new(PrintedDetector::new(
                *mode,
                designs_of(config, *mode),
                sizes,
            ))),
            MarkerType::Circle => out.push(Box::new(CircleDetector::new(
                sizes,
                &designs_of(config, *mode),
            ))),
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_size_range_accepts_the_measurements_slack_and_no_more() {
        let range = SizeRange {
            min_px: 40.0,
            max_px: 200.0,
            reach_px: 200.0,
        };
        let slack = SizeSlack {
            below: 1.10,
            above: 1.15,
        };
        // 40 / 1.10 = 36.4 px; 200 x 1.15 = 230 px.
        for (size, fits) in [(36.5, true), (35.5, false), (229.0, true), (231.0, false)] {
            assert_eq!(range.accepts(size, slack), fits, "{size} px");
        }
    }
}
