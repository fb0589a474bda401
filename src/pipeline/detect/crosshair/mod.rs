//! Printed crosshair targets: a white cross on a black square, and the 2x2
//! checker ("X" / diagonal target).
//!
//! 1. Candidates: local maxima of the ring-harmonic response of
//!    [`harmonic`] (2-fold for checkers, 4-fold for crosses), each refined on
//!    the full-resolution tile to the centre where that response peaks and
//!    the size where it fades.
//! 2. A ring of samples at two radii classifies the candidate: four narrow
//!    bright arcs (cross bars) or four alternating quadrants (checker), and
//!    gives the four arm directions ([`ring`]).
//! 3. Each arm is measured outward until its structure ends (a cross's bar
//!    where it stops keeping its width); a structure that runs on (panel
//!    grids, paving, road markings) is rejected, except one arm meeting an
//!    object, or a cross lying on a stripe ([`arms`]).
//! 4. Subpixel centre: the two cross bars' centre lines (midpoints of both
//!    bar edges on profiles across the bar, every half pixel along both arms
//!    of each bar) or the checker's two quadrant boundaries (edge crossings
//!    along their whole length) are fitted as straight lines, outliers left
//!    out; the centre is their intersection: the saddle point of a checker,
//!    the bars' crossing for a cross, exact under perspective since lines
//!    stay lines ([`fit`]).
//! 5. Structure checks tell targets from look-alikes ([`structure`]; the
//!    order they run in and the thresholds are in `analyse` and the
//!    constants here).

use std::f64::consts::{PI, TAU};

use opencv::core::Mat;
use opencv::prelude::*;

use super::fiducial::grey_view;
use super::found::{best_per_target, to_detection, Found};
use super::geometry::{self, Pt};
use super::harmonic::{self, Candidate, RingBasis, Symmetry};
use super::profile::{self as pr, add, perp, unit};
use super::refine::{fit_line, intersect, GreyView};
use super::shadow;
use super::{DetectError, Detection, Detector, MarkerType, SizeRange, SizeSlack};

mod arms;
mod fit;
mod ring;
mod structure;
#[cfg(test)]
mod tests;

use arms::{
    across_if_longer, arm_dir, checker_polarity, extent, measure_arm, object_against_board, ArmEnd,
};
use fit::fit_lines;
use ring::{classify_ring, match_arms, orient};
use structure::{
    board_sides_seen, checker_quadrants_uniform, dark_pair_apart, grid_lines_around,
    quadrant_centre, quadrant_levels, quadrants_are_dark, quadrants_whole,
    shadow_explains_quadrants, side_lines_run_on, tiles_past,
};

/// Ring samples: 2.8 degrees apart.
const RING_SAMPLES: usize = 128;
/// Radii of the ring that confirms a candidate's arms, as fractions of its
/// size guess, tried in turn (the inner ring is at 0.28).
const OUTER_RINGS: [f64; 2] = [0.4, 0.34];
/// Ring samples when refining a candidate's centre and size.
const RESPONSE_SAMPLES: usize = 32;
/// Fewest grey levels between a target's dark and light parts.
const MIN_CONTRAST: f64 = 15.0;
/// Candidates closer than this fraction of their size are one candidate.
const SAME_CANDIDATE: f64 = 0.05;
/// Fraction of an arm's profiles that must give an edge or bar centre.
const MIN_COVERAGE: f64 = 0.6;
/// Fraction of a line's edge points that must lie on the fitted line.
const MIN_INLIER_SHARE: f64 = 0.45;
/// Arms of one target may differ this much in length: mild perspective (5%
/// corner shifts) moves them by ~10%; clutter junctions that pass the other
/// checks typically differ by 1.4-1.6 (1.6 let 5 through on 4 frames).
const MAX_ARM_RATIO: f64 = 1.3;
/// Bar length over width (each arm is half the square minus nothing): the
/// designs in use have bars of 1/12 to 1/3 of the side, so 1.5..6. Arms are
/// measured a little longer (they run past the board's blurred edge): at
/// most 4.39 on the nine crosshair sets, whose narrowest design is 4.17,
/// and 6.33 on the same frames drawn with bars of 1/12 to 0.12 of the side
/// (99th percentile 6.16). Road-marking crosses (7x longer than wide and
/// more) measured 6.94 (held-out clutter scene 1705) under the 7.0 of
/// before.
const ARM_TO_BAR: (f64, f64) = (1.2, 6.6);
/// The two bars' median widths may differ this much: 1.19 at most on the
/// targets of 8 frames (seeds 500-503, 800-803: perspective, blur); 1.4 for
/// road markings of two widths crossing (clutter seed 754).
const MAX_BAR_WIDTH_RATIO: f64 = 1.3;
/// Past a checker arm's end, a flipped boundary is paving when its log
/// contrast ratio is the quadrants' within this fraction.
const FLIP_RATIO: f64 = 0.5;
/// Paving flips in a row (1 px apart) right past a checker arm's gap that
/// make it paving even where the paving is a single tile wide (a strip's
/// end, paving under other clutter).
const MIN_LEAD_FLIPS: usize = 4;
/// Paving's tiles right past a checker arm's end repeat the quadrants'
/// levels swapped, to this fraction of the quadrants' difference.
const TILE_LEVEL_TOLERANCE: f64 = 0.3;
/// Samples of 15, one tile past a checker's outer side, that must show the
/// other colour's level for that band to be a paving tile. On the nine
/// crosshair sets and four fresh ones (2200-2500), no target had tiles
/// past both colours on all its accepted looks at 8 to 12 (the band
/// beyond ending under half); at 6, two had. On the clutter scenes with
/// detections, 10 removes 3 of 39 and 8 would remove 5.
const TILE_BAND_HITS: usize = 10;
/// Largest RMS distance of edge points from their fitted line: above it the
/// "lines" are not straight (a fold, an object on the target, clutter).
/// Measured on 1060 true detections (40-200 px, blur up to 1.4 px, motion
/// blur, shadow): at most 0.41 px but for two checkers whose centres are
/// 0.74 and 0.96 px off (0.50 and 0.84 px); paving corners and stripe ends
/// passing every other check fitted at 0.60-0.63 px.
const MAX_FIT_RMS_PX: f64 = 0.55;
/// Largest angle between the two halves of a cross's bar or a checker's
/// boundary, each fitted on its own arm (a checker's only where its
/// quadrant pairs are even, within 0.5 of the strength). Measured on the
/// nine crosshair sets (`printed_misses crosshair SEED 4` with
/// `ACCEPTED=1`): 1225 cross candidates accepted there (every tile and
/// look) bent 3.17 degrees at most, shadow or not; 1946 checker candidates
/// with even pairs, 4.43 (those in shadow, up to 11.8). Clutter: two
/// stripes' corners touching (held-out scene 2804) 15.0, the saddle between
/// two touching manholes (scene 1610) 9.8, a junction of several objects
/// (scene 1812) 11.2 (uneven 0.32), a cross where paving meets a panel grid
/// (scene 2313) 37.6.
const MAX_BEND_DEG: f64 = 8.0;
/// Samples of a quadrant's 25 that may lie off its level when a checker arm
/// ends beside something. On the fifteen crosshair sets, of the 11 checkers
/// found only with such an arm before this check, 6 had at most 1 in every
/// quadrant and 5 had 6-14 (a shadow or an object across a quadrant; the
/// second look finds some of them with the shadow lifted, as frame 2300's).
/// The paving junctions taken so on the clutter sets with no tile past
/// their sides had 4-10 (clutter scenes 735, 1111, 3310).
const MAX_QUADRANT_OUTLIERS: usize = 3;
/// Radius, in size guesses, searched for a shadow edge across a failed
/// candidate: the target's square (corners at 0.71) and ground around it.
const SHADOW_SEARCH: f64 = 1.1;
/// Rejections that a shadow does not cause and that a second look with a
/// shadow lifted is not tried for: the rings around the candidate are read
/// in log intensity, where a shadow is an offset, and each arm found is
/// checked on its own local contrast, so a shadow leaves their verdict
/// alone. Most candidates on a cluttered frame end here (about 70%), and a
/// second look at each cost 3.5x the crosshair mode's time. Paving is left
/// too: with a shadow lifted, two paving junctions on 28 clutter frames
/// passed as checkers, and no target was lost without it on 28 frames.
/// So are the tiles around a checker: with a shadow lifted, a paving
/// block in shadow (clutter scene 2615) passed on the second look. So is
/// the bar ratio, a median over profiles along both whole bars: on
/// the nine crosshair sets no target failed it on the first look and passed
/// on the second, while a road-marking cross (bars over 7x longer than
/// wide, held-out clutter scene 2503) measured 6.0 on a copy with an edge lifted.
/// So is structure running on past two arms: on the thirteen crosshair sets
/// (1560 targets) no target failed it on the first look and passed on the
/// second, while two panel-grid crossings did (held-out clutter scenes 3108
/// and 3202), the copy's lifted edge cutting the bars' continuation off.
const NOT_SHADOW: [&str; 13] = [
    "too small",
    "inner ring",
    "outer ring",
    "rings disagree",
    "arms do not match",
    "line fit",
    "parallel lines",
    "checker polarity",
    "paving",
    "tiles around",
    "tiles past a corner",
    "bar ratio",
    "structure runs on",
];
/// Half side, in sizes (the guessed, then the found if larger), of the copy
/// with the shadow lifted: the arms' walk and the ground checked past their
/// ends (about 1.9 arm lengths).
const SHADOW_COPY: f64 = 1.3;
/// How far inside a target's sides (half the found size from its centre) a
/// shadow edge must pass for the second look to stand. An edge closer in
/// runs along a side, in its blur, or cuts off the square's corners only:
/// lifting it changes the ground past the side, not the target. Four
/// look-alikes on the clutter sets passed so, their edge 0.3-1.2 px inside
/// the side (a panel's border a cell past a grid crossing, scene 3604);
/// the closest a true target's came on thirteen crosshair sets was 4 px
/// inside (a 79 px checker, frame 2403).
const SHADOW_INSIDE_PX: f64 = 2.0;
/// Light quadrants of a checker agree when the lower is this fraction of
/// the higher at least.
const LIGHT_PAIR_AGREES: f64 = 0.9;
/// Half-sides of a cross's board that must show against the ground when a
/// bar runs on along a stripe (one way or both) or ends far out.
const BOARD_SIDES_SEEN: usize = 4;
/// Which look at a candidate: the first, on the tile, or the second, on a
/// copy with a shadow edge lifted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Look {
    First,
    Lifted,
}
/// The slack on a measured size (the arms' lengths): measured over true
/// size on the 1059 hits of the nine crosshair sets (`printed_misses
/// crosshair SEED 4` with `RMS=1`, 2026-12-04) ran 0.964-1.116 (median
/// 1.03: the arms run a little past the board's blurred edge), and 0.986
/// at least on the 118 targets under 50 px. Below, 1.05 (a 40 px target
/// measured down to 38.1 px); the circles' 1.10 let three clutter
/// junctions of 36.9-37.7 px through as 40 px targets. Above, 1.15.
const SIZE_SLACK: SizeSlack = SizeSlack {
    below: 1.05,
    above: 1.15,
};

#[derive(Debug, Clone, Copy, PartialEq)]
enum Kind {
    Cross,
    Checker,
}

/// What a ring around a candidate shows.
#[derive(Debug, Clone, Copy)]
struct RingPattern {
    kind: Kind,
    /// Arm angles, ascending in [0, 2pi).
    arms: [f64; 4],
    /// Mean angular width of the bright arcs (cross bars), radians.
    bar_rad: f64,
}

/// An arm after measuring it.
#[derive(Debug, Clone, Copy)]
struct Arm {
    /// Where the structure ends, in pixels from the centre.
    length: f64,
    /// Typical feature strength (grey levels) near the centre.
    strength: f64,
    /// Checker: +1 when the arm's left side (its +normal) is the light one.
    polarity: f64,
}

/// Detector of crosses and checkers within a size range.
pub struct CrosshairDetector {
    sizes: SizeRange,
    /// Sample directions of the rings that classify a candidate.
    ring_basis: RingBasis,
    /// ... and of those that refine its centre and size.
    response_basis: RingBasis,
}

impl CrosshairDetector {
    pub fn new(sizes: SizeRange) -> Self {
        CrosshairDetector {
            sizes,
            ring_basis: RingBasis::new(RING_SAMPLES),
            response_basis: RingBasis::new(RESPONSE_SAMPLES),
        }
    }

    /// A candidate's centre and size at full resolution: the position
    /// within its pyramid pixel where the ring response peaks, then the
    /// radius beyond which it fades (the target's edge).
    fn refine_start(&self, img: &GreyView, c: &Candidate) -> Option<(Pt, f64)> {
        let eval = |p: Pt, r: f64| -> Option<f64> {
            let ring = pr::ring(img, p, r, &self.response_basis)?;
            let logs: Vec<f64> = ring.iter().map(|v| harmonic::log_grey(*v)).collect();
            Some(harmonic::score(
                c.symmetry,
                self.response_basis.response(&logs),
            ))
        };
        let search = |centre: Pt, r: f64, reach: f64, step: f64| -> Option<(Pt, f64)> {
            let n = (reach / step).round() as i32;
            let mut best: Option<(Pt, f64)> = None;
            for j in -n..=n {
                for i in -n..=n {
                    let p = (centre.0 + i as f64 * step, centre.1 + j as f64 * step);
                    if let Some(v) = eval(p, r) {
                        if best.is_none_or(|(_, b)| v > b) {
                            best = Some((p, v));
                        }
                    }
                }
            }
            best
        };
        // Coarse to fine, 3x3 positions a step apart, halving the step.
        let descend = |mut centre: Pt, r: f64, mut step: f64| -> Option<Pt> {
            loop {
                centre = search(centre, r, step, step)?.0;
                if step <= 0.5 {
                    return Some(centre);
                }
                step /= 2.0;
            }
        };
        let r0 = (harmonic::RING_TO_SIZE * c.size).max(3.0);
        let centre = descend(c.centre, r0, (c.scale / 2.0).max(1.0))?;
        // Radius scan: the response holds while the ring is on the target.
        let mut scores = Vec::new();
        let mut r = (0.12 * c.size).max(3.0);
        while r <= 0.9 * c.size {
            scores.push((r, eval(centre, r).unwrap_or(f64::MIN)));
            r += (0.04 * c.size).max(1.0);
        }
        let (k_peak, &(_, peak)) = scores
            .iter()
            .enumerate()
            .max_by(|a, b| a.1 .1.total_cmp(&b.1 .1))?;
        if peak < harmonic::MIN_SCORE {
            return None;
        }
        let r_end = scores[k_peak..]
            .iter()
            .find(|(_, v)| *v < 0.5 * peak)
            .map_or(0.9 * c.size, |(r, _)| *r);
        // A checker's quadrants reach past the edge's middle at the
        // diagonals; a cross's bars end at it.
        let size = match c.symmetry {
            Symmetry::Checker => 2.0 * r_end / 1.25,
            Symmetry::Cross => 2.0 * r_end,
        };
        let r1 = (harmonic::RING_TO_SIZE * size).max(3.0);
        let centre = descend(centre, r1, 1.0)?;
        Some((centre, size))
    }

    fn analyse(
        &self,
        img: &GreyView,
        start: Pt,
        size_guess: f64,
        look: Look,
    ) -> Result<Found, &'static str> {
        let r1 = 0.28 * size_guess;
        if r1 < 3.0 {
            return Err("too small");
        }
        let ring1 = pr::ring(img, start, r1, &self.ring_basis).ok_or("inner ring")?;
        let p1 = classify_ring(&self.ring_basis, &ring1).ok_or("inner ring")?;
        // The outer ring confirms the inner one's arms farther out. The size
        // guess runs large on a faint target; a ring beyond its square sees
        // the dark corners as a pattern turned by 45 degrees: nearer then.
        let mut outer = Err("outer ring");
        for r2 in OUTER_RINGS.map(|f| f * size_guess) {
            let ring2 = pr::ring(img, start, r2, &self.ring_basis).ok_or("outer ring")?;
            outer = classify_ring(&self.ring_basis, &ring2)
                .ok_or("outer ring")
                .and_then(|p2| {
                    if p2.kind != p1.kind {
                        return Err("rings disagree");
                    }
                    let arms2 = match_arms(&p1.arms, &p2.arms).ok_or("arms do not match")?;
                    Ok((r2, p2, arms2))
                });
            if outer.is_ok() {
                break;
            }
        }
        let (r2, p2, arms2) = outer?;
        let kind = p1.kind;
        // Arm k passes through its crossings of both rings.
        let on = |k: usize| {
            [
                add(start, unit(p1.arms[k]), r1),
                add(start, unit(arms2[k]), r2),
            ]
        };
        let [a0, a1] = on(0);
        let [c0, c1] = on(2);
        let line_a = fit_line(&[a0, a1, c0, c1]).ok_or("line fit")?;
        let [b0, b1] = on(1);
        let [d0, d1] = on(3);
        let line_b = fit_line(&[b0, b1, d0, d1]).ok_or("line fit")?;
        let mut centre = intersect(line_a, line_b).ok_or("parallel lines")?;
        let mut dirs = [
            orient(line_a.1, unit(arms2[0])),
            orient(line_b.1, unit(arms2[1])),
        ];
        let mut bar = (r2 * p2.bar_rad).max(2.0);

        // First fit inside a conservative radius, then measure the arms and
        // fit again along their whole length.
        let guess = Arm {
            length: 0.38 * size_guess,
            strength: MIN_CONTRAST,
            polarity: 0.0,
        };
        let mut arms = [guess; 4];
        if kind == Kind::Checker {
            for (k, arm) in arms.iter_mut().enumerate() {
                arm.polarity = checker_polarity(img, centre, arm_dir(&dirs, k), 0.25 * size_guess)
                    .ok_or("checker polarity")?;
            }
        }
        let mut fit = fit_lines(img, kind, centre, dirs, &arms, bar).ok_or("first fit")?;
        centre = fit.centre;
        dirs = fit.dirs;
        bar = fit.bar.unwrap_or(bar);
        let max_reach = 0.75 * self.sizes.reach_px;
        // The arms end: a grid or paving runs on. One arm may meet something
        // lying against the target (a path, an object), and a cross may lie
        // on a stripe (two opposite arms run on); the checks below (grid
        // lines around a cross, uniform checker quadrants) tell those from a
        // grid's or paving's junction.
        let mut runs_on: Vec<(usize, Option<Arm>)> = Vec::new();
        let mut beside = None;
        for (k, arm) in arms.iter_mut().enumerate() {
            let dir = arm_dir(&dirs, k);
            match measure_arm(
                img,
                kind,
                centre,
                dir,
                bar,
                arm.polarity,
                size_guess,
                max_reach,
            ) {
                ArmEnd::Ends(a) => *arm = a,
                ArmEnd::RunsOn(a) => runs_on.push((k, a)),
                // Paving strips and clutter junctions look like this, and so
                // does a checker with something lying against one arm's end
                // (a disc, a stripe): one such arm is kept, and the board
                // must then show itself whole (below).
                ArmEnd::Beside(a) if kind == Kind::Checker && beside.is_none() => {
                    *arm = a;
                    beside = Some(k);
                }
                ArmEnd::Beside(_) => return Err("edge beside"),
                ArmEnd::Flips => return Err("paving"),
                ArmEnd::Unknown => return Err("arm leaves the tile"),
            }
        }
        if beside.is_some() && !runs_on.is_empty() {
            return Err("edge beside");
        }
        let stripe = kind == Kind::Cross && runs_on.len() == 2 && runs_on[1].0 == runs_on[0].0 + 2;
        if runs_on.len() > 1 && !stripe {
            return Err("structure runs on");
        }
        for &(k, a) in &runs_on {
            // As far as its own structure went, or else as the opposite arm
            // (a stripe: as the arms across it).
            let like = if stripe {
                let (p, q) = (arms[(k + 1) % 4], arms[(k + 3) % 4]);
                Arm {
                    length: (p.length + q.length) / 2.0,
                    ..p
                }
            } else {
                arms[(k + 2) % 4]
            };
            arms[k] = a.unwrap_or(Arm {
                polarity: arms[k].polarity,
                ..like
            });
        }
        // A checker with something lying against one arm's end (a dark
        // object beside a dark quadrant) lets the boundary run on past the
        // board: that arm as long as its opposite, as one running on is.
        let mut long_arm = 0;
        if kind == Kind::Checker && runs_on.is_empty() {
            let l = arms.map(|a| a.length);
            for k in 0..4 {
                let (lo, hi) = extent(&[l[(k + 1) % 4], l[(k + 2) % 4], l[(k + 3) % 4]]);
                if hi / lo <= MAX_ARM_RATIO && l[k] > MAX_ARM_RATIO * hi {
                    if !object_against_board(img, centre, arm_dir(&dirs, k), l[(k + 2) % 4], l[k]) {
                        return Err("arm lengths differ");
                    }
                    arms[k].length = l[(k + 2) % 4];
                    long_arm = 1;
                    break;
                }
            }
        }
        // A stripe under a cross that ends not far past the board: two
        // opposite bars go on to the stripe's ends, the two across it stop
        // at the board's edge. Those bars as long as the arms across. A
        // short road marking crossing a longer one looks the same, so the
        // board must show against the ground (below).
        let mut under_stripe = 0;
        // One bar runs on along a stripe and the opposite one went on along
        // it too, ending where the stripe leaves the bar's line or fades:
        // both as long as the arms across. Two road markings crossing look
        // the same, so the board must show against the ground (below).
        let mut one_sided_stripe = false;
        if kind == Kind::Cross && runs_on.len() == 1 {
            let k = runs_on[0].0;
            if let Some(l) = across_if_longer(&arms, k, arms[(k + 2) % 4].length) {
                for j in [k, (k + 2) % 4] {
                    arms[j].length = l;
                }
                under_stripe = 1;
                one_sided_stripe = true;
            }
        }
        if kind == Kind::Cross && runs_on.is_empty() {
            for k in 0..2 {
                let long_lo = arms[k].length.min(arms[k + 2].length);
                if let Some(l) = across_if_longer(&arms, k, long_lo) {
                    for j in [k, k + 2] {
                        arms[j].length = l;
                    }
                    under_stripe = 2;
                    break;
                }
            }
        }
        for _ in 0..2 {
            fit = fit_lines(img, kind, centre, dirs, &arms, bar).ok_or("fit")?;
            centre = fit.centre;
            dirs = fit.dirs;
            bar = fit.bar.unwrap_or(bar);
        }

        // Structure checks.
        let lengths = arms.map(|a| a.length);
        let (lmin, lmax) = extent(&lengths);
        let size = lengths.iter().sum::<f64>() / 2.0;
        let strength = arms.iter().map(|a| a.strength).fold(f64::MAX, f64::min);
        let cos = (dirs[0].0 * dirs[1].0 + dirs[0].1 * dirs[1].1).abs();
        if lmax / lmin > MAX_ARM_RATIO {
            return Err("arm lengths differ");
        }
        if !self.sizes.accepts(size, SIZE_SLACK) {
            return Err("size");
        }
        if cos > (35f64).to_radians().sin() {
            return Err("arms not square");
        }
        if geometry::dist(centre, start) > 0.3 * size {
            return Err("centre moved");
        }
        if fit.coverage < MIN_COVERAGE {
            return Err("edge coverage");
        }
        if fit.rms > MAX_FIT_RMS_PX {
            return Err("fit rms");
        }
        let quadrants = quadrant_levels(img, centre, &dirs, &lengths).ok_or("quadrants")?;
        match kind {
            Kind::Cross => {
                // A printed bar keeps its width; the zig-zag "bars" along a
                // checker paving's diagonals do not.
                let (w10, w90) = (
                    pr::quantile(&fit.widths, 0.1),
                    pr::quantile(&fit.widths, 0.9),
                );
                if w90 - w10 > 0.5 * bar {
                    return Err("bar width varies");
                }
                // A printed cross's bars are equally wide; road markings
                // crossing each other seldom are.
                let [wa, wb] = fit.bar_widths;
                if wa.min(wb) > 0.0 && wa.max(wb) / wa.min(wb) > MAX_BAR_WIDTH_RATIO {
                    return Err("bar widths differ");
                }
                // A printed bar runs straight through the centre, in shadow
                // too.
                if fit.bend > MAX_BEND_DEG.to_radians() {
                    return Err("bars bent");
                }
                // The bars' crossing is bright (a dark tile amid paving is not).
                let middle = img.sample(centre.0, centre.1).ok_or("centre")?;
                let dark = quadrants.iter().sum::<f64>() / 4.0;
                if middle < dark + 0.6 * strength {
                    return Err("centre not bright");
                }
                if !quadrants_are_dark(img, centre, &dirs, &lengths, bar, strength) {
                    return Err("quadrants");
                }
                let (at_end, near_end) =
                    grid_lines_around(img, centre, &dirs, &lengths, bar, strength);
                if at_end >= 3 || at_end + near_end >= 4 {
                    return Err("grid lines around");
                }
                // A short road marking crossing a longer one is a cross on
                // a stripe whose board matches the ground, whether its two
                // ends are equal or not (the held-out clutter set 1500-1515:
                // 86 and 92 px across a marking cut by another and by a
                // shadow), and whether the marking's other side runs on too
                // or stops at something lying over it: one bar that never
                // ends within the reach is a stripe (a printed bar ends at
                // its board's edge, even where something bright lies past
                // it). A printed bar seldom lies along a stripe of its own
                // width; when it does, its board must show.
                let endless = runs_on.iter().any(|(_, a)| a.is_none());
                if (one_sided_stripe || stripe || endless || under_stripe == 2)
                    && board_sides_seen(img, centre, &dirs, &lengths, strength) < BOARD_SIDES_SEEN
                {
                    return Err("no board");
                }
                let ratio = size / 2.0 / bar;
                let (lo, hi) = quadrants
                    .iter()
                    .fold((f64::MAX, f64::MIN), |(a, b), &q| (a.min(q), b.max(q)));
                if !(ARM_TO_BAR.0..=ARM_TO_BAR.1).contains(&ratio) {
                    return Err("bar ratio");
                }
                // A cross taken with an arm running on (something lying
                // against it, a stripe under it) must show its board whole:
                // its quadrants as even as a shadow leaves one material. True
                // ones on the nine crosshair sets differ by 0.15 of the
                // strength at most; a panel-grid
                // crossing with a stripe over one cell, 0.41 (scene 2601).
                let even = if runs_on.is_empty() { 0.6 } else { 0.3 };
                if hi - lo > even * strength
                    && !shadow_explains_quadrants(img, centre, &dirs, &lengths, &quadrants)
                {
                    return Err("quadrant levels differ");
                }
            }
            Kind::Checker => {
                // Alternating: both light quadrants lighter than both dark
                // ones (a shadow may dim one light quadrant, not swap them).
                let [q0, q1, q2, q3] = quadrants;
                let (a_lo, a_hi) = (q0.min(q2), q0.max(q2));
                let (b_lo, b_hi) = (q1.min(q3), q1.max(q3));
                if !(a_lo - b_hi >= 0.4 * MIN_CONTRAST || b_lo - a_hi >= 0.4 * MIN_CONTRAST) {
                    return Err("quadrants do not alternate");
                }
                if !checker_quadrants_uniform(img, centre, &dirs, &lengths, strength) {
                    return Err("quadrants not uniform");
                }
                // Paving whose boundaries' continuations past the arms are
                // hidden (under other objects, in shadow) may still show a
                // tile past a light quadrant's side and one past a dark
                // one's.
                let tiles = tiles_past(img, centre, &dirs, &lengths, &quadrants);
                if tiles == [true; 2] {
                    return Err("tiles around");
                }
                // With a tile past one side only, a side line of the board
                // running on past a corner as a tile boundary: the two
                // together are paving's grid. Each alone lies beside printed
                // checkers (on seventeen crosshair sets, a tile past a side
                // beside 54 of 987, a side line running on beside 5), the
                // two together beside none; 12 of 46 paving blocks taken
                // on the clutter sets had both.
                if tiles != [false; 2]
                    && side_lines_run_on(img, centre, &dirs, &lengths, &quadrants) > 0
                {
                    return Err("tiles past a corner");
                }
                // Light quadrants that agree beside dark ones that do not:
                // a shadow over one dark quadrant, or paving's dark tile
                // beside an object of another grey (a roof face, a car) in
                // its place. The shadow's edge must show, the darker one's
                // middle on its shaded side and further in. With a shadow
                // lifted, none is looked for: lifting the edge of an object
                // leaves a step the other way that could pass for one.
                if let Some((lower, higher)) = dark_pair_apart(&quadrants) {
                    let patch = |k| quadrant_centre(centre, &dirs, &lengths, k);
                    let shaded = look == Look::First
                        && shadow::find(img, centre, SHADOW_SEARCH * size).is_some_and(|e| {
                            let (lo, hi) = (e.distance(patch(lower)), e.distance(patch(higher)));
                            lo < 0.0 && lo < hi
                        });
                    if !shaded {
                        return Err("dark quadrants differ");
                    }
                }
                // A printed boundary runs straight through the centre: each
                // line's two halves, fitted apart, agree. Two objects'
                // corners meeting (a stripe's end touching another's side,
                // two manholes touching) bend it. A shadow across a
                // checker bends the fitted halves too, and leaves its pairs
                // uneven.
                let uneven = (q0 - q2).abs().max((q1 - q3).abs());
                if uneven <= 0.5 * strength && fit.bend > MAX_BEND_DEG.to_radians() {
                    return Err("boundary bent");
                }
                // An arm ending beside something may hide paving's
                // continuation there; a junction of paving partly hidden
                // passes every check above. Such a checker must show every
                // quadrant of one level out to its sides and no tile past
                // any side. A shadow across a quadrant fails this; the
                // second look, with the shadow lifted, sees the board whole.
                if beside.is_some()
                    && (tiles != [false; 2]
                        || !quadrants_whole(img, centre, &dirs, &lengths, &quadrants))
                {
                    return Err("edge beside");
                }
            }
        }
        let confidence = (fit.coverage
            * (1.0 / (1.0 + (fit.rms / 0.25).powi(2)))
            * (strength / 40.0).clamp(0.0, 1.0)
            * (1.0 - (lmax / lmin - 1.0) / (MAX_ARM_RATIO - 1.0) * 0.5)
            * 0.7f64.powi(
                (runs_on.len() + under_stripe + long_arm + beside.is_some() as usize) as i32,
            ))
        .powf(0.25);
        let corners: [Pt; 4] = std::array::from_fn(|k| {
            let (a, b) = (arm_dir(&dirs, k), arm_dir(&dirs, (k + 1) % 4));
            add(add(centre, a, lengths[k]), b, lengths[(k + 1) % 4])
        });
        tracing::trace!(
            x = centre.0,
            y = centre.1,
            kind = ?kind,
            lengths = ?lengths,
            dirs = ?dirs,
            rms = fit.rms,
            bend = fit.bend.to_degrees(),
            bar,
            strength,
            runs_on = ?runs_on.iter().map(|r| r.0).collect::<Vec<_>>(),
            endless = ?runs_on.iter().filter(|r| r.1.is_none()).map(|r| r.0).collect::<Vec<_>>(),
            quadrants = ?quadrants.map(|q| q.round()),
            under_stripe,
            beside = ?beside,
            confidence,
            "crosshair candidate accepted"
        );
        Ok(Found {
            centre,
            corners,
            size,
            shift: geometry::dist(centre, start),
            rms: fit.rms,
            confidence,
        })
    }

    /// The candidate analysed again with the shadow edge across it (if one
    /// is found) lifted: a shadow's edge ends arms early and splits
    /// quadrants and bars into two levels.
    fn analyse_lifted(
        &self,
        img: &GreyView,
        start: Pt,
        size_guess: f64,
    ) -> Result<Found, &'static str> {
        let cap = 0.75 * self.sizes.reach_px + size_guess;
        let half_for = |size: f64| (SHADOW_COPY * size).min(cap);
        // Reach: half a side, through the target's square, clear of its
        // sides' blur.
        shadow::second_look(
            img,
            start,
            SHADOW_SEARCH * size_guess,
            (half_for(size_guess), half_for),
            |size| 0.5 * size - SHADOW_INSIDE_PX,
            |view, at| self.analyse(view, at, size_guess, Look::Lifted),
        )
    }
}

impl Detector for CrosshairDetector {
    fn marker_type(&self) -> MarkerType {
        MarkerType::Crosshair
    }

    fn detect(
        &mut self,
        tile: &Mat,
        origin: (usize, usize),
        seams: [bool; 4],
    ) -> Result<Vec<Detection>, DetectError> {
        let err = DetectError::at(origin);
        let candidates =
            harmonic::candidates(tile, self.sizes, harmonic::Quadrants::Plain).map_err(err)?;
        let img = grey_view(tile).map_err(err)?;
        // Strongest first, so a target's best start survives the merging.
        let mut ranked: Vec<(f64, Pt, f64)> = candidates
            .iter()
            .filter_map(|c| self.refine_start(&img, c).map(|(p, s)| (c.score, p, s)))
            .filter(|(_, _, s)| *s >= 0.7 * self.sizes.min_px && *s <= 1.4 * self.sizes.max_px)
            .collect();
        ranked.sort_by(|a, b| {
            b.0.total_cmp(&a.0)
                .then(a.1 .1.total_cmp(&b.1 .1))
                .then(a.1 .0.total_cmp(&b.1 .0))
        });
        let starts = dedup_points(
            ranked.into_iter().map(|(_, p, s)| (p, s)).collect(),
            SAME_CANDIDATE,
        );
        let mut found: Vec<Found> = starts
            .into_iter()
            .filter_map(|(c, s)| {
                let verdict = shadow::with_second_look(
                    self.analyse(&img, c, s, Look::First),
                    &NOT_SHADOW,
                    || self.analyse_lifted(&img, c, s),
                );
                verdict
                    .map_err(|(why, lifted)| {
                        tracing::trace!(
                            x = c.0 + origin.0 as f64,
                            y = c.1 + origin.1 as f64,
                            size = s,
                            why,
                            lifted,
                            "crosshair candidate rejected"
                        )
                    })
                    .ok()
            })
            .collect();
        let (w, h) = (tile.cols() as f64, tile.rows() as f64);
        Ok(best_per_target(&mut found)
            .into_iter()
            .map(|f| to_detection(MarkerType::Crosshair, f, origin, w, h, seams))
            .collect())
    }
}

/// Keeps the first of points closer than `fraction` of their size.
fn dedup_points(points: Vec<(Pt, f64)>, fraction: f64) -> Vec<(Pt, f64)> {
    let mut kept: Vec<(Pt, f64)> = Vec::new();
    let mut grid: std::collections::HashMap<(i64, i64), Vec<usize>> = Default::default();
    const CELL: f64 = 16.0;
    for (p, s) in points {
        let r = fraction * s;
        let (cx, cy) = ((p.0 / CELL).floor() as i64, (p.1 / CELL).floor() as i64);
        let reach = (r / CELL).ceil() as i64;
        let near = (-reach..=reach).any(|dy| {
            (-reach..=reach).any(|dx| {
                grid.get(&(cx + dx, cy + dy)).is_some_and(|v| {
                    v.iter().any(|&i| {
                        let (q, qs) = kept[i];
                        geometry::dist(p, q) < r && (qs / s - 1.0).abs() < 0.3
                    })
                })
            })
        });
        if !near {
            grid.entry((cx, cy)).or_default().push(kept.len());
            kept.push((p, s));
        }
    }
    kept
}
