//! Intensity profiles on the grey tile for the printed-target detectors:
//! rings around a candidate centre, straight profiles, and midpoint
//! crossings. A crossing at the midpoint of its own dark and light levels
//! is unbiased for any symmetric blur (defocus, motion) and any local
//! brightness scale (shadow), which is what makes these fits subpixel.

use super::geometry::Pt;
use super::refine::GreyView;

/// Samples along a straight profile, in pixels.
pub const STEP_PX: f64 = 0.25;

/// Samples on a circle of radius `r` around `c`, in the directions of
/// `basis`; None when the circle leaves the tile.
pub fn ring(img: &GreyView, c: Pt, r: f64, basis: &super::harmonic::RingBasis) -> Option<Vec<f64>> {
    (0..basis.len())
        .map(|i| {
            let (dx, dy) = basis.direction(i);
            img.sample(c.0 + r * dx, c.1 + r * dy)
        })
        .collect()
}

/// Samples from `base - half * dir` to `base + half * dir` every
/// [`STEP_PX`]; None when the profile leaves the tile.
pub fn line(img: &GreyView, base: Pt, dir: Pt, half: f64, out: &mut Vec<f64>) -> Option<()> {
    let n = (2.0 * half / STEP_PX).round() as usize;
    out.clear();
    for k in 0..=n {
        let s = -half + k as f64 * STEP_PX;
        out.push(img.sample(base.0 + dir.0 * s, base.1 + dir.1 * s)?);
    }
    Some(())
}

/// Offset from the profile's centre of a sample index (fractional).
pub fn offset(index: f64, half: f64) -> f64 {
    -half + index * STEP_PX
}

/// Fractional index where `p` crosses `level` upward (`rising`) or downward,
/// nearest to index `near` (the lower one of two as near).
///
/// Crossings lie in increasing order along the profile (each interval
/// holds at most one, and two neighbours cannot share their common
/// sample), so the nearest is one of the first met walking out from
/// `near`: the search stops there, not at the profile's ends.
pub fn crossing(p: &[f64], level: f64, rising: bool, near: f64) -> Option<f64> {
    let hit = |i: usize| -> Option<f64> {
        let (a, b) = (p[i], p[i + 1]);
        let crosses = if rising {
            a < level && b >= level
        } else {
            a >= level && b < level
        };
        crosses.then(|| i as f64 + (level - a) / (b - a))
    };
    let intervals = p.len().saturating_sub(1);
    if intervals == 0 {
        return None;
    }
    // The interval holding `near` (clamped to the profile).
    let first = if near <= 0.0 {
        0
    } else {
        (near as usize).min(intervals - 1)
    };
    // The crossing in `near`'s interval and, unless that one lies at or
    // past `near`, the first after it; then the last before the interval,
    // looked for only as far as it could still be nearer.
    let mut best = hit(first);
    if best.is_none_or(|x| x < near) {
        if let Some(x) = (first + 1..intervals).find_map(hit) {
            if best.is_none_or(|bx| (x - near).abs() < (bx - near).abs()) {
                best = Some(x);
            }
        }
    }
    let bound = best.map_or(f64::INFINITY, |x| (x - near).abs());
    for i in (0..first).rev() {
        if near - (i + 1) as f64 > bound {
            break;
        }
        if let Some(x) = hit(i) {
            // Before the others: it wins a tie, as the lower index.
            if best.is_none_or(|bx| (x - near).abs() <= (bx - near).abs()) {
                best = Some(x);
            }
            break;
        }
    }
    best
}

/// Mean of `p[range]` (clamped to the profile).
pub fn mean(p: &[f64], from: usize, to: usize) -> f64 {
    let to = to.min(p.len());
    let from = from.min(to.saturating_sub(1));
    p[from..to].iter().sum::<f64>() / (to - from).max(1) as f64
}

/// The q-quantile of `v` (0..=1), nearest rank.
pub fn quantile(v: &[f64], q: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[((s.len() - 1) as f64 * q).round() as usize]
}

/// Root mean square distance of points from a line (point, unit direction).
pub fn line_rms(points: &[Pt], line: (Pt, Pt)) -> f64 {
    let ((px, py), (dx, dy)) = line;
    let ss: f64 = points
        .iter()
        .map(|&(x, y)| {
            let d = (x - px) * dy - (y - py) * dx;
            d * d
        })
        .sum();
    (ss / points.len().max(1) as f64).sqrt()
}

pub fn unit(a: f64) -> Pt {
    (a.cos(), a.sin())
}

/// `a` rotated by +90 degrees in image axes.
pub fn perp(a: Pt) -> Pt {
    (-a.1, a.0)
}

pub fn add(p: Pt, d: Pt, t: f64) -> Pt {
    (p.0 + d.0 * t, p.1 + d.1 * t)
}

/// A line through `points` that ignores outliers (profiles a shadow edge or
/// a blemish crossed): least squares, then again on the points within 2.5
/// robust standard deviations (median absolute residual), at least 0.1 px.
pub fn robust_line(points: &[Pt]) -> Option<((Pt, Pt), Vec<Pt>)> {
    let first = super::refine::fit_line(points)?;
    let residual = |p: &Pt, l: (Pt, Pt)| ((p.0 - l.0 .0) * l.1 .1 - (p.1 - l.0 .1) * l.1 .0).abs();
    let r: Vec<f64> = points.iter().map(|p| residual(p, first)).collect();
    let inliers = inliers(points, &r);
    if inliers.len() < 6 {
        return None;
    }
    Some((super::refine::fit_line(&inliers)?, inliers))
}

/// The points whose residual (distance from a first fit) is within 2.5
/// robust standard deviations (1.4826 x the median residual), at least
/// 0.1 px.
pub fn inliers(points: &[Pt], residuals: &[f64]) -> Vec<Pt> {
    let limit = (2.5 * 1.4826 * quantile(residuals, 0.5)).max(0.1);
    points
        .iter()
        .zip(residuals)
        .filter(|(_, r)| **r <= limit)
        .map(|(p, _)| *p)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::crossing;

    /// The nearest crossing by looking at every interval.
    fn every_interval(p: &[f64], level: f64, rising: bool, near: f64) -> Option<f64> {
        let mut best: Option<f64> = None;
        for i in 0..p.len().saturating_sub(1) {
            let (a, b) = (p[i], p[i + 1]);
            let hit = if rising {
                a < level && b >= level
            } else {
                a >= level && b < level
            };
            if hit {
                let x = i as f64 + (level - a) / (b - a);
                if best.is_none_or(|bx| (x - near).abs() < (bx - near).abs()) {
                    best = Some(x);
                }
            }
        }
        best
    }

    #[test]
    fn the_nearest_crossing_is_the_one_found_by_looking_everywhere() {
        // Noisy steps and ramps on coarse grey levels (ties and samples
        // exactly at the level included), `near` inside, on and past the
        // ends of the profile.
        let mut state = 0x2545_f491_u64;
        let mut next = move |n: u64| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) % n
        };
        for _ in 0..20_000 {
            let len = next(40) as usize;
            let p: Vec<f64> = (0..len).map(|_| next(6) as f64 * 10.0).collect();
            let level = next(6) as f64 * 10.0 + [0.0, 5.0][next(2) as usize];
            let near = next(90) as f64 / 2.0 - 2.0;
            for rising in [true, false] {
                assert_eq!(
                    crossing(&p, level, rising, near),
                    every_interval(&p, level, rising, near),
                    "{p:?} level {level} rising {rising} near {near}"
                );
            }
        }
        assert_eq!(crossing(&[], 1.0, true, 0.0), None);
        assert_eq!(crossing(&[0.0, 2.0], 1.0, true, f64::NAN), Some(0.5));
    }
}
