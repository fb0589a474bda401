//! What a raw drone frame says about the camera that took it: EXIF GPS
//! position and altitude, focal length and sensor size, and DJI's XMP
//! fields (altitudes, gimbal and flight angles). GDAL reads both (EXIF as
//! `EXIF_*` metadata items, XMP in the `xml:XMP` domain), so no second
//! image parser touches untrusted files. Kept with the frame's result; the
//! survey matcher predicts where surveyed points appear from it.

use gdal::{Dataset, Metadata};
use serde::{Deserialize, Serialize};

/// Camera position, orientation and intrinsics from a frame's metadata.
/// Angles in degrees; DJI conventions (yaw clockwise from north, pitch -90
/// looking straight down).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraMeta {
    /// WGS84 latitude and longitude of the camera (EXIF GPS).
    pub lat: f64,
    pub lon: f64,
    /// EXIF GPS altitude, or DJI AbsoluteAltitude when present.
    pub abs_alt_m: Option<f64>,
    /// DJI RelativeAltitude: height above the take-off point.
    pub rel_alt_m: Option<f64>,
    pub gimbal_yaw_deg: Option<f64>,
    pub gimbal_pitch_deg: Option<f64>,
    pub gimbal_roll_deg: Option<f64>,
    pub flight_yaw_deg: Option<f64>,
    pub focal_mm: Option<f64>,
    pub focal_35mm: Option<f64>,
    /// Sensor pixels per millimetre (EXIF FocalPlaneXResolution and unit).
    pub focal_plane_px_per_mm: Option<f64>,
}

impl CameraMeta {
    /// Reads the camera metadata of an open dataset; `None` without a GPS
    /// position.
    pub fn from_dataset(dataset: &Dataset) -> Option<CameraMeta> {
        let item = |key: &str| dataset.metadata_item(key, "");
        let xmp = dataset
            .metadata_domain("xml:XMP")
            .map(|v| v.join("\n"))
            .unwrap_or_default();
        CameraMeta::from_items(item, &xmp)
    }

    /// Builds the metadata from GDAL's `EXIF_*` items and the XMP packet.
    pub fn from_items(item: impl Fn(&str) -> Option<String>, xmp: &str) -> Option<CameraMeta> {
        let lat = dms(&item("EXIF_GPSLatitude")?)?;
        let lon = dms(&item("EXIF_GPSLongitude")?)?;
        let sign = |r: Option<String>, neg: &str| {
            if r.is_some_and(|r| r.trim().eq_ignore_ascii_case(neg)) {
                -1.0
            } else {
                1.0
            }
        };
        let lat = lat * sign(item("EXIF_GPSLatitudeRef"), "S");
        let lon = lon * sign(item("EXIF_GPSLongitudeRef"), "W");
        if !(lat.abs() <= 90.0 && lon.abs() <= 180.0) {
            return None;
        }
        let gps_alt = item("EXIF_GPSAltitude").and_then(|v| number(&v)).map(|a| {
            // Ref 1: below sea level.
            if item("EXIF_GPSAltitudeRef").is_some_and(|r| number(&r) == Some(1.0)) {
                -a
            } else {
                a
            }
        });
        let dji = |name: &str| xmp_number(xmp, &format!("drone-dji:{name}"));
        let px_per_mm = item("EXIF_FocalPlaneXResolution")
            .and_then(|v| number(&v))
            .and_then(|res| {
                let unit = item("EXIF_FocalPlaneResolutionUnit")
                    .and_then(|u| number(&u))
                    .unwrap_or(2.0);
                let mm = match unit as i64 {
                    2 => 25.4,
                    3 => 10.0,
                    4 => 1.0,
                    5 => 0.001,
                    _ => return None,
                };
                Some(res / mm)
            })
            .filter(|v| v.is_finite() && *v > 0.0);
        Some(CameraMeta {
            lat,
            lon,
            abs_alt_m: dji("AbsoluteAltitude").or(gps_alt),
            rel_alt_m: dji("RelativeAltitude"),
            gimbal_yaw_deg: dji("GimbalYawDegree"),
            gimbal_pitch_deg: dji("GimbalPitchDegree"),
            gimbal_roll_deg: dji("GimbalRollDegree"),
            flight_yaw_deg: dji("FlightYawDegree"),
            focal_mm: item("EXIF_FocalLength")
                .and_then(|v| number(&v))
                .filter(|f| *f > 0.0),
            focal_35mm: item("EXIF_FocalLengthIn35mmFilm")
                .and_then(|v| number(&v))
                .filter(|f| *f > 0.0),
            focal_plane_px_per_mm: px_per_mm,
        })
    }
}

/// Steepest look off nadir (degrees) for which a frame's ground sample
/// distance is taken from its height: beyond it the ground's distance
/// varies too much across the frame.
const MAX_GSD_TILT_DEG: f64 = 20.0;

impl CameraMeta {
    /// Focal length in pixels, from the focal length and the focal plane
    /// resolution, or else the 35 mm equivalent over the frame's diagonal.
    pub fn focal_px(&self, width: usize, height: usize) -> Option<f64> {
        match (self.focal_mm, self.focal_plane_px_per_mm, self.focal_35mm) {
            (Some(f), Some(ppm), _) => Some(f * ppm),
            (_, _, Some(f35)) => {
                Some(f35 * (width as f64).hypot(height as f64) / 36f64.hypot(24.0))
            }
            _ => None,
        }
    }

    /// Ground sample distance (metres per pixel) at the frame's centre for
    /// a camera looking down: the height above the take-off point (DJI
    /// RelativeAltitude, so level ground is assumed) over the focal length
    /// in pixels, along the tilted line of sight. None without those, or
    /// when the gimbal's pitch is unknown or more than
    /// [`MAX_GSD_TILT_DEG`] off nadir.
    pub fn ground_m_per_px(&self, width: usize, height: usize) -> Option<f64> {
        let height_m = self.rel_alt_m.filter(|h| *h > 1.0)?;
        let tilt = 90.0 + self.gimbal_pitch_deg?;
        if tilt.abs() > MAX_GSD_TILT_DEG {
            return None;
        }
        let focal = self.focal_px(width, height).filter(|f| *f > 0.0)?;
        Some(height_m / tilt.to_radians().cos() / focal)
    }
}

/// The numbers in a GDAL EXIF value: `(37) (46) (30.12)` or `24`.
fn numbers(value: &str) -> Vec<f64> {
    value
        .split(|c: char| c == '(' || c == ')' || c.is_whitespace() || c == ',')
        .filter(|t| !t.is_empty())
        .filter_map(|t| t.parse::<f64>().ok())
        .filter(|v| v.is_finite())
        .collect()
}

fn number(value: &str) -> Option<f64> {
    numbers(value).first().copied()
}

/// Degrees, minutes, seconds to decimal degrees.
fn dms(value: &str) -> Option<f64> {
    let n = numbers(value);
    match n.as_slice() {
        [d, m, s, ..] => Some(d + m / 60.0 + s / 3600.0),
        [d] => Some(*d),
        _ => None,
    }
}

/// A numeric XMP property, as an attribute (`name="+12.5"`) or an element
/// (`<name>12.5</name>`).
fn xmp_number(xmp: &str, name: &str) -> Option<f64> {
    if let Some(start) = xmp.find(&format!("{name}=\"")) {
        let rest = &xmp[start + name.len() + 2..];
        return rest[..rest.find('"')?].trim().parse().ok();
    }
    let open = format!("<{name}>");
    let start = xmp.find(&open)? + open.len();
    let rest = &xmp[start..];
    rest[..rest.find('<')?].trim().parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What the generator writes as a drone camera does (its own EXIF and
    /// XMP writer), GDAL and this module read back.
    #[test]
    fn gdal_reads_the_metadata_a_drone_frame_carries() {
        use gcp_synth::{write_drone_meta, write_image, DroneMeta, GreyImage, SampleFormat};
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("DJI_0001.JPG");
        let img = GreyImage {
            width: 64,
            height: 48,
            data: vec![128.0; 64 * 48],
        };
        write_image(&path, &img, SampleFormat::Jpeg, None).unwrap();
        let meta = DroneMeta {
            lat: -33.8567844,
            lon: 151.2152967,
            abs_alt_m: 152.3,
            rel_alt_m: 99.9,
            gimbal_yaw_deg: -31.5,
            gimbal_pitch_deg: -89.9,
            gimbal_roll_deg: 0.1,
            flight_yaw_deg: -30.0,
            focal_mm: 8.8,
            focal_plane_px_per_cm: 3003.0,
        };
        write_drone_meta(&path, &meta).unwrap();
        crate::pipeline::init_native();
        let ds = gdal::Dataset::open(&path).unwrap();
        let m = CameraMeta::from_dataset(&ds).expect("camera metadata");
        assert!((m.lat - meta.lat).abs() < 1e-7, "{m:?}");
        assert!((m.lon - meta.lon).abs() < 1e-7, "{m:?}");
        assert_eq!(m.abs_alt_m, Some(152.3));
        assert_eq!(m.rel_alt_m, Some(99.9));
        assert_eq!(m.gimbal_yaw_deg, Some(-31.5));
        assert_eq!(m.gimbal_pitch_deg, Some(-89.9));
        assert_eq!(m.flight_yaw_deg, Some(-30.0));
        assert_eq!(m.focal_mm, Some(8.8));
        assert!((m.focal_plane_px_per_mm.unwrap() - 300.3).abs() < 1e-9);
    }

    #[test]
    fn exif_and_dji_xmp_values_are_read() {
        let items = |k: &str| {
            Some(
                match k {
                    "EXIF_GPSLatitude" => "(37) (46) (30.6)",
                    "EXIF_GPSLatitudeRef" => "N",
                    "EXIF_GPSLongitude" => "(122) (25) (9)",
                    "EXIF_GPSLongitudeRef" => "W",
                    "EXIF_GPSAltitude" => "(120.5)",
                    "EXIF_FocalLength" => "(8.8)",
                    "EXIF_FocalPlaneXResolution" => "(4000)",
                    "EXIF_FocalPlaneResolutionUnit" => "3",
                    _ => return None,
                }
                .to_string(),
            )
        };
        let xmp = r#"<rdf:Description drone-dji:RelativeAltitude="+80.20"
            drone-dji:GimbalPitchDegree="-89.90"><drone-dji:GimbalYawDegree>-30.5</drone-dji:GimbalYawDegree>"#;
        let m = CameraMeta::from_items(items, xmp).unwrap();
        assert!((m.lat - 37.7751666).abs() < 1e-6);
        assert!((m.lon + 122.4191666).abs() < 1e-6);
        assert_eq!(m.abs_alt_m, Some(120.5));
        assert_eq!(m.rel_alt_m, Some(80.2));
        assert_eq!(m.gimbal_pitch_deg, Some(-89.9));
        assert_eq!(m.gimbal_yaw_deg, Some(-30.5));
        assert_eq!(m.focal_plane_px_per_mm, Some(400.0));
        assert_eq!(m.gimbal_roll_deg, None);
        assert!(CameraMeta::from_items(|_| None, xmp).is_none());
        // 80.2 m over 8.8 mm x 400 px/mm = 3520 px: 2.28 cm per pixel.
        let gsd = m.ground_m_per_px(4000, 3000).unwrap();
        assert!(
            (gsd - 80.2 / 3520.0 / 0.1f64.to_radians().cos()).abs() < 1e-9,
            "{gsd}"
        );
        let oblique = CameraMeta {
            gimbal_pitch_deg: Some(-45.0),
            ..m.clone()
        };
        assert_eq!(oblique.ground_m_per_px(4000, 3000), None);
        let no_height = CameraMeta {
            rel_alt_m: None,
            ..m
        };
        assert_eq!(no_height.ground_m_per_px(4000, 3000), None);
    }
}
