//! Printed targets without a code (crosshair, checker, bullseye, disc) and
//! the aerial look-alikes that must not be taken for them.

use std::f64::consts::PI;

use super::canvas::{bbox_of, paint, square_corners, Canvas, Truth};
use super::canvas::{PAPER_BLACK, PAPER_WHITE};
use super::geometry::{Homography, Pt};
use super::tags::TargetKind;
use super::Rng;

/// Designs of printed targets. Sizes are fractions of the target's size
/// (the square's side, or the outermost ring's diameter).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PrintedDesign {
    /// A white cross with bars `bar` wide running the full side of a black
    /// square, with a white `marking` in one quadrant.
    Cross { bar: f64, marking: Marking },
    /// 2x2 checker: two black and two white quadrants.
    Checker,
    /// Black disc, white ring and black ring with edges at `inner`,
    /// `middle` and 1 of the outer radius (1/3 and 2/3 for the classic
    /// 1:2:3), on a white square board 1.25x the outer diameter.
    Bullseye { inner: f64, middle: f64 },
    /// A disc on a square board of twice its diameter, in the other colour.
    Disc { white_on_black: bool },
}

/// A marking in one of a cross's quadrants, as real targets carry (a
/// number's stroke, a bar, a hook, a triangle): most touch or run beside
/// a bar, which must neither end that arm nor move the centre.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Marking {
    None,
    /// A small square near the outer corner, clear of the bars.
    Square,
    /// A short bar beside a bar, touching it along its length.
    BarBeside,
    /// A triangle in the quadrant's inner corner, touching both bars.
    Triangle,
    /// A bar along the quadrant's diagonal from the bars' corner outward.
    Diagonal,
    /// An L: a short bar beside a bar, touching it, its end turned away.
    Hook,
}

impl Marking {
    pub const ALL: [Marking; 6] = [
        Marking::None,
        Marking::Square,
        Marking::BarBeside,
        Marking::Triangle,
        Marking::Diagonal,
        Marking::Hook,
    ];

    /// Whether the marking covers (x, y) of a cross with bars `bar` wide
    /// (target units, centre at 0, the side 1); it lies in the quadrant
    /// x > 0, y < 0 and inside the board's outer band (|x|, |y| < 0.42).
    fn covers(self, x: f64, y: f64, bar: f64) -> bool {
        // Distances from the vertical and the horizontal bar's edges.
        let (u, v) = (x - bar / 2.0, -y - bar / 2.0);
        if u < 0.0 || v < 0.0 || x > 0.42 || -y > 0.42 {
            return false;
        }
        match self {
            Marking::None => false,
            Marking::Square => (x - 0.36).abs() < 0.05 && (y + 0.36).abs() < 0.05,
            Marking::BarBeside => u < 0.05 && (0.08..0.3).contains(&v),
            Marking::Triangle => u + v < 0.16,
            Marking::Diagonal => (x + y).abs() < 0.03,
            Marking::Hook => {
                (v < 0.05 && (0.06..0.25).contains(&u)) || ((0.2..0.25).contains(&u) && v < 0.15)
            }
        }
    }
}

impl PrintedDesign {
    pub fn kind(self) -> TargetKind {
        match self {
            PrintedDesign::Cross { .. } | PrintedDesign::Checker => TargetKind::Crosshair,
            PrintedDesign::Bullseye { .. } | PrintedDesign::Disc { .. } => TargetKind::Circle,
        }
    }
}

/// One printed target to place.
#[derive(Debug, Clone)]
pub struct PrintedSpec {
    pub design: PrintedDesign,
    pub center: Pt,
    /// Side of the square (cross, checker) or outer diameter (bullseye, disc).
    pub size_px: f64,
    pub rotation_deg: f64,
    /// Corners move by up to this fraction of the size: mild perspective.
    pub perspective: f64,
    /// Print contrast: 1 = paper black and white; less moves both toward grey.
    pub contrast: f64,
    /// A shadow edge (x 0.55) crosses the target near its centre.
    pub shadow: bool,
}

/// Paints `spec`; `index` becomes the truth's id (printed targets carry none).
pub(super) fn place(img: &mut Canvas, spec: &PrintedSpec, index: u32, rng: &mut Rng) -> Truth {
    let corners = square_corners(
        spec.center,
        spec.size_px,
        spec.rotation_deg,
        spec.perspective,
        rng,
    );
    let h = Homography::from_unit_square(&corners);
    let inv = h.inverse();
    let mid = 0.5f32;
    let k = spec.contrast as f32;
    let (black, white) = (mid - (mid - PAPER_BLACK) * k, mid + (PAPER_WHITE - mid) * k);
    // Extent of the paper around the unit square, in target units.
    let reach = match spec.design {
        PrintedDesign::Cross { .. } | PrintedDesign::Checker => 0.5,
        PrintedDesign::Bullseye { .. } => 0.625,
        PrintedDesign::Disc { .. } => 1.0,
    };
    let outline = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
        .map(|(u, v)| h.apply((0.5 + u * reach, 0.5 + v * reach)));
    let design = spec.design;
    paint(img, bbox_of(&outline), |px, py| {
        let (u, v) = inv.apply((px, py));
        let (x, y) = (u - 0.5, v - 0.5);
        if x.abs() > reach || y.abs() > reach {
            return None;
        }
        let r = x.hypot(y);
        let is_white = match design {
            PrintedDesign::Cross { bar, marking } => {
                x.abs() < bar / 2.0 || y.abs() < bar / 2.0 || marking.covers(x, y, bar)
            }
            PrintedDesign::Checker => x * y < 0.0,
            PrintedDesign::Bullseye { inner, middle } => {
                !(r < inner / 2.0 || (middle / 2.0..0.5).contains(&r))
            }
            PrintedDesign::Disc { white_on_black } => (r < 0.5) == white_on_black,
        };
        Some(if is_white { white } else { black })
    });
    if spec.shadow {
        let angle = rng.range(0.0, PI);
        let offset = rng.range(-0.25, 0.25) * spec.size_px;
        local_shadow(img, spec.center, angle, offset, 2.0 * spec.size_px);
    }
    Truth {
        kind: spec.design.kind(),
        id: index,
        center: h.apply((0.5, 0.5)),
        corners,
        side_px: spec.size_px,
    }
}

/// A straight shadow edge through `center` (moved by `offset` along its
/// normal) darkening one side within `radius`, as a pole or a tree casts.
fn local_shadow(img: &mut Canvas, center: Pt, angle: f64, offset: f64, radius: f64) {
    let (s, c) = angle.sin_cos();
    super::canvas::paint_over(img, center, radius, |x, y| {
        let d = -s * (x - center.0) + c * (y - center.1) - offset;
        let cover = (0.5 - d).clamp(0.0, 1.0) as f32;
        1.0 - 0.45 * cover
    });
}

/// What a look-alike is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LookalikeKind {
    PanelGrid,
    Paving,
    RoadCross,
    Manhole,
    PyramidRoof,
    TankOnRoof,
    Car,
}

/// A look-alike painted into a scene: its kind, centre and the radius of a
/// circle around everything it painted (pixels). Objects painted later may
/// hide parts of it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lookalike {
    pub kind: LookalikeKind,
    pub center: (f64, f64),
    pub radius: f64,
}

impl Lookalike {
    /// Whether the look-alike's extent covers `p`.
    pub fn covers(&self, p: (f64, f64)) -> bool {
        (p.0 - self.center.0).hypot(p.1 - self.center.1) <= self.radius
    }
}

/// Paints one random look-alike of a printed target.
pub(super) fn lookalike(img: &mut Canvas, rng: &mut Rng) -> Lookalike {
    let (w, h) = (img.frame.0 as f64, img.frame.1 as f64);
    let c = (rng.range(0.0, w), rng.range(0.0, h));
    let angle = rng.range(0.0, PI);
    let (s, co) = angle.sin_cos();
    // Point in the object's own frame (u along its rotated x axis).
    let local = move |x: f64, y: f64| {
        let (dx, dy) = (x - c.0, y - c.1);
        (co * dx + s * dy, -s * dx + co * dy)
    };
    let (kind, radius) = match (rng.uniform() * 7.0) as usize {
        0 => {
            // Solar-panel array: dark cells in a light frame, a grid whose
            // every inner crossing looks like a cross target.
            let cell = rng.range(10.0, 35.0);
            let (cols, rows) = (
                4 + (rng.uniform() * 5.0) as usize,
                3 + (rng.uniform() * 3.0) as usize,
            );
            let line = cell * rng.range(0.1, 0.25);
            let (hw, hh) = (cols as f64 * cell / 2.0, rows as f64 * cell / 2.0);
            let r = hw.hypot(hh) + line;
            paint(img, (c.0 - r, c.1 - r, c.0 + r, c.1 + r), |x, y| {
                let (u, v) = local(x, y);
                if u.abs() > hw + line / 2.0 || v.abs() > hh + line / 2.0 {
                    return None;
                }
                let fu = (u + hw).rem_euclid(cell);
                let fv = (v + hh).rem_euclid(cell);
                let on_line = fu < line / 2.0
                    || fu > cell - line / 2.0
                    || fv < line / 2.0
                    || fv > cell - line / 2.0;
                Some(if on_line { 0.8 } else { 0.12 })
            });
            (LookalikeKind::PanelGrid, r)
        }
        1 => {
            // Paving in a checker pattern: every inner corner is a saddle.
            let tile = rng.range(10.0, 30.0);
            let n = 4 + (rng.uniform() * 5.0) as usize;
            let half = n as f64 * tile / 2.0;
            let (a, b) = (rng.range(0.15, 0.35) as f32, rng.range(0.55, 0.85) as f32);
            let r = half * 1.5;
            paint(img, (c.0 - r, c.1 - r, c.0 + r, c.1 + r), |x, y| {
                let (u, v) = local(x, y);
                if u.abs() > half || v.abs() > half {
                    return None;
                }
                let (i, j) = (((u + half) / tile) as usize, ((v + half) / tile) as usize);
                Some(if (i + j) % 2 == 0 { a } else { b })
            });
            (LookalikeKind::Paving, r)
        }
        2 => {
            // Road-marking cross: long white bars on a wide asphalt patch.
            let width = rng.range(6.0, 20.0);
            let arm = width * rng.range(7.0, 20.0);
            let patch = arm * 1.5;
            let r = patch * 1.5;
            paint(img, (c.0 - r, c.1 - r, c.0 + r, c.1 + r), |x, y| {
                let (u, v) = local(x, y);
                if u.abs() > patch || v.abs() > patch {
                    return None;
                }
                let bar = (u.abs() < width / 2.0 && v.abs() < arm)
                    || (v.abs() < width / 2.0 && u.abs() < arm);
                Some(if bar { 0.85 } else { 0.13 })
            });
            (LookalikeKind::RoadCross, r)
        }
        3 => {
            // Manhole: dark cover inside a light rim.
            let radius = rng.range(10.0, 45.0);
            let rim = radius * rng.range(1.08, 1.25);
            paint(img, (c.0 - rim, c.1 - rim, c.0 + rim, c.1 + rim), |x, y| {
                let d = (x - c.0).hypot(y - c.1);
                (d <= rim).then_some(if d < radius { 0.12 } else { 0.62 })
            });
            (LookalikeKind::Manhole, rim)
        }
        4 => {
            // Pyramid roof: four triangular faces lit by a low sun.
            let half = rng.range(20.0, 90.0);
            let sun = rng.range(0.0, 2.0 * PI);
            let r = half * 1.5;
            paint(img, (c.0 - r, c.1 - r, c.0 + r, c.1 + r), |x, y| {
                let (u, v) = local(x, y);
                if u.abs() > half || v.abs() > half {
                    return None;
                }
                // The face's outward direction in the object frame, then the
                // frame's rotation, dotted with the sun.
                let face: f64 = if u.abs() > v.abs() {
                    if u > 0.0 {
                        0.0
                    } else {
                        PI
                    }
                } else if v > 0.0 {
                    PI / 2.0
                } else {
                    -PI / 2.0
                };
                Some((0.45 + 0.35 * (face + angle - sun).cos()) as f32)
            });
            (LookalikeKind::PyramidRoof, r)
        }
        5 => {
            // Round tank on a square flat roof, off the roof's centre.
            let radius = rng.range(12.0, 40.0);
            let half = radius * rng.range(1.6, 3.5);
            let off = (half - radius) * rng.range(0.4, 0.9);
            let r = half * 1.5;
            paint(img, (c.0 - r, c.1 - r, c.0 + r, c.1 + r), |x, y| {
                let (u, v) = local(x, y);
                if u.abs() > half || v.abs() > half {
                    return None;
                }
                let tank = (u - off).hypot(v - off * 0.5) < radius;
                Some(if tank { 0.85 } else { 0.2 })
            });
            (LookalikeKind::TankOnRoof, r)
        }
        _ => {
            // Car: body with dark windscreen and rear window.
            let len = rng.range(35.0, 55.0);
            let wid = len * 0.45;
            let body = rng.range(0.1, 0.9) as f32;
            let r = len;
            paint(img, (c.0 - r, c.1 - r, c.0 + r, c.1 + r), |x, y| {
                let (u, v) = local(x, y);
                if u.abs() > len / 2.0 || v.abs() > wid / 2.0 {
                    return None;
                }
                let glass = v.abs() < wid * 0.4
                    && ((u - len * 0.12).abs() < len * 0.08 || (u + len * 0.25).abs() < len * 0.06);
                Some(if glass { 0.08 } else { body })
            });
            (LookalikeKind::Car, r)
        }
    };
    Lookalike {
        kind,
        center: c,
        radius,
    }
}
