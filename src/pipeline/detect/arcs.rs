//! Circles proposed from the arcs of contours that are not round: a disc
//! crossed by a shadow's edge thresholds into two pieces, the lit part and
//! the shadowed one, parted by the dark band the adaptive threshold leaves
//! along the shadow's edge. Neither piece is an ellipse, but each is bounded
//! by an arc of the disc's edge and a chord, and the arc alone gives the
//! disc's centre and radius well enough for the detector's rays to start.
//!
//! Like the blobs it starts from, this only proposes: the detector verifies
//! every circle on the grey image.

use super::geometry::Pt;

/// Spacings (in contour points) of the three points whose circumcircle is
/// tried as an arc's circle: short ones for small discs, long ones for the
/// radius of large discs to be read over pixel-quantised points.
const SPACINGS: [usize; 4] = [6, 12, 24, 48];
/// A triple is read only when it spans this range of angle (radians) on
/// its circle: on a shorter stretch the quantisation decides the radius, on
/// a longer one the three points need not lie on one arc.
const TRIPLE_ANGLE: (f64, f64) = (0.5, 2.5);
/// Consecutive contour points off the circle an arc may run through (a
/// pixel step of noise or a notch of the threshold).
const MAX_GAP: usize = 3;
/// An arc spans at least this angle (radians, 150 degrees): a disc split by
/// a shadow leaves one piece with at least half of its edge.
const MIN_ARC: f64 = 150.0 * std::f64::consts::PI / 180.0;
/// Points an arc holds per pixel of its length, at least (8-connected
/// contour points are 1 to 1.41 px apart).
const MIN_DENSITY: f64 = 0.6;

/// A circle in tile pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circle {
    pub c: Pt,
    pub r: f64,
}

/// How far (pixels) a contour point may lie from a circle of radius `r` and
/// still be on it: the contour runs through pixel centres of a thresholded
/// edge (about a pixel of quantisation, and of blur and noise).
fn tolerance(r: f64) -> f64 {
    1.0 + 0.03 * r
}

/// The circles that long arcs of a closed contour lie on, with radii in
/// `r_range`: where a contour runs along a circle for 150 degrees or more.
/// Each circle is reported once (arcs of one circle are [`same`]), in the
/// order the contour's points first show it.
pub fn arc_circles(points: &[Pt], r_range: (f64, f64)) -> Vec<Circle> {
    let n = points.len();
    let mut out = Vec::new();
    // An arc of 150 degrees of the least radius needs a box at least this
    // wide both ways (2 r sin 75 degrees).
    let least = 1.93 * r_range.0;
    let span = |f: fn(&Pt) -> f64| {
        let (lo, hi) = points
            .iter()
            .map(f)
            .fold((f64::MAX, f64::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)));
        hi - lo
    };
    if n == 0 || span(|p| p.0) < least || span(|p| p.1) < least {
        return out;
    }
    let mut covered = vec![false; n];
    for m in SPACINGS {
        if 4 * m > n {
            break;
        }
        for i in (0..n).step_by(m / 2) {
            let mid = (i + m) % n;
            if covered[mid] {
                continue;
            }
            let Some(c) = circumcircle(points[i], points[mid], points[(i + 2 * m) % n]) else {
                continue;
            };
            if !(r_range.0..=r_range.1).contains(&c.r) {
                continue;
            }
            let swept = angle(&c, points[i], points[(i + 2 * m) % n]).abs();
            if !(TRIPLE_ANGLE.0..=TRIPLE_ANGLE.1).contains(&swept) {
                continue;
            }
            let Some((run, c)) = arc_from(points, mid, c) else {
                continue;
            };
            if !(r_range.0..=r_range.1).contains(&c.r) {
                continue;
            }
            for k in run.clone() {
                covered[k % n] = true;
            }
            if !out.iter().any(|o| same(o, &c)) {
                out.push(c);
            }
        }
    }
    out
}

/// The arc through contour point `mid` on circle `c`, walked and refitted
/// (least squares to its points) three times: its index range (may pass n,
/// to be taken mod n) and circle, if it is long and dense enough.
fn arc_from(points: &[Pt], mid: usize, mut c: Circle) -> Option<(std::ops::Range<usize>, Circle)> {
    let mut run = 0..0;
    for _ in 0..3 {
        run = walk(points, mid, &c);
        let on: Vec<Pt> = run
            .clone()
            .map(|k| points[k % points.len()])
            .filter(|p| is_on(&c, *p))
            .collect();
        c = fit(&on)?;
    }
    let n = points.len();
    // The angle swept along the run, step by step (a run may pass 180
    // degrees, where the angle between its ends alone would wrap).
    let mut swept = 0.0;
    let mut count = 0usize;
    let mut prev = points[run.start % n];
    for k in run.clone() {
        let p = points[k % n];
        if is_on(&c, p) {
            swept += angle(&c, prev, p);
            prev = p;
            count += 1;
        }
    }
    (swept.abs() >= MIN_ARC && count as f64 >= MIN_DENSITY * swept.abs() * c.r).then_some((run, c))
}

/// The longest stretch of the contour around `mid` that stays on `c`
/// (through gaps of up to [`MAX_GAP`] points), as indices from `mid`'s
/// side: start..end with start <= mid < end, possibly past n.
fn walk(points: &[Pt], mid: usize, c: &Circle) -> std::ops::Range<usize> {
    let n = points.len();
    let reach = |dir: isize| -> usize {
        let (mut last, mut gap) = (0usize, 0usize);
        for step in 1..n {
            let k = (mid as isize + dir * step as isize).rem_euclid(n as isize) as usize;
            if is_on(c, points[k]) {
                last = step;
                gap = 0;
            } else {
                gap += 1;
                if gap > MAX_GAP {
                    break;
                }
            }
        }
        last
    };
    let ahead = reach(1);
    let back = reach(-1).min(n - 1 - ahead);
    (mid + n - back)..(mid + n + ahead + 1)
}

/// Two arcs of one circle, as read from a contour's pixels.
pub fn same(a: &Circle, b: &Circle) -> bool {
    (a.c.0 - b.c.0).hypot(a.c.1 - b.c.1) < 0.2 * a.r && (0.8..1.25).contains(&(a.r / b.r))
}

fn is_on(c: &Circle, p: Pt) -> bool {
    ((p.0 - c.c.0).hypot(p.1 - c.c.1) - c.r).abs() <= tolerance(c.r)
}

/// Signed angle (radians, -pi..pi) from `a` to `b` about the circle's centre.
fn angle(c: &Circle, a: Pt, b: Pt) -> f64 {
    let (ax, ay) = (a.0 - c.c.0, a.1 - c.c.1);
    let (bx, by) = (b.0 - c.c.0, b.1 - c.c.1);
    (ax * by - ay * bx).atan2(ax * bx + ay * by)
}

/// The circle through three points; `None` when they are (nearly) collinear.
fn circumcircle(a: Pt, b: Pt, c: Pt) -> Option<Circle> {
    let (bx, by) = (b.0 - a.0, b.1 - a.1);
    let (cx, cy) = (c.0 - a.0, c.1 - a.1);
    let d = 2.0 * (bx * cy - by * cx);
    if d.abs() < 1e-9 {
        return None;
    }
    let (b2, c2) = (bx * bx + by * by, cx * cx + cy * cy);
    let ux = (cy * b2 - by * c2) / d;
    let uy = (bx * c2 - cx * b2) / d;
    Some(Circle {
        c: (a.0 + ux, a.1 + uy),
        r: ux.hypot(uy),
    })
}

/// Algebraic least-squares circle (Kasa): minimises the squared difference
/// of squared radii, solved about the points' mean for conditioning.
fn fit(points: &[Pt]) -> Option<Circle> {
    if points.len() < 3 {
        return None;
    }
    let n = points.len() as f64;
    let mx = points.iter().map(|p| p.0).sum::<f64>() / n;
    let my = points.iter().map(|p| p.1).sum::<f64>() / n;
    let (mut suu, mut svv, mut suv, mut suuu, mut svvv, mut suvv, mut svuu) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for p in points {
        let (u, v) = (p.0 - mx, p.1 - my);
        suu += u * u;
        svv += v * v;
        suv += u * v;
        suuu += u * u * u;
        svvv += v * v * v;
        suvv += u * v * v;
        svuu += v * u * u;
    }
    let det = suu * svv - suv * suv;
    if det.abs() < 1e-9 {
        return None;
    }
    let (bu, bv) = (0.5 * (suuu + suvv), 0.5 * (svvv + svuu));
    let uc = (bu * svv - bv * suv) / det;
    let vc = (suu * bv - suv * bu) / det;
    let r = (uc * uc + vc * vc + (suu + svv) / n).sqrt();
    r.is_finite().then_some(Circle {
        c: (mx + uc, my + vc),
        r,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The outline of the part of a disc (radius `r`, centre `c`) below the
    /// line y = c.1 + `cut`, as pixel-centre points along arc and chord.
    fn piece(c: Pt, r: f64, cut: f64) -> Vec<Pt> {
        let mut out = Vec::new();
        // Arc below the chord (y > c.1 + cut), then the chord back.
        let a0 = (cut / r).clamp(-1.0, 1.0).asin();
        let a1 = std::f64::consts::PI - a0;
        let steps = (r * (a1 - a0)).ceil() as usize;
        for k in 0..=steps {
            let a = a0 + (a1 - a0) * k as f64 / steps as f64;
            out.push(((c.0 + r * a.cos()).round(), (c.1 + r * a.sin()).round()));
        }
        let half = (r * r - cut * cut).sqrt();
        let steps = (2.0 * half).ceil() as usize;
        for k in 1..steps {
            let x = c.0 - half + 2.0 * half * k as f64 / steps as f64;
            out.push((x.round(), (c.1 + cut).round()));
        }
        out
    }

    #[test]
    fn the_pieces_of_a_disc_cut_by_a_shadow_give_its_circle() {
        let c = (100.3, 80.6);
        for (r, cut) in [(34.0, -20.0), (34.0, 0.0), (30.0, -10.0), (57.0, 8.0)] {
            let got = arc_circles(&piece(c, r, cut), (10.0, 80.0));
            assert_eq!(got.len(), 1, "{r} {cut}: {got:?}");
            let got = got[0];
            assert!(
                (got.c.0 - c.0).hypot(got.c.1 - c.1) < 1.0,
                "{r} {cut}: {got:?}"
            );
            assert!((got.r - r).abs() < 1.0, "{r} {cut}: {got:?}");
        }
    }

    #[test]
    fn a_square_or_a_short_arc_gives_no_circle() {
        let mut square = Vec::new();
        for k in 0..40 {
            square.push((10.0 + k as f64, 10.0));
        }
        for k in 0..40 {
            square.push((50.0, 10.0 + k as f64));
        }
        for k in 0..40 {
            square.push((50.0 - k as f64, 50.0));
        }
        for k in 0..40 {
            square.push((10.0, 50.0 - k as f64));
        }
        assert_eq!(arc_circles(&square, (17.0, 80.0)), vec![]);
        // A shallow cap: a 60 degree arc and its chord.
        let cap = piece((100.0, 100.0), 40.0, 35.0);
        assert_eq!(arc_circles(&cap, (5.0, 80.0)), vec![]);
    }

    #[test]
    fn a_circle_outside_the_radius_range_is_not_proposed() {
        assert_eq!(
            arc_circles(&piece((50.0, 50.0), 34.0, -20.0), (40.0, 80.0)),
            vec![]
        );
    }
}
