//! Detection parameters of a submission: parsed from the request's query
//! string, checked once at submission, stored with the flight, and turned
//! into the pipeline's [`FrameOptions`] by the worker that runs each job.

use serde::{Deserialize, Serialize};

use crate::pipeline::detect::{
    AprilTagFamily, ArucoDictionary, DetectorConfig, MarkerType, TargetDesign,
};
use crate::pipeline::frame::{
    default_tile_size, FrameOptions, InvalidSetting, DEFAULT_MAX_TARGET_PX,
};
use crate::pipeline::georef::TargetCrs;

/// Detection parameters, in canonical form once [`JobParams::parse`] accepted
/// them. Defaults match the command line's, except that `crs` defaults to
/// WGS84 (`EPSG:4326`) so a bare upload works.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct JobParams {
    /// Target types, comma separated: `apriltag`, `aruco`, `crosshair`, `circle`.
    #[schema(example = "apriltag")]
    pub marker_types: String,
    /// ArUco dictionary (used when `aruco` is asked for).
    #[schema(example = "4X4_50")]
    pub dictionary: String,
    /// AprilTag family (used when `apriltag` is asked for).
    #[schema(example = "36h11")]
    pub apriltag_family: String,
    /// CRS of the world coordinates: `EPSG:n`, WKT, PROJJSON or a PROJ string.
    #[schema(example = "EPSG:32611")]
    pub crs: String,
    /// Survey matching: farthest a detection may lie from its point's
    /// expected position, in pixels (default 20; raw frames add the
    /// prediction's uncertainty).
    pub pixel_tolerance: Option<f64>,
    /// Largest corner move accepted from subpixel refinement, in pixels
    /// (default: 0.6 of a marker cell, at least 1.5 px).
    #[serde(default)]
    pub max_refine_shift_px: Option<f64>,
    /// Tile side in pixels (default 1024 for coded targets only, 2048 when
    /// printed targets are searched).
    #[serde(default)]
    pub tile_size: Option<usize>,
    /// Largest target side in pixels.
    pub max_target_px: usize,
    /// Smallest target side in pixels.
    pub min_target_px: f64,
    /// Printed targets' physical size in metres (square side, outer diameter).
    pub target_size_m: Option<f64>,
    /// Expected ground sample distance, cm per pixel (default: from the
    /// frame's georeference when it has one).
    pub gsd_cm: Option<f64>,
    /// A printed target's design, found from its description: a preset
    /// name (`cross`, `checker`, `bullseye`, `bullseye-5`, `disc-black`,
    /// `disc-white`) or the design as JSON text (see the
    /// README's "Printed targets"). Stored in canonical JSON.
    #[serde(default)]
    #[schema(example = "cross")]
    pub target_design: Option<String>,
}

impl Default for JobParams {
    fn default() -> Self {
        JobParams {
            marker_types: "apriltag".into(),
            dictionary: ArucoDictionary::default().to_string(),
            apriltag_family: AprilTagFamily::default().to_string(),
            crs: "EPSG:4326".into(),
            pixel_tolerance: None,
            max_refine_shift_px: None,
            tile_size: None,
            max_target_px: DEFAULT_MAX_TARGET_PX,
            min_target_px: 16.0,
            target_size_m: None,
            gsd_cm: None,
            target_design: None,
        }
    }
}

/// The query keys that are detection parameters.
pub const PARAM_KEYS: &[&str] = &[
    "marker_types",
    "dictionary",
    "apriltag_family",
    "crs",
    "pixel_tolerance",
    "max_refine_shift_px",
    "tile_size",
    "max_target_px",
    "min_target_px",
    "target_size_m",
    "gsd_cm",
    "target_design",
];

impl JobParams {
    /// Builds parameters from `key=value` pairs over the defaults; a key
    /// that is not a parameter, a repeated key or a value of the wrong type
    /// is an error naming it. Call [`JobParams::check`] afterwards.
    pub fn from_pairs<'a>(
        pairs: impl IntoIterator<Item = (&'a str, &'a str)>,
    ) -> Result<JobParams, InvalidSetting> {
        let mut p = JobParams::default();
        let mut seen: Vec<&str> = Vec::new();
        for (key, value) in pairs {
            let Some(&field) = PARAM_KEYS.iter().find(|k| **k == key) else {
                continue;
            };
            if seen.contains(&field) {
                return Err(invalid(field, "given more than once".into()));
            }
            seen.push(field);
            let number = |what: &str| invalid(field, format!("{value:?} is not {what}"));
            match field {
                "marker_types" => p.marker_types = value.to_string(),
                "dictionary" => p.dictionary = value.to_string(),
                "apriltag_family" => p.apriltag_family = value.to_string(),
                "crs" => p.crs = value.to_string(),
                "pixel_tolerance" => {
                    p.pixel_tolerance = Some(value.parse().map_err(|_| number("a number"))?)
                }
                "max_refine_shift_px" => {
                    p.max_refine_shift_px = Some(value.parse().map_err(|_| number("a number"))?)
                }
                "tile_size" => p.tile_size = Some(value.parse().map_err(|_| number("an integer"))?),
                "max_target_px" => {
                    p.max_target_px = value.parse().map_err(|_| number("an integer"))?
                }
                "min_target_px" => {
                    p.min_target_px = value.parse().map_err(|_| number("a number"))?
                }
                "target_size_m" => {
                    p.target_size_m = Some(value.parse().map_err(|_| number("a number"))?)
                }
                "gsd_cm" => p.gsd_cm = Some(value.parse().map_err(|_| number("a number"))?),
                "target_design" => p.target_design = Some(value.to_string()),
                _ => unreachable!("every key in PARAM_KEYS is handled"),
            }
        }
        Ok(p)
    }

    /// Validates every field (the CRS through PROJ, so call it off the async
    /// runtime) and returns the canonical form and the pipeline's options.
    pub fn check(&self) -> Result<(JobParams, FrameOptions), InvalidSetting> {
        let mut modes = Vec::new();
        for name in self
            .marker_types
            .split(',')
            .filter(|s| !s.trim().is_empty())
        {
            modes.push(
                name.parse::<MarkerType>()
                    .map_err(|e| invalid("marker_types", e))?,
            );
        }
        // A design is a preset's name or inline JSON, never a path: a
        // client's string must not name a file on the server.
        let design = match self.target_design.as_deref().map(str::trim) {
            None => None,
            Some(text) if text.starts_with('{') => Some(
                TargetDesign::from_json(text)
                    .map_err(|e| invalid("target_design", e.to_string()))?,
            ),
            Some(name) => Some(TargetDesign::preset(name).ok_or_else(|| {
                invalid(
                    "target_design",
                    format!(
                        "{name:?} is neither a preset ({}) nor a JSON design",
                        crate::pipeline::detect::design::preset_names()
                    ),
                )
            })?),
        };
        modes.extend(design.iter().map(|d| d.marker_type()));
        modes.sort();
        modes.dedup();
        let dictionary: ArucoDictionary = self
            .dictionary
            .parse()
            .map_err(|e| invalid("dictionary", e))?;
        let family: AprilTagFamily = self
            .apriltag_family
            .parse()
            .map_err(|e| invalid("apriltag_family", e))?;
        let crs = TargetCrs::parse(&self.crs).map_err(|e| invalid("crs", e.to_string()))?;
        if let Some(t) = self.pixel_tolerance {
            if !(t.is_finite() && t > 0.0 && t <= 10_000.0) {
                return Err(invalid(
                    "pixel_tolerance",
                    format!("{t} must be a positive number of pixels, at most 10000"),
                ));
            }
        }
        let tile_size = self.tile_size.unwrap_or_else(|| default_tile_size(&modes));
        let options = FrameOptions::new(
            DetectorConfig {
                modes: modes.clone(),
                aruco_dictionary: dictionary,
                apriltag_family: family,
                min_target_px: self.min_target_px,
                max_refine_shift_px: self.max_refine_shift_px,
                gsd_cm: self.gsd_cm,
                target_size_m: self
                    .target_size_m
                    .or(design.as_ref().and_then(|d| d.size_m)),
                designs: design.iter().cloned().collect(),
            },
            tile_size,
            self.max_target_px,
            crs,
        )?;
        let canonical = JobParams {
            marker_types: modes
                .iter()
                .map(|m| m.as_str())
                .collect::<Vec<_>>()
                .join(","),
            dictionary: dictionary.to_string(),
            apriltag_family: family.to_string(),
            crs: self.crs.trim().to_string(),
            target_design: design
                .as_ref()
                .map(|d| serde_json::to_string(d).expect("a design serialises")),
            tile_size: Some(tile_size),
            ..self.clone()
        };
        Ok((canonical, options))
    }
}

fn invalid(field: &'static str, message: String) -> InvalidSetting {
    InvalidSetting { field, message }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_override_defaults_and_name_the_bad_field() {
        let p = JobParams::from_pairs([("marker_types", "aruco,apriltag"), ("tile_size", "1024")])
            .unwrap();
        assert_eq!(p.tile_size, Some(1024));
        let (canonical, options) = p.check().unwrap();
        assert_eq!(canonical.marker_types, "apriltag,aruco");
        assert_eq!(options.detector.modes.len(), 2);

        let e = JobParams::from_pairs([("tile_size", "big")]).unwrap_err();
        assert_eq!(e.field, "tile_size");
        let e = JobParams::from_pairs([("crs", "a"), ("crs", "b")]).unwrap_err();
        assert_eq!(e.field, "crs");
        let e = JobParams::from_pairs([("marker_types", "qr")])
            .unwrap()
            .check()
            .unwrap_err();
        assert_eq!(e.field, "marker_types");
        let e = JobParams::from_pairs([("crs", "EPSG:999999")])
            .unwrap()
            .check()
            .unwrap_err();
        assert_eq!(e.field, "crs");

        // A design by preset name is stored as its canonical JSON, which
        // reads back to the same design and adds its mode.
        let p = JobParams::from_pairs([("target_design", "cross")]).unwrap();
        let (canonical, options) = p.check().unwrap();
        assert!(options.detector.modes.contains(&MarkerType::Crosshair));
        assert_eq!(
            options.detector.designs,
            vec![TargetDesign::preset("cross").unwrap()]
        );
        let again = canonical.check().unwrap().0;
        assert_eq!(again, canonical);
        for bad in ["star", r#"{"name":"x","kind":"cross"}"#, "/etc/passwd"] {
            let e = JobParams::from_pairs([("target_design", bad)])
                .unwrap()
                .check()
                .unwrap_err();
            assert_eq!(e.field, "target_design", "{bad}");
        }
    }
}
