//! Candidate regions for the circle detector: dark regions of an adaptive
//! threshold and the holes inside them, as OpenCV contours.
//!
//! This stage only proposes; every candidate is verified on the grey image
//! by its detector, so it errs on the side of proposing too much.

use opencv::core::{Mat, Point, Vector};
use opencv::imgproc;

/// Adaptive-threshold window, in pixels: wider than the bars and rings of
/// targets down to the smallest size searched (a 40 px cross has 6-10 px
/// bars), so their dark parts stand out against the local mean.
pub const THRESHOLD_WINDOW_PX: i32 = 31;
/// A pixel is dark when this many grey levels below its window's mean: above
/// ground-texture grain, below the ~35 levels left of a low-contrast print
/// in shadow.
pub const THRESHOLD_OFFSET: f64 = 10.0;

/// One contour of the thresholded tile.
#[derive(Debug, Clone)]
pub struct Blob {
    /// Enclosed area in square pixels.
    pub area: f64,
    /// The contour's points (pixel centres), for ellipse fitting.
    pub points: Vector<Point>,
}

/// Dark regions and their holes whose enclosed area lies in `area_range`.
/// `mask` is scratch space reused across tiles.
pub fn find_blobs(tile: &Mat, area_range: (f64, f64), mask: &mut Mat) -> opencv::Result<Vec<Blob>> {
    // OpenCV compares with (mean - C): BINARY_INV marks src <= mean - C.
    imgproc::adaptive_threshold(
        tile,
        mask,
        255.0,
        imgproc::ADAPTIVE_THRESH_MEAN_C,
        imgproc::THRESH_BINARY_INV,
        THRESHOLD_WINDOW_PX,
        THRESHOLD_OFFSET,
    )?;
    let mut contours: Vector<Vector<Point>> = Vector::new();
    // Outer boundaries of dark regions and of their holes alike.
    imgproc::find_contours(
        mask,
        &mut contours,
        imgproc::RETR_LIST,
        imgproc::CHAIN_APPROX_NONE,
        Point::new(0, 0),
    )?;
    let mut out = Vec::new();
    for contour in contours.iter() {
        // A contour encloses at least (perimeter / 4)^2 when square; skip
        // tiny ones before computing moments.
        let n = contour.len() as f64;
        if n * n / 16.0 < area_range.0 * 0.5 || n < 8.0 {
            continue;
        }
        let m = imgproc::moments(&contour, false)?;
        if m.m00 < area_range.0 || m.m00 > area_range.1 {
            continue;
        }
        out.push(Blob {
            area: m.m00,
            points: contour,
        });
    }
    Ok(out)
}
