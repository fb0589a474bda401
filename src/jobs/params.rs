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
    /// `disc-white`) or the design as JSON text (see
    /// docs/target-designs.md). Stored in canonical JSON.
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

/// The detection parameters as a request's query gives them: this one type
/// is both what the API documents (OpenAPI, `IntoParams`) and what
/// [`DetectionQuery::from_pairs`] fills; a field absent takes
/// [`JobParams`]'s default.
#[derive(Debug, Clone, Default, PartialEq, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct DetectionQuery {
    /// Target types, comma separated: `apriltag`, `aruco`, `crosshair`, `circle` (default `apriltag`).
    pub marker_types: Option<String>,
    /// ArUco dictionary, e.g. `4X4_50` (default), `5X5_100`, `ARUCO_ORIGINAL`.
    pub dictionary: Option<String>,
    /// AprilTag family: `16h5`, `25h9`, `36h10`, `36h11` (default),
    /// `Standard41h12`, `Circle21h7`, `Custom48h12`.
    pub apriltag_family: Option<String>,
    /// CRS of world coordinates: `EPSG:n`, WKT, PROJJSON or PROJ string (default `EPSG:4326`).
    pub crs: Option<String>,
    /// Survey matching: farthest a detection may lie from its point's expected position, in pixels (default 20).
    pub pixel_tolerance: Option<f64>,
    /// Largest subpixel corner move accepted, in pixels (default: 0.6 of a marker cell, at least 1.5 px).
    pub max_refine_shift_px: Option<f64>,
    /// Tile side in pixels, 256..=8192 (default 1024 for coded targets only,
    /// 2048 when printed targets are searched).
    pub tile_size: Option<usize>,
    /// Largest target side in pixels (default 200).
    pub max_target_px: Option<usize>,
    /// Smallest target side in pixels (default 16).
    pub min_target_px: Option<f64>,
    /// Printed targets' physical size in metres (square side, outer diameter); with the GSD it narrows the size range.
    pub target_size_m: Option<f64>,
    /// Expected ground sample distance in cm per pixel (default: from the frame's georeference).
    pub gsd_cm: Option<f64>,
    /// A printed target's design: a preset name (`cross`, `checker`, `bullseye`, `bullseye-5`, `disc-black`, `disc-white`) or the design as JSON text.
    pub target_design: Option<String>,
}

/// A query value of one of [`DetectionQuery`]'s field types.
trait QueryValue: Sized {
    fn parse_as(field: &'static str, value: &str) -> Result<Self, InvalidSetting>;
}

impl QueryValue for String {
    fn parse_as(_: &'static str, value: &str) -> Result<String, InvalidSetting> {
        Ok(value.to_string())
    }
}

impl QueryValue for f64 {
    fn parse_as(field: &'static str, value: &str) -> Result<f64, InvalidSetting> {
        value
            .parse()
            .map_err(|_| invalid(field, format!("{value:?} is not a number")))
    }
}

impl QueryValue for usize {
    fn parse_as(field: &'static str, value: &str) -> Result<usize, InvalidSetting> {
        value
            .parse()
            .map_err(|_| invalid(field, format!("{value:?} is not an integer")))
    }
}

/// [`PARAM_KEYS`] and [`DetectionQuery::from_pairs`] from the list of the
/// query's fields. The struct literal in `from_pairs` names every field, so
/// a field added to the struct and not here does not compile.
macro_rules! query_fields {
    ($($field:ident),+ $(,)?) => {
        /// The query keys that are detection parameters.
        pub const PARAM_KEYS: &[&str] = &[$(stringify!($field)),+];

        impl DetectionQuery {
            /// The parameters among `key=value` pairs (other keys are the
            /// caller's); a repeated key or a value of the wrong type is an
            /// error naming it.
            pub fn from_pairs<'a>(
                pairs: impl IntoIterator<Item = (&'a str, &'a str)>,
            ) -> Result<DetectionQuery, InvalidSetting> {
                let mut q = DetectionQuery { $($field: None),+ };
                for (key, value) in pairs {
                    $(
                        if key == stringify!($field) {
                            if q.$field.is_some() {
                                return Err(invalid(stringify!($field), "given more than once".into()));
                            }
                            q.$field = Some(QueryValue::parse_as(stringify!($field), value)?);
                            continue;
                        }
                    )+
                }
                Ok(q)
            }
        }
    };
}

query_fields!(
    marker_types,
    dictionary,
    apriltag_family,
    crs,
    pixel_tolerance,
    max_refine_shift_px,
    tile_size,
    max_target_px,
    min_target_px,
    target_size_m,
    gsd_cm,
    target_design,
);

impl JobParams {
    /// Builds parameters from `key=value` pairs over the defaults (see
    /// [`DetectionQuery::from_pairs`]). Call [`JobParams::check`] afterwards.
    pub fn from_pairs<'a>(
        pairs: impl IntoIterator<Item = (&'a str, &'a str)>,
    ) -> Result<JobParams, InvalidSetting> {
        Ok(JobParams::from_query(DetectionQuery::from_pairs(pairs)?))
    }

    /// The query's parameters over the defaults.
    pub fn from_query(q: DetectionQuery) -> JobParams {
        let d = JobParams::default();
        JobParams {
            marker_types: q.marker_types.unwrap_or(d.marker_types),
            dictionary: q.dictionary.unwrap_or(d.dictionary),
            apriltag_family: q.apriltag_family.unwrap_or(d.apriltag_family),
            crs: q.crs.unwrap_or(d.crs),
            pixel_tolerance: q.pixel_tolerance.or(d.pixel_tolerance),
            max_refine_shift_px: q.max_refine_shift_px.or(d.max_refine_shift_px),
            tile_size: q.tile_size.or(d.tile_size),
            max_target_px: q.max_target_px.unwrap_or(d.max_target_px),
            min_target_px: q.min_target_px.unwrap_or(d.min_target_px),
            target_size_m: q.target_size_m.or(d.target_size_m),
            gsd_cm: q.gsd_cm.or(d.gsd_cm),
            target_design: q.target_design.or(d.target_design),
        }
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
    fn the_documented_query_is_the_parsed_one() {
        use utoipa::IntoParams;
        let documented: Vec<String> = DetectionQuery::into_params(|| None)
            .into_iter()
            .map(|p| p.name)
            .collect();
        assert_eq!(documented, PARAM_KEYS);
        let q = DetectionQuery::from_pairs([
            ("tile_size", "512"),
            ("crs", "EPSG:32611"),
            ("wait", "3"),
        ])
        .unwrap();
        assert_eq!(q.tile_size, Some(512));
        assert_eq!(q.crs.as_deref(), Some("EPSG:32611"));
        let e = DetectionQuery::from_pairs([("gsd_cm", "two")]).unwrap_err();
        assert_eq!(e.field, "gsd_cm");
        let e = DetectionQuery::from_pairs([("crs", "a"), ("crs", "b")]).unwrap_err();
        assert!(e.message.contains("more than once"), "{}", e.message);
    }

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
