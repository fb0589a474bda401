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
    /// Distance from the centre where the bar's centre line was last
    /// measured (a half step past it): where the bar itself ends, when a
    /// side of the profile stayed at board level past it. None for a
    /// checker's boundary.
    pub bar_end: Option<f64>,
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
    let (mut samples, mut prefix) = (Vec::new(), Vec::new());
    let mut off = 0usize;
    let mut first_off = 0.0;
    // Consecutive profiles off the board that end the arm: two pixels' worth.
    let end_after = (2.0 / step).ceil().max(2.0) as usize;
    let need = params.side_share * contrast;
    let mut t = start;
    arm.length = start;
    // Ground as dark as the board beside an arm's end keeps one side at
    // board level on and on, so a walk that never leaves the "board" (to
    // its limit or the tile's edge) ends at its bar's end (`arm.bar_end`).
    // A walk that did leave it keeps its own end: cutting those too (a
    // light stripe at the end) let paving in shadow through as a cross.
    let is_bar = matches!(feature, Feature::Bar { .. });
    let bar_end = |arm: &Arm, length: f64| arm.bar_end.map_or(length, |end| length.min(end));
    while t <= limit {
        let base = add(centre, dir, t);
        if pr::line(img, base, n, half, &mut samples).is_none() {
            // The tile's edge: the arm cannot be followed to its end.
            arm.left_tile = true;
            arm.length = bar_end(&arm, arm.length);
            return arm;
        }
        let across = Across {
            samples: &samples,
            prefix: running_sums(&samples, &mut prefix),
            half,
            side_from,
            base,
            n,
        };
        let points = arm.points.len();
        let on_board = match feature {
            Feature::Bar { sign } => across.bar(sign, width, need, params, &mut arm),
            Feature::Step { sign } => across.step(sign, need, &mut arm),
        };
        if is_bar && arm.points.len() > points {
            arm.bar_end = Some(t + 0.5 * step);
        }
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
    // On the board to the walk's limit; a bar seen last well before it
    // ended there (one side dark ground from then on).
    arm.length = bar_end(&arm, limit);
    arm.unended = arm.length > limit - 2.0 * step - width;
    arm
}

/// Share of the profiles past an arm's end, from `from` to `to` pixels
/// along unit `dir`, that show the feature again in either polarity: a bar
/// with the board on both sides at the bar's width, or a step. A target's
/// structure ends at its board's side; a lattice's bar runs on past the
/// next line, paving's boundary past the next square (with its sign
/// turned). None when the probe leaves the tile.
#[allow(clippy::too_many_arguments)]
pub fn continuation(
    img: &GreyView,
    feature: Feature,
    centre: Pt,
    dir: Pt,
    width: f64,
    contrast: f64,
    (from, to, step): (f64, f64, f64),
    params: &Params,
) -> Option<f64> {
    let n = perp(dir);
    let (half, side_from) = match feature {
        Feature::Bar { .. } => (2.5 * width + 4.0, 0.5 * width + 1.5),
        Feature::Step { .. } => (width, 1.5),
    };
    let need = params.side_share * contrast;
    let (mut samples, mut prefix) = (Vec::new(), Vec::new());
    let (mut seen, mut total) = (0usize, 0usize);
    let mut t = from;
    while t <= to {
        pr::line(img, add(centre, dir, t), n, half, &mut samples)?;
        let across = Across {
            samples: &samples,
            prefix: running_sums(&samples, &mut prefix),
            half,
            side_from,
            base: add(centre, dir, t),
            n,
        };
        let shows = [1.0, -1.0].iter().any(|&sign| {
            let mut scratch = Arm::default();
            match feature {
                Feature::Bar { .. } => {
                    across.bar(sign, width, need, params, &mut scratch);
                }
                Feature::Step { .. } => {
                    across.step(sign, need, &mut scratch);
                }
            }
            !scratch.points.is_empty()
        });
        seen += shows as usize;
        total += 1;
        t += step;
    }
    (total > 0).then(|| seen as f64 / total as f64)
}

/// `out[i]` = the sum of `samples[..i]` (one more entry than samples), so
/// that any band's mean costs two lookups.
fn running_sums<'a>(samples: &[f64], out: &'a mut Vec<f64>) -> &'a [f64] {
    out.clear();
    out.push(0.0);
    let mut sum = 0.0;
    for v in samples {
        sum += v;
        out.push(sum);
    }
    out
}

/// One profile across the feature: samples every [`pr::STEP_PX`] from
/// `-half` to `half` along `n`, centred on `base`; the sides are measured
/// from `side_from` outward.
struct Across<'a> {
    samples: &'a [f64],
    /// Running sums of `samples` (see [`running_sums`]).
    prefix: &'a [f64],
    half: f64,
    side_from: f64,
    base: Pt,
    n: Pt,
}

impl Across<'_> {
    /// Mean of the samples between `from` and `to` pixels from the
    /// profile's centre (signed).
    fn band_mean(&self, from: f64, to: f64) -> f64 {
        let last = (self.samples.len() - 1) as f64;
        let idx = |x: f64| ((x + self.half) / pr::STEP_PX).round().clamp(0.0, last) as usize;
        let (a, b) = (idx(from.min(to)), idx(from.max(to)) + 1);
        (self.prefix[b] - self.prefix[a]) / (b - a) as f64
    }

    /// The point at `offset` pixels along the profile.
    fn at(&self, offset: f64) -> Pt {
        add(self.base, self.n, offset)
    }

    /// A bar lighter (`sign` +1) or darker than the board on both sides by
    /// `need` in log grey: its centre-line point and width into `arm`.
    /// Whether the profile is on the board (a side may show a marking).
    fn bar(&self, sign: f64, width: f64, need: f64, params: &Params, arm: &mut Arm) -> bool {
        // The bar where the profile is lightest (darkest) near its middle,
        // then its sides a band's width out from there.
        let reach = 0.5 * width + 2.0;
        let (mut at, mut core) = (0.0, f64::MIN);
        let mut x = -reach;
        while x <= reach {
            let v = sign * self.band_mean(x - 0.25 * width, x + 0.25 * width);
            if v > core {
                (core, at) = (v, x);
            }
            x += pr::STEP_PX;
        }
        let outer = 1.5 * width + 2.0;
        let left = self.band_mean(at - outer, at - self.side_from);
        let right = self.band_mean(at + self.side_from, at + outer);
        // Sides and bar compared in log grey, where a shadow is an offset.
        let core_log = log_grey(sign * core);
        let (l_step, r_step) = (
            sign * (core_log - log_grey(left)),
            sign * (core_log - log_grey(right)),
        );
        let (l_board, r_board) = (l_step >= need, r_step >= need);
        if !l_board && !r_board {
            return false;
        }
        if !(l_board && r_board) {
            // One side lighter than the board: a marking beside the bar, or
            // a corner of the board. On the board, but no point.
            return true;
        }
        arm.contrasts.push(l_step.min(r_step));
        // Edges: where the profile crosses halfway between the bar and each
        // side, nearest the expected edges.
        let centre_idx = (self.half + at) / pr::STEP_PX;
        let hw = 0.5 * width / pr::STEP_PX;
        let s: Vec<f64> = self.samples.iter().map(|v| sign * v).collect();
        let lo = pr::crossing(&s, 0.5 * (core + sign * left), true, centre_idx - hw);
        let hi = pr::crossing(&s, 0.5 * (core + sign * right), false, centre_idx + hw);
        if let (Some(a), Some(b)) = (lo, hi) {
            let w = (b - a) * pr::STEP_PX;
            if w > 0.0 && w >= params.width_band.0 * width && w <= params.width_band.1 * width {
                arm.points
                    .push(self.at(pr::offset(0.5 * (a + b), self.half)));
                arm.widths.push(w);
            }
        }
        true
    }

    /// A step whose +normal side is lighter (`sign` +1) or darker by `need`
    /// in log grey: its edge point into `arm`. Whether the profile is on
    /// the board.
    fn step(&self, sign: f64, need: f64, arm: &mut Arm) -> bool {
        let minus = self.band_mean(-self.half, -self.side_from);
        let plus = self.band_mean(self.side_from, self.half);
        let step = sign * (log_grey(plus) - log_grey(minus));
        if step < need {
            return false;
        }
        arm.contrasts.push(step);
        let centre_idx = self.half / pr::STEP_PX;
        let level = 0.5 * (plus + minus);
        if let Some(x) = pr::crossing(self.samples, level, plus > minus, centre_idx) {
            let off = pr::offset(x, self.half);
            if off.abs() < self.half - self.side_from {
                arm.points.push(self.at(off));
            }
        }
        true
    }
}
