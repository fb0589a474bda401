//! The image of a circle's centre under perspective: from its board's
//! sides (the pole of the vanishing line, or pairs of sides), or from two
//! concentric rings; and the conic algebra they need.

use super::*;

/// The image of a disc's centre from its board's sides (homogeneous lines
/// relative to the ellipse's centre, as [`board_sides`] gives them). With
/// all four, the pole of the board plane's vanishing line (through the
/// vanishing points of opposite sides) with respect to the disc's conic;
/// with one pair of opposite sides, [`centre_between`]; with two adjacent
/// ones, [`centre_beside`]. All are exact under perspective.
pub(super) fn perspective_centre(
    e: &Ellipse,
    sides: &[Option<[f64; 3]>; 4],
    params: &Params,
) -> Option<Pt> {
    // Each pair of sides places the centre on its own; a side found on
    // something lying against the board moves every pair it is in. When the
    // pairs disagree, the sides without one of the four if they agree, or
    // else no correction (the ellipse's own centre, biased by up to ~2 px
    // under the mild perspective measured).
    let tolerance = params
        .max_pair_spread_px
        .max(params.max_pair_spread * e.radius());
    let centres = pair_centres(e, sides);
    // Largest distance between two pairs' centres, leaving out those that
    // use side `skip`.
    let spread = |skip: Option<usize>| {
        let kept: Vec<Pt> = centres
            .iter()
            .filter(|(used, _)| skip.is_none_or(|k| used & (1 << k) == 0))
            .map(|c| c.1)
            .collect();
        kept.iter()
            .flat_map(|p| kept.iter().map(|q| geometry::dist(*p, *q)))
            .fold(0.0, f64::max)
    };
    if spread(None) <= tolerance {
        return centre_from_sides(e, sides);
    }
    if sides.iter().all(Option::is_some) {
        let (least, k) = (0..4)
            .map(|k| (spread(Some(k)), k))
            .min_by(|a, b| a.0.total_cmp(&b.0))?;
        if least <= tolerance {
            let mut fewer = *sides;
            fewer[k] = None;
            return centre_from_sides(e, &fewer);
        }
    }
    None
}

/// The centre placed by each pair of sides seen (adjacent or opposite),
/// with the pair as a bit mask of side indices.
pub(super) fn pair_centres(e: &Ellipse, sides: &[Option<[f64; 3]>; 4]) -> Vec<(u8, Pt)> {
    let mut centres = Vec::new();
    for k in 0..4 {
        let j = (k + 1) % 4;
        if let (Some(a), Some(b)) = (&sides[k], &sides[j]) {
            centres.extend(centre_beside(e, a, b).map(|c| (1 << k | 1 << j, c)));
        }
    }
    for k in 0..2 {
        if let (Some(a), Some(b)) = (&sides[k], &sides[k + 2]) {
            centres.extend(centre_between(e, a, b).map(|c| (1 << k | 1 << (k + 2), c)));
        }
    }
    centres
}

/// The disc's centre from the sides given (see [`perspective_centre`]).
pub(super) fn centre_from_sides(e: &Ellipse, sides: &[Option<[f64; 3]>; 4]) -> Option<Pt> {
    match sides {
        [Some(a), Some(b), Some(c), Some(d)] => pole(e, &cross3(cross3(*a, *c), cross3(*b, *d))),
        [Some(a), _, Some(c), _] | [_, Some(a), _, Some(c)] => centre_between(e, a, c),
        [Some(a), Some(b), None, None]
        | [None, Some(a), Some(b), None]
        | [None, None, Some(a), Some(b)]
        | [Some(b), None, None, Some(a)] => centre_beside(e, a, b),
        _ => None,
    }
}

pub(super) fn dot3(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// An image line (homogeneous) as foot + s * dir, to find where other lines
/// and a conic cross it.
pub(super) struct ImageLine {
    foot: [f64; 3],
    dir: [f64; 3],
}

impl ImageLine {
    fn new(l: [f64; 3]) -> Option<ImageLine> {
        let norm = l[0].hypot(l[1]);
        if norm < 1e-12 {
            return None;
        }
        let k = -l[2] / (norm * norm);
        Some(ImageLine {
            foot: [l[0] * k, l[1] * k, 1.0],
            dir: [-l[1] / norm, l[0] / norm, 0.0],
        })
    }

    fn at(&self, s: f64) -> [f64; 3] {
        [
            self.foot[0] + s * self.dir[0],
            self.foot[1] + s * self.dir[1],
            1.0,
        ]
    }

    /// Where line `l` crosses this one; None when parallel (or nearly).
    fn crossing(&self, l: &[f64; 3]) -> Option<f64> {
        let along = dot3(*l, self.dir);
        (along.abs() > 1e-12).then(|| -dot3(*l, self.foot) / along)
    }

    /// Where a point (homogeneous, finite) lies along this line.
    fn position(&self, p: [f64; 3]) -> f64 {
        (p[0] / p[2] - self.foot[0]) * self.dir[0] + (p[1] / p[2] - self.foot[1]) * self.dir[1]
    }

    /// The conic's crossings: roots of a2 s^2 + 2 a1 s + a0 = 0, as
    /// (a2, a1, a0).
    fn conic_terms(&self, conic: &[f64; 9]) -> (f64, f64, f64) {
        (
            dot3(self.dir, mat_vec(conic, self.dir)),
            dot3(self.dir, mat_vec(conic, self.foot)),
            dot3(self.foot, mat_vec(conic, self.foot)),
        )
    }
}

/// The image of a disc's centre from two opposite sides `l0`, `l2` of its
/// square board (homogeneous, relative to the ellipse's centre). On the
/// board the sides are parallel, at -h and +h across the disc's diameter
/// perpendicular to them, which touches the disc at -r and +r. That
/// diameter's image is the polar of the sides' vanishing point; along it,
/// the mirror x -> -x of the board becomes an involution that swaps the
/// sides' crossings and the disc's two edge points, and the centre is its
/// fixed point inside the ellipse.
pub(super) fn centre_between(e: &Ellipse, l0: &[f64; 3], l2: &[f64; 3]) -> Option<Pt> {
    let conic = e.conic(e.c);
    let diameter = ImageLine::new(mat_vec(&conic, cross3(*l0, *l2)))?;
    let (s0, s2) = (diameter.crossing(l0)?, diameter.crossing(l2)?);
    let (a2, a1, a0) = diameter.conic_terms(&conic);
    if a2.abs() < 1e-12 {
        return None;
    }
    // Involution A s s' + B (s + s') + C = 0 through both pairs.
    let [a, b, c] = cross3([a0 / a2, -2.0 * a1 / a2, 1.0], [s0 * s2, s0 + s2, 1.0]);
    // Fixed points: A s^2 + 2 B s + C = 0; the centre is inside the disc.
    let disc = b * b - a * c;
    if disc < 0.0 || a.abs() < 1e-15 {
        return None;
    }
    [(-b + disc.sqrt()) / a, (-b - disc.sqrt()) / a]
        .into_iter()
        .map(|s| diameter.at(s))
        .find(|x| dot3(*x, mat_vec(&conic, *x)) < 0.0)
        .map(|x| (x[0] + e.c.0, x[1] + e.c.1))
}

/// The image of a disc's centre from two adjacent sides `l0`, `l1` of its
/// square board (homogeneous, relative to the ellipse's centre). A guess of
/// the centre fixes the vanishing line (its polar) and so each side's
/// vanishing point. On the board the sides are perpendicular (their
/// vanishing points conjugate with respect to the disc) and equally far
/// from the centre (the same ratio to the disc's radius, a cross ratio
/// along the diameter perpendicular to each). Newton's method on those two
/// conditions from the ellipse's centre.
pub(super) fn centre_beside(e: &Ellipse, l0: &[f64; 3], l1: &[f64; 3]) -> Option<Pt> {
    let conic = e.conic(e.c);
    let q = |a: [f64; 3], b: [f64; 3]| dot3(a, mat_vec(&conic, b));
    // Side over radius for side `l` with vanishing point `v` about centre `p`
    // (vanishing line `horizon`): along the diameter perpendicular to the
    // side (the polar of v, through p), the cross ratio of the centre, the
    // diameter's vanishing point, the disc's edge and the side's crossing.
    let side_ratio = |l: &[f64; 3], v: [f64; 3], p: [f64; 3], horizon: &[f64; 3]| {
        let diameter = ImageLine::new(mat_vec(&conic, v))?;
        let (a2, a1, a0) = diameter.conic_terms(&conic);
        let root = a1 * a1 - a2 * a0;
        if root < 0.0 || a2.abs() < 1e-12 {
            return None;
        }
        let edge = (-a1 + root.sqrt()) / a2;
        let (centre, side) = (diameter.position(p), diameter.crossing(l)?);
        // The vanishing point's side of the cross ratio, 1 when at infinity.
        let far = diameter
            .crossing(horizon)
            .map_or(1.0, |inf| (edge - inf) / (side - inf));
        Some(((side - centre) / (edge - centre) * far).abs())
    };
    let residual = |c: [f64; 2]| -> Option<[f64; 2]> {
        let p = [c[0], c[1], 1.0];
        let horizon = mat_vec(&conic, p);
        let (v0, v1) = (cross3(*l0, horizon), cross3(*l1, horizon));
        let norm = (q(v0, v0) * q(v1, v1)).abs().sqrt();
        if norm < 1e-300 {
            return None;
        }
        let h0 = side_ratio(l0, v0, p, &horizon)?;
        let h1 = side_ratio(l1, v1, p, &horizon)?;
        Some([h0 - h1, q(v0, v1) / norm])
    };
    // Finite differences for the Jacobian.
    let step = 1e-4 * e.radius();
    let mut c = [0.0, 0.0];
    for _ in 0..ADJACENT_ITERATIONS {
        let f = residual(c)?;
        let fx = residual([c[0] + step, c[1]])?;
        let fy = residual([c[0], c[1] + step])?;
        let j = [
            [(fx[0] - f[0]) / step, (fy[0] - f[0]) / step],
            [(fx[1] - f[1]) / step, (fy[1] - f[1]) / step],
        ];
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if det.abs() < 1e-300 {
            return None;
        }
        let dx = (f[0] * j[1][1] - f[1] * j[0][1]) / det;
        let dy = (f[1] * j[0][0] - f[0] * j[1][0]) / det;
        c = [c[0] - dx, c[1] - dy];
        if dx.hypot(dy) < 1e-6 {
            return Some((c[0] + e.c.0, c[1] + e.c.1));
        }
    }
    None
}

/// Row-major 3x3 matrix `m` times column vector `v`.
pub(super) fn mat_vec(m: &[f64; 9], v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|r| (0..3).map(|i| m[r * 3 + i] * v[i]).sum())
}

pub(super) fn cross3(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Pole of line `l` (homogeneous, relative to `e.c`) with respect to the
/// ellipse: C^-1 l, back in tile pixels.
pub(super) fn pole(e: &Ellipse, l: &[f64; 3]) -> Option<Pt> {
    let c = geometry::invert3(&e.conic(e.c))?;
    let x = mat_vec(&c, *l);
    (x[2].abs() > 1e-12).then(|| (x[0] / x[2] + e.c.0, x[1] / x[2] + e.c.1))
}

/// Image of the common centre of two concentric circles seen as ellipses
/// `inner` and `outer`: the eigenvector of C1^-1 C2 whose eigenvalue is the
/// single one (the other two are equal for concentric circles).
pub(super) fn concentric_centre(inner: &Ellipse, outer: &Ellipse) -> Option<Pt> {
    let origin = inner.c;
    let c1 = inner.conic(origin);
    let c2 = outer.conic(origin);
    let m = mul(&geometry::invert3(&c1)?, &c2);
    let lambda = single_eigenvalue(&m)?;
    let a = [
        m[0] - lambda,
        m[1],
        m[2],
        m[3],
        m[4] - lambda,
        m[5],
        m[6],
        m[7],
        m[8] - lambda,
    ];
    // The null vector of a rank-2 matrix: the largest cross product of two rows.
    let rows = [[a[0], a[1], a[2]], [a[3], a[4], a[5]], [a[6], a[7], a[8]]];
    let norm = |v: [f64; 3]| v.iter().map(|x| x * x).sum::<f64>();
    let x = [
        cross3(rows[0], rows[1]),
        cross3(rows[0], rows[2]),
        cross3(rows[1], rows[2]),
    ]
    .into_iter()
    .max_by(|p, q| norm(*p).total_cmp(&norm(*q)))?;
    if x[2].abs() < 1e-12 {
        return None;
    }
    Some((x[0] / x[2] + origin.0, x[1] / x[2] + origin.1))
}

/// The eigenvalue of a 3x3 matrix that stands apart from the other two
/// (roots of the characteristic cubic; a near-double pair may come out
/// complex, and then the real root is the single one).
pub(super) fn single_eigenvalue(m: &[f64; 9]) -> Option<f64> {
    let tr = m[0] + m[4] + m[8];
    let minors = m[0] * m[4] - m[1] * m[3] + m[0] * m[8] - m[2] * m[6] + m[4] * m[8] - m[5] * m[7];
    let det = det3(m);
    // lambda^3 - tr lambda^2 + minors lambda - det = 0; lambda = t + tr/3.
    let p = minors - tr * tr / 3.0;
    let q = -2.0 * tr.powi(3) / 27.0 + tr * minors / 3.0 - det;
    let disc = (q / 2.0).powi(2) + (p / 3.0).powi(3);
    let shift = tr / 3.0;
    if disc > 0.0 {
        let s = disc.sqrt();
        return Some((-q / 2.0 + s).cbrt() + (-q / 2.0 - s).cbrt() + shift);
    }
    let r = (-p / 3.0).max(0.0).sqrt();
    if r == 0.0 {
        return None;
    }
    let arg = ((-q / 2.0) / r.powi(3)).clamp(-1.0, 1.0);
    let theta = arg.acos() / 3.0;
    let roots: Vec<f64> = (0..3)
        .map(|k| 2.0 * r * (theta - 2.0 * std::f64::consts::PI * k as f64 / 3.0).cos() + shift)
        .collect();
    (0..3)
        .max_by(|&i, &j| {
            let apart = |k: usize| {
                (0..3)
                    .filter(|&o| o != k)
                    .map(|o| (roots[o] - roots[k]).abs())
                    .fold(f64::MAX, f64::min)
            };
            apart(i).total_cmp(&apart(j))
        })
        .map(|k| roots[k])
}

pub(super) fn det3(m: &[f64; 9]) -> f64 {
    m[0] * (m[4] * m[8] - m[5] * m[7]) - m[1] * (m[3] * m[8] - m[5] * m[6])
        + m[2] * (m[3] * m[7] - m[4] * m[6])
}

pub(super) fn mul(x: &[f64; 9], y: &[f64; 9]) -> [f64; 9] {
    std::array::from_fn(|k| {
        let (r, c) = (k / 3, k % 3);
        (0..3).map(|i| x[r * 3 + i] * y[i * 3 + c]).sum()
    })
}
