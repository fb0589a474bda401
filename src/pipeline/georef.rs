//! Pixel to world: the raster's affine geotransform, then PROJ from the
//! raster's CRS to the client's CRS and to WGS84 for GeoJSON.
//!
//! Pixel convention: detections use OpenCV's (pixel centres on integers);
//! GDAL's geotransform puts pixel corners on integers, so 0.5 is added first.
//! Axis order is normalized for visualization everywhere: x = easting or
//! longitude, y = northing or latitude.

use std::collections::HashMap;
use std::ffi::{CStr, CString};

use gdal::Dataset;
use proj::Proj;

/// CRS of GeoJSON geometry (RFC 7946: WGS84 longitude, latitude).
pub const WGS84: &str = "EPSG:4326";

/// Why a CRS or a transformation could not be used.
#[derive(Debug, thiserror::Error)]
pub enum GeorefError {
    #[error("unknown or invalid CRS {crs:?}: {reason}")]
    InvalidCrs { crs: String, reason: String },
    #[error("no transformation from {from} to {to}: {reason}")]
    NoTransform {
        from: String,
        to: String,
        reason: String,
    },
    #[error("coordinate transformation failed: {0}")]
    Transform(String),
}

/// Why a frame has no usable georeference (said in its warning; the frame
/// still gets pixel results).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NoGeoreference {
    #[error("frame has no geotransform")]
    NoGeotransform,
    #[error("frame has a geotransform but no CRS")]
    NoCrs,
    #[error("frame CRS cannot be exported: {0}")]
    CrsNotExportable(String),
}

/// A CRS the client asked for, checked by PROJ before any frame is read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TargetCrs {
    /// What goes to PROJ and into the `crs` column: `AUTH:CODE` when PROJ
    /// knows one, else the definition as given.
    pub name: String,
    /// Geographic CRSs are written with more decimals (degrees, not metres).
    pub geographic: bool,
}

impl TargetCrs {
    /// Parses and validates a CRS definition: `EPSG:32611`, WKT, PROJJSON,
    /// a PROJ string with or without `+type=crs` (as GDAL's
    /// `SetFromUserInput` reads it: `+proj=utm +zone=11 +datum=WGS84`, the
    /// first line of OpenDroneMap's own `gcp_list.txt` files), or ODM's
    /// `WGS84 UTM 11N`. Only coordinate reference systems are accepted, not
    /// bare coordinate operations. The name is `AUTH:CODE` when the
    /// definition is, or is equivalent to, one EPSG CRS.
    pub fn parse(definition: &str) -> Result<TargetCrs, GeorefError> {
        let invalid = |reason: &str| GeorefError::InvalidCrs {
            crs: definition.to_string(),
            reason: reason.to_string(),
        };
        let trimmed = definition.trim();
        if trimmed.is_empty() {
            return Err(invalid("empty"));
        }
        let text = odm_utm(trimmed).unwrap_or_else(|| proj_string_as_crs(trimmed));
        let trimmed = text.as_str();
        let c_def = CString::new(trimmed).map_err(|_| invalid("contains a NUL byte"))?;
        // SAFETY: a fresh context and object, both destroyed before returning;
        // every string PROJ returns is copied before destruction.
        unsafe {
            let ctx = proj_sys::proj_context_create();
            // PROJ logs failures to stderr itself; the error value says it.
            proj_sys::proj_log_level(ctx, proj_sys::PJ_LOG_LEVEL_PJ_LOG_NONE);
            let pj = proj_sys::proj_create(ctx, c_def.as_ptr());
            if pj.is_null() {
                proj_sys::proj_context_destroy(ctx);
                return Err(invalid(
                    "not a CRS known to PROJ (expected EPSG:n, WKT, PROJJSON or a PROJ string)",
                ));
            }
            use proj_sys::*;
            let ty = proj_get_type(pj);
            let geographic = [
                PJ_TYPE_PJ_TYPE_GEOGRAPHIC_2D_CRS,
                PJ_TYPE_PJ_TYPE_GEOGRAPHIC_3D_CRS,
            ]
            .contains(&ty);
            let is_crs = geographic
                || [
                    PJ_TYPE_PJ_TYPE_PROJECTED_CRS,
                    PJ_TYPE_PJ_TYPE_COMPOUND_CRS,
                    PJ_TYPE_PJ_TYPE_BOUND_CRS,
                    PJ_TYPE_PJ_TYPE_GEOCENTRIC_CRS,
                ]
                .contains(&ty);
            let name = auth_code(pj)
                .or_else(|| is_crs.then(|| identified_epsg(ctx, pj)).flatten())
                .unwrap_or_else(|| trimmed.to_string());
            proj_sys::proj_destroy(pj);
            proj_sys::proj_context_destroy(ctx);
            if !is_crs {
                return Err(invalid("not a coordinate reference system"));
            }
            Ok(TargetCrs { name, geographic })
        }
    }
}

/// `AUTH:CODE` of a PROJ object that carries an identifier.
///
/// # Safety
/// `pj` is a live PROJ object.
unsafe fn auth_code(pj: *const proj_sys::PJ) -> Option<String> {
    let auth = proj_sys::proj_get_id_auth_name(pj, 0);
    let code = proj_sys::proj_get_id_code(pj, 0);
    (!auth.is_null() && !code.is_null()).then(|| {
        format!(
            "{}:{}",
            CStr::from_ptr(auth).to_string_lossy(),
            CStr::from_ptr(code).to_string_lossy()
        )
    })
}

/// The one EPSG CRS PROJ finds equivalent to `pj` (confidence 70 and up:
/// equal in every parameter, the name aside), if exactly one is.
///
/// # Safety
/// `ctx` and `pj` are live PROJ objects.
unsafe fn identified_epsg(
    ctx: *mut proj_sys::PJ_CONTEXT,
    pj: *const proj_sys::PJ,
) -> Option<String> {
    let mut confidence: *mut std::os::raw::c_int = std::ptr::null_mut();
    let list =
        proj_sys::proj_identify(ctx, pj, c"EPSG".as_ptr(), std::ptr::null(), &mut confidence);
    if list.is_null() {
        return None;
    }
    let n = proj_sys::proj_list_get_count(list).max(0) as usize;
    let best = (0..n)
        .map(|i| (*confidence.add(i), i))
        .filter(|&(c, _)| c >= 70)
        .collect::<Vec<_>>();
    let top = best.iter().map(|b| b.0).max();
    let winners: Vec<usize> = best
        .iter()
        .filter(|b| Some(b.0) == top)
        .map(|b| b.1)
        .collect();
    let name = if let [only] = winners[..] {
        let obj = proj_sys::proj_list_get(ctx, list, only as std::os::raw::c_int);
        let name = if obj.is_null() { None } else { auth_code(obj) };
        if !obj.is_null() {
            proj_sys::proj_destroy(obj);
        }
        name
    } else {
        None
    };
    proj_sys::proj_int_list_destroy(confidence);
    proj_sys::proj_list_destroy(list);
    name
}

/// OpenDroneMap's `WGS84 UTM <zone><N|S>` header as its EPSG code.
fn odm_utm(s: &str) -> Option<String> {
    let words: Vec<&str> = s.split_whitespace().collect();
    let [datum, utm, zone] = words[..] else {
        return None;
    };
    if !datum.eq_ignore_ascii_case("WGS84") || !utm.eq_ignore_ascii_case("UTM") {
        return None;
    }
    let (number, hemisphere) = zone.split_at(zone.len().checked_sub(1)?);
    let number: u32 = number.parse().ok().filter(|z| (1..=60).contains(z))?;
    let base = match hemisphere {
        "N" | "n" => 32600,
        "S" | "s" => 32700,
        _ => return None,
    };
    Some(format!("EPSG:{}", base + number))
}

/// A PROJ string without `+type=crs` is a conversion to PROJ; GDAL, ODM
/// and most tools read it as the CRS it implies, and so do we.
fn proj_string_as_crs(s: &str) -> String {
    let is_proj = s.starts_with("+proj=") || s.starts_with("proj=");
    let words = || s.split_whitespace().map(|t| t.trim_start_matches('+'));
    // A pipeline is an operation whatever it is told.
    let operation = words().any(|t| t == "proj=pipeline" || t == "step");
    if is_proj && !operation && !words().any(|t| t == "type=crs") {
        format!("{s} +type=crs")
    } else {
        s.to_string()
    }
}

/// A raster's georeference: affine geotransform plus the CRS it maps into.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Georeference {
    /// GDAL order: x0, dx/dcol, dx/drow, y0, dy/dcol, dy/drow.
    pub geotransform: [f64; 6],
    /// CRS definition for PROJ: `AUTH:CODE` when GDAL identifies one, else WKT.
    pub crs: String,
    /// Ground size of a pixel in metres, when the CRS is projected (its
    /// linear unit converts to metres) or geographic (degrees at the frame's
    /// latitude, on a sphere: good to 0.5% for a size range).
    pub ground_m_per_px: Option<f64>,
}

impl Georeference {
    /// Reads the georeference of an open dataset, or says why there is none.
    pub fn from_dataset(dataset: &Dataset) -> Result<Georeference, NoGeoreference> {
        let geotransform = dataset
            .geo_transform()
            .map_err(|_| NoGeoreference::NoGeotransform)?;
        if geotransform == [0.0, 1.0, 0.0, 0.0, 0.0, 1.0] {
            return Err(NoGeoreference::NoGeotransform);
        }
        let srs = dataset.spatial_ref().map_err(|_| NoGeoreference::NoCrs)?;
        let crs = match (srs.auth_name(), srs.auth_code()) {
            (Some(name), Ok(code)) => format!("{name}:{code}"),
            _ => srs
                .to_wkt()
                .map_err(|e| NoGeoreference::CrsNotExportable(e.to_string()))?,
        };
        let pixel = geotransform[1].hypot(geotransform[4]);
        let ground_m_per_px = if srs.is_projected() {
            Some(pixel * srs.linear_units())
        } else if srs.is_geographic() {
            let lat = geotransform[3].to_radians();
            Some(pixel * 111_320.0 * lat.cos().abs().max(0.01))
        } else {
            None
        }
        .filter(|m| m.is_finite() && *m > 0.0);
        Ok(Georeference {
            geotransform,
            crs,
            ground_m_per_px,
        })
    }

    /// OpenCV pixel coordinates of a point given in the raster's CRS (the
    /// inverse of [`Georeference::pixel_to_raster_crs`]); `None` for a
    /// degenerate geotransform.
    pub fn raster_crs_to_pixel(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let g = &self.geotransform;
        let det = g[1] * g[5] - g[2] * g[4];
        if det.abs() < 1e-300 {
            return None;
        }
        let (dx, dy) = (x - g[0], y - g[3]);
        let col = (g[5] * dx - g[2] * dy) / det;
        let row = (-g[4] * dx + g[1] * dy) / det;
        Some((col - 0.5, row - 0.5))
    }

    /// World coordinates, in the raster's CRS, of a point in OpenCV pixel
    /// coordinates (pixel centres on integers).
    pub fn pixel_to_raster_crs(&self, px: f64, py: f64) -> (f64, f64) {
        let g = &self.geotransform;
        let (col, row) = (px + 0.5, py + 0.5);
        (
            g[0] + col * g[1] + row * g[2],
            g[3] + col * g[4] + row * g[5],
        )
    }
}

/// PROJ transformations, created on first use and kept per (source, target).
/// `Proj` is neither Send nor Sync and costs ~10 ms to create, so each worker
/// thread owns one cache.
#[derive(Default)]
pub struct Transformer {
    cache: HashMap<(String, String), Proj>,
}

impl Transformer {
    /// Transforms points from CRS `from` to CRS `to`, in place.
    pub fn transform(
        &mut self,
        from: &str,
        to: &str,
        points: &mut [(f64, f64)],
    ) -> Result<(), GeorefError> {
        if from == to {
            return Ok(());
        }
        let key = (from.to_string(), to.to_string());
        if !self.cache.contains_key(&key) {
            let proj =
                Proj::new_known_crs(from, to, None).map_err(|e| GeorefError::NoTransform {
                    from: short_crs(from),
                    to: short_crs(to),
                    reason: e.to_string(),
                })?;
            self.cache.insert(key.clone(), proj);
        }
        let proj = &self.cache[&key];
        for p in points.iter_mut() {
            *p = proj
                .convert(*p)
                .map_err(|e| GeorefError::Transform(e.to_string()))?;
            if !(p.0.is_finite() && p.1.is_finite()) {
                return Err(GeorefError::Transform(
                    "point outside the CRS's domain".into(),
                ));
            }
        }
        Ok(())
    }
}

/// A WKT definition is too long for a message: keep its first line's start.
fn short_crs(def: &str) -> String {
    let first = def.lines().next().unwrap_or(def);
    first.chars().take(60).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crs_forms_that_gdal_and_odm_accept_are_crss() {
        for form in [
            "EPSG:32611",
            "+proj=utm +zone=11 +ellps=WGS84 +datum=WGS84 +units=m +no_defs",
            "+proj=utm +zone=11 +datum=WGS84 +units=m +no_defs +type=crs",
            "WGS84 UTM 11N",
            "wgs84 utm 11n",
        ] {
            let crs = TargetCrs::parse(form).unwrap();
            assert_eq!(crs.name, "EPSG:32611", "{form}");
            assert!(!crs.geographic);
        }
        assert_eq!(
            TargetCrs::parse("WGS84 UTM 33S").unwrap().name,
            "EPSG:32733"
        );
        let lonlat = TargetCrs::parse("+proj=longlat +datum=WGS84 +no_defs").unwrap();
        assert_eq!(lonlat.name, "EPSG:4326");
        assert!(lonlat.geographic);
        // A PROJ string no EPSG CRS equals keeps its text.
        let local = TargetCrs::parse(
            "+proj=tmerc +lat_0=0 +lon_0=7.3 +k=1 +x_0=5000 +y_0=0 +ellps=GRS80 +units=m",
        )
        .unwrap();
        assert!(local.name.starts_with("+proj=tmerc"), "{}", local.name);
        for bad in [
            "WGS84 UTM 61N",
            "WGS84 UTM 11X",
            "+proj=pipeline +step +proj=utm +zone=11",
        ] {
            assert!(TargetCrs::parse(bad).is_err(), "{bad}");
        }
    }
}
