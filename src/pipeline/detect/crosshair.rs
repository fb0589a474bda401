//! Printed crosshair targets: a white cross on a black square, and the 2x2
//! checker ("X" / diagonal target).
//!
//! 1. Candidates: local maxima of the ring-harmonic response of
//!    [`harmonic`] (2-fold for checkers, 4-fold for crosses), each refined on
//!    the full-resolution tile to the centre where that response peaks and
//!    the size where it fades.
//! 2. A ring of samples at two radii classifies the candidate: four narrow
//!    bright arcs (cross bars) or four alternating quadrants (checker), and
//!    gives the four arm directions.
//! 3. Each arm is measured outward until its structure ends (a cross's bar
//!    where it stops keeping its width); a structure that runs on (panel
//!    grids, paving, road markings) is rejected, except one arm meeting an
//!    object, or a cross lying on a stripe.
//! 4. Subpixel centre: the two cross bars' centre lines (midpoints of both
//!    bar edges on profiles across the bar, every half pixel along both arms
//!    of each bar) or the checker's two quadrant boundaries (edge crossings
//!    along their whole length) are fitted as straight lines, outliers left
//!    out; the centre is their intersection: the saddle point of a checker,
//!    the bars' crossing for a cross, exact under perspective since lines
//!    stay lines.
//! 5. Structure checks tell targets from look-alikes (see `analyse`).

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
        let candidates = harmonic::candidates(tile, self.sizes).map_err(err)?;
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

/// Classifies a ring of samples: four alternating quadrants (checker) or
/// four narrow bright arcs on dark (cross), and finds the arms.
///
/// In log intensity (a shadow is an offset) the ring's 2nd or 4th harmonic
/// predicts where the quadrant boundaries or bars are; each is then found
/// locally, within 25 degrees of the prediction (perspective skews the
/// angles), and checked on its own: a boundary steps the expected way, a bar
/// stands above the dark on both its sides. A shadow edge across the ring
/// changes levels between arms, not these local contrasts.
fn classify_ring(basis: &RingBasis, v: &[f64]) -> Option<RingPattern> {
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
fn match_arms(inner: &[f64; 4], outer: &[f64; 4]) -> Option<[f64; 4]> {
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
fn orient(d: Pt, like: Pt) -> Pt {
    if d.0 * like.0 + d.1 * like.1 < 0.0 {
        (-d.0, -d.1)
    } else {
        d
    }
}

/// Direction of arm k: arms 0 and 2 lie on line A, 1 and 3 on line B.
fn arm_dir(dirs: &[Pt; 2], k: usize) -> Pt {
    let d = dirs[k % 2];
    if k >= 2 {
        (-d.0, -d.1)
    } else {
        d
    }
}

/// The shorter and the longer of the two arms across arm k (k+1 and k+3).
fn across(lengths: &[f64; 4], k: usize) -> (f64, f64) {
    let (p, q) = (lengths[(k + 1) % 4], lengths[(k + 3) % 4]);
    (p.min(q), p.max(q))
}

/// The mean length of the two arms across arm k, when they agree within
/// [`MAX_ARM_RATIO`] and `long` exceeds both by more than it: arm k's bar
/// lies on a stripe, and its length is the board's, as across.
fn across_if_longer(arms: &[Arm; 4], k: usize, long: f64) -> Option<f64> {
    let (lo, hi) = across(&arms.map(|a| a.length), k);
    (hi / lo <= MAX_ARM_RATIO && long > MAX_ARM_RATIO * hi).then_some((lo + hi) / 2.0)
}

/// The eight half-sides of a target's square, each quadrant's two outer
/// sides: per arm k and each neighbouring arm, arm k's direction and length
/// (the side lies that far out along it) and the neighbour's direction and
/// length (how far the side runs).
fn half_sides<'a>(
    dirs: &'a [Pt; 2],
    lengths: &'a [f64; 4],
) -> impl Iterator<Item = (Pt, f64, Pt, f64)> + 'a {
    (0..4).flat_map(move |k| {
        [(k + 1) % 4, (k + 3) % 4].map(|side| {
            (
                arm_dir(dirs, k),
                lengths[k],
                arm_dir(dirs, side),
                lengths[side],
            )
        })
    })
}

/// +1 when the left (+normal) side of a checker arm is the light quadrant.
fn checker_polarity(img: &GreyView, c: Pt, a: Pt, t: f64) -> Option<f64> {
    let n = perp(a);
    let base = add(c, a, t);
    let o = (0.4 * t).max(2.0);
    let (l, r) = (
        img.sample(add(base, n, o).0, add(base, n, o).1)?,
        img.sample(add(base, n, -o).0, add(base, n, -o).1)?,
    );
    if (l - r).abs() < MIN_CONTRAST {
        return None;
    }
    Some(if l > r { 1.0 } else { -1.0 })
}

enum ArmEnd {
    Ends(Arm),
    /// The structure continues past the arm's end (with the arm as far as
    /// its own structure went, if it ended at all): a grid, paving, a road,
    /// or something lying against the target.
    RunsOn(Option<Arm>),
    /// A checker's boundary continues with the colours swapped: paving.
    Flips,
    /// Past a checker arm's end, an edge of the other polarity off the
    /// arm's line that does not cross the whole target (a shadow's edge
    /// does): something lying beside the target, or a junction of
    /// unrelated regions. With the arm as far as its own structure went.
    Beside(Arm),
    /// The arm leaves the tile before it can be judged.
    Unknown,
}

/// Feature strength at `t` along arm `a`: for a cross, how much brighter the
/// bar's centre line is than both sides; for a checker, the edge contrast
/// with the arm's polarity. Averaged over three points one pixel apart.
/// Second, for a cross, the same with the bar's brightness taken as the
/// least of its centre line and `width` either side of it (a bar keeps its
/// width; a narrower stripe does not); the first again for a checker.
fn feature(
    img: &GreyView,
    kind: Kind,
    (c, a): (Pt, Pt),
    t: f64,
    o: f64,
    polarity: f64,
    width: f64,
) -> Option<(f64, f64)> {
    let n = perp(a);
    let (mut sum, mut narrow) = (0.0, 0.0);
    for dt in [-1.0, 0.0, 1.0] {
        let base = add(c, a, t + dt);
        let at = |s: f64| {
            let p = add(base, n, s);
            img.sample(p.0, p.1)
        };
        match kind {
            Kind::Cross => {
                let centre = at(0.0)?;
                let side = at(-o)?.max(at(o)?);
                sum += centre - side;
                narrow += if width > 0.0 {
                    centre.min(at(-width)?).min(at(width)?) - side
                } else {
                    centre - side
                };
            }
            Kind::Checker => {
                let f = polarity * (at(o)? - at(-o)?);
                sum += f;
                narrow += f;
            }
        }
    }
    Some((sum / 3.0, narrow / 3.0))
}

/// Walks arm `a` outward: where its structure fades, and whether anything
/// like it continues beyond.
#[allow(clippy::too_many_arguments)]
fn measure_arm(
    img: &GreyView,
    kind: Kind,
    c: Pt,
    a: Pt,
    bar: f64,
    polarity: f64,
    size_guess: f64,
    max_reach: f64,
) -> ArmEnd {
    let o = match kind {
        Kind::Cross => bar / 2.0 + (0.5 * bar).max(2.5),
        Kind::Checker => (0.1 * size_guess).max(3.0),
    };
    let t0 = match kind {
        Kind::Cross => bar / 2.0 + 3.0,
        Kind::Checker => 3.0 + 0.08 * size_guess,
    };
    let reference_end = t0 + (0.15 * size_guess).max(3.0);
    let mut near = Vec::new();
    // Checker: the quadrants' levels either side of the arm near the centre.
    let mut sides = (Vec::new(), Vec::new());
    let level = |t: f64, s: f64| beside_arm(img, (c, a), t, s);
    let mut t = t0;
    let mut below = 0;
    let mut length = None;
    let mut strength = 0.0;
    // A cross's bar keeps its width: bright a third of the way to either
    // edge too, so an arm ends where its bar goes on as a narrower stripe
    // (a road marking under the target, a short stripe across a long one).
    // The arm's strength stays the plain bar's contrast.
    let width = 0.3 * bar;
    let (mut near_w, mut strength_w) = (Vec::new(), 0.0);
    while t <= max_reach {
        let Some((f, fw)) = feature(img, kind, (c, a), t, o, polarity, width) else {
            return ArmEnd::Unknown;
        };
        if t <= reference_end {
            near.push(f);
            near_w.push(fw);
            if kind == Kind::Checker {
                if let (Some(l), Some(r)) = (level(t, o), level(t, -o)) {
                    sides.0.push(l);
                    sides.1.push(r);
                }
            }
        } else {
            if strength == 0.0 {
                strength = pr::quantile(&near, 0.5);
                if strength < 0.7 * MIN_CONTRAST {
                    return ArmEnd::Unknown;
                }
                strength_w = pr::quantile(&near_w, 0.5);
            }
            // 0.4: a shadow edge across the arm (x 0.55) is not its end.
            if fw < 0.4 * strength_w {
                below += 1;
                if below == 3 {
                    length = Some(t - 2.0);
                    break;
                }
            } else {
                below = 0;
            }
        }
        t += 1.0;
    }
    let Some(length) = length else {
        return ArmEnd::RunsOn(None);
    };
    let arm = Arm {
        length: length + 0.5,
        strength,
        polarity,
    };
    // Paving cut short by something lying over it: only the tiles right
    // past the end may show, inside the gap below.
    if kind == Kind::Checker
        && !sides.0.is_empty()
        && tiles_swap_past_end(
            img,
            (c, a),
            length,
            o,
            polarity,
            strength,
            (pr::quantile(&sides.0, 0.5), pr::quantile(&sides.1, 0.5)),
        )
    {
        return ArmEnd::Flips;
    }
    // Beyond the end: ground, not more of the same pattern. From a gap past
    // the end (a panel grid's cross line or a blurred square edge must not
    // count), for 0.6 of the arm: a repeating pattern continues right after
    // the gap; something else beside the target (a path, a car, a stripe)
    // further out does not make it part of a pattern.
    let from = length + (0.3 * length).max(3.0);
    let to = from + (0.6 * length).max(6.0);
    let mut active = 0;
    let mut flipped = 0;
    // Flipped samples in a row from the gap on: a tile of paving right
    // past the arm's end, however far the paving goes beyond it.
    let mut lead = 0;
    let mut total = 0;
    // Paving's boundary flips between the same two tiles, lit or in shadow
    // alike (a shadow scales both, so their log ratio holds); a shadow edge
    // or a stripe continuing a target's boundary separates ground from
    // something else, at another ratio. Checkers only.
    let ratio = if sides.0.is_empty() {
        0.0
    } else {
        harmonic::log_grey(pr::quantile(&sides.0, 0.5))
            - harmonic::log_grey(pr::quantile(&sides.1, 0.5))
    };
    let flips_tiles = |t: f64| match (level(t, o), level(t, -o)) {
        (Some(l), Some(r)) => {
            let flipped = harmonic::log_grey(r) - harmonic::log_grey(l);
            (flipped - ratio).abs() < FLIP_RATIO * ratio.abs()
        }
        _ => false,
    };
    let mut t = from;
    while t <= to {
        let Some((f, _)) = feature(img, kind, (c, a), t, o, polarity, 0.0) else {
            break;
        };
        // A cross's bar continues as a bright bar (a grid line); a checker's
        // boundary continues as the same edge (a long straight edge) or, in
        // paving, flipped at the tile corner, often fainter than the
        // junction measured near the centre.
        let continues = match kind {
            Kind::Cross => f >= 0.5 * strength,
            Kind::Checker => f >= 0.5 * strength || f <= -0.4 * strength,
        };
        active += continues as usize;
        // A flip as strong as the junction is paving whatever its levels.
        let paving = kind == Kind::Checker
            && (f <= -0.7 * strength || (f <= -0.4 * strength && flips_tiles(t)));
        flipped += paving as usize;
        if paving && lead == total {
            lead += 1;
        }
        total += 1;
        t += 1.0;
    }
    if total > 0 && (flipped * 2 > total || lead >= MIN_LEAD_FLIPS) {
        // Paving continues the boundary on the arm's own line; an edge of
        // something else crosses the profiles wherever it happens to lie.
        let (mut aligned, mut tried) = (0, 0);
        let mut profile = Vec::new();
        let mut edge = Vec::new();
        let mut t = from;
        while t <= to {
            tried += 1;
            if pr::line(img, add(c, a, t), perp(a), o, &mut profile).is_some() {
                if let Some((s, _)) = edge_offset(&profile, o, -polarity, 0.7 * strength) {
                    aligned += (s.abs() <= (0.05 * length).max(1.0)) as usize;
                    edge.push(add(add(c, a, t), perp(a), s));
                }
            }
            t += 1.0;
        }
        if aligned * 2 > tried {
            // Ground right past the arm's end (across the gap no edge on
            // the arm's line, at neither quadrant's level) and the pattern
            // only further out: paving lying near the target along the
            // arm's line, not tiles meeting the target's at the arm's end
            // (crosshair frame 2701: a paving block 16 px past a checker's
            // corner).
            if lead == 0
                && !sides.0.is_empty()
                && gap_is_ground(
                    img,
                    (c, a),
                    (length, from),
                    o,
                    (pr::quantile(&sides.0, 0.5), pr::quantile(&sides.1, 0.5)),
                )
            {
                return ArmEnd::Ends(arm);
            }
            return ArmEnd::Flips;
        }
        if edge_crosses_target(img, c, &edge, size_guess, o, 0.7 * strength) {
            return ArmEnd::Ends(arm);
        }
        return ArmEnd::Beside(arm);
    }
    if total > 0 && active * 2 > total {
        return ArmEnd::RunsOn(Some(arm));
    }
    ArmEnd::Ends(arm)
}

/// Whether a checker arm's line shows ground from 3 px past the arm's end
/// at `length` to `to` px from `c`, on 2 samples at least: either side `o`
/// px off the line at one level (no edge), and that level unlike both
/// quadrants' beside the arm, `(left, right)` (by a quarter of their
/// difference; paving rows set off from each other put a tile there).
fn gap_is_ground(
    img: &GreyView,
    (c, a): (Pt, Pt),
    (length, to): (f64, f64),
    o: f64,
    (left, right): (f64, f64),
) -> bool {
    let diff = (left - right).abs();
    let mut n = 0;
    let mut t = length + 3.0;
    while t < to {
        let (Some(l), Some(r)) = (
            beside_arm(img, (c, a), t, o),
            beside_arm(img, (c, a), t, -o),
        ) else {
            return false;
        };
        let level = (l + r) / 2.0;
        if (l - r).abs() >= 0.3 * diff
            || (level - left).abs() < 0.25 * diff
            || (level - right).abs() < 0.25 * diff
        {
            return false;
        }
        n += 1;
        t += 1.0;
    }
    n >= 2
}

/// The grey level `t` px out along the arm `a` from `c` and `s` px across
/// it (towards `perp(a)`).
fn beside_arm(img: &GreyView, (c, a): (Pt, Pt), t: f64, s: f64) -> Option<f64> {
    let p = add(add(c, a, t), perp(a), s);
    img.sample(p.0, p.1)
}

/// The least and largest of `v`.
fn extent(v: &[f64]) -> (f64, f64) {
    v.iter()
        .fold((f64::MAX, f64::MIN), |(lo, hi), &x| (lo.min(x), hi.max(x)))
}

/// Whether a checker arm that runs on past the board (from `board` to
/// `end` px from the centre `c` along `a`) is the edge of something lying
/// against the board: one side keeps its quadrant's level all along (a dark
/// object against a dark quadrant), the other is ground of one level,
/// unlike its quadrant's; or each side is of one level of its own, the two
/// apart and not the quadrants' levels swapped (an object darker than the
/// dark quadrant, beside ground). Paving's boundary running on passes
/// tiles of both levels.
fn object_against_board(img: &GreyView, c: Pt, a: Pt, board: f64, end: f64) -> bool {
    let o = (0.1 * board).max(3.0);
    // Either side at `o` and `2 o` from the line: a level taken off an
    // edge that leaves the arm's line at a small angle is the edge's blur
    // (clutter scene 1400: a dark triangle's corner at paving's edge, its
    // edge read 3 px out as ground of one level).
    let levels = |from: f64, to: f64, s: f64| -> Vec<f64> {
        let mut v = Vec::new();
        let mut t = from;
        while t <= to {
            v.extend(
                [s, 2.0 * s]
                    .into_iter()
                    .filter_map(|off| beside_arm(img, (c, a), t, off)),
            );
            t += 1.0;
        }
        v
    };
    let near = (
        levels(0.3 * board, 0.8 * board, o),
        levels(0.3 * board, 0.8 * board, -o),
    );
    let past = (
        levels(board + 3.0, end - 3.0, o),
        levels(board + 3.0, end - 3.0, -o),
    );
    if near.0.is_empty() || near.1.is_empty() || past.0.len() < 6 || past.1.len() < 6 {
        return false;
    }
    let q = (pr::quantile(&near.0, 0.5), pr::quantile(&near.1, 0.5));
    let contrast = (q.0 - q.1).abs();
    let keeps = |v: &[f64], level: f64| {
        [0.1, 0.9]
            .iter()
            .all(|&f| (pr::quantile(v, f) - level).abs() < 0.25 * contrast)
    };
    // One level: its spread under a quarter of the quadrants' difference.
    let uniform = |v: &[f64]| pr::quantile(v, 0.9) - pr::quantile(v, 0.1) < 0.25 * contrast;
    let ground =
        |v: &[f64], level: f64| (pr::quantile(v, 0.5) - level).abs() > 0.4 * contrast && uniform(v);
    if (keeps(&past.0, q.0) && ground(&past.1, q.1))
        || (keeps(&past.1, q.1) && ground(&past.0, q.0))
    {
        return true;
    }
    // An object of its own level (a dark disc darker than the dark
    // quadrant) on one side and ground on the other: both sides of one
    // level each, apart, and not the quadrants swapped (paving's next tiles).
    let m = (pr::quantile(&past.0, 0.5), pr::quantile(&past.1, 0.5));
    let swapped = (m.0 - q.1).abs() < 0.25 * contrast && (m.1 - q.0).abs() < 0.25 * contrast;
    uniform(&past.0) && uniform(&past.1) && (m.0 - m.1).abs() > 0.4 * contrast && !swapped
}

/// Whether a checker arm's boundary runs on, right past its end, between
/// the same two tiles swapped: paving, its continuation perhaps cut short
/// by something lying over it. Each side must show the level of the
/// quadrant across the arm (within [`TILE_LEVEL_TOLERANCE`] of the
/// quadrants' difference) near the line and a third of the arm from it
/// (a narrow stripe along the line is not a tile), and the edge between
/// them must lie on the arm's line, for [`MIN_LEAD_FLIPS`] samples in a
/// row from just past the end. `(left, right)`: the quadrants' levels on
/// the arm's two sides near the centre.
fn tiles_swap_past_end(
    img: &GreyView,
    (c, a): (Pt, Pt),
    length: f64,
    o: f64,
    polarity: f64,
    strength: f64,
    (left, right): (f64, f64),
) -> bool {
    let level = |t: f64, s: f64| beside_arm(img, (c, a), t, s);
    let tolerance = TILE_LEVEL_TOLERANCE * (left - right).abs();
    let swapped = |t: f64, s: f64| match (level(t, s), level(t, -s)) {
        (Some(l), Some(r)) => (l - right).abs() < tolerance && (r - left).abs() < tolerance,
        _ => false,
    };
    let mut profile = Vec::new();
    let mut t = length + (0.1 * length).max(2.0);
    let mut lead = 0;
    while t <= 1.5 * length && lead < MIN_LEAD_FLIPS {
        let on_line = swapped(t, o)
            && swapped(t, 0.3 * length)
            && pr::line(img, add(c, a, t), perp(a), o, &mut profile).is_some()
            && edge_offset(&profile, o, -polarity, 0.7 * strength)
                .is_some_and(|(s, _)| s.abs() <= (0.05 * length).max(1.0));
        if !on_line {
            return false;
        }
        lead += 1;
        t += 1.0;
    }
    lead >= MIN_LEAD_FLIPS
}

/// Whether the edge found past an arm's end (its points in `edge`) is a
/// straight edge that crosses the whole target: the same side lighter on
/// the target's far side, beyond its square, as here. A shadow's edge or a
/// boundary of the ground runs under the target like that; something lying
/// against the target ends at it, and paving's edges lie on the arms' lines
/// (found before this is asked).
fn edge_crosses_target(
    img: &GreyView,
    c: Pt,
    edge: &[Pt],
    size: f64,
    o: f64,
    strength: f64,
) -> bool {
    if edge.len() < 6 {
        return false;
    }
    let Some(((p0, d), inliers)) = pr::robust_line(edge) else {
        return false;
    };
    if inliers.len() * 3 < edge.len() * 2 || pr::line_rms(&inliers, (p0, d)) > 1.0 {
        return false;
    }
    let m = perp(d);
    let across = |p: Pt| -> Option<f64> {
        let (a, b) = (add(p, m, o), add(p, m, -o));
        Some(img.sample(a.0, a.1)? - img.sample(b.0, b.1)?)
    };
    let near: Vec<f64> = inliers.iter().filter_map(|&p| across(p)).collect();
    if near.len() < 6 {
        return false;
    }
    let contrast = pr::quantile(&near, 0.5);
    if contrast.abs() < strength {
        return false;
    }
    // Along the line from its point nearest the centre, away from the
    // near side's points, starting where it leaves the target's square.
    let u0 = (c.0 - p0.0) * d.0 + (c.1 - p0.1) * d.1;
    let foot = add(p0, d, u0);
    let mid = inliers
        .iter()
        .fold((0.0, 0.0), |s, p| (s.0 + p.0, s.1 + p.1));
    let mid = (mid.0 / inliers.len() as f64, mid.1 / inliers.len() as f64);
    let side = -((mid.0 - foot.0) * d.0 + (mid.1 - foot.1) * d.1).signum();
    let off = geometry::dist(foot, c);
    let reach = 0.75 * size;
    let start = (reach * reach - off * off).max(0.0).sqrt();
    // As far as the edge was followed past the arm's end.
    let (mut same, mut total) = (0, 0);
    let mut u = start;
    while u <= start + edge.len() as f64 {
        if let Some(v) = across(add(foot, d, side * u)) {
            same += (v * contrast.signum() >= 0.5 * contrast.abs()) as usize;
        }
        total += 1;
        u += 1.0;
    }
    same * 3 >= total * 2
}

/// Result of fitting the two centre lines.
struct LineFit {
    centre: Pt,
    dirs: [Pt; 2],
    /// Median bar width (cross only).
    bar: Option<f64>,
    /// Every bar width measured (cross only).
    widths: Vec<f64>,
    /// Median width of each bar (cross only; 0 without widths).
    bar_widths: [f64; 2],
    /// Smallest fraction of usable profiles over the four arms.
    coverage: f64,
    /// Largest RMS point-to-line distance of the two lines.
    rms: f64,
    /// Largest angle (radians) between the two halves of a line, each
    /// fitted on its own arm's points: a printed boundary runs straight
    /// through the centre.
    bend: f64,
}

/// Fits both lines from profiles across every arm, every half pixel.
fn fit_lines(
    img: &GreyView,
    kind: Kind,
    c: Pt,
    dirs: [Pt; 2],
    arms: &[Arm; 4],
    bar: f64,
) -> Option<LineFit> {
    let mut lines = [((0.0, 0.0), (0.0, 0.0)); 2];
    let mut widths = Vec::new();
    let mut bar_widths = [0.0; 2];
    let mut coverage = 1f64;
    let mut rms = 0f64;
    let mut bend = 0f64;
    let mut profile = Vec::new();
    for (li, line) in lines.iter_mut().enumerate() {
        let mut points = Vec::new();
        // Where the second arm's points start.
        let mut split = 0;
        let first_width = widths.len();
        for k in [li, li + 2] {
            split = points.len();
            let a = arm_dir(&dirs, k);
            let n = perp(a);
            let arm = arms[k];
            let (t0, half) = match kind {
                Kind::Cross => (
                    bar / 2.0 + 3.0,
                    bar / 2.0 + (0.6 * bar).clamp(2.5, (0.6 * (arm.length - bar / 2.0)).max(2.5)),
                ),
                Kind::Checker => (3.0 + 0.08 * arm.length, (0.2 * arm.length).clamp(3.0, 15.0)),
            };
            let t1 = arm.length - 3.0;
            let (mut tried, mut got) = (0usize, 0usize);
            let mut t = t0;
            while t <= t1 {
                tried += 1;
                let base = add(c, a, t);
                if pr::line(img, base, n, half, &mut profile).is_some() {
                    let hit = match kind {
                        Kind::Cross => bar_centre(&profile, half, bar, arm.strength),
                        Kind::Checker => edge_offset(&profile, half, arm.polarity, arm.strength)
                            .map(|(s, _)| {
                                let local = edge_at_local_levels(&profile, half, s, arm.polarity);
                                (local.unwrap_or(s), None)
                            }),
                    };
                    if let Some((s, width)) = hit {
                        points.push(add(base, n, s));
                        if let Some(w) = width {
                            widths.push(w);
                        }
                        got += 1;
                    }
                }
                t += 0.5;
            }
            if tried < 3 {
                return None;
            }
            coverage = coverage.min(got as f64 / tried as f64);
        }
        if points.len() < 6 {
            return None;
        }
        if widths.len() > first_width {
            bar_widths[li] = pr::quantile(&widths[first_width..], 0.5);
        }
        let (fitted, inliers) = pr::robust_line(&points)?;
        rms = rms.max(pr::line_rms(&inliers, fitted));
        let (near, far) = points.split_at(split);
        let halves = (near.len().min(far.len()) >= 6)
            .then(|| pr::robust_line(near).zip(pr::robust_line(far)))
            .flatten();
        if let Some(((a, _), (b, _))) = halves {
            bend = bend.max((a.1 .0 * b.1 .1 - a.1 .1 * b.1 .0).abs().asin());
        }
        // Outliers count against coverage: under MIN_INLIER_SHARE fails it.
        let share = inliers.len() as f64 / points.len() as f64;
        coverage = coverage.min(share / MIN_INLIER_SHARE * MIN_COVERAGE);
        *line = (fitted.0, orient(fitted.1, dirs[li]));
    }
    let centre = intersect(lines[0], lines[1])?;
    let bar = (!widths.is_empty()).then(|| pr::quantile(&widths, 0.5));
    Some(LineFit {
        centre,
        dirs: [lines[0].1, lines[1].1],
        bar,
        widths,
        bar_widths,
        coverage,
        rms,
        bend,
    })
}

/// Centre offset and width of a bright bar across a profile (dark on both
/// ends): the midpoint of its rising and falling midpoint crossings, each at
/// the middle of its own dark side and the bar just inside that edge (a
/// shadow edge crossing the profile in a dark part, or along the bar, shifts
/// neither).
fn bar_centre(p: &[f64], half: f64, bar: f64, strength: f64) -> Option<(f64, Option<f64>)> {
    let k = (p.len() / 7).max(1);
    let (left, right) = (pr::mean(p, 0, k), pr::mean(p, p.len() - k, p.len()));
    let mid = p.len() / 2;
    let span = ((bar / 2.0) / pr::STEP_PX) as usize;
    let bright = p[mid.saturating_sub(span / 2)..(mid + span / 2 + 1).min(p.len())]
        .iter()
        .fold(f64::MIN, |a, &b| a.max(b));
    // 0.35: a shadow dims a bar to 0.55 of the strength measured outside it.
    if bright - left.max(right) < 0.35 * strength {
        return None;
    }
    let centre_idx = half / pr::STEP_PX;
    let w = bar / 2.0 / pr::STEP_PX;
    let up = pr::crossing(p, (left + bright) / 2.0, true, centre_idx - w)?;
    let down = pr::crossing(p, (right + bright) / 2.0, false, centre_idx + w)?;
    if down <= up {
        return None;
    }
    // The width as the crossings at the bar's brightest level give it: the
    // bar-width and grid-line checks were set with that.
    let width = (down - up) * pr::STEP_PX;
    if !(0.5 * bar..=1.6 * bar).contains(&width) {
        return None;
    }
    // The bar's level beside each edge: a quarter of the bar in from it (at
    // most 2.5 px, past most of a blurred edge). The same inset on both
    // sides keeps a bar without shadow centred however blurred. With a
    // shadow edge along the bar, the first crossing on the shadowed side
    // lies too far in; each pass moves it out toward its own level.
    let (mut up, mut down) = (up, down);
    for _ in 0..3 {
        let inset = (0.25 * (down - up)).min(2.5 / pr::STEP_PX);
        let next_up = pr::crossing(p, (left + pr::level_near(p, up + inset)) / 2.0, true, up)?;
        let next_down = pr::crossing(
            p,
            (right + pr::level_near(p, down - inset)) / 2.0,
            false,
            down,
        )?;
        (up, down) = (next_up, next_down);
        if down <= up {
            return None;
        }
    }
    Some((pr::offset((up + down) / 2.0, half), Some(width)))
}

/// Offset of a checker boundary across a profile, rising toward the light
/// side given by `polarity`.
fn edge_offset(p: &[f64], half: f64, polarity: f64, strength: f64) -> Option<(f64, Option<f64>)> {
    let k = (p.len() / 5).max(1);
    let (first, last) = (pr::mean(p, 0, k), pr::mean(p, p.len() - k, p.len()));
    if polarity * (last - first) < 0.35 * strength {
        return None;
    }
    let level = (first + last) / 2.0;
    let idx = pr::crossing(p, level, polarity > 0.0, half / pr::STEP_PX)?;
    Some((pr::offset(idx, half), None))
}

/// A checker boundary's offset `s` (from [`edge_offset`]) moved to the
/// midpoint of the levels just either side of it: 2.5 px out, at most half
/// the profile's half length. The profile's ends may lie across a shadow
/// edge that runs along the boundary, and the middle of their levels then
/// falls on the shadow edge; the levels beside the boundary do not.
fn edge_at_local_levels(p: &[f64], half: f64, s: f64, polarity: f64) -> Option<f64> {
    let inset = 2.5f64.min(0.5 * half) / pr::STEP_PX;
    let mut x = (s + half) / pr::STEP_PX;
    for _ in 0..3 {
        let level = (pr::level_near(p, x - inset) + pr::level_near(p, x + inset)) / 2.0;
        x = pr::crossing(p, level, polarity > 0.0, x)?;
    }
    Some(pr::offset(x, half))
}

/// A cross's quadrants are dark all over: on a 3x3 grid across each one,
/// nearly every sample is darker than the bar beside it (a local comparison,
/// so a shadow edge across the target does not matter). The bright diagonal
/// "crosses" of checker paving have light tiles inside their quadrants.
fn quadrants_are_dark(
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
fn grid_lines_around(
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
fn board_sides_seen(
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
fn checker_quadrants_uniform(
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
fn quadrants_whole(
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
fn shadow_explains_quadrants(
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
fn tiles_past(
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
fn side_lines_run_on(
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
fn dark_pair_apart(quadrants: &[f64; 4]) -> Option<(usize, usize)> {
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
fn quadrant_centre(c: Pt, dirs: &[Pt; 2], lengths: &[f64; 4], k: usize) -> Pt {
    let (a, b) = (arm_dir(dirs, k), arm_dir(dirs, (k + 1) % 4));
    add(add(c, a, 0.55 * lengths[k]), b, 0.55 * lengths[(k + 1) % 4])
}

/// A checker's quadrant levels paired: the mean of quadrants 0 and 2, of
/// 1 and 3, and their difference.
fn pair_levels(quadrants: &[f64; 4]) -> (f64, f64, f64) {
    let even = (quadrants[0] + quadrants[2]) / 2.0;
    let odd = (quadrants[1] + quadrants[3]) / 2.0;
    (even, odd, (even - odd).abs())
}

/// Mean grey level of each quadrant, between arm k and arm k+1, sampled on
/// a small patch halfway along the bisector.
fn quadrant_levels(img: &GreyView, c: Pt, dirs: &[Pt; 2], lengths: &[f64; 4]) -> Option<[f64; 4]> {
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

#[cfg(test)]
mod tests {
    use super::super::test_image::{render_image, Cross};
    use super::*;

    fn ring_of(f: impl Fn(f64) -> f64) -> Vec<f64> {
        (0..RING_SAMPLES)
            .map(|i| f(TAU * i as f64 / RING_SAMPLES as f64))
            .collect()
    }

    #[test]
    fn rings_tell_crosses_from_checkers_and_clutter() {
        let checker = ring_of(|a| {
            if (a + 0.3).sin() * (a + 0.3).cos() > 0.0 {
                200.0
            } else {
                30.0
            }
        });
        let basis = RingBasis::new(RING_SAMPLES);
        let p = classify_ring(&basis, &checker).expect("checker");
        assert_eq!(p.kind, Kind::Checker);
        let cross = ring_of(|a| {
            let d = ((a - 0.2).rem_euclid(PI / 2.0) - PI / 4.0).abs();
            if d > PI / 4.0 - 0.2 {
                210.0
            } else {
                20.0
            }
        });
        let p = classify_ring(&basis, &cross).expect("cross");
        assert_eq!(p.kind, Kind::Cross);
        for (k, arm) in p.arms.iter().enumerate() {
            let want = 0.2 + k as f64 * PI / 2.0;
            assert!((arm - want).abs() < 0.03, "arm {k}: {arm} vs {want}");
        }
        // A plain edge (two halves) and a flat ring are neither.
        assert!(classify_ring(&basis, &ring_of(|a| if a < PI { 200.0 } else { 30.0 })).is_none());
        assert!(classify_ring(&basis, &ring_of(|_| 120.0)).is_none());
    }

    #[test]
    fn dark_quadrants_apart_beside_light_ones_that_agree_are_picked_out() {
        // Quadrants 0 and 2 light, 1 and 3 dark: quadrant 3 at a shadow's
        // 0.55 of quadrant 1 is the lower.
        assert_eq!(dark_pair_apart(&[200.0, 80.0, 196.0, 44.0]), Some((3, 1)));
        assert_eq!(dark_pair_apart(&[44.0, 200.0, 80.0, 196.0]), Some((0, 2)));
        // Dark ones as close as the weakest shadow looked for: not apart.
        assert_eq!(dark_pair_apart(&[200.0, 80.0, 200.0, 64.0]), None);
        // Light ones apart too (a shadow over a light quadrant as well, or
        // across the board): left to the other checks.
        assert_eq!(dark_pair_apart(&[200.0, 80.0, 170.0, 44.0]), None);
        // Dark print's noise: 8 against 16 is under a tenth of the
        // quadrants' difference.
        assert_eq!(dark_pair_apart(&[220.0, 8.0, 220.0, 16.0]), None);
    }

    #[test]
    fn a_shadow_explains_darker_quadrants_but_other_ground_does_not() {
        // A 100 px cross (bars 24 px wide, grey 200) on dark quadrants (100)
        // centred at (60, 60), axis-aligned.
        let render = |shade: &dyn Fn(usize, usize) -> f64| {
            let mut data = vec![0u8; 120 * 120];
            for y in 0..120 {
                for x in 0..120 {
                    let on_bar = (x as i64 - 60).abs() < 12 || (y as i64 - 60).abs() < 12;
                    let v = if on_bar { 200.0 } else { 100.0 };
                    data[y * 120 + x] = (v * shade(x, y)) as u8;
                }
            }
            data
        };
        let (dirs, lengths) = ([(1.0, 0.0), (0.0, 1.0)], [50.0; 4]);
        let check = |data: &[u8]| {
            let img = GreyView {
                data,
                width: 120,
                height: 120,
                stride: 120,
            };
            let q = quadrant_levels(&img, (60.0, 60.0), &dirs, &lengths).unwrap();
            shadow_explains_quadrants(&img, (60.0, 60.0), &dirs, &lengths, &q)
        };
        // A shadow (x 0.5) over everything below y = 60 + 12: two quadrants
        // and the bar between them darker, by the same factor.
        assert!(check(&render(&|_, y| if y >= 72 { 0.5 } else { 1.0 })));
        // One quadrant of lighter ground under lit bars: not a shadow.
        let lighter = render(&|x, y| if x >= 72 && y >= 72 { 1.6 } else { 1.0 });
        assert!(!check(&lighter));
    }

    /// A blurred step from 0 to 1 at `at` (a logistic edge of scale 0.8 px).
    fn blurred_step(x: f64, at: f64) -> f64 {
        1.0 / (1.0 + (-(x - at) / 0.8).exp())
    }

    /// `grey` sampled like fit_lines' profiles of half 11 px.
    fn profile_of(grey: impl Fn(f64) -> f64) -> Vec<f64> {
        (0..=(22.0 / pr::STEP_PX) as usize)
            .map(|i| grey(-11.0 + i as f64 * pr::STEP_PX))
            .collect()
    }

    #[test]
    fn a_shadow_edge_along_a_bar_does_not_move_its_centre() {
        // A 10 px bar centred at +0.3 px, blurred; shadowed from `shadow` on:
        // bar and dark side at 0.55.
        let profile = |shadow: Option<f64>| {
            profile_of(|x| {
                let lit = 20.0 + 210.0 * (blurred_step(x, -4.7) - blurred_step(x, 5.3));
                match shadow {
                    Some(at) => lit * (1.0 - 0.45 * blurred_step(x, at)),
                    None => lit,
                }
            })
        };
        // A shadow edge 4 or 2.7 px in from the bar's edges reaches into
        // their blur: within 0.2 px there (one bar level for both edges:
        // 0.83 px off, or no bar). Nearer (2.3 px) it moves the centre 0.4 px.
        for (shadow, within) in [(None, 0.02), (Some(1.3), 0.2), (Some(-2.0), 0.2)] {
            let (s, width) = bar_centre(&profile(shadow), 11.0, 10.0, 150.0).expect("bar");
            assert!((s - 0.3).abs() < within, "shadow {shadow:?}: centre {s}");
            if shadow.is_none() {
                assert!((width.unwrap() - 10.0).abs() < 0.6, "width {width:?}");
            }
        }
    }

    #[test]
    fn a_shadow_edge_beside_a_checker_boundary_does_not_move_it() {
        // A boundary at +0.3 px rising from 20 to 230, blurred; from
        // `shadow` on, in shadow (x 0.55).
        let profile = |shadow: f64| {
            profile_of(|x| {
                (20.0 + 210.0 * blurred_step(x, 0.3)) * (1.0 - 0.45 * blurred_step(x, shadow))
            })
        };
        for shadow in [20.0, 5.0, -5.0] {
            let p = profile(shadow);
            let (s, _) = edge_offset(&p, 11.0, 1.0, 150.0).expect("edge");
            let local = edge_at_local_levels(&p, 11.0, s, 1.0).expect("edge");
            assert!(
                (local - 0.3).abs() < 0.08,
                "shadow at {shadow}: {local} (ends: {s})"
            );
            if shadow == 5.0 {
                // The profile's ends alone: the middle of lit dark and
                // shadowed light, more than 0.3 px off.
                assert!((s - 0.3).abs() > 0.3, "ends alone: {s}");
            }
        }
    }

    #[test]
    fn a_shadow_across_a_low_contrast_checker_leaves_its_arms() {
        let basis = RingBasis::new(RING_SAMPLES);
        // 40% print (grey 82 and 173), boundaries at 0.5 + k * 90 degrees,
        // and a shadow (x 0.55) over the half-ring from 1.2 to 1.2 + pi:
        // a shadowed light quadrant (95) is barely lighter than a sunlit
        // dark one (82).
        let ring = ring_of(|a| {
            let light = ((a - 0.5).rem_euclid(TAU) / (PI / 2.0)) as usize % 2 == 0;
            let v = if light { 173.0 } else { 82.0 };
            if (a - 1.2).rem_euclid(TAU) < PI {
                v * 0.55
            } else {
                v
            }
        });
        let p = classify_ring(&basis, &ring).expect("checker");
        assert_eq!(p.kind, Kind::Checker);
        for (k, arm) in p.arms.iter().enumerate() {
            let want = 0.5 + k as f64 * PI / 2.0;
            assert!((arm - want).abs() < 0.06, "arm {k}: {arm} vs {want}");
        }
    }

    /// The found centre within 0.05 px of `truth`.
    fn assert_centre(f: &Found, truth: Pt) {
        assert!(geometry::dist(f.centre, truth) < 0.05, "{:?}", f.centre);
    }

    /// `analyse` on a w x w image, started at its middle.
    fn analyse_image(data: &[u8], w: usize, size_guess: f64) -> Result<Found, &'static str> {
        analyse_in_range(data, w, size_guess, (30.0, 200.0))
    }

    /// `analyse_image` with sizes narrowed to `range` (as a target size
    /// and GSD narrow them), frames searched up to 200 px.
    fn analyse_in_range(
        data: &[u8],
        w: usize,
        size_guess: f64,
        range: (f64, f64),
    ) -> Result<Found, &'static str> {
        let img = GreyView {
            data,
            width: w,
            height: w,
            stride: w,
        };
        let detector = CrosshairDetector::new(SizeRange {
            min_px: range.0,
            max_px: range.1,
            reach_px: 200.0,
        });
        let m = (w / 2) as f64;
        detector.analyse(&img, (m, m), size_guess, Look::First)
    }

    /// White road markings (230) on dark asphalt (30), 320 x 320: `on(dx,
    /// dy)` from the image's middle.
    fn markings(on: impl Fn(f64, f64) -> bool) -> Vec<u8> {
        render_image(320, |x, y| {
            if on(x - 160.0, y - 160.0) {
                230.0
            } else {
                30.0
            }
        })
    }

    #[test]
    fn crossing_road_markings_of_two_widths_are_not_a_cross() {
        // A stripe 18 px wide across the frame and one 12 px wide, 140 px
        // long, across it; then both 12 px wide: a cross lying on a stripe,
        // but its board does not show against the ground.
        for (thick, thin) in [(18.0, 12.0), (12.0, 12.0)] {
            let data = markings(|dx, dy| {
                dy.abs() < thick / 2.0 || (dx.abs() < thin / 2.0 && dy.abs() < 70.0)
            });
            let found = analyse_image(&data, 320, 140.0);
            let why = if thick == thin {
                "no board"
            } else {
                "bar widths differ"
            };
            assert_eq!(found.err(), Some(why));
        }
    }

    #[test]
    fn a_cross_with_bars_a_twelfth_of_its_side_is_found_but_narrower_is_not() {
        // The narrowest design in use: bars 10 px on a 120 px board on grey
        // ground, arms 6x the bar. A road-marking cross on a dark patch,
        // arms 68 px over bars 10 px wide (6.8x), all four ending on the
        // patch: narrower than any printed design.
        let printed = Cross {
            centre: (160.25, 159.75),
            side: 120.0,
            bar: 10.0,
            white: 230.0,
            black: 30.0,
        };
        let data = printed.render(320, |_, _| 120.0, (1.0, 0.0), -1e9, 1.0);
        // Unblurred, its edges are rendered in quarter-pixel steps.
        let found = analyse_image(&data, 320, 120.0).unwrap();
        assert!(
            geometry::dist(found.centre, printed.centre) < 0.13,
            "{:?}",
            found.centre
        );
        let marking = markings(|dx, dy| {
            (dx.abs() < 5.0 && dy.abs() < 68.0) || (dy.abs() < 5.0 && dx.abs() < 68.0)
        });
        assert_eq!(analyse_image(&marking, 320, 136.0).err(), Some("bar ratio"));
    }

    #[test]
    fn road_markings_crossing_are_not_a_cross_with_equal_ends_or_not() {
        // Both 16 px wide, the shorter marking running 80 px to one side and
        // 100 px to the other (it ends where it meets something), or 80 and
        // 88 px: within the arm ratio, but no board shows.
        for end in [100.0, 88.0] {
            let data =
                markings(|dx, dy| dy.abs() < 8.0 || (dx.abs() < 8.0 && (-80.0..end).contains(&dy)));
            let found = analyse_image(&data, 320, 180.0);
            assert_eq!(found.err(), Some("no board"), "ends at 80 and {end} px");
        }
    }

    #[test]
    fn a_narrower_size_range_does_not_excuse_a_long_arm() {
        // Two road markings 12 px wide crossing on dark ground, three arms
        // 35 px and one 110 px: the arms differ, whether sizes are searched
        // up to 200 px or narrowed to 40-90 px by the expected size (the
        // arm's end then lies past that range's reach, but not past the
        // frame's).
        let data = markings(|dx, dy| {
            (dy.abs() < 6.0 && dx.abs() < 35.0) || (dx.abs() < 6.0 && (-35.0..110.0).contains(&dy))
        });
        for range in [(30.0, 200.0), (40.0, 90.0)] {
            let found = analyse_in_range(&data, 320, 70.0, range);
            assert_eq!(found.err(), Some("arm lengths differ"), "{range:?}");
        }
    }

    #[test]
    fn a_cross_measured_a_little_under_the_least_size_is_not_found() {
        // Crosses measured 0.964-1.116 of their true size: one measured
        // 1.04 times under the least size is found, 1.06 times under not
        // (the circles' slack, 1.10, let clutter junctions through).
        let data = Cross {
            centre: (80.0, 80.0),
            side: 40.0,
            bar: 8.0,
            white: 220.0,
            black: 40.0,
        }
        .render(160, |_, _| 120.0, (1.0, 0.0), -1e9, 1.0);
        let measured = analyse_in_range(&data, 160, 40.0, (30.0, 200.0))
            .expect("the cross")
            .size;
        for (under, found) in [(1.04, true), (1.06, false)] {
            let result = analyse_in_range(&data, 160, 40.0, (under * measured, 200.0));
            assert_eq!(result.is_ok(), found, "{under}: {:?}", result.err());
        }
    }

    #[test]
    fn paving_under_an_object_is_not_a_checker_target() {
        // A 2x2 checker of 30 px tiles on grey ground, with one more row of
        // the same tiles past its top edge: paving. A dark object covers
        // that row from `cover` px above the edge (lying over it). Covered
        // from 8 px on, only the tiles right past the arm's end show; the
        // object at the edge itself leaves a target.
        for (cover, paving) in [(8.0, true), (0.0, false)] {
            let data = render_image(320, |x, y| {
                let (dx, dy) = (x - 160.0, y - 160.0);
                if dx.abs() >= 30.0 || !(-60.0..30.0).contains(&dy) {
                    return 120.0;
                }
                if dy < -30.0 - cover {
                    return 20.0;
                }
                let (i, j) = ((dx / 30.0).floor() as i64, (dy / 30.0).floor() as i64);
                if (i + j).rem_euclid(2) == 0 {
                    60.0
                } else {
                    200.0
                }
            });
            let found = analyse_image(&data, 320, 60.0);
            if paving {
                assert_eq!(found.err(), Some("paving"));
            } else {
                assert_centre(&found.expect("a checker target"), (160.0, 160.0));
            }
        }
    }

    #[test]
    fn a_checker_with_wavy_boundaries_is_not_a_printed_one() {
        // A 2x2 checker (100 px) on grey ground whose quadrant boundaries
        // wave across by `amp` px (period 24 px): a printed boundary is
        // straight; a wave of 0.9 px (fit RMS 0.58) is a junction of
        // clutter, 0.3 px still a target.
        for (amp, clutter) in [(0.9, true), (0.3, false)] {
            let wave = |t: f64| amp * (t * std::f64::consts::TAU / 24.0).sin();
            let data = render_image(320, |x, y| {
                let (dx, dy) = (x - 160.0, y - 160.0);
                if dx.abs() >= 50.0 || dy.abs() >= 50.0 {
                    return 120.0;
                }
                let (u, v) = (dx - wave(dy), dy - wave(dx));
                if (u > 0.0) == (v > 0.0) {
                    220.0
                } else {
                    30.0
                }
            });
            let found = analyse_image(&data, 320, 100.0);
            if clutter {
                assert_eq!(found.err(), Some("fit rms"));
            } else {
                assert_centre(&found.expect("a checker"), (160.0, 160.0));
            }
        }
    }

    /// A cross (100 px, bars 16 px, board from x = 110 to 210) on ground
    /// of grey `ground`, with a white stripe `stripe` px wide along its x
    /// bar from x = `from` to `to`.
    fn cross_on_stripe(stripe: f64, (from, to): (f64, f64), ground: f64) -> Vec<u8> {
        let cross = Cross {
            centre: (160.0, 160.0),
            side: 100.0,
            bar: 16.0,
            white: 220.0,
            black: 30.0,
        };
        let lay = |x: f64, y: f64| {
            if (y - 160.0).abs() < stripe / 2.0 && (from..to).contains(&x) {
                220.0
            } else {
                ground
            }
        };
        cross.render(320, lay, (1.0, 0.0), -1000.0, 1.0)
    }

    #[test]
    fn a_narrower_stripe_past_a_bar_does_not_lengthen_its_arm() {
        // A 6 px stripe 30 px on from one bar: the plain bar walk follows it
        // and the arms differ (80 against 50 px); a bar keeps its width, so
        // the arm ends at the board.
        assert_the_cross(&cross_on_stripe(6.0, (80.0, 160.0), 120.0));
    }

    /// The cross of [`cross_on_stripe`] is found at its centre and size.
    fn assert_the_cross(data: &[u8]) {
        let f = analyse_image(data, 320, 100.0).expect("the cross");
        assert_centre(&f, (160.0, 160.0));
        assert!((f.size - 100.0).abs() < 5.0, "{}", f.size);
    }

    /// A cross on a stripe as wide as its bars, over `span` of x: found at
    /// its centre and size on grey ground, where the board shows; on ground
    /// as dark as the board, "no board".
    fn found_on_grey_not_on_dark_ground(span: (f64, f64)) {
        assert_the_cross(&cross_on_stripe(16.0, span, 120.0));
        let markings = analyse_image(&cross_on_stripe(16.0, span, 30.0), 320, 100.0);
        assert_eq!(markings.err(), Some("no board"));
    }

    #[test]
    fn a_cross_on_a_stripe_that_stops_short_needs_its_board_to_show() {
        // A stripe as wide as the bars, on to the frame's edge on the right:
        // that arm runs on, the opposite one ends 30 px past the board. On
        // grey ground the board shows and both arms are taken from those
        // across; on ground as dark as the board it is two road markings
        // crossing.
        found_on_grey_not_on_dark_ground((80.0, 320.0));
    }

    #[test]
    fn a_cross_on_a_stripe_ending_past_both_sides_needs_its_board_to_show() {
        // A stripe as wide as the bars under the x bar, 30 px past the
        // board on both sides: those arms run 80 px against 50 across, and
        // are taken from those across. On grey ground the board shows; on
        // ground as dark as the board it is a short road marking crossing a
        // longer one.
        found_on_grey_not_on_dark_ground((80.0, 240.0));
    }

    #[test]
    fn a_cross_on_a_stripe_running_on_one_way_needs_its_board_to_show() {
        // A stripe as wide as the bars from under the board to the frame's
        // edge: that arm never ends, the opposite one ends at the board. On
        // ground as dark as the board it is a road marking crossing one
        // that runs under something lying over it.
        found_on_grey_not_on_dark_ground((200.0, 320.0));
    }

    #[test]
    fn a_bar_that_ends_before_a_stripe_needs_no_board() {
        // The same stripe from 8 px past the board: the bar ends at the
        // board's edge and something bright lies past it. Found on ground
        // as dark as the board.
        assert_the_cross(&cross_on_stripe(16.0, (218.0, 320.0), 30.0));
    }

    #[test]
    fn a_cross_on_a_stripe_running_on_both_ways_needs_its_board_to_show() {
        // A stripe as wide as the bars under the x bar across the whole
        // frame: both of those arms run on. On grey ground the board shows;
        // on ground as dark as the board it is a short road marking crossing
        // a long one, its ends equal.
        found_on_grey_not_on_dark_ground((0.0, 320.0));
    }

    #[test]
    fn a_panel_grids_corner_is_boxed_in_but_a_cross_on_a_white_disc_is_not() {
        // Bright lines 3 px wide (blurred) 17 px apart: a 2x2-cell corner of
        // a panel grid on grey ground, the cell up and left open to a dark
        // shadow, so every arm from the middle crossing ends at a line. The
        // arms' ends fall on the lines' middles, not half a bar past them.
        let pitch = 17.0;
        // (horizontal, offset across, from, to along)
        let lines = [
            (false, 0.0, -pitch, pitch),
            (true, 0.0, -pitch, pitch),
            (false, pitch, -pitch, pitch),
            (true, pitch, -pitch, pitch),
            (false, -pitch, 0.0, pitch),
            (true, -pitch, 0.0, pitch),
        ];
        let grid = render_image(200, |x, y| {
            let (dx, dy) = (x - 100.0, y - 100.0);
            let line = lines
                .iter()
                .map(|&(horizontal, off, from, to)| {
                    let (across, along) = if horizontal {
                        (dy - off, dx)
                    } else {
                        (dx - off, dy)
                    };
                    (blurred_step(across, -1.5) - blurred_step(across, 1.5))
                        * (blurred_step(along, from - 1.5) - blurred_step(along, to + 1.5))
                })
                .fold(0.0, f64::max);
            let boxed = dx.abs() < pitch + 1.5 && dy.abs() < pitch + 1.5;
            let ground = if boxed || (dx < 0.0 && dy < 0.0) {
                30.0
            } else {
                110.0
            };
            ground + (200.0 - ground) * line
        });
        assert_eq!(
            analyse_image(&grid, 200, 36.0).err(),
            Some("grid lines around")
        );

        // A printed cross (66 px square, bars 13 px) on a white disc of
        // radius 45 on grey ground: past the square the disc's rim is a
        // bright band, narrowing towards the corners, so its ridge moves
        // (7 px along each half-edge): not a line. (A disc of radius 58, a
        // white margin all round, is taken for grid lines, by the lines at
        // the arms' ends alone too.)
        let on_disc = render_image(200, |x, y| {
            let (dx, dy) = (x - 100.0, y - 100.0);
            let (half, bar) = (33.0, 13.0);
            if dx.abs() < half && dy.abs() < half {
                if dx.abs() < bar / 2.0 || dy.abs() < bar / 2.0 {
                    220.0
                } else {
                    25.0
                }
            } else if dx.hypot(dy) < 45.0 {
                220.0
            } else {
                110.0
            }
        });
        let f = analyse_image(&on_disc, 200, 66.0).expect("the cross on a disc");
        assert_centre(&f, (100.0, 100.0));
    }

    /// A 2x2 checker's grey at `(dx, dy)` from its centre, `half` its
    /// half side: `light` where both are of one sign, else `dark`; `None`
    /// off the board.
    fn checker_grey(dx: f64, dy: f64, half: f64, (light, dark): (f64, f64)) -> Option<f64> {
        (dx.abs() < half && dy.abs() < half).then_some(if (dx > 0.0) == (dy > 0.0) {
            light
        } else {
            dark
        })
    }

    /// A 100 px checker of `greys` centred at (160, 160) on `ground`, with
    /// `object` (its grey where it lies) beside the board, is found there at
    /// its own size.
    fn a_checker_beside_an_object_is_found(
        greys: (f64, f64),
        ground: f64,
        object: impl Fn(f64, f64) -> Option<f64>,
    ) {
        let data = render_image(320, |x, y| {
            checker_grey(x - 160.0, y - 160.0, 50.0, greys)
                .or_else(|| object(x, y))
                .unwrap_or(ground)
        });
        let found = analyse_image(&data, 320, 100.0).expect("a checker");
        assert_centre(&found, (160.0, 160.0));
        assert!((found.size - 100.0).abs() < 4.0, "size {}", found.size);
    }

    #[test]
    fn a_checker_with_a_dark_object_against_one_quadrant_is_found() {
        // A 2x2 checker (100 px, x and y from 110 to 210) on grey ground,
        // and a dark object (a car, a manhole's cover) lying against its
        // lower left dark quadrant, 50 px long: the boundary along the arm
        // to the left runs on as the object's edge against the ground, to
        // twice the other arms' length. Its length is then the opposite
        // arm's, as for an arm running on past the reach.
        a_checker_beside_an_object_is_found((220.0, 30.0), 120.0, |x, y| {
            let (dx, dy) = (x - 160.0, y - 160.0);
            ((-100.0..-50.0).contains(&dx) && (0.0..40.0).contains(&dy)).then_some(25.0)
        });
    }

    #[test]
    fn a_checker_with_a_darker_disc_against_one_arm_is_found() {
        // A 2x2 checker (100 px, greys 205 and 90) on ground of 128, and a
        // disc darker than its dark quadrant (30, radius 40) partly under
        // the board's lower left quadrant, its right edge within 2.3 px of
        // the downward arm's line for 32 px past the board (crosshair frame
        // 2603's missed target). Past the board that arm's boundary runs
        // on between the disc and the ground, each of one level: an object
        // against the board, though not at its quadrant's level.
        a_checker_beside_an_object_is_found((205.0, 90.0), 128.0, |x, y| {
            ((x - 122.0).hypot(y - 222.0) < 40.0).then_some(30.0)
        });
    }

    #[test]
    fn paving_a_gap_past_a_checker_along_its_arm_is_not_its_tiles() {
        // An 80 px checker (greys 170 and 90) on ground of 128, and paving
        // of 30 px tiles of the same greys from 16 px past its right arm's
        // end, one tile boundary on that arm's line with the colours
        // swapped (crosshair frame 2701's missed target). Ground fills the
        // gap: paving lying near the target, not tiles meeting its own.
        // With no gap it is paving.
        for gap in [16.0, 0.0] {
            let data = render_image(320, |x, y| {
                let (dx, dy) = (x - 160.0, y - 160.0);
                if let Some(g) = checker_grey(dx, dy, 40.0, (170.0, 90.0)) {
                    return g;
                }
                let px = dx - 40.0 - gap;
                if (0.0..90.0).contains(&px) && dy.abs() < 60.0 {
                    let (i, j) = ((px / 30.0).floor(), (dy / 30.0).floor());
                    return if (i + j).rem_euclid(2.0) == 0.0 {
                        90.0
                    } else {
                        170.0
                    };
                }
                128.0
            });
            let found = analyse_image(&data, 320, 80.0);
            if gap > 0.0 {
                let f = found.expect("a checker with paving beyond a gap");
                assert_centre(&f, (160.0, 160.0));
            } else {
                assert_eq!(found.err(), Some("paving"));
            }
        }
    }

    #[test]
    fn paving_running_on_beside_a_darker_object_is_not_a_checker() {
        // Paving of 30 px tiles (greys 58 and 27) on ground of 40: a 2x2
        // block, and two more tiles of its column below it, beside a darker
        // object (12) below the block's dark quadrant: the boundary
        // between them runs on to three times the other arms' length
        // (the test's clutter scene 702). The object is not at the dark
        // quadrant's level, and the tiles beside it are of both levels.
        let data = render_image(320, |x, y| {
            let (dx, dy) = (x - 160.0, y - 160.0);
            let tile = |i: f64, j: f64| {
                if ((i / 30.0).floor() + (j / 30.0).floor()).rem_euclid(2.0) == 0.0 {
                    58.0
                } else {
                    27.0
                }
            };
            if dx.abs() < 30.0 && dy.abs() < 30.0
                || (0.0..30.0).contains(&dx) && (30.0..90.0).contains(&dy)
            {
                return tile(dx, dy);
            }
            if (-30.0..0.0).contains(&dx) && (30.0..90.0).contains(&dy) {
                return 12.0;
            }
            40.0
        });
        assert_eq!(
            analyse_image(&data, 320, 60.0).err(),
            Some("arm lengths differ")
        );
    }

    #[test]
    fn a_shadow_edge_past_a_checker_arm_is_not_an_object_beside_it() {
        // An 80 px checker (greys 90 and 170) on ground of 150 centred at
        // (100, 100). Below the line y = 264 - x (through (160, 104)),
        // shadow (x 0.5): past the right arm's end, an edge of the other
        // polarity crossing the arm's line. A shadow's edge cuts the target's
        // corner and goes on beyond it: the arm ends there. A dark object's
        // edge that ends at the target (only right of the target's square)
        // lies beside the arm; the checker, whole and with no tile past its
        // sides, is found with the object against it.
        for shadow_crosses in [true, false] {
            let data = render_image(200, |x, y| {
                let (dx, dy) = (x - 100.0, y - 100.0);
                let base = checker_grey(dx, dy, 40.0, (170.0, 90.0)).unwrap_or(150.0);
                let below = y > 104.0 - (x - 160.0);
                let shaded = below && (shadow_crosses || dx > 40.0);
                base * if shaded { 0.5 } else { 1.0 }
            });
            let img = GreyView {
                data: &data,
                width: 200,
                height: 200,
                stride: 200,
            };
            let (c, right) = ((100.0, 100.0), (1.0, 0.0));
            let polarity = checker_polarity(&img, c, right, 20.0).expect("polarity");
            let end = measure_arm(&img, Kind::Checker, c, right, 0.0, polarity, 80.0, 150.0);
            if shadow_crosses {
                assert!(matches!(end, ArmEnd::Ends(_)), "the arm ends");
            } else {
                assert!(matches!(end, ArmEnd::Beside(_)), "an edge beside the arm");
            }
            let f = analyse_image(&data, 200, 80.0).expect("the checker");
            assert_centre(&f, (100.0, 100.0));
        }
    }

    /// A 100 px cross of 45% print (bars 20 px) centred at (150.25, 149.5)
    /// (on the 4x4 subsamples' grid) on textured ground, with a shadow (x
    /// 0.55) on one side of the line `off` px from the centre, normal at
    /// `angle`.
    fn shadowed_cross(angle: f64, off: f64) -> Vec<u8> {
        let cross = Cross {
            centre: (150.25, 149.5),
            side: 100.0,
            bar: 20.0,
            white: 176.0,
            black: 78.0,
        };
        let ground = |x: f64, y: f64| 120.0 + 12.0 * ((x / 7.0).sin() * (y / 11.0).cos());
        cross.render(300, ground, unit(angle), off, 0.55)
    }

    /// A shadow's edge across a faint cross ends arms early or breaks its
    /// quadrants (most first looks fail, and some pass with the centre a
    /// pixel off); with the shadow lifted every one is found where the same
    /// cross without shadow is, within 0.02 px.
    #[test]
    fn a_cross_in_partial_shadow_is_found_on_a_second_look() {
        let detector = CrosshairDetector::new(SizeRange {
            min_px: 30.0,
            max_px: 200.0,
            reach_px: 200.0,
        });
        fn view(data: &[u8]) -> GreyView<'_> {
            GreyView {
                data,
                width: 300,
                height: 300,
                stride: 300,
            }
        }
        let lit = shadowed_cross(0.0, -1e9);
        let truth = detector
            .analyse(&view(&lit), (150.0, 150.0), 100.0, Look::First)
            .expect("the cross in full light")
            .centre;
        // On this sharp (unblurred) render the lit cross is found 0.08 px
        // right of where it is drawn (150.25, 149.5); not traced.
        assert!(geometry::dist(truth, (150.25, 149.5)) < 0.1, "{truth:?}");
        let mut first_failed = 0;
        for angle in [0.5f64, 0.9, 1.3, 2.0, 2.6] {
            for off in [-30.0, -15.0, 0.0, 15.0, 30.0] {
                let data = shadowed_cross(angle, off);
                let img = view(&data);
                first_failed += detector
                    .analyse(&img, (150.0, 150.0), 100.0, Look::First)
                    .is_err() as usize;
                let f = detector
                    .analyse_lifted(&img, (150.0, 150.0), 100.0)
                    .unwrap_or_else(|why| panic!("angle {angle}, offset {off}: {why}"));
                assert!(
                    geometry::dist(f.centre, truth) < 0.02,
                    "angle {angle}, offset {off}: {:?}",
                    f.centre
                );
            }
        }
        assert!(first_failed >= 15, "first looks failed: {first_failed}");
    }

    #[test]
    fn tiles_around_a_checker_end_a_tile_out_where_ground_goes_on() {
        // A 2x2 checker of 30 px quadrants at (160, 160), light where x
        // and y have one sign, amid light (200) and dark (50) grey.
        let checker = |x: f64, y: f64| if (x > 0.0) == (y > 0.0) { 200.0 } else { 50.0 };
        let around = |data: &[u8]| {
            let img = GreyView {
                data,
                width: 320,
                height: 320,
                stride: 320,
            };
            tiles_past(
                &img,
                (160.0, 160.0),
                &[(1.0, 0.0), (0.0, 1.0)],
                &[30.0; 4],
                &[200.0, 50.0, 200.0, 50.0],
            ) == [true; 2]
        };
        // Paving: one ring of tiles past the block, then grey ground.
        let paving = render_image(320, |x, y| {
            let (u, v) = (x - 160.0, y - 160.0);
            if u.abs() >= 60.0 || v.abs() >= 60.0 {
                return 128.0;
            }
            let (i, j) = ((u / 30.0).floor() as i64, (v / 30.0).floor() as i64);
            if (i + j).rem_euclid(2) == 0 {
                200.0
            } else {
                50.0
            }
        });
        assert!(around(&paving));
        // The same levels past the sides, but ground that goes on: light
        // left of the checker, dark right of it.
        let ground = render_image(320, |x, y| {
            let (u, v) = (x - 160.0, y - 160.0);
            if u.abs() < 30.0 && v.abs() < 30.0 {
                checker(u, v)
            } else if u < 0.0 {
                200.0
            } else {
                50.0
            }
        });
        assert!(!around(&ground));
        // That ground ending a tile out, as paving does.
        let ended = render_image(320, |x, y| {
            let (u, v) = (x - 160.0, y - 160.0);
            if u.abs() < 30.0 && v.abs() < 30.0 {
                checker(u, v)
            } else if u.abs() >= 60.0 || v.abs() >= 60.0 {
                128.0
            } else if u < 0.0 {
                200.0
            } else {
                50.0
            }
        });
        assert!(around(&ended));
    }

    #[test]
    fn paving_past_a_corner_runs_the_sides_on_where_ground_does_not() {
        // A 2x2 checker of 30 px quadrants at (160, 160), light (200) where
        // x and y have one sign, dark (50) otherwise, on grey (128) ground.
        let lines = |ground: &dyn Fn(f64, f64) -> f64| {
            let data = render_image(320, |x, y| {
                let (u, v) = (x - 160.0, y - 160.0);
                checker_grey(u, v, 30.0, (200.0, 50.0)).unwrap_or_else(|| ground(u, v))
            });
            let img = GreyView {
                data: &data,
                width: 320,
                height: 320,
                stride: 320,
            };
            side_lines_run_on(
                &img,
                (160.0, 160.0),
                &[(1.0, 0.0), (0.0, 1.0)],
                &[30.0; 4],
                &[200.0, 50.0, 200.0, 50.0],
            )
        };
        // Paving seen only past one corner (its three tiles there; the rest
        // hidden under an object of the ground's grey): both side lines
        // through that corner run on.
        let corner = |u: f64, v: f64| {
            if (0.0..60.0).contains(&u) && (0.0..60.0).contains(&v) {
                let (i, j) = ((u / 30.0).floor() as i64, (v / 30.0).floor() as i64);
                if (i + j) % 2 == 0 {
                    200.0
                } else {
                    50.0
                }
            } else {
                128.0
            }
        };
        assert_eq!(lines(&corner), 2);
        // Plain ground, and ground stepping along a side line between
        // levels unlike the quadrants', do not.
        assert_eq!(lines(&|_, _| 128.0), 0);
        assert_eq!(lines(&|u, _| if u < 30.0 { 100.0 } else { 160.0 }), 0);
        // Ground of the quadrants' levels stepping along a side line past
        // a corner, in a band `half` px wide on each side of the line.
        let step = |half: f64| {
            move |u: f64, v: f64| {
                if v <= 30.0 || (u - 30.0).abs() >= half {
                    128.0
                } else if u < 30.0 {
                    50.0
                } else {
                    200.0
                }
            }
        };
        // A band a fifth of the arm wide (a pattern of texture there by
        // chance) does not count: it must hold two fifths out.
        assert_eq!(lines(&step(8.0)), 0);
        // The same step held a whole tile wide does (a tile boundary).
        assert_eq!(lines(&step(30.0)), 1);
    }
}
