//! Plane geometry shared by detectors: quadrilateral centres, homographies
//! and tile-border distances. Pure functions, no OpenCV.

pub type Pt = (f64, f64);

/// Intersection of the diagonals 0-2 and 1-3 of a quadrilateral: the image of
/// the target's centre under any perspective, unlike the mean of the corners.
/// Falls back to the corner mean for a degenerate quad.
pub fn diagonal_intersection(c: &[Pt; 4]) -> Pt {
    let (p, r) = (c[0], (c[2].0 - c[0].0, c[2].1 - c[0].1));
    let (q, s) = (c[1], (c[3].0 - c[1].0, c[3].1 - c[1].1));
    let denom = r.0 * s.1 - r.1 * s.0;
    if denom.abs() < 1e-12 {
        return mean(c);
    }
    let t = ((q.0 - p.0) * s.1 - (q.1 - p.1) * s.0) / denom;
    (p.0 + t * r.0, p.1 + t * r.1)
}

pub fn mean(c: &[Pt; 4]) -> Pt {
    let sx: f64 = c.iter().map(|p| p.0).sum();
    let sy: f64 = c.iter().map(|p| p.1).sum();
    (sx / 4.0, sy / 4.0)
}

pub fn dist(a: Pt, b: Pt) -> f64 {
    (a.0 - b.0).hypot(a.1 - b.1)
}

/// Mean side length of a quadrilateral.
pub fn mean_side(c: &[Pt; 4]) -> f64 {
    (0..4).map(|i| dist(c[i], c[(i + 1) % 4])).sum::<f64>() / 4.0
}

/// Homography (row-major 3x3, h[8] = 1) mapping the unit-square corners
/// (0,0), (1,0), (1,1), (0,1) onto `c`.
pub fn square_to_quad(c: &[Pt; 4]) -> [f64; 9] {
    // Heckbert's closed form for the square-to-quad projective map.
    let (x0, y0) = c[0];
    let (x1, y1) = c[1];
    let (x2, y2) = c[2];
    let (x3, y3) = c[3];
    let sx = x0 - x1 + x2 - x3;
    let sy = y0 - y1 + y2 - y3;
    let (dx1, dx2, dy1, dy2) = (x1 - x2, x3 - x2, y1 - y2, y3 - y2);
    let den = dx1 * dy2 - dx2 * dy1;
    let (g, h) = if den.abs() < 1e-12 {
        (0.0, 0.0)
    } else {
        ((sx * dy2 - dx2 * sy) / den, (dx1 * sy - sx * dy1) / den)
    };
    [
        x1 - x0 + g * x1,
        x3 - x0 + h * x3,
        x0,
        y1 - y0 + g * y1,
        y3 - y0 + h * y3,
        y0,
        g,
        h,
        1.0,
    ]
}

/// Inverse of a row-major 3x3 matrix (adjugate over determinant); None when
/// singular.
pub fn invert3(m: &[f64; 9]) -> Option<[f64; 9]> {
    let [a, b, c, d, e, f, g, h, i] = *m;
    let det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g);
    if det.abs() < 1e-300 {
        return None;
    }
    Some([
        (e * i - f * h) / det,
        (c * h - b * i) / det,
        (b * f - c * e) / det,
        (f * g - d * i) / det,
        (a * i - c * g) / det,
        (c * d - a * f) / det,
        (d * h - e * g) / det,
        (b * g - a * h) / det,
        (a * e - b * d) / det,
    ])
}

/// Applies a row-major 3x3 homography to a point.
pub fn apply(h: &[f64; 9], p: Pt) -> Pt {
    let w = h[6] * p.0 + h[7] * p.1 + h[8];
    (
        (h[0] * p.0 + h[1] * p.1 + h[2]) / w,
        (h[3] * p.0 + h[4] * p.1 + h[5]) / w,
    )
}

/// Smallest distance from any corner to a tile side flagged as an interior
/// seam (left, top, right, bottom); infinite when no side is a seam.
pub fn seam_margin(corners: &[Pt; 4], tile_w: f64, tile_h: f64, seams: [bool; 4]) -> f64 {
    let mut m = f64::INFINITY;
    for &(x, y) in corners {
        if seams[0] {
            m = m.min(x)
        }
        if seams[1] {
            m = m.min(y)
        }
        if seams[2] {
            m = m.min(tile_w - 1.0 - x)
        }
        if seams[3] {
            m = m.min(tile_h - 1.0 - y)
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn diagonal_intersection_is_projective_centre() {
        // A perspective view of the unit square: the projected centre (0.5, 0.5)
        // is the diagonal intersection but not the corner mean.
        let quad = [(10.0, 10.0), (50.0, 12.0), (46.0, 40.0), (14.0, 44.0)];
        let h = square_to_quad(&quad);
        for (i, corner) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
            .iter()
            .enumerate()
        {
            let p = apply(&h, *corner);
            assert!(dist(p, quad[i]) < 1e-9, "corner {i}: {p:?}");
        }
        let centre = apply(&h, (0.5, 0.5));
        assert!(dist(diagonal_intersection(&quad), centre) < 1e-9);
        assert!(dist(mean(&quad), centre) > 0.05);
    }

    #[test]
    fn seam_margin_ignores_frame_borders() {
        let c = [(2.0, 5.0), (8.0, 5.0), (8.0, 9.0), (2.0, 9.0)];
        assert_eq!(seam_margin(&c, 20.0, 20.0, [false; 4]), f64::INFINITY);
        assert_eq!(
            seam_margin(&c, 20.0, 20.0, [true, false, false, false]),
            2.0
        );
        assert_eq!(
            seam_margin(&c, 20.0, 20.0, [false, false, true, true]),
            10.0
        );
    }
}
