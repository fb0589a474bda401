//! The rings of samples around a candidate that classify it (a cross's
//! four bright bars or a checker's four alternating quadrants) and give
//! its arms' directions.

use super::*;

/// Classifies a ring of samples: four alternating quadrants (checker) or
/// four narrow bright arcs on dark (cross), and finds the arms.
///
/// In log intensity (a shadow is an offset) the ring's 2nd or 4th harmonic
/// predicts where the quadrant boundaries or bars are; each is then found
/// locally, within 25 degrees of the prediction (perspective skews the
/// angles), and checked on its own: a boundary steps the expected way, a bar
/// stands above the dark on both its sides. A shadow edge across the ring
/// changes levels between arms, not these local contrasts.
pub(super) fn classify_ring(basis: &RingBasis, v: &[f64]) -> Option<RingPattern> {
    let (lo, hi) = (pr::quantile(v, 0.1), pr::quantile(v, 0.9));
    if hi - lo < MIN_CONTRAST {
        return None;
    }
    let n = v.len();
    // [1 2 1] smoothing against noise.
    let lv: Vec<f64> = (0..n)
        .map(|i| harmonic::log_grey((v[(i + n - 1) % n] + 2.0 * v[i] + v[(i + 1) % n]) / 4.0))
        .collect();
    let response = basis.response(&lv);
    let symmetry = if harmonic::score(Symmetry::Checker, response) >= harmonic::MIN_SCORE {
        Symmetry::Checker
    } else if harmonic::score(Symmetry::Cross, response) >= harmonic::MIN_SCORE {
        Symmetry::Cross
    } else {
        return None;
    };
    let step = TAU / n as f64;
    let at = |a: f64| lv[((a / step).round() as i64).rem_euclid(n as i64) as usize];
    // Mean of the ring over angles [a, b].
    let mean = |a: f64, b: f64| {
        let k = ((b - a) / step).round().max(1.0) as usize;
        (0..=k).map(|j| at(a + j as f64 * step)).sum::<f64>() / (k + 1) as f64
    };
    let window = 25f64.to_radians();
    let deg = |d: f64| d.to_radians();
    match symmetry {
        Symmetry::Checker => {
            // lv ~ m + a cos(2(theta - phi/2)): light at phi/2, boundaries
            // 45 degrees either side, falling first (counter-clockwise).
            let light = basis.phase(2, &lv) / 2.0;
            let mut arms = [0.0; 4];
            for (k, arm) in arms.iter_mut().enumerate() {
                let predicted = light + PI / 4.0 + k as f64 * PI / 2.0;
                let sign = if k % 2 == 0 { -1.0 } else { 1.0 };
                // Steepest expected-sign slope within the window.
                let m = (window / step).round() as i64;
                let slope = |j: i64| {
                    let a = predicted + j as f64 * step;
                    sign * (at(a + step) - at(a - step))
                };
                let best = (-m..=m).max_by(|&a, &b| slope(a).total_cmp(&slope(b)))?;
                let (y0, y1, y2) = (slope(best - 1), slope(best), slope(best + 1));
                let d = y0 - 2.0 * y1 + y2;
                let frac = if d < 0.0 {
                    (0.5 * (y0 - y2) / d).clamp(-0.5, 0.5)
                } else {
                    0.0
                };
                let a = predicted + (best as f64 + frac) * step;
                // Local step across the boundary, 5-20 degrees either side.
                let contrast =
                    sign * (mean(a + deg(5.0), a + deg(20.0)) - mean(a - deg(20.0), a - deg(5.0)));
                if contrast < harmonic::MIN_SCORE {
                    return None;
                }
                *arm = a.rem_euclid(TAU);
            }
            let mut sorted = arms;
            sorted.sort_by(f64::total_cmp);
            let spans_ok = (0..4).all(|k| {
                let g = (sorted[(k + 1) % 4] - sorted[k]).rem_euclid(TAU);
                (deg(35.0)..=deg(145.0)).contains(&g)
            });
            spans_ok.then_some(RingPattern {
                kind: Kind::Checker,
                arms: sorted,
                bar_rad: 0.0,
            })
        }
        Symmetry::Cross => {
            let bar0 = basis.phase(4, &lv) / 4.0;
            let m = (window / step).round() as i64;
            let mut arms = Vec::with_capacity(4);
            let mut width = 0.0;
            for k in 0..4 {
                let predicted = bar0 + k as f64 * PI / 2.0;
                let best = (-m..=m).max_by(|&a, &b| {
                    at(predicted + a as f64 * step).total_cmp(&at(predicted + b as f64 * step))
                })?;
                let peak_a = predicted + best as f64 * step;
                let peak = at(peak_a);
                // The dark quadrants on either side: the lowest level within
                // 60 degrees.
                let side = |dir: f64| {
                    (1..=(deg(60.0) / step) as i64)
                        .map(|j| at(peak_a + dir * j as f64 * step))
                        .fold(f64::MAX, f64::min)
                };
                let (left, right) = (side(-1.0), side(1.0));
                if peak - left.max(right) < harmonic::MIN_SCORE {
                    return None;
                }
                // Half-level crossings on each side give the bar's centre.
                let edge = |dir: f64, dark: f64| {
                    let level = (peak + dark) / 2.0;
                    let mut prev = peak;
                    for j in 1..=(deg(60.0) / step) as i64 {
                        let x = at(peak_a + dir * j as f64 * step);
                        if x < level {
                            let f = (prev - level) / (prev - x);
                            return Some(peak_a + dir * (j as f64 - 1.0 + f) * step);
                        }
                        prev = x;
                    }
                    None
                };
                let (a0, a1) = (edge(-1.0, left)?, edge(1.0, right)?);
                if a1 - a0 > deg(100.0) {
                    return None;
                }
                width += (a1 - a0) / 4.0;
                arms.push(((a0 + a1) / 2.0).rem_euclid(TAU));
            }
            arms.sort_by(f64::total_cmp);
            let gaps_ok = (0..4).all(|k| {
                let g = (arms[(k + 1) % 4] - arms[k]).rem_euclid(TAU);
                // Dark between bars: at least 15 degrees of it.
                (deg(50.0)..=deg(130.0)).contains(&g) && g - width >= deg(15.0)
            });
            gaps_ok.then(|| RingPattern {
                kind: Kind::Cross,
                arms: [arms[0], arms[1], arms[2], arms[3]],
                bar_rad: width,
            })
        }
    }
}

/// Pairs the arms of the outer ring with the inner ring's (both ascending):
/// the cyclic shift with the smallest angle differences, each under 15°.
pub(super) fn match_arms(inner: &[f64; 4], outer: &[f64; 4]) -> Option<[f64; 4]> {
    let diff = |a: f64, b: f64| {
        let d = (a - b).rem_euclid(TAU);
        d.min(TAU - d)
    };
    let shift = (0..4).min_by(|&i, &j| {
        let cost = |s: usize| {
            (0..4)
                .map(|k| diff(inner[k], outer[(k + s) % 4]))
                .sum::<f64>()
        };
        cost(i).total_cmp(&cost(j))
    })?;
    let paired: [f64; 4] = std::array::from_fn(|k| outer[(k + shift) % 4]);
    (0..4)
        .all(|k| diff(inner[k], paired[k]) < 15f64.to_radians())
        .then_some(paired)
}

/// `d` flipped, if needed, to point like `like`.
pub(super) fn orient(d: Pt, like: Pt) -> Pt {
    if d.0 * like.0 + d.1 * like.1 < 0.0 {
        (-d.0, -d.1)
    } else {
        d
    }
}
