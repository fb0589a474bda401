//! The canvas every frame is drawn on (float grey, 0 = black, 1 = white,
//! the whole frame or a window of it) and the painting primitives that
//! targets, look-alikes and the scene share: area anti-aliased shapes,
//! shading over a disc, square corners under mild perspective. What was
//! painted where is a [`Truth`].

use super::geometry::Pt;
use super::tags::TargetKind;
use super::Rng;

/// Subsamples per pixel side when painting shapes: 8x8 = 64 samples keeps
/// the area-coverage error of an edge under 1/64 of a pixel.
const SUPERSAMPLE: usize = 8;
/// Printed target paper: white and black reflectance.
pub(super) const PAPER_WHITE: f32 = 0.92;
pub(super) const PAPER_BLACK: f32 = 0.07;

/// Where a marker really is.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    pub kind: TargetKind,
    pub id: u32,
    /// Image of the marker's centre under its homography.
    pub center: Pt,
    /// Outer black-border corners, marker order.
    pub corners: [Pt; 4],
    pub side_px: f64,
}

/// The part of a frame being drawn: the frame's size, and the region of it
/// held in memory (the whole frame, or a window and a margin around it).
/// Drawing takes the same random draws and gives every pixel of the region
/// the value it has in the whole frame; filters (blur) see the region's
/// edge as the frame's, so a margin wider than their reach keeps the
/// window inside it exact.
pub(super) struct Canvas {
    /// The frame's width and height.
    pub frame: (usize, usize),
    /// The region's top left corner in the frame, and its size.
    pub(super) x0: usize,
    pub(super) y0: usize,
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) data: Vec<f32>,
}

impl Canvas {
    /// Frame columns in the region.
    pub fn xs(&self) -> std::ops::Range<usize> {
        self.x0..self.x0 + self.width
    }
    /// Frame rows in the region.
    pub fn ys(&self) -> std::ops::Range<usize> {
        self.y0..self.y0 + self.height
    }
    /// The pixel at frame position (x, y), which must be in the region.
    pub fn px(&mut self, x: usize, y: usize) -> &mut f32 {
        &mut self.data[(y - self.y0) * self.width + (x - self.x0)]
    }
}

/// Paints a shape over `bbox` with area anti-aliasing: `shade(x, y)` gives
/// the shape's value at an image point, or None outside the shape.
pub(super) fn paint(
    img: &mut Canvas,
    bbox: (f64, f64, f64, f64),
    shade: impl Fn(f64, f64) -> Option<f32>,
) {
    let x0 = ((bbox.0.floor() as i64).max(0) as usize).max(img.x0);
    let y0 = ((bbox.1.floor() as i64).max(0) as usize).max(img.y0);
    let x1 = ((bbox.2.ceil() as i64).max(0) as usize).min(img.xs().end - 1);
    let y1 = ((bbox.3.ceil() as i64).max(0) as usize).min(img.ys().end - 1);
    let n = SUPERSAMPLE;
    let step = 1.0 / n as f64;
    for y in y0..=y1 {
        for x in x0..=x1 {
            let (mut sum, mut hits) = (0.0f32, 0usize);
            for sy in 0..n {
                for sx in 0..n {
                    let px = x as f64 - 0.5 + (sx as f64 + 0.5) * step;
                    let py = y as f64 - 0.5 + (sy as f64 + 0.5) * step;
                    if let Some(v) = shade(px, py) {
                        sum += v;
                        hits += 1;
                    }
                }
            }
            if hits > 0 {
                let px = img.px(x, y);
                let total = (n * n) as f32;
                *px = *px * (total - hits as f32) / total + sum / total;
            }
        }
    }
}

pub(super) fn bbox_of(points: &[Pt]) -> (f64, f64, f64, f64) {
    points
        .iter()
        .fold((f64::MAX, f64::MAX, f64::MIN, f64::MIN), |b, p| {
            (b.0.min(p.0), b.1.min(p.1), b.2.max(p.0), b.3.max(p.1))
        })
}

/// Corners of a square of `side` px around `center`, rotated, each moved by
/// up to `perspective` x side: a mild perspective view.
pub(super) fn square_corners(
    center: Pt,
    side: f64,
    rotation_deg: f64,
    perspective: f64,
    rng: &mut Rng,
) -> [Pt; 4] {
    let (s, c) = rotation_deg.to_radians().sin_cos();
    let half = side / 2.0;
    let unit = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)];
    unit.map(|(u, v)| {
        let jx = rng.range(-1.0, 1.0) * perspective * side;
        let jy = rng.range(-1.0, 1.0) * perspective * side;
        let (x, y) = (u * half, v * half);
        (center.0 + c * x - s * y + jx, center.1 + s * x + c * y + jy)
    })
}

/// Multiplies the pixels within `reach` of `centre` by `factor(x, y)`.
pub(super) fn paint_over(
    img: &mut Canvas,
    centre: Pt,
    reach: f64,
    factor: impl Fn(f64, f64) -> f32,
) {
    let x0 = ((centre.0 - reach).max(0.0) as usize).max(img.x0);
    let y0 = ((centre.1 - reach).max(0.0) as usize).max(img.y0);
    let x1 = ((centre.0 + reach) as usize).min(img.xs().end - 1);
    let y1 = ((centre.1 + reach) as usize).min(img.ys().end - 1);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let (fx, fy) = (x as f64, y as f64);
            if (fx - centre.0).hypot(fy - centre.1) <= reach {
                *img.px(x, y) *= factor(fx, fy);
            }
        }
    }
}
