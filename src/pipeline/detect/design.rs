//! Printed targets described, not hard-coded: a [`TargetDesign`] says what a
//! target looks like (its kind, polarity, proportions as ranges, which parts
//! may carry any marking, its physical size), and the printed-target
//! detector fits and verifies that description.
//!
//! Designs are read from JSON (`--target-design FILE`, or `target_design` in
//! the API) or taken from the built-in [`presets`]. Proportions are
//! fractions of the board's side, so one description serves every size.

use serde::{Deserialize, Serialize};

/// The geometry a design is built on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DesignKind {
    /// Two bars crossing at right angles, each running the board's full side.
    Cross,
    /// A 2x2 checker: four quadrants of alternating colour.
    Checker,
    /// A bullseye: a centre disc and concentric rings of alternating
    /// colour, their edges at `ring_radii` of the outermost edge.
    Rings,
    /// A disc on a square board of the other colour.
    Disc,
}

/// Which colour the design's figure (the cross's bars, the disc, a
/// bullseye's centre disc) has on its board.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Polarity {
    LightOnDark,
    DarkOnLight,
}

/// Parts of a design that may hold anything (a number, a marking) without
/// stopping or breaking detection.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FreeArea {
    /// Every part of the design is as described.
    #[default]
    None,
    /// The inside of a cross's four quadrants may hold markings; the bars
    /// and a band along the board's outer sides may not.
    Quadrants,
}

/// An inclusive range of a proportion; in JSON `[min, max]`, or one number
/// for an exact value.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(from = "RangeJson")]
pub struct Range(pub f64, pub f64);

#[derive(Deserialize)]
#[serde(untagged)]
enum RangeJson {
    Exact(f64),
    Between(f64, f64),
}

impl From<RangeJson> for Range {
    fn from(r: RangeJson) -> Range {
        match r {
            RangeJson::Exact(v) => Range(v, v),
            RangeJson::Between(lo, hi) => Range(lo, hi),
        }
    }
}

impl Range {
    pub fn contains(&self, v: f64) -> bool {
        v >= self.0 && v <= self.1
    }
}

/// A printed target's description.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetDesign {
    /// A short name, reported with each detection's design.
    pub name: String,
    pub kind: DesignKind,
    /// The figure's colour on the board: the cross's bars, the disc, or
    /// the bullseye's centre disc.
    #[serde(default = "light_on_dark")]
    pub polarity: Polarity,
    /// Cross only: bar width over the board's side.
    #[serde(default)]
    pub bar_width: Option<Range>,
    /// Rings only: the radius of each edge, from the centre disc's edge
    /// outward, over the outermost edge's (so the last is 1). Colours
    /// alternate across the edges; past the last, the board.
    #[serde(default)]
    pub ring_radii: Option<Vec<Range>>,
    /// Disc only: the board's side over the disc's diameter.
    #[serde(default)]
    pub board: Option<Range>,
    #[serde(default)]
    pub free: FreeArea,
    /// Width of the band along the board's sides that stays as described
    /// when the quadrants are free, as a fraction of half the side.
    #[serde(default = "default_border_band")]
    pub border_band: f64,
    /// The board's side in metres, when known: with the frame's ground
    /// sample distance it narrows the searched sizes.
    #[serde(default)]
    pub size_m: Option<f64>,
}

fn light_on_dark() -> Polarity {
    Polarity::LightOnDark
}

/// A disc's board side over its diameter when the design does not say:
/// the field designs in use lie within it (2 is the most common).
pub const DEFAULT_DISC_BOARD: Range = Range(1.4, 3.0);

fn default_border_band() -> f64 {
    0.2
}

/// Why a design description was refused.
#[derive(Debug, thiserror::Error)]
pub enum DesignError {
    #[error("target design is not valid JSON for a design: {0}")]
    Json(#[from] serde_json::Error),
    #[error("target design {name:?}: {what}")]
    Invalid { name: String, what: String },
    #[error("target design {arg:?} is neither a preset ({presets}) nor a readable file: {source}")]
    NotFound {
        arg: String,
        presets: String,
        source: std::io::Error,
    },
    #[error("{file}: {source}")]
    InFile {
        file: String,
        source: Box<DesignError>,
    },
}

impl TargetDesign {
    /// The detection mode that looks for this design.
    pub fn marker_type(&self) -> super::MarkerType {
        match self.kind {
            DesignKind::Cross | DesignKind::Checker => super::MarkerType::Crosshair,
            DesignKind::Rings | DesignKind::Disc => super::MarkerType::Circle,
        }
    }

    /// Parses and validates a JSON description.
    pub fn from_json(text: &str) -> Result<TargetDesign, DesignError> {
        let d: TargetDesign = serde_json::from_str(text)?;
        d.validate()?;
        Ok(d)
    }

    /// A built-in design by name (see [`presets`]).
    pub fn preset(name: &str) -> Option<TargetDesign> {
        presets().into_iter().find(|d| d.name == name)
    }

    /// A preset's name or a JSON file's path.
    pub fn from_name_or_file(arg: &str) -> Result<TargetDesign, DesignError> {
        if let Some(d) = TargetDesign::preset(arg) {
            return Ok(d);
        }
        let text = std::fs::read_to_string(arg).map_err(|source| DesignError::NotFound {
            arg: arg.to_string(),
            presets: preset_names(),
            source,
        })?;
        TargetDesign::from_json(&text).map_err(|e| DesignError::InFile {
            file: arg.to_string(),
            source: Box::new(e),
        })
    }

    /// Checks that the proportions describe a drawable target.
    pub fn validate(&self) -> Result<(), DesignError> {
        let bad = |what: String| DesignError::Invalid {
            name: self.name.clone(),
            what,
        };
        if self.name.trim().is_empty() || self.name.len() > 64 {
            return Err(bad("name must be 1 to 64 characters".into()));
        }
        if self.kind != DesignKind::Cross && self.bar_width.is_some() {
            return Err(bad("only a cross has a bar_width".into()));
        }
        if self.kind != DesignKind::Rings && self.ring_radii.is_some() {
            return Err(bad("only rings have ring_radii".into()));
        }
        if self.kind != DesignKind::Disc && self.board.is_some() {
            return Err(bad("only a disc has a board ratio".into()));
        }
        if self.kind != DesignKind::Cross && self.free != FreeArea::None {
            return Err(bad("only a cross's quadrants can be free".into()));
        }
        match self.kind {
            DesignKind::Cross => {
                let Some(Range(lo, hi)) = self.bar_width else {
                    return Err(bad("a cross needs bar_width [min, max]".into()));
                };
                if !(lo.is_finite() && hi.is_finite() && 0.02 <= lo && lo <= hi && hi <= 0.4) {
                    return Err(bad(format!(
                        "bar_width [{lo}, {hi}] must satisfy 0.02 <= min <= max <= 0.4"
                    )));
                }
            }
            DesignKind::Checker => {}
            DesignKind::Rings => {
                let Some(radii) = &self.ring_radii else {
                    return Err(bad("rings need ring_radii [[min, max], ..., 1]".into()));
                };
                if !(2..=8).contains(&radii.len()) {
                    return Err(bad(format!(
                        "ring_radii lists {} edges; 2 to 8 (the centre disc's edge to the outermost)",
                        radii.len()
                    )));
                }
                let mut last = 0.0;
                for Range(lo, hi) in radii {
                    if !(lo.is_finite() && hi.is_finite() && 0.1 <= *lo && lo <= hi && *hi <= 1.0)
                        || *lo <= last
                    {
                        return Err(bad(format!(
                            "ring_radii [{lo}, {hi}] must satisfy 0.1 <= min <= max <= 1, \
                             each edge's min past the previous edge's"
                        )));
                    }
                    last = *lo;
                }
                if radii.last() != Some(&Range(1.0, 1.0)) {
                    return Err(bad("the last of ring_radii is the outermost edge: 1".into()));
                }
            }
            DesignKind::Disc => {
                let Range(lo, hi) = self.board.unwrap_or(DEFAULT_DISC_BOARD);
                if !(lo.is_finite() && hi.is_finite() && 1.2 <= lo && lo <= hi && hi <= 3.0) {
                    return Err(bad(format!(
                        "board [{lo}, {hi}] must satisfy 1.2 <= min <= max <= 3"
                    )));
                }
            }
        }
        if !(self.border_band.is_finite() && (0.05..=0.5).contains(&self.border_band)) {
            return Err(bad(format!(
                "border_band {} must be within 0.05..=0.5",
                self.border_band
            )));
        }
        if let Some(s) = self.size_m {
            if !(s.is_finite() && s > 0.0 && s <= 100.0) {
                return Err(bad(format!("size_m {s} must be within 0..100 metres")));
            }
        }
        Ok(())
    }
}

/// Built-in designs, named by `--target-design NAME`. A plain cross is the
/// marked cross with nothing marked, so one preset serves both; bars from
/// 7% to 25% of the side cover the field designs in use (about 1/8 on the
/// real photos of the README, 1/6 on 60 cm boards with 10 cm bars). Road
/// markings' crosses, with arms 7 to 20 bar widths long, are thinner.
/// The three-edge bullseye takes the ring ratios in use (1:2:3, a wide
/// centre disc with a thin outer ring, and between), measured on each
/// target; the five-edge one is the archery-style target of equal rings.
pub fn presets() -> Vec<TargetDesign> {
    let base = |name: &str, kind, polarity| TargetDesign {
        name: name.into(),
        kind,
        polarity,
        bar_width: None,
        ring_radii: None,
        board: None,
        free: FreeArea::None,
        border_band: default_border_band(),
        size_m: None,
    };
    let rings = |name: &str, radii: &[(f64, f64)]| TargetDesign {
        ring_radii: Some(radii.iter().map(|&(lo, hi)| Range(lo, hi)).collect()),
        ..base(name, DesignKind::Rings, Polarity::DarkOnLight)
    };
    vec![
        TargetDesign {
            bar_width: Some(Range(0.07, 0.25)),
            free: FreeArea::Quadrants,
            ..base("cross", DesignKind::Cross, Polarity::LightOnDark)
        },
        base("checker", DesignKind::Checker, Polarity::LightOnDark),
        rings("bullseye", &[(0.2, 0.5), (0.45, 0.8), (1.0, 1.0)]),
        rings(
            "bullseye-5",
            &[
                (0.15, 0.25),
                (0.35, 0.45),
                (0.55, 0.65),
                (0.75, 0.85),
                (1.0, 1.0),
            ],
        ),
        TargetDesign {
            board: Some(DEFAULT_DISC_BOARD),
            ..base("disc-black", DesignKind::Disc, Polarity::DarkOnLight)
        },
        TargetDesign {
            board: Some(DEFAULT_DISC_BOARD),
            ..base("disc-white", DesignKind::Disc, Polarity::LightOnDark)
        },
    ]
}

/// The presets' names, for messages.
pub fn preset_names() -> String {
    presets()
        .into_iter()
        .map(|d| d.name)
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_users_design_is_read_and_checked() {
        let d = TargetDesign::from_json(
            r#"{"name":"club","kind":"cross","bar_width":[0.08,0.14],"free":"quadrants","size_m":0.6}"#,
        )
        .unwrap();
        assert_eq!(d.kind, DesignKind::Cross);
        assert_eq!(d.polarity, Polarity::LightOnDark);
        assert_eq!(d.size_m, Some(0.6));
        for (text, says) in [
            (r#"{"name":"x","kind":"cross"}"#, "needs bar_width"),
            (
                r#"{"name":"x","kind":"cross","bar_width":[0.3,0.1]}"#,
                "must satisfy",
            ),
            (
                r#"{"name":"x","kind":"checker","free":"quadrants"}"#,
                "only a cross's quadrants",
            ),
            (r#"{"name":"x","kind":"star"}"#, "unknown variant"),
            (
                r#"{"name":"x","kind":"checker","colour":1}"#,
                "unknown field",
            ),
        ] {
            let e = TargetDesign::from_json(text).unwrap_err().to_string();
            assert!(e.contains(says), "{text}: {e}");
        }
        for p in presets() {
            p.validate().unwrap();
        }
        let d = TargetDesign::from_json(
            r#"{"name":"b","kind":"rings","polarity":"dark_on_light","ring_radii":[[0.3,0.4],0.7,1]}"#,
        )
        .unwrap();
        assert_eq!(
            d.ring_radii,
            Some(vec![Range(0.3, 0.4), Range(0.7, 0.7), Range(1.0, 1.0)])
        );
        assert_eq!(d.marker_type(), crate::pipeline::detect::MarkerType::Circle);
        for (text, says) in [
            (r#"{"name":"x","kind":"rings"}"#, "need ring_radii"),
            (r#"{"name":"x","kind":"rings","ring_radii":[1]}"#, "2 to 8"),
            (
                r#"{"name":"x","kind":"rings","ring_radii":[0.6,0.5,1]}"#,
                "past the previous",
            ),
            (
                r#"{"name":"x","kind":"rings","ring_radii":[0.3,0.6]}"#,
                "outermost edge: 1",
            ),
            (
                r#"{"name":"x","kind":"disc","board":[1.0,2.0]}"#,
                "1.2 <= min",
            ),
            (
                r#"{"name":"x","kind":"disc","ring_radii":[0.5,1]}"#,
                "only rings",
            ),
        ] {
            let e = TargetDesign::from_json(text).unwrap_err().to_string();
            assert!(e.contains(says), "{text}: {e}");
        }
    }
}
