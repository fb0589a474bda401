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
}

/// Which colour the design's figure (the cross's bars) has on its board.
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

/// An inclusive range of a proportion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Range(pub f64, pub f64);

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
    /// Cross only: the bars' colour on the board.
    #[serde(default = "light_on_dark")]
    pub polarity: Polarity,
    /// Cross only: bar width over the board's side.
    #[serde(default)]
    pub bar_width: Option<Range>,
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
}

impl TargetDesign {
    /// The detection mode that looks for this design.
    pub fn marker_type(&self) -> super::MarkerType {
        match self.kind {
            DesignKind::Cross | DesignKind::Checker => super::MarkerType::Crosshair,
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
    pub fn from_name_or_file(arg: &str) -> Result<TargetDesign, String> {
        if let Some(d) = TargetDesign::preset(arg) {
            return Ok(d);
        }
        let text = std::fs::read_to_string(arg).map_err(|e| {
            let names: Vec<String> = presets().into_iter().map(|d| d.name).collect();
            format!(
                "target design {arg:?} is neither a preset ({}) nor a readable file: {e}",
                names.join(", ")
            )
        })?;
        TargetDesign::from_json(&text).map_err(|e| format!("{arg}: {e}"))
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
            DesignKind::Checker => {
                if self.bar_width.is_some() {
                    return Err(bad("a checker has no bar_width".into()));
                }
                if self.free != FreeArea::None {
                    return Err(bad("a checker's quadrants cannot be free".into()));
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
pub fn presets() -> Vec<TargetDesign> {
    vec![
        TargetDesign {
            name: "cross".into(),
            kind: DesignKind::Cross,
            polarity: Polarity::LightOnDark,
            bar_width: Some(Range(0.07, 0.25)),
            free: FreeArea::Quadrants,
            border_band: default_border_band(),
            size_m: None,
        },
        TargetDesign {
            name: "checker".into(),
            kind: DesignKind::Checker,
            polarity: Polarity::LightOnDark,
            bar_width: None,
            free: FreeArea::None,
            border_band: default_border_band(),
            size_m: None,
        },
    ]
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
                "cannot be free",
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
    }
}
