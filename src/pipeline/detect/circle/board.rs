//! A disc's board: found from where rays leave its level (or from the
//! levels along its sides where the ground is nearly as dark), checked to
//! be a square of the designed proportions centred on its disc, and its
//! sides fitted to subpixel precision.

use super::centre::cross3;
use super::*;
use crate::pipeline::detect::refine::fit_line;

/// A disc's board: the other colour, uniform out to 1.25x the disc's radius
/// on most rays, ending in a square of the designed proportions.
/// Returns the board's four sides as homogeneous lines in coordinates
/// relative to the disc's centre, each fitted to subpixel precision, or None
/// where a side is hidden or too faint against the ground for that; an error
/// when there is no such board.
pub(super) fn board_sides(
    img: &GreyView,
    e: &Ellipse,
    polarity: f64,
    board_to_disc: (f64, f64),
    params: &Params,
) -> Result<[Option<[f64; 3]>; 4], Rejection> {
    let n = 64;
    let mut ends: Vec<Pt> = Vec::new();
    let mut contrasts: Vec<f64> = Vec::new();
    let mut curvature: Vec<f64> = Vec::new();
    let mut uniform = 0;
    for i in 0..n {
        let phi = std::f64::consts::TAU * i as f64 / n as f64;
        let d = e.ray(phi);
        let at = |s: f64| img.sample(e.c.0 + d.0 * s, e.c.1 + d.1 * s);
        let (Some(disc), Some(b1), Some(b2), Some(b3)) = (at(0.5), at(1.25), at(1.45), at(1.65))
        else {
            continue;
        };
        let board = (b1 + b2 + b3) / 3.0;
        let contrast = board - disc;
        if contrast * polarity < params.min_contrast
            || [b1, b2, b3]
                .iter()
                .any(|b| (b - board).abs() > 0.3 * contrast.abs())
        {
            continue;
        }
        uniform += 1;
        contrasts.push(contrast.abs());
        curvature.push((b1 - 2.0 * b2 + b3).abs());
        // Walk out to where the board ends.
        let len = d.0.hypot(d.1);
        let mut s = 1.65;
        let mut away = 0;
        while s <= 4.5 {
            let Some(v) = at(s) else { break };
            // A fifth of the disc's contrast: a black board on shadowed
            // ground differs from it by far less than from a white disc.
            if (v - board).abs() > (0.2 * contrast.abs()).max(1.5 * params.min_contrast) {
                away += 1;
                if away == 2 {
                    ends.push((d.0 * (s - 1.0 / len), d.1 * (s - 1.0 / len)));
                    break;
                }
            } else {
                away = 0;
            }
            s += 1.0 / len;
        }
    }
    if (uniform as f64) < 0.8 * n as f64 {
        return Err(Rejection::BoardNotUniform);
    }
    let contrast = pr::quantile(&contrasts, 0.5);
    // The board's noise: second differences of its three samples per ray
    // (a shading gradient cancels), a robust standard deviation.
    let noise = 1.4826 * pr::quantile(&curvature, 0.5) / 6f64.sqrt();
    let fitted = if (ends.len() as f64) < params.min_end_agreement * n as f64 {
        Err(Rejection::BoardDoesNotEnd)
    } else {
        fit_board_square(&ends, n, params).ok_or(Rejection::BoardNotSquare)
    };
    // Ground of nearly the board's grey runs rays past the board's end here
    // and there; the sides still show where the board's level stops.
    let levels = Levels::new(img, e, contrast, noise, params);
    let mut square = fitted
        .or_else(|why| board_by_levels(&levels, board_orientation(&ends, params)).ok_or(why))?;
    if square.sides.iter().any(Option::is_none) {
        complete_by_levels(&levels, &mut square);
    }
    let ratio = square.half / e.radius();
    // A flat roof around a tank is seldom square: the board's sides
    // must lie as a square's would around this disc.
    if board_aspect(e, &square).is_some_and(|a| a.max(1.0 / a) > params.max_board_aspect) {
        return Err(Rejection::BoardNotSquare);
    }
    if !(board_to_disc.0..=board_to_disc.1).contains(&ratio) {
        return Err(Rejection::BoardNotSquare);
    }
    // A side hidden by something lying on or against the board (or ground
    // of the board's grey) has no line.
    let mut lines = [None; 4];
    for (line, side) in lines.iter_mut().zip(&square.sides) {
        let Some(side) = side else { continue };
        let rough = fit_line(side).ok_or(Rejection::BoardSide)?;
        // Subpixel where the profiles allow (ground of enough contrast);
        // pixel-level sides move the centre more than the perspective bias
        // they would remove.
        *line = board_side(img, e, rough, side, polarity, params)
            .map(|(p, d)| cross3([p.0, p.1, 1.0], [p.0 + d.0, p.1 + d.1, 1.0]));
    }
    Ok(lines)
}

/// How far `points` bow away from a straight line through them: the
/// quadratic of least squares across `line` (a point, the unit direction),
/// its rise from the middle to the farther end of their span. An arc of
/// radius R over a span of 2u bows u^2 / 2R.
pub(super) fn sagitta(points: &[Pt], (p, d): (Pt, Pt)) -> f64 {
    // Each point: its position along the line, its offset across it.
    let uv: Vec<Pt> = points
        .iter()
        .map(|q| {
            let (x, y) = (q.0 - p.0, q.1 - p.1);
            (x * d.0 + y * d.1, -x * d.1 + y * d.0)
        })
        .collect();
    let mean = uv.iter().map(|q| q.0).sum::<f64>() / uv.len().max(1) as f64;
    // Normal equations of v = a + b u + c u^2: sums of u^k (k < 5), v u^k.
    let (mut s, mut t) = ([0.0f64; 5], [0.0f64; 3]);
    for &(u, v) in &uv {
        let u = u - mean;
        let mut power = 1.0;
        for (k, sk) in s.iter_mut().enumerate() {
            *sk += power;
            if k < 3 {
                t[k] += v * power;
            }
            power *= u;
        }
    }
    let m = [s[0], s[1], s[2], s[1], s[2], s[3], s[2], s[3], s[4]];
    let Some(inv) = geometry::invert3(&m) else {
        return 0.0;
    };
    let c = inv[6] * t[0] + inv[7] * t[1] + inv[8] * t[2];
    let half = uv.iter().map(|q| (q.0 - mean).abs()).fold(0.0, f64::max);
    (c * half * half).abs()
}

/// How much wider the board is across one pair of opposite sides than
/// across the other, each width over the disc's own width the same way:
/// a square board and its disc lie in one plane, so (locally) one affine
/// map takes both and this is 1. None unless all four sides are held.
pub(super) fn board_aspect(e: &Ellipse, square: &BoardSquare) -> Option<f64> {
    let mut spans = [0.0; 2];
    for (k, span) in spans.iter_mut().enumerate() {
        let theta = square.psi + k as f64 * std::f64::consts::FRAC_PI_2;
        let n = (theta.cos(), theta.sin());
        let along = |side: &Option<Vec<Pt>>, sign: f64| {
            let points = side.as_ref()?;
            let sum: f64 = points.iter().map(|p| sign * (p.0 * n.0 + p.1 * n.1)).sum();
            Some(sum / points.len() as f64)
        };
        let width = along(&square.sides[k], 1.0)? + along(&square.sides[k + 2], -1.0)?;
        *span = width / e.half_width(n);
    }
    Some(spans[0] / spans[1])
}

/// A square board centred on its disc, fitted to the end points of rays.
pub(super) struct BoardSquare {
    /// Mean distance of the held sides from the disc's centre.
    pub(super) half: f64,
    /// Orientation of the square (radians): side k's outward normal is
    /// at psi + k pi/2.
    pub(super) psi: f64,
    /// Each side's end points (relative to the disc's centre) lying on it,
    /// None for a side too few points agree on (hidden or unseen).
    pub(super) sides: [Option<Vec<Pt>>; 4],
}

/// Fits a square centred on the origin to a board's end points `ends`
/// (from `n` rays): for every orientation, each point is assigned to the
/// nearest side and projected on that side's normal, turned by up to
/// [`max_side_tilt_deg`](Params::max_side_tilt_deg) the way most of the side's points agree on; a side
/// holds when enough of its points agree with their median. The orientation with the
/// most agreeing points wins among those where: all four sides hold and the
/// board's diagonals cross at the disc; or sides hold at nearly one
/// distance with [`min_end_agreement`](Params::min_end_agreement) of all end points on them. A
/// round board (a ring around a disc) fails: the agreeing points of a
/// square reach sqrt 2 farther at its corners than at its sides' middles, a
/// circle's do not; and a fifth of them at least lie towards the corners
/// ([`corner_sine`](Params::corner_sine)), which clutter lying about a ring does not give. So
/// does a roof with a tank off its centre: its sides lie at different
/// distances, its diagonals cross away from the tank.
pub(super) fn fit_board_square(ends: &[Pt], n: usize, params: &Params) -> Option<BoardSquare> {
    let per_side = n as f64 / 4.0;
    let mut best: Option<(usize, BoardSquare)> = None;
    for deg in 0..90 {
        let psi = (deg as f64).to_radians();
        let sides = assign_sides(ends, psi);
        // Sides that hold: their median distance, and how far from the
        // centre their agreeing points lie.
        let mut held: Vec<(f64, Vec<(Pt, f64)>)> = Vec::new();
        let mut lines: [Option<Vec<Pt>>; 4] = Default::default();
        for (k, side) in sides.iter().enumerate() {
            if side.is_empty() {
                continue;
            }
            // Perspective turns each side a little off the square's normal:
            // the side's own tilt that most of its points agree on.
            // (tilt's normal, median distance, points agreeing), counted
            // first and collected for the best tilt only.
            let mut side_best: Option<(Pt, f64, usize)> = None;
            let mut h: Vec<f64> = Vec::with_capacity(side.len());
            // Nearest the square first: a tie keeps the smaller tilt.
            let tilts = (0..=params.max_side_tilt_deg).flat_map(|t| [t, -t]).skip(1);
            for tilt in tilts {
                let theta =
                    psi + k as f64 * std::f64::consts::FRAC_PI_2 + (tilt as f64).to_radians();
                let normal = (theta.cos(), theta.sin());
                h.clear();
                h.extend(side.iter().map(|s| s.0 .0 * normal.0 + s.0 .1 * normal.1));
                let mid = h.len() / 2;
                let m = *h.select_nth_unstable_by(mid, f64::total_cmp).1;
                let agree = h
                    .iter()
                    .filter(|d| (*d - m).abs() < params.square_tolerance * m)
                    .count();
                if side_best.is_none_or(|b| agree > b.2) {
                    side_best = Some((normal, m, agree));
                }
            }
            let Some((normal, m, _)) = side_best else {
                continue;
            };
            // Each agreeing point with the sine of its angle off the normal.
            let on: Vec<(Pt, f64)> = side
                .iter()
                .filter_map(|s| {
                    let d = s.0 .0 * normal.0 + s.0 .1 * normal.1;
                    let r = s.0 .0.hypot(s.0 .1);
                    ((d - m).abs() < params.square_tolerance * m)
                        .then(|| (s.0, (1.0 - (d / r).powi(2)).max(0.0).sqrt()))
                })
                .collect();
            if (on.len() as f64) < params.min_side_support * per_side {
                continue;
            }
            // The side's line from points away from the corners, where
            // perspective may put a point on the neighbouring side.
            let middle: Vec<Pt> = on.iter().filter(|s| s.1 < 0.5).map(|s| s.0).collect();
            lines[k] = (middle.len() >= 4).then_some(middle);
            held.push((m, on));
        }
        // A round board (a ring around a disc) fits a square loosely too; a
        // square's corners lie sqrt 2 farther out than its sides' middles,
        // and a fifth of its points at least lie towards them. Each agreeing
        // point with the sine of its angle off its side's normal.
        let cornered = |on: &[(Pt, f64)]| {
            let reach: Vec<f64> = on.iter().map(|s| s.0 .0.hypot(s.0 .1)).collect();
            let near = on.iter().filter(|s| s.1 >= params.corner_sine).count();
            pr::quantile(&reach, 0.9) / pr::quantile(&reach, 0.1) >= 1.2
                && near as f64 >= params.min_corner_share * on.len() as f64
        };
        let mut consider = |agree: usize, half: f64| {
            if best.as_ref().is_none_or(|b| agree > b.0) {
                let sides = lines.clone();
                best = Some((agree, BoardSquare { half, psi, sides }));
            }
        };
        // All four sides seen: at whatever distances perspective gives them,
        // so long as the board's own centre (where its diagonals cross) is
        // the disc's.
        if held.len() == 4 {
            let on: Vec<(Pt, f64)> = held.iter().flat_map(|h| h.1.iter().copied()).collect();
            let half = held.iter().map(|h| h.0).sum::<f64>() / 4.0;
            if centred_on_disc(&lines, half, params) && cornered(&on) {
                consider(on.len(), half);
            }
        }
        // Or sides at nearly one distance, most of all end points on them:
        // an object or ground of the board's grey (a shadow) may hide the
        // rest. A roof's tank off its centre lies nearer some sides.
        let mut halves: Vec<f64> = held.iter().map(|h| h.0).collect();
        halves.sort_by(f64::total_cmp);
        for (i, &lo) in halves.iter().enumerate() {
            let same: Vec<f64> = halves[i..]
                .iter()
                .copied()
                .take_while(|h| *h <= params.max_side_ratio * lo)
                .collect();
            let half = same.iter().sum::<f64>() / same.len() as f64;
            let on: Vec<(Pt, f64)> = sides
                .iter()
                .flatten()
                .filter(|s| (s.1 - half).abs() < params.square_tolerance * half)
                .map(|s| (s.0, s.2))
                .collect();
            let agree = on.len();
            if agree as f64 >= params.min_end_agreement * n as f64 && cornered(&on) {
                consider(agree, half);
            }
        }
    }
    best.map(|b| b.1)
}

/// End points `ends` assigned to the nearest side of a square at
/// orientation `psi`: per side, each point, its distance along the side's
/// normal and the sine of its angle off that normal.
pub(super) fn assign_sides(ends: &[Pt], psi: f64) -> [Vec<(Pt, f64, f64)>; 4] {
    let mut sides: [Vec<(Pt, f64, f64)>; 4] = Default::default();
    for p in ends {
        let a = (p.1.atan2(p.0) - psi).rem_euclid(std::f64::consts::TAU);
        let k = (a / std::f64::consts::FRAC_PI_2).round() as usize % 4;
        // cos is even and 2pi-periodic: no wrap-around to mind.
        let off = a - k as f64 * std::f64::consts::FRAC_PI_2;
        sides[k].push((*p, p.0.hypot(p.1) * off.cos(), off.sin().abs()));
    }
    sides
}

/// The square orientation (radians, 0 to pi/2) most of the end points `ends`
/// agree with: the one where most lie on their side's median distance.
pub(super) fn board_orientation(ends: &[Pt], params: &Params) -> f64 {
    let mut best = (0usize, 0.0);
    for deg in 0..90 {
        let psi = (deg as f64).to_radians();
        let agree: usize = assign_sides(ends, psi)
            .iter()
            .filter(|side| !side.is_empty())
            .map(|side| {
                let h: Vec<f64> = side.iter().map(|s| s.1).collect();
                let m = pr::quantile(&h, 0.5);
                h.iter()
                    .filter(|d| (*d - m).abs() < params.square_tolerance * m)
                    .count()
            })
            .sum();
        if agree > best.0 {
            best = (agree, psi);
        }
    }
    best.1
}

/// A profile across a board's side: where along the side, the board's
/// level next to the disc, the samples outward (1 px apart from
/// 1.3x the disc's radius) and whether each is at the board's level.
pub(super) struct Column {
    u: f64,
    level: f64,
    values: Vec<f64>,
    on: Vec<bool>,
}

/// What tells a disc's board from its ground by level: the disc, and how
/// far from the board's level a sample may lie and still be board.
pub(super) struct Levels<'a> {
    img: &'a GreyView<'a>,
    e: &'a Ellipse,
    tol: f64,
    params: &'a Params,
}

/// One side of a board found by levels: its edge points (relative to the
/// disc's centre), its distance from the disc and its outward normal.
pub(super) struct LevelSide {
    points: Vec<Pt>,
    distance: f64,
    normal: Pt,
}

impl Levels<'_> {
    /// `contrast` between disc and board, `noise` of the board's samples:
    /// the board's level within 4 noise deviations, or a tenth of the
    /// contrast where shading across a large board exceeds its noise.
    pub(super) fn new<'a>(
        img: &'a GreyView<'a>,
        e: &'a Ellipse,
        contrast: f64,
        noise: f64,
        params: &'a Params,
    ) -> Levels<'a> {
        let tol = (4.0 * noise).max(0.1 * contrast).max(8.0);
        Levels {
            img,
            e,
            tol,
            params,
        }
    }

    fn at(&self, p: Pt) -> Option<f64> {
        self.img.sample(self.e.c.0 + p.0, self.e.c.1 + p.1)
    }

    /// The side whose outward normal is near direction `theta`: columns
    /// along normals within two tilts of it start at the board's level next
    /// to the disc; the share of columns still at that level drops from
    /// all to few where the board ends, whatever the ground does column by
    /// column. Each column's own end near that drop (its crossing halfway
    /// to the ground's level past it) gives the side's edge points.
    fn side(&self, theta: f64) -> Option<LevelSide> {
        let r = self.e.radius();
        let h_lo = 1.3 * r;
        let bins = ((MAX_BOARD_TO_DISC + 0.3 - 1.3) * r) as usize + 1;
        // Drop window: a fraction of the disc's radius, several pixels.
        let w = (0.3 * r).max(6.0) as usize;
        // The drop, its bin, the normal and tangent, the columns.
        let mut best: Option<(f64, usize, Pt, Pt, Vec<Column>)> = None;
        for tilt in [0.0, -1.0, 1.0, -2.0, 2.0].map(|f| f * LEVEL_TILT_DEG) {
            let a = theta + f64::to_radians(tilt);
            let (n, t) = ((a.cos(), a.sin()), (-a.sin(), a.cos()));
            let columns = self.columns(n, t, h_lo, bins);
            if columns.len() < 8 {
                continue;
            }
            let frac: Vec<f64> = (0..bins)
                .map(|b| columns.iter().filter(|c| c.on[b]).count() as f64 / columns.len() as f64)
                .collect();
            let mut here: Option<(f64, usize)> = None;
            for b in w..bins.saturating_sub(w) {
                let inside = frac[b - w..b].iter().sum::<f64>() / w as f64;
                let outside = frac[b..b + w].iter().sum::<f64>() / w as f64;
                let drop = inside - outside;
                if inside >= 0.8 && here.is_none_or(|x| drop > x.0) {
                    here = Some((drop, b));
                }
            }
            if let Some((drop, b)) = here {
                if best.as_ref().is_none_or(|x| drop > x.0) {
                    best = Some((drop, b, n, t, columns));
                }
            }
        }
        let (drop, bin, n, t, columns) = best?;
        if drop < self.params.min_level_drop {
            return None;
        }
        // The bin, not h - h_lo, which rounding may put just below it.
        let h = h_lo + bin as f64;
        // Each column's end: the first of two samples off the board's level
        // from a window before the drop, then where the column crosses
        // halfway between the board's level and the ground's just past it.
        let start = bin - w;
        let points: Vec<Pt> = columns
            .iter()
            .filter_map(|c| {
                let j = (start..bins - 1).find(|&j| !c.on[j] && !c.on[j + 1])?;
                let ground = pr::mean(&c.values, j + 1, (j + 4).min(bins));
                let mid = (c.level + ground) / 2.0;
                let x = pr::crossing(&c.values, mid, ground > c.level, j as f64)?;
                let edge = h_lo + x;
                ((edge - h).abs() <= w as f64)
                    .then_some((n.0 * edge + t.0 * c.u, n.1 * edge + t.1 * c.u))
            })
            .collect();
        if (points.len() as f64) < self.params.min_side_support * columns.len() as f64 {
            return None;
        }
        let ((p, d), inliers) = pr::robust_line(&points)?;
        // A ring's arc is not a board's side.
        if sagitta(&inliers, (p, d)) > self.params.max_side_bow_px {
            return None;
        }
        let mut normal = (-d.1, d.0);
        let mut distance = p.0 * normal.0 + p.1 * normal.1;
        if distance < 0.0 {
            (normal, distance) = ((-normal.0, -normal.1), -distance);
        }
        Some(LevelSide {
            points: inliers,
            distance,
            normal,
        })
    }

    /// Columns along normal `n`, every 1.5 px along the side's middle
    /// (tangent `t`), each sampled `bins` times from `h_lo` out.
    fn columns(&self, n: Pt, t: Pt, h_lo: f64, bins: usize) -> Vec<Column> {
        let r = self.e.radius();
        let mut columns = Vec::new();
        let mut u = -0.9 * r;
        while u <= 0.9 * r {
            let point = |h: f64| (n.0 * h + t.0 * u, n.1 * h + t.1 * u);
            let inner: Option<Vec<f64>> = [1.15, 1.2, 1.25]
                .iter()
                .map(|f| self.at(point(f * r)))
                .collect();
            let values: Option<Vec<f64>> =
                (0..bins).map(|b| self.at(point(h_lo + b as f64))).collect();
            if let (Some(inner), Some(values)) = (inner, values) {
                let level = inner.iter().sum::<f64>() / 3.0;
                let on = values
                    .iter()
                    .map(|v| (v - level).abs() <= self.tol)
                    .collect();
                columns.push(Column {
                    u,
                    level,
                    values,
                    on,
                });
            }
            u += 1.5;
        }
        columns
    }

    /// Whether the board's level reaches past the nearer of two
    /// neighbouring sides' distances along the diagonal between them (a
    /// square's corner; a round board stops there).
    fn corner(&self, a: &LevelSide, b: &LevelSide) -> bool {
        let r = self.e.radius();
        let diag = (a.normal.0 + b.normal.0, a.normal.1 + b.normal.1);
        let len = diag.0.hypot(diag.1);
        let diag = (diag.0 / len, diag.1 / len);
        let sample = |f: f64| self.at((diag.0 * f, diag.1 * f));
        let (Some(b1), Some(b2)) = (sample(1.15 * r), sample(1.25 * r)) else {
            return false;
        };
        let level = (b1 + b2) / 2.0;
        let reach = a.distance.min(b.distance);
        [1.1, 1.2, 1.3]
            .iter()
            .all(|f| sample(f * reach).is_some_and(|v| (v - level).abs() <= self.tol))
    }
}

/// A disc's board found by levels (for boards on ground of nearly their
/// grey, where rays run past the board's end here and there), the square's
/// orientation `psi` taken from the rays' ends. With all four sides showing
/// their drop, the board's diagonals must cross at the disc and at least
/// three corners must reach past the sides. With one side hidden (ground of
/// the board's grey there), the two sides across it must lie equally far
/// from the disc and the third as far as they do, within
/// [`three_side_tolerance`](Params::three_side_tolerance), and both corners of the third must reach past.
pub(super) fn board_by_levels(levels: &Levels, psi: f64) -> Option<BoardSquare> {
    let found: [Option<LevelSide>; 4] =
        std::array::from_fn(|k| levels.side(psi + k as f64 * std::f64::consts::FRAC_PI_2));
    let hidden: Vec<usize> = (0..4).filter(|&k| found[k].is_none()).collect();
    let distance = |k: usize| found[k % 4].as_ref().map(|s| s.distance);
    // Whether the corner between sides k and k + 1 reaches past them.
    let corner = |k: usize| match (&found[k % 4], &found[(k + 1) % 4]) {
        (Some(a), Some(b)) => levels.corner(a, b),
        _ => false,
    };
    let (half, shaped) = match hidden[..] {
        [] => (
            (0..4).filter_map(distance).sum::<f64>() / 4.0,
            (0..4).filter(|&k| corner(k)).count() >= 3,
        ),
        [m] => {
            let [a, third, b] = [1, 2, 3].map(|i| distance(m + i).expect("not hidden"));
            let close =
                |x: f64, y: f64| x.max(y) / x.min(y) <= 1.0 + levels.params.three_side_tolerance;
            (
                (a + third + b) / 3.0,
                close(a, b) && close(third, (a + b) / 2.0) && corner(m + 1) && corner(m + 2),
            )
        }
        _ => return None,
    };
    let sides = found.map(|s| s.map(|s| s.points));
    // Four sides: where the board's diagonals cross (three: the equal
    // distances above).
    let centred = !hidden.is_empty() || centred_on_disc(&sides, half, levels.params);
    (shaped && centred).then_some(BoardSquare { half, psi, sides })
}

/// A board accepted without all four sides' edge points: the missing sides
/// found by levels, kept only when the four sides' diagonals then cross at
/// the disc (else the board keeps its missing sides, and the disc the
/// ellipse's centre).
pub(super) fn complete_by_levels(levels: &Levels, square: &mut BoardSquare) {
    let mut sides = square.sides.clone();
    for (k, side) in sides.iter_mut().enumerate() {
        if side.is_none() {
            let theta = square.psi + k as f64 * std::f64::consts::FRAC_PI_2;
            let found = levels.side(theta);
            let Some(found) = found else { return };
            *side = Some(found.points);
        }
    }
    if centred_on_disc(&sides, square.half, levels.params) {
        square.sides = sides;
    }
}

/// Whether the board bounded by four side lines (its half side `half`) has
/// its centre at the disc's, within [`max_centre_offset`](Params::max_centre_offset) of the half side
/// plus a pixel.
pub(super) fn centred_on_disc(sides: &[Option<Vec<Pt>>; 4], half: f64, params: &Params) -> bool {
    board_centre(sides).is_some_and(|c| c.0.hypot(c.1) < params.max_centre_offset * half + 1.0)
}

/// Where the diagonals of the quadrilateral bounded by four side lines
/// (each through its points, in order around the board) cross: the image
/// of the board's centre under any perspective.
pub(super) fn board_centre(sides: &[Option<Vec<Pt>>; 4]) -> Option<Pt> {
    let mut lines = Vec::with_capacity(4);
    for side in sides {
        lines.push(fit_line(side.as_deref()?)?);
    }
    let corners: Vec<Pt> = (0..4)
        .map(|k| intersect(lines[k], lines[(k + 1) % 4]))
        .collect::<Option<_>>()?;
    let diagonal = |p: Pt, q: Pt| (p, (q.0 - p.0, q.1 - p.1));
    intersect(
        diagonal(corners[0], corners[2]),
        diagonal(corners[1], corners[3]),
    )
}

/// One side of a disc's board to subpixel precision: from the pixel-level
/// line `rough` through the board's end points `ends` (relative to the
/// disc's centre), profiles across the side every pixel along its middle
/// give midpoint crossings between the board's level and the ground's, and
/// a line is fitted through them, outliers left out.
pub(super) fn board_side(
    img: &GreyView,
    e: &Ellipse,
    rough: (Pt, Pt),
    ends: &[Pt],
    polarity: f64,
    params: &Params,
) -> Option<(Pt, Pt)> {
    let ((px, py), d) = rough;
    // Outward normal: away from the disc's centre (the origin here).
    let mut n = (-d.1, d.0);
    if n.0 * px + n.1 * py < 0.0 {
        n = (-n.0, -n.1);
    }
    let along: Vec<f64> = ends
        .iter()
        .map(|q| (q.0 - px) * d.0 + (q.1 - py) * d.1)
        .collect();
    let (lo, hi) = along
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &t| (a.min(t), b.max(t)));
    let half = (0.25 * e.radius()).clamp(3.0, 10.0);
    let mut points = Vec::new();
    let mut profile = Vec::new();
    let mut t = lo;
    while t <= hi {
        let base = (e.c.0 + px + d.0 * t, e.c.1 + py + d.1 * t);
        if pr::line(img, base, n, half, &mut profile).is_some() {
            let k = (profile.len() / 4).max(1);
            let (board, ground) = (
                pr::mean(&profile, 0, k),
                pr::mean(&profile, profile.len() - k, profile.len()),
            );
            // A white board is lighter than its ground (polarity < 0 means
            // the disc is lighter than its board).
            let rising = ground > board;
            let expected = if polarity > 0.0 { !rising } else { rising };
            if (ground - board).abs() >= params.min_contrast && expected {
                let centre = half / pr::STEP_PX;
                if let Some(x) = pr::crossing(&profile, (board + ground) / 2.0, rising, centre) {
                    let s = pr::offset(x, half);
                    points.push((px + d.0 * t + n.0 * s, py + d.1 * t + n.1 * s));
                }
            }
        }
        t += 1.0;
    }
    if points.len() < 6 {
        return None;
    }
    // Ground texture crossing the midpoint scatters a faint side's points:
    // no subpixel line there.
    let (line, inliers) = pr::robust_line(&points)?;
    (pr::line_rms(&inliers, line) <= params.max_side_rms_px).then_some(line)
}
