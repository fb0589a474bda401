//! Following a target's structure outward from a candidate centre: along a
//! cross's bar (profiles across it find both edges; their midpoint lies on
//! the bar's centre line) or a checker's quadrant boundary (profiles across
//! it find the step). Each profile's edges are the crossings of the level
//! halfway between its own two sides, which no symmetric blur and no
//! brightness scale (shadow, exposure) moves.
//!
//! A free area (a marking in a quadrant) shows as a light side beside the
//! bar: that profile gives no point, and the walk goes on. The arm ends
//! where neither side is the board any more (ground past the board's side),
//! or where the bar itself fades into the board.

use super::super::geometry::Pt;
use super::super::harmonic::log_grey;
use super::super::profile::{self as pr, add, perp};
use super::super::refine::GreyView;
use super::Params;

/// What is followed along an arm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Feature {
    /// A bar lighter (+1) or darker (-1) than the board on both sides.
    Bar { sign: f64 },
    /// A step whose +normal side is lighter (+1) or darker (-1).
    Step { sign: f64 },
}

/// One arm followed from the centre.
#[derive(Debug, Clone, Default)]
pub struct Arm {
    /// Points on the feature's centre line (bar) or edge (step).
    pub points: Vec<Pt>,
    /// Bar widths measured at those points.
    pub widths: Vec<f64>,
    /// Log-grey contrast of the profiles that showed the board on both
    /// sides (bar over its darker side, or the step).
    pub contrasts: Vec<f64>,
    /// Profiles taken on the board (points or not).
    pub profiles: usize,
    /// Distance from the centre where the board ends along this arm.
    pub length: f64,
    /// The walk reached its limit with the board still there.
    pub unended: bool,
    /// The walk left the tile with the board still there.
    pub left_tile: bool,
}

/// Follows the feature from `centre` along unit `dir`, from `start` to at
/// most `limit` pixels, every `step` pixels. `width` is the bar's expected
/// width (or, for a step, the half-width of the band profiled across it);
/// `contrast` the difference in log grey between the design's light and
/// dark parts near the centre.
#[allow(clippy::too_many_arguments)]
pub fn follow(
    img: &GreyView,
    feature: Feature,
    centre: Pt,
    dir: Pt,
    width: f64,
    contrast: f64,
    (start, limit, step): (f64, f64, f64),
    params: &Params,
) -> Arm {
    let n = perp(dir);
    // A bar's profile reaches a bar width past each side band, so that a
    // bar bent off the fitted line (cloth, perspective) is still measured.
    let half = match feature {
        Feature::Bar { .. } => 2.5 * width + 4.0,
        Feature::Step { .. } => width,
    };
    let side_from = match feature {
        Feature::Bar { .. } => 0.5 * width + 1.5,
        Feature::Step { .. } => 1.5,
    };
    let mut arm = Arm::default();
    let mut profile = Vec::new();
    let mut off = 0usize;
    let mut first_off = 0.0;
    // Consecutive profiles off the board that end the arm: two pixels' worth.
    let end_after = (2.0 / step).ceil().max(2.0) as usize;
    let mut t = start;
    arm.length = start;
    while t <= limit {
        let base = add(centre, dir, t);
        if pr::line(img, base, n, half, &mut profile).is_none() {
            // The tile's edge: the arm cannot be followed to its end.
            arm.left_tile = true;
            return arm;
        }
        let on_board = match feature {
            Feature::Bar { sign } => bar_profile(
                &profile, half, side_from, sign, width, contrast, params, &mut arm, base, n,
            ),
            Feature::Step { sign } => step_profile(
                &profile, half, side_from, sign, contrast, params, &mut arm, base, n,
            ),
        };
        if on_board {
            arm.profiles += 1;
            off = 0;
            arm.length = t;
        } else {
            if off == 0 {
                first_off = t;
            }
            off += 1;
            if off >= end_after {
                arm.length = 0.5 * (arm.length + first_off);
                return arm;
            }
        }
        t += step;
    }
    arm.unended = true;
    arm.length = limit;
    arm
}

/// Mean of the profile's samples between `from` and `to` pixels from its
/// centre (signed).
fn band_mean(p: &[f64], half: f64, from: f64, to: f64) -> f64 {
    let idx = |x: f64| {
        ((x + half) / pr::STEP_PX)
            .round()
            .clamp(0.0, (p.len() - 1) as f64) as usize
    };
    let (a, b) = (idx(from.min(to)), idx(from.max(to)));
    pr::mean(p, a, b + 1)
}

#[allow(clippy::too_many_arguments)]
fn bar_profile(
    p: &[f64],
    half: f64,
    side_from: f64,
    sign: f64,
    width: f64,
    contrast: f64,
    params: &Params,
    arm: &mut Arm,
    base: Pt,
    n: Pt,
) -> bool {
    // The bar where the profile is lightest (darkest) near its middle, then
    // its sides a band's width out from there.
    let reach = 0.5 * width + 2.0;
    let step_px = pr::STEP_PX;
    let mut at = 0.0;
    let mut best = f64::MIN;
    let mut x = -reach;
    while x <= reach {
        let v = sign * band_mean(p, half, x - 0.25 * width, x + 0.25 * width);
        if v > best {
            best = v;
            at = x;
        }
        x += step_px;
    }
    let outer = 1.5 * width + 2.0;
    let left = band_mean(p, half, at - outer, at - side_from);
    let right = band_mean(p, half, at + side_from, at + outer);
    let core = best;
    let (l, r) = (sign * left, sign * right);
    // Sides and bar compared in log grey, where a shadow is an offset.
    let need = params.side_share * contrast;
    let core_log = log_grey(sign * core);
    let (l_board, r_board) = (
        sign * (core_log - log_grey(left)) >= need,
        sign * (core_log - log_grey(right)) >= need,
    );
    if !l_board && !r_board {
        return false;
    }
    if !(l_board && r_board) {
        // One side lighter than the board: a marking beside the bar, or a
        // corner of the board. On the board, but no point.
        return true;
    }
    arm.contrasts
        .push(sign * (core_log - log_grey(left)).min(sign * (core_log - log_grey(right))));
    // Edges: where the profile crosses halfway between the bar and each side,
    // nearest the expected edges.
    let centre_idx = (half + at) / pr::STEP_PX;
    let hw = 0.5 * width / pr::STEP_PX;
    let s: Vec<f64> = p.iter().map(|v| sign * v).collect();
    let lo = pr::crossing(&s, 0.5 * (core + l), true, centre_idx - hw);
    let hi = pr::crossing(&s, 0.5 * (core + r), false, centre_idx + hw);
    if let (Some(a), Some(b)) = (lo, hi) {
        let w = (b - a) * pr::STEP_PX;
        if w > 0.0 && w >= params.width_band.0 * width && w <= params.width_band.1 * width {
            let mid = pr::offset(0.5 * (a + b), half);
            arm.points.push(add(base, n, mid));
            arm.widths.push(w);
        }
    }
    true
}

#[allow(clippy::too_many_arguments)]
fn step_profile(
    p: &[f64],
    half: f64,
    side_from: f64,
    sign: f64,
    contrast: f64,
    params: &Params,
    arm: &mut Arm,
    base: Pt,
    n: Pt,
) -> bool {
    let minus = band_mean(p, half, -half, -side_from);
    let plus = band_mean(p, half, side_from, half);
    if sign * (log_grey(plus) - log_grey(minus)) < params.side_share * contrast {
        return false;
    }
    arm.contrasts
        .push(sign * (log_grey(plus) - log_grey(minus)));
    let centre_idx = half / pr::STEP_PX;
    let level = 0.5 * (plus + minus);
    if let Some(x) = pr::crossing(p, level, plus > minus, centre_idx) {
        let off = pr::offset(x, half);
        if off.abs() < half - side_from {
            arm.points.push(add(base, n, off));
        }
    }
    true
}
