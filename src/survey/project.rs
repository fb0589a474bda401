//! Where a surveyed point should appear in a frame, and how sure that is.
//!
//! - Georeferenced frames: the point goes through PROJ into the raster's
//!   CRS and through the inverse geotransform to pixels; the prediction is
//!   as good as the georeference (uncertainty 0 here; the tolerance covers
//!   the rest).
//! - Raw frames: a pinhole camera at the EXIF GPS position, looking along
//!   DJI's gimbal yaw/pitch/roll (flight yaw, or nadir, when absent), with
//!   the focal length in pixels from the focal length and focal plane
//!   resolution (or the 35 mm equivalent). The uncertainty in pixels grows
//!   with what the metadata cannot know: GPS position (5 m), height (5 m
//!   with DJI's relative altitude, 15 m from GPS altitude), tilt and yaw
//!   (3 degrees from the gimbal, 10 without it).
//!
//! Pixel coordinates are OpenCV's: the top-left pixel's centre is 0,0.

use crate::pipeline::camera::CameraMeta;
use crate::pipeline::frame::FrameResult;
use crate::pipeline::georef::{GeorefError, Transformer, WGS84};

use super::Survey;

/// Metres per degree of latitude on the WGS84 mean sphere.
const M_PER_DEG: f64 = 6_371_008.8 * std::f64::consts::PI / 180.0;

/// What an expected position rests on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Basis {
    Georeference,
    Camera,
}

/// A surveyed point's expected position in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Expected {
    pub px: f64,
    pub py: f64,
    /// One standard deviation of the prediction, in pixels.
    pub sigma_px: f64,
    pub basis: Basis,
}

/// Why a frame allows no prediction of where survey points appear (the
/// note beside the frame in a match report).
#[derive(Debug, thiserror::Error)]
pub enum NoPrediction {
    #[error("the frame has neither a georeference nor camera GPS metadata")]
    NoPose,
    #[error("the frame's metadata gives no focal length (EXIF FocalLength with FocalPlaneXResolution, or FocalLengthIn35mmFilm)")]
    NoFocalLength,
    #[error("survey to {to}: {source}")]
    Projection {
        to: &'static str,
        source: GeorefError,
    },
}

/// Expected positions of every survey point in `frame` (`None` for a point
/// behind the camera), or why the frame allows no prediction.
pub fn expected_positions(
    frame: &FrameResult,
    survey: &Survey,
    transformer: &mut Transformer,
) -> Result<Vec<Option<Expected>>, NoPrediction> {
    let mut points: Vec<(f64, f64)> = survey.points.iter().map(|p| (p.x, p.y)).collect();
    if let Some(geo) = &frame.georeference {
        transformer
            .transform(&survey.crs, &geo.crs, &mut points)
            .map_err(|source| NoPrediction::Projection {
                to: "the frame's CRS",
                source,
            })?;
        return Ok(points
            .iter()
            .map(|&(x, y)| {
                geo.raster_crs_to_pixel(x, y).map(|(px, py)| Expected {
                    px,
                    py,
                    sigma_px: 0.0,
                    basis: Basis::Georeference,
                })
            })
            .collect());
    }
    let Some(camera) = &frame.camera else {
        return Err(NoPrediction::NoPose);
    };
    let focal = focal_px(camera, frame.width, frame.height).ok_or(NoPrediction::NoFocalLength)?;
    transformer
        .transform(&survey.crs, WGS84, &mut points)
        .map_err(|source| NoPrediction::Projection {
            to: "WGS84",
            source,
        })?;
    Ok(points
        .iter()
        .zip(&survey.points)
        .map(|(&(lon, lat), p)| {
            project_camera(camera, focal, frame.width, frame.height, lon, lat, p.z)
        })
        .collect())
}

/// Focal length in pixels.
pub fn focal_px(camera: &CameraMeta, width: usize, height: usize) -> Option<f64> {
    camera.focal_px(width, height)
}

/// Projects a WGS84 point (`z` in the survey's heights) into the frame.
pub fn project_camera(
    camera: &CameraMeta,
    focal: f64,
    width: usize,
    height: usize,
    lon: f64,
    lat: f64,
    z: f64,
) -> Option<Expected> {
    let (h, sigma_h) = match (camera.rel_alt_m, camera.abs_alt_m) {
        (Some(rel), _) => (rel, 5.0),
        (None, Some(abs)) => (abs - z, 15.0),
        _ => return None,
    };
    if h < 1.0 {
        return None;
    }
    // East, north, up from the camera to the point.
    let east = (lon - camera.lon) * M_PER_DEG * camera.lat.to_radians().cos();
    let north = (lat - camera.lat) * M_PER_DEG;
    let v = [east, north, -h];
    let (yaw, sigma_yaw) = match (camera.gimbal_yaw_deg, camera.flight_yaw_deg) {
        (Some(y), _) => (y, 3.0_f64),
        (None, Some(y)) => (y, 10.0),
        (None, None) => (0.0, 180.0),
    };
    let (pitch, sigma_tilt) = match camera.gimbal_pitch_deg {
        Some(p) => (p, 3.0_f64),
        None => (-90.0, 10.0),
    };
    let roll = camera.gimbal_roll_deg.unwrap_or(0.0);
    let (right, down, forward) = camera_axes(yaw, pitch, roll);
    let dot = |a: [f64; 3]| a[0] * v[0] + a[1] * v[1] + a[2] * v[2];
    let depth = dot(forward);
    if depth <= 0.0 {
        return None;
    }
    let (cx, cy) = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    let px = cx + focal * dot(right) / depth;
    let py = cy + focal * dot(down) / depth;
    let r = (px - cx).hypot(py - cy);
    let sigma_px = ((5.0 * focal / h).powi(2)
        + (r * sigma_h / h).powi(2)
        + (focal * sigma_tilt.to_radians()).powi(2)
        + (r * sigma_yaw.to_radians()).powi(2))
    .sqrt();
    Some(Expected {
        px,
        py,
        sigma_px,
        basis: Basis::Camera,
    })
}

/// The camera's right, down and forward unit vectors in east-north-up,
/// for DJI angles in degrees: yaw clockwise from north, pitch from the
/// horizon (-90 straight down, image top towards the yaw), roll about the
/// optical axis (positive: right side down).
pub fn camera_axes(yaw: f64, pitch: f64, roll: f64) -> ([f64; 3], [f64; 3], [f64; 3]) {
    let (sy, cy) = yaw.to_radians().sin_cos();
    let (sp, cp) = pitch.to_radians().sin_cos();
    let (sr, cr) = roll.to_radians().sin_cos();
    let heading = [sy, cy, 0.0];
    let right0 = [cy, -sy, 0.0];
    let forward = [cp * heading[0], cp * heading[1], sp];
    let up0 = [-sp * heading[0], -sp * heading[1], cp];
    let right = [
        cr * right0[0] - sr * up0[0],
        cr * right0[1] - sr * up0[1],
        cr * right0[2] - sr * up0[2],
    ];
    let up = [
        cr * up0[0] + sr * right0[0],
        cr * up0[1] + sr * right0[1],
        cr * up0[2] + sr * right0[2],
    ];
    (right, [-up[0], -up[1], -up[2]], forward)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nadir(yaw: f64) -> CameraMeta {
        CameraMeta {
            lat: 37.0,
            lon: -122.0,
            abs_alt_m: None,
            rel_alt_m: Some(100.0),
            gimbal_yaw_deg: Some(yaw),
            gimbal_pitch_deg: Some(-90.0),
            gimbal_roll_deg: Some(0.0),
            flight_yaw_deg: None,
            focal_mm: Some(10.0),
            focal_plane_px_per_mm: Some(300.0),
            focal_35mm: None,
        }
    }

    #[test]
    fn a_nadir_camera_puts_north_up_and_turns_with_its_yaw() {
        let m_lat = 10.0 / M_PER_DEG;
        // 10 m north of a nadir camera facing north, 100 m up, f = 3000 px:
        // 300 px above the centre.
        let e = project_camera(&nadir(0.0), 3000.0, 4001, 3001, -122.0, 37.0 + m_lat, 0.0).unwrap();
        assert!(
            (e.px - 2000.0).abs() < 1e-6 && (e.py - 1200.0).abs() < 1e-6,
            "{e:?}"
        );
        // Facing east, north is to the left.
        let e =
            project_camera(&nadir(90.0), 3000.0, 4001, 3001, -122.0, 37.0 + m_lat, 0.0).unwrap();
        assert!(
            (e.px - 1700.0).abs() < 1e-6 && (e.py - 1500.0).abs() < 1e-6,
            "{e:?}"
        );
        // Looking at the horizon facing north, a point below is behind the
        // image centre's ray but in front of the camera: below the centre.
        let (right, down, forward) = camera_axes(0.0, 0.0, 0.0);
        assert_eq!(
            (right, down, forward),
            ([1.0, -0.0, 0.0], [-0.0, -0.0, -1.0], [0.0, 1.0, 0.0])
        );
    }
}
