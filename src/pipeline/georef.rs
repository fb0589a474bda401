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
    /// Parses and validates a CRS definition (`EPSG:32611`, WKT, PROJJSON or
    /// a PROJ string). Only coordinate reference systems are accepted, not
    /// bare coordinate operations.
    pub fn parse(definition: &str) -> Result<TargetCrs, GeorefError> {
        let invalid = |reason: &str| GeorefError::InvalidCrs {
            crs: definition.to_string(),
            reason: reason.to_string(),
        };
        let trimmed = definition.trim();
        if trimmed.is_empty() {
            return Err(invalid("empty"));
        }
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
            let auth = proj_sys::proj_get_id_auth_name(pj, 0);
            let code = proj_sys::proj_get_id_code(pj, 0);
            let name = if !auth.is_null() && !code.is_null() {
                format!(
                    "{}:{}",
                    CStr::from_ptr(auth).to_string_lossy(),
                    CStr::from_ptr(code).to_string_lossy()
                )
            } else {
                trimmed.to_string()
            };
            proj_sys::proj_destroy(pj);
            proj_sys::proj_context_destroy(ctx);
            if !is_crs {
                return Err(invalid("not a coordinate reference system"));
            }
            Ok(TargetCrs { name, geographic })
        }
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
    pub fn from_dataset(dataset: &Dataset) -> Result<Georeference, String> {
        let geotransform = dataset
            .geo_transform()
            .map_err(|_| "frame has no geotransform".to_string())?;
        if geotransform == [0.0, 1.0, 0.0, 0.0, 0.0, 1.0] {
            return Err("frame has no geotransform".into());
        }
        let srs = dataset
            .spatial_ref()
            .map_err(|_| "frame has a geotransform but no CRS".to_string())?;
        let crs = match (srs.auth_name(), srs.auth_code()) {
            (Some(name), Ok(code)) => format!("{name}:{code}"),
            _ => srs
                .to_wkt()
                .map_err(|e| format!("frame CRS cannot be exported: {e}"))?,
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
