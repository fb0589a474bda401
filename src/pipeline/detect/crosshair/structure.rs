//! Structure checks on an accepted shape that tell printed targets from
//! look-alikes: dark quadrants, grid lines and paving around, the board's
//! sides against the ground, whole and uniform quadrants.

use super::arms::half_sides;
use super::*;

/// A cross's quadrants are dark all over: on a 3x3 grid across each one,
/// nearly every sample is darker than the bar beside it (a local comparison,
/// so a shadow edge across the target does not matter). The bright diagonal
/// "crosses" of checker paving have light tiles inside their quadrants.
pub(super) fn quadrants_are_dark(
    img: &GreyView,
    c: Pt,
    dirs: &[Pt; 2],
    lengths: &[f64; 4],
    bar: f64,
    strength: f64,
) -> bool {
    let inner = bar / 2.0 + 2.5;
    let (mut dark, mut total) = (0, 0);
    for k in 0..4 {
        let (a, b) = (arm_dir(dirs, k), arm_dir(dirs, (k + 1) % 4));
        let (la, lb) = (lengths[k] - 2.5, lengths[(k + 1) % 4] - 2.5);
        for fu in [0.15, 0.5, 0.85] {
            for fv in [0.15, 0.5, 0.85] {
                let (u, v) = (inner + (la - inner) * fu, inner + (lb - inner) * fv);
                let on_bar = add(c, a, u);
                let p = add(on_bar, b, v);
                if let (Some(q), Some(bright)) =
                    (img.sample(p.0, p.1), img.sample(on_bar.0, on_bar.1))
                {
                    total += 1;
                    dark += (q < bright - 0.3 * strength) as usize;
                }
            }
        }
    }
    total == 36 && dark >= 33
}

/// How many of the square's eight half-edges (each quadrant's two outer
/// sides) are bright lines: brighter than both the quadrant inside and the
/// ground beyond. A crossing of a panel grid or window frame is boxed in by
/// such lines; a printed cross ends on plain ground.
///
/// Returns the lines right at the arms' ends, and those found only within a
/// bar's width of them, peaking in a straight row. The arm's measured end
/// lies a pixel or two either side of a crossing line's middle (blur, the
/// end test's 3 px run): two panel grids' corners measured 0-1 lines at the
/// ends and 4 more near them. A printed cross on a white disc measured 2 at
/// the ends, and 2 more if the row may bend by half a bar: the disc's rim
/// past the square is a bright band whose middle moved 3.5 px along a
/// half-edge; the row may bend by a fifth of a bar (1.5 px at least).
pub(super) fn grid_lines_around(
    img: &GreyView,
    c: Pt,
    dirs: &[Pt; 2],
    lengths: &[f64; 4],
    bar: f64,
    strength: f64,
) -> (usize, usize) {
    let o = (0.5 * bar).max(2.5);
    let (mut at_end, mut near_end) = (0, 0);
    // The two quadrants beside each arm's end: towards arm k+1 and k-1.
    for (a, la, b, lb) in half_sides(dirs, lengths) {
        let (mut bright, mut total) = (0, 0);
        // Where a line peaks near the arm's end, on each profile.
        let mut peaks = Vec::new();
        for f in [0.3, 0.45, 0.6, 0.75, 0.9] {
            let v = bar / 2.0 + f * (lb - bar / 2.0);
            let at = |u: f64| {
                let p = add(add(c, a, u), b, v);
                img.sample(p.0, p.1)
            };
            let ridge = |line: f64| -> Option<f64> {
                let (mid, inside, outside) = (
                    at(line)?,
                    at(line - bar / 2.0 - o)?,
                    at(line + bar / 2.0 + o)?,
                );
                Some(mid - inside.max(outside))
            };
            let centre = la + bar / 2.0;
            if let Some(here) = ridge(centre) {
                total += 1;
                bright += (here >= 0.25 * strength) as usize;
            }
            let steps = (2.0 * bar).ceil() as i32;
            let best = (-steps..=steps)
                .filter_map(|j| {
                    let u = centre + 0.5 * j as f64;
                    ridge(u).map(|r| (u, r))
                })
                .max_by(|x, y| x.1.total_cmp(&y.1));
            if let Some((u, r)) = best {
                if r >= 0.25 * strength {
                    peaks.push(u);
                }
            }
        }
        // ... on four profiles of five, in a straight row (ground's
        // texture has ridges too, scattered).
        let (lo, hi) = peaks
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), &u| (l.min(u), h.max(u)));
        let in_row = peaks.len() >= 4 && hi - lo <= (0.2 * bar).max(1.5);
        if total == 5 && bright >= 3 {
            at_end += 1;
        } else if total == 5 && in_row {
            near_end += 1;
        }
    }
    (at_end, near_end)
}

/// How many of a cross's eight half-sides (each quadrant's two outer sides)
/// show as an edge between the board and the ground: on at least two of
/// three profiles across the side, the ground 3 px out differs from the
/// quadrant 3 px in by a quarter of the bars' contrast.
pub(super) fn board_sides_seen(
    img: &GreyView,
    c: Pt,
    dirs: &[Pt; 2],
    lengths: &[f64; 4],
    strength: f64,
) -> usize {
    let mut seen = 0;
    for (a, la, b, lb) in half_sides(dirs, lengths) {
        let edges = [0.45, 0.65, 0.85]
            .iter()
            .filter(|&&f| {
                let at = |u: f64| {
                    let p = add(add(c, a, u), b, f * lb);
                    img.sample(p.0, p.1)
                };
                match (at(la - 3.0), at(la + 3.0)) {
                    (Some(inside), Some(outside)) => (outside - inside).abs() >= 0.25 * strength,
                    _ => false,
                }
            })
            .count();
        seen += (edges >= 2) as usize;
    }
    seen
}

/// A checker's quadrants are uniform out to its edge: on a 3x3 grid across
/// each quadrant, a sample differs from its mirror image across the
/// neighbouring arm (in the quadrant of the other colour) the same way as
/// the quadrants do. A junction of unrelated regions (a paving corner by a
/// road marking) has "quadrants" that change colour within the square. A
/// quarter of the pairs may fail: a shadow edge across a low-contrast
/// checker brings its shadowed light part close to the lit dark one.
pub(super) fn checker_quadrants_uniform(
    img: &GreyView,
    c: Pt,
    dirs: &[Pt; 2],
    lengths: &[f64; 4],
    strength: f64,
) -> bool {
    let mut diffs = [[0.0; 9]; 4];
    for (k, d) in diffs.iter_mut().enumerate() {
        let (a, b) = (arm_dir(dirs, k), arm_dir(dirs, (k + 1) % 4));
        let (la, lb) = (lengths[k], lengths[(k + 1) % 4]);
        let inner = (0.12 * la).max(3.0);
        for (i, (fu, fv)) in [0.25, 0.5, 0.8]
            .iter()
            .flat_map(|u| [0.25, 0.5, 0.8].map(|v| (*u, v)))
            .enumerate()
        {
            let (u, v) = (
                inner + (la - inner - 2.0) * fu,
                inner + (lb - inner - 2.0) * fv,
            );
            let (p, q) = (add(add(c, a, u), b, v), add(add(c, a, u), b, -v));
            match (img.sample(p.0, p.1), img.sample(q.0, q.1)) {
                (Some(x), Some(y)) => d[i] = x - y,
                _ => return false,
            }
        }
    }
    // Quadrants 0 and 2 share a colour; which one is light.
    let sum: f64 = (0..4)
        .map(|k| if k % 2 == 0 { 1.0 } else { -1.0 } * diffs[k].iter().sum::<f64>())
        .sum();
    let light0 = if sum >= 0.0 { 1.0 } else { -1.0 };
    let passed = (0..4)
        .map(|k| {
            let sign = if k % 2 == 0 { light0 } else { -light0 };
            diffs[k]
                .iter()
                .filter(|d| sign * **d >= 0.25 * strength)
                .count()
        })
        .sum::<usize>();
    passed >= 28
}

/// Whether each checker quadrant is of one level over its whole square: on
/// a 5x5 grid over it (clear of the blurred boundaries and outer sides), at
/// most [`MAX_QUADRANT_OUTLIERS`] samples lie off the quadrant's median by
/// more than 0.3 of the quadrants' difference.
pub(super) fn quadrants_whole(
    img: &GreyView,
    c: Pt,
    dirs: &[Pt; 2],
    lengths: &[f64; 4],
    quadrants: &[f64; 4],
) -> bool {
    let tolerance = 0.3 * pair_levels(quadrants).2;
    (0..4).all(|k| {
        let (a, b) = (arm_dir(dirs, k), arm_dir(dirs, (k + 1) % 4));
        let (la, lb) = (lengths[k], lengths[(k + 1) % 4]);
        let (ma, mb) = ((0.15 * la).max(3.0), (0.15 * lb).max(3.0));
        let mut v = Vec::with_capacity(25);
        for fu in [0.1, 0.3, 0.5, 0.7, 0.9] {
            for fv in [0.1, 0.3, 0.5, 0.7, 0.9] {
                let (u, w) = (ma + (la - 2.0 * ma) * fu, mb + (lb - 2.0 * mb) * fv);
                let p = add(add(c, a, u), b, w);
                match img.sample(p.0, p.1) {
                    Some(x) => v.push(x),
                    None => return false,
                }
            }
        }
        let level = pr::quantile(&v, 0.5);
        v.iter().filter(|x| (*x - level).abs() > tolerance).count() <= MAX_QUADRANT_OUTLIERS
    })
}

/// Whether a shadow accounts for a cross's quadrants differing in level: a
/// shadow scales a quadrant and the bars beside it alike, so each
/// quadrant's level over its bars' (sampled as far out along them) holds.
/// Quadrants of different materials around a bright cross (a road marking
/// between asphalt and grass) keep their difference.
pub(super) fn shadow_explains_quadrants(
    img: &GreyView,
    c: Pt,
    dirs: &[Pt; 2],
    lengths: &[f64; 4],
    quadrants: &[f64; 4],
) -> bool {
    let mut bars = [0.0; 4];
    for (k, b) in bars.iter_mut().enumerate() {
        let a = arm_dir(dirs, k);
        let sum: Option<f64> = [0.45, 0.55, 0.65]
            .iter()
            .map(|f| {
                let p = add(c, a, f * lengths[k]);
                img.sample(p.0, p.1)
            })
            .sum();
        let Some(sum) = sum else { return false };
        *b = sum / 3.0;
    }
    let ratios: [f64; 4] =
        std::array::from_fn(|k| quadrants[k] / ((bars[k] + bars[(k + 1) % 4]) / 2.0).max(1.0));
    let (lo, hi) = ratios
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &r| (a.min(r), b.max(r)));
    hi < 1.0 && hi - lo <= 0.6 * (1.0 - hi)
}

/// Whether paving's tiles lie past a checker's outer sides, `[past a dark
/// quadrant, past a light one]`: a band one tile out that shows the other
/// colour's level for [`TILE_BAND_HITS`] of its 15 samples (three rows out,
/// five along the side), and a band one tile further out that does not go
/// on at that level (fewer than half its samples within the same
/// tolerance). Ground beside a target goes on; a tile ends. Tolerance: 0.3
/// of the quadrants' difference.
pub(super) fn tiles_past(
    img: &GreyView,
    c: Pt,
    dirs: &[Pt; 2],
    lengths: &[f64; 4],
    quadrants: &[f64; 4],
) -> [bool; 2] {
    let light0 = quadrants[0] + quadrants[2] > quadrants[1] + quadrants[3];
    let (even, odd, difference) = pair_levels(quadrants);
    let tolerance = 0.3 * difference;
    // Tiles found past [dark, light] quadrants.
    let mut past = [false; 2];
    // Half-side i lies past arm i / 2's end, beside quadrant i / 2 (the one
    // towards the next arm) or the one before it.
    for (i, (out, reach, along, span)) in half_sides(dirs, lengths).enumerate() {
        let q = if i % 2 == 0 { i / 2 } else { (i / 2 + 3) % 4 };
        let other = if q % 2 == 0 { odd } else { even };
        let light = (q % 2 == 0) == light0;
        let band = |from: f64| -> Option<Vec<f64>> {
            let mut v = Vec::with_capacity(15);
            for f in [0.0, 0.25, 0.5] {
                let d = from + (0.15 * reach).max(3.0) + f * reach;
                for g in [0.2, 0.35, 0.5, 0.65, 0.8] {
                    let p = add(add(c, out, d), along, g * span);
                    v.push(img.sample(p.0, p.1)?);
                }
            }
            Some(v)
        };
        let near =
            |v: &[f64], level: f64| v.iter().filter(|x| (*x - level).abs() < tolerance).count();
        let Some(first) = band(reach) else { continue };
        if near(&first, other) < TILE_BAND_HITS {
            continue;
        }
        let level = pr::quantile(&first, 0.5);
        let Some(second) = band(2.0 * reach) else {
            continue;
        };
        if near(&second, level) * 2 < second.len() {
            past[light as usize] = true;
        }
    }
    past
}

/// How many of a checker's eight side lines run on past the board's
/// corners as paving's tile boundaries. Past the corner of quadrant q, a
/// side line extended has, on the board's side of it, the other colour's
/// level (the tile beside q) and, outside, q's own level (the tile
/// diagonal to q): both one fifth and two fifths of the arm off the line
/// (3 px at least), on 3 of 5 points along it, within
/// [`TILE_LEVEL_TOLERANCE`] of the quadrants' difference. Ground beside a
/// printed board has no step of those levels along the board's side lines
/// but by chance, near the line only: objects of those greys past a
/// shadowed checker's corner (crosshair frame 2001) match a fifth of an
/// arm out, not two fifths.
pub(super) fn side_lines_run_on(
    img: &GreyView,
    c: Pt,
    dirs: &[Pt; 2],
    lengths: &[f64; 4],
    quadrants: &[f64; 4],
) -> usize {
    let (even, odd, difference) = pair_levels(quadrants);
    let tolerance = TILE_LEVEL_TOLERANCE * difference;
    let mut on = 0;
    for q in 0..4 {
        let (own, other) = if q % 2 == 0 { (even, odd) } else { (odd, even) };
        for (k, j) in [(q, (q + 1) % 4), ((q + 1) % 4, q)] {
            // The side out along arm k, extended along arm j past the corner.
            let (a, b) = (arm_dir(dirs, k), arm_dir(dirs, j));
            let (la, lb) = (lengths[k], lengths[j]);
            let off = (0.2 * la).max(3.0);
            let hits = [0.2, 0.35, 0.5, 0.65, 0.8]
                .iter()
                .filter(|&&f| {
                    let at = |u: f64, level: f64| {
                        let p = add(add(c, a, u), b, lb * (1.0 + f));
                        img.sample(p.0, p.1)
                            .is_some_and(|x| (x - level).abs() < tolerance)
                    };
                    [1.0, 2.0]
                        .iter()
                        .all(|m| at(la - m * off, other) && at(la + m * off, own))
                })
                .count();
            on += (hits >= 3) as usize;
        }
    }
    on
}

/// A checker's dark quadrants `(lower, higher)` when they differ as a
/// shadow would make them and its light quadrants do not: the light pair
/// within [`LIGHT_PAIR_AGREES`], the dark pair by more than the weakest
/// shadow searched for ([`shadow::MIN_STEP`] in ln grey) and by a tenth of
/// the quadrants' difference at least (dark print is noisy in ratio).
pub(super) fn dark_pair_apart(quadrants: &[f64; 4]) -> Option<(usize, usize)> {
    let (even, odd, difference) = pair_levels(quadrants);
    let (dark, light) = if even < odd { (0, 1) } else { (1, 0) };
    let (l, d) = ((light, light + 2), (dark, dark + 2));
    let ratio = |(a, b): (usize, usize)| {
        quadrants[a].min(quadrants[b]) / quadrants[a].max(quadrants[b]).max(1.0)
    };
    let (lower, higher) = if quadrants[d.0] < quadrants[d.1] {
        d
    } else {
        (d.1, d.0)
    };
    (ratio(l) >= LIGHT_PAIR_AGREES
        && -ratio(d).ln() > shadow::MIN_STEP
        && quadrants[higher] - quadrants[lower] >= 0.1 * difference)
        .then_some((lower, higher))
}

/// Where quadrant `k` (between arm k and arm k+1) is sampled for its level:
/// 0.55 of the arms out along its bisector, a little past halfway.
pub(super) fn quadrant_centre(c: Pt, dirs: &[Pt; 2], lengths: &[f64; 4], k: usize) -> Pt {
    let (a, b) = (arm_dir(dirs, k), arm_dir(dirs, (k + 1) % 4));
    add(add(c, a, 0.55 * lengths[k]), b, 0.55 * lengths[(k + 1) % 4])
}

/// A checker's quadrant levels paired: the mean of quadrants 0 and 2, of
/// 1 and 3, and their difference.
pub(super) fn pair_levels(quadrants: &[f64; 4]) -> (f64, f64, f64) {
    let even = (quadrants[0] + quadrants[2]) / 2.0;
    let odd = (quadrants[1] + quadrants[3]) / 2.0;
    (even, odd, (even - odd).abs())
}

/// Mean grey level of each quadrant, between arm k and arm k+1, sampled on
/// a small patch halfway along the bisector.
pub(super) fn quadrant_levels(
    img: &GreyView,
    c: Pt,
    dirs: &[Pt; 2],
    lengths: &[f64; 4],
) -> Option<[f64; 4]> {
    let mut out = [0.0; 4];
    for (k, q) in out.iter_mut().enumerate() {
        let centre = quadrant_centre(c, dirs, lengths, k);
        let r = 0.08 * (lengths[k] + lengths[(k + 1) % 4]);
        let mut sum = 0.0;
        for i in 0..9 {
            let ang = PI * 2.0 * i as f64 / 9.0;
            let s = if i == 0 { 0.0 } else { r };
            sum += img.sample(centre.0 + s * ang.cos(), centre.1 + s * ang.sin())?;
        }
        *q = sum / 9.0;
    }
    Some(out)
}
