//! Printed targets without a code, found from their [`TargetDesign`]:
//!
//! 1. **Candidates** from invariant geometry: centres where a ring of
//!    samples shows four-fold (cross) or two-fold (checker) symmetry, on an
//!    image pyramid ([`harmonic`]).
//! 2. **Fit**: the two lines through the centre (a cross's bar centre lines,
//!    a checker's quadrant boundaries) are followed outward along all four
//!    arms to the board's sides and fitted as straight lines, points beside a
//!    marking left out ([`walk`]). The centre is their intersection, which
//!    perspective does not move off the target's centre (lines stay lines).
//! 3. **Verify once**: the design drawn under that fit is compared with the
//!    image on the design's non-free area ([`verify`]); the correlation is
//!    the detection's confidence.
//!
//! Every threshold is a field of [`Params`].

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};

use opencv::core::Mat;
use opencv::prelude::*;

use super::design::{DesignKind, FreeArea, Polarity, TargetDesign};
use super::fiducial::grey_view;
use super::found::{one_per_board, to_detection, Found};
use super::geometry::{self, Pt};
use super::harmonic::{self, Candidate, RingBasis, Symmetry};
use super::modelfit::{fit_checker, fit_cross, FitParams, Lines, MAX_RESIDUAL_SHARE};
use super::profile::{self as pr, add, unit};
use super::refine::{intersect, GreyView};
use super::{DetectError, Detection, Detector, MarkerType, SizeRange};

#[cfg(test)]
mod tests;
mod verify;
mod walk;

use verify::{verify, Fit, Verdict};
use walk::{continuation, follow, Arm, Feature};

/// Thresholds of the printed-target detector, checked on generated frames
/// (`tools/src/bin/printed_misses.rs`, `DESIGN=cross,checker`) and on the real
/// photos of the README. `max_repeat_score`, `min_score`,
/// `max_arm_offset_px`, `max_width_spread` and `max_fit_rms_px` were
/// chosen on generated frames (targets against look-alikes: true targets
/// fit to 0.32 px, bars spread 0.17 at most; stripes' and paving's fits
/// 0.8 px and more, 0.58). `min_salience` and `min_light_ratio` sit below
/// the weakest generated targets (12.1 and 1.96 on seeds 300, 3100, 3200).
/// `max_fit_rms_share` (cloth targets' bent bars, 0.57 px at 168 px
/// there), `min_checker_px` and the 32 px floor were set while reading the
/// real photos (foliage taken for checkers measures 29 to 45 px), so they
/// are the first to re-check on other photos.
#[derive(Debug, Clone, PartialEq)]
pub struct Params {
    /// Smallest normalised correlation of the drawn design with the image.
    pub min_score: f64,
    /// Least ratio of the light parts' mean grey to the dark parts': a
    /// print's inks differ in reflectance by 5 to 15 times, which the
    /// camera's gamma and haze bring down to 2 and more (the generator's
    /// weakest prints: 1.96), while blobs of foliage and sand ripples
    /// differ by 1.2 to 1.8.
    pub min_light_ratio: f64,
    /// Smallest checker accepted, as measured, whatever the job's least
    /// size: its quadrants, half the side, are told from blobs of foliage
    /// only from about 20 px (a cross's long bars are told from 32 px).
    pub min_checker_px: f64,
    /// Fewest grey levels between the design's light and dark parts.
    pub min_contrast: f64,
    /// Least ratio of the target's contrast to the ground's texture around
    /// it (see `verify::ground_texture`).
    pub min_salience: f64,
    /// A profile's side is the board when it differs from the bar (or the
    /// other side of a step) by this share of the target's contrast.
    pub side_share: f64,
    /// Bar widths measured on a profile, relative to the expected width,
    /// that give a centre-line point.
    pub width_band: (f64, f64),
    /// Points where a cross's bar measures wider than its own width (the
    /// narrower quarter of its widths) by more than this share, plus half
    /// a pixel, lie beside a marking that touches the bar: left out.
    pub max_widening: f64,
    /// Share of an arm's on-board profiles that must give a point.
    pub min_coverage: f64,
    /// Largest RMS distance, in pixels, of the points from their line...
    pub max_fit_rms_px: f64,
    /// ...or this share of the board's side, whichever is larger (a large
    /// cloth target's bars bend by more pixels).
    pub max_fit_rms_share: f64,
    /// Largest distance, in pixels, between two opposite arms' median
    /// offsets from their common line (see `arms_offset`).
    pub max_arm_offset_px: f64,
    /// Largest spread of a bar's measured widths (10th to 90th
    /// percentile) over their median.
    pub max_width_spread: f64,
    /// Largest ratio of two opposite arms' lengths (perspective, a side
    /// partly hidden).
    pub max_arm_ratio: f64,
    /// Largest ratio of two opposite arms' lengths when the longer one is
    /// cut back to where its bar was last seen (see `even_out`): a bar's
    /// end is measured to a step, so the two differ by perspective only.
    pub max_cut_arm_ratio: f64,
    /// Largest correlation the design may reach again about one board
    /// away (see `repeats`): a lattice's next copy, partly hidden or at
    /// the lattice's edge, still reaches well over it.
    pub max_repeat_score: f64,
    /// Measured sizes may fall this factor outside the searched range.
    pub size_slack: f64,
    /// Share of the profiles past an arm's end showing the feature again
    /// (see `walk::continuation`) from which that arm runs on.
    pub max_continuation: f64,
    /// Farthest the whole-target fit (see `modelfit`) may move the centre
    /// found from the lines, pixels: farther, it has fitted something else.
    pub max_refit_move_px: f64,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            min_score: 0.75,
            min_light_ratio: 1.8,
            min_checker_px: 40.0,
            min_contrast: 15.0,
            min_salience: 10.0,
            side_share: 0.4,
            width_band: (0.6, 1.5),
            max_widening: 0.15,
            min_coverage: 0.35,
            max_fit_rms_px: 0.75,
            max_fit_rms_share: 0.005,
            max_arm_offset_px: 1.0,
            max_width_spread: 0.4,
            max_arm_ratio: 1.6,
            max_cut_arm_ratio: 1.15,
            size_slack: 1.1,
            max_repeat_score: 0.6,
            max_continuation: 0.4,
            max_refit_move_px: 1.0,
        }
    }
}

/// Why a candidate is not a target of the design.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rejection {
    /// The ring around the candidate leaves the tile.
    AtTileEdge,
    /// The ring shows too little contrast for the design.
    LowContrast,
    /// An arm gave too few points on its line.
    ArmUnclear,
    /// An arm did not end within reach (the structure runs on).
    RunsOn,
    /// A line fit failed or its points scatter.
    LineFit,
    /// A bar's width changes along it (paving's squares meeting at their
    /// corners), where a printed bar's does not.
    UnevenBar,
    /// Opposite arms lie on two parallel lines, not one.
    ArmsOffset,
    /// Opposite arms differ more than perspective explains.
    UnevenArms,
    /// Bar width or board size outside the design's or search's range.
    Proportions,
    /// The drawn design does not match the image.
    NoMatch,
    /// The light parts are too little brighter than the dark ones for
    /// two inks (see `Params::min_light_ratio`).
    NotInk,
    /// The pattern is no stronger than the ground's texture around it.
    Texture,
    /// The design repeats one board away: a lattice, not a target.
    Repeats,
    /// The bars or boundaries run on past the board on two or more arms:
    /// a lattice or paving, not a target.
    RunsPastBoard,
    /// A checker whose board's corners or sides' middles are saddles
    /// too: a corner of paving, not a 2x2 target.
    Paving,
    /// A cross with a crossing of its own two levels where an arm ends or
    /// at a board corner: a node of a lattice, not a target.
    Lattice,
}

/// Detector of the designs of one kind family (crosses and checkers).
pub struct PrintedDetector {
    marker_type: MarkerType,
    designs: Vec<TargetDesign>,
    sizes: SizeRange,
    params: Params,
    basis: RingBasis,
}

/// Smallest printed target searched for, whatever the job's least size: a
/// design without a code is told from the ground by its shape alone, and
/// under this size a checker's quadrants (16 px) are the size of the blobs
/// of foliage, gravel and sand ripples, which match it as well as a print.
pub const MIN_PRINTED_PX: f64 = 32.0;

/// Ring samples for a candidate's orientation and levels.
const RING_SAMPLES: usize = 64;

impl PrintedDetector {
    /// A detector of `designs`' crosses and checkers (others are ignored).
    pub fn new(marker_type: MarkerType, designs: Vec<TargetDesign>, mut sizes: SizeRange) -> Self {
        sizes.min_px = sizes.min_px.max(MIN_PRINTED_PX);
        PrintedDetector {
            marker_type,
            designs: designs
                .into_iter()
                .filter(|d| matches!(d.kind, DesignKind::Cross | DesignKind::Checker))
                .collect(),
            sizes,
            params: Params::default(),
            basis: RingBasis::new(RING_SAMPLES),
        }
    }

    /// The same detector with other thresholds.
    pub fn with_params(self, params: Params) -> Self {
        PrintedDetector { params, ..self }
    }

    /// The designs a candidate of this symmetry may be.
    fn designs_for(&self, s: Symmetry) -> impl Iterator<Item = &TargetDesign> {
        self.designs.iter().filter(move |d| {
            matches!(
                (d.kind, s),
                (DesignKind::Cross, Symmetry::Cross) | (DesignKind::Checker, Symmetry::Checker)
            )
        })
    }

    /// Fits and verifies `design` at candidate `c`.
    fn analyse(
        &self,
        img: &GreyView,
        c: &Candidate,
        design: &TargetDesign,
        seams: [bool; 4],
    ) -> Result<Found, Rejection> {
        let p = &self.params;
        let r = (harmonic::RING_TO_SIZE * c.size).max(3.0);
        let ring = pr::ring(img, c.centre, r, &self.basis).ok_or(Rejection::AtTileEdge)?;
        let (lo, hi) = ring
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(*v), b.max(*v)));
        if hi - lo < p.min_contrast {
            return Err(Rejection::LowContrast);
        }
        // The arms are followed in log grey, where a shadow across the
        // target changes no difference.
        let mut contrast = harmonic::log_grey(hi) - harmonic::log_grey(lo);
        let (k, sign) = match design.kind {
            DesignKind::Cross => (
                4,
                if design.polarity == Polarity::LightOnDark {
                    1.0
                } else {
                    -1.0
                },
            ),
            // A checker (the detector holds crosses and checkers only).
            _ => (2, 1.0),
        };
        let signed: Vec<f64> = ring.iter().map(|v| sign * v).collect();
        // Harmonic k peaks on the bars (cross) or the light quadrants'
        // middles (checker, whose boundaries lie 45 degrees from them).
        let mut a0 = self.basis.phase(k, &signed) / k as f64;
        if design.kind == DesignKind::Checker {
            a0 += FRAC_PI_4;
        }
        let mut dirs = [unit(a0), unit(a0 + FRAC_PI_2)];
        let width0 = match design.kind {
            DesignKind::Cross => bar_width_on_ring(&ring, sign, r, a0),
            // A checker (the detector holds crosses and checkers only).
            _ => (0.08 * c.size).max(2.5),
        };
        let mut centre = c.centre;
        let mut width = width0;
        // Two passes: the first near the centre from the candidate's
        // guesses, the second along the whole arms from the first's lines.
        let mut arms: [Arm; 4] = Default::default();
        let mut lines = [(centre, dirs[0]); 2];
        let mut rms = [0.0; 2];
        // Each line's bar widths as measured, markings' included.
        let mut measured: [Vec<f64>; 2] = Default::default();
        for pass in 0..2 {
            let limit = if pass == 0 {
                0.35 * c.size
            } else {
                1.1 * c.size
            };
            let start = match design.kind {
                DesignKind::Cross => 0.5 * width + 2.5,
                // A checker (the detector holds crosses and checkers only).
                _ => width + 1.5,
            };
            // The first pass only finds the lines near the centre; the
            // second's points make the fit, at the finer spacing.
            let step = if pass == 0 {
                (limit / 40.0).max(0.75)
            } else {
                (limit / 60.0).max(0.5)
            };
            // Each line is judged as soon as its two arms are followed: most
            // candidates (ground texture) fail on the first line.
            for i in [0, 2, 1, 3] {
                let arm = &mut arms[i];
                let d = arm_dir(&dirs, i);
                let feature = match design.kind {
                    DesignKind::Cross => Feature::Bar { sign },
                    // Boundary i's +normal side is quadrant (i, i+1): light
                    // on arms 0 and 2 when quadrant (+,+) is light.
                    // A checker (the detector holds crosses and checkers only).
                    _ => Feature::Step {
                        sign: checker_side(img, centre, &dirs, i, width)
                            .ok_or(Rejection::ArmUnclear)?,
                    },
                };
                *arm = follow(
                    img,
                    feature,
                    centre,
                    d,
                    width,
                    contrast,
                    (start, limit, step),
                    p,
                );
                if pass == 1 && arm.unended {
                    return Err(Rejection::RunsOn);
                }
                // A board cut by a tile seam is seen whole from the tile
                // past it; one cut by the frame's edge is measured as seen.
                if pass == 1
                    && arm.left_tile
                    && crosses_seam(img, add(centre, d, arm.length + 2.0 * width), seams)
                {
                    return Err(Rejection::AtTileEdge);
                }
                // A marking may run beside a whole arm (a free quadrant's
                // triangle on a bar): each line is judged on both its arms.
                if i >= 2 {
                    let l = i - 2;
                    let (a, b) = (&arms[l], &arms[l + 2]);
                    let points = (a.points.len() + b.points.len()) as f64;
                    let wanted = (p.min_coverage * (a.profiles + b.profiles) as f64).max(6.0);
                    if points < wanted {
                        return Err(Rejection::ArmUnclear);
                    }
                    // The second pass follows the arms to their ends:
                    // opposite arms differ by perspective only.
                    if pass == 1 && design.kind == DesignKind::Cross {
                        even_out(&mut arms, l, p.max_arm_ratio, p.max_cut_arm_ratio);
                    }
                    let (a, b) = (arms[l].length, arms[l + 2].length);
                    if pass == 1 && a.max(b) > p.max_arm_ratio * a.min(b) {
                        return Err(Rejection::UnevenArms);
                    }
                }
            }
            // A marking touching a bar along its side widens it there, and
            // moves those points' middles by half the widening: they are
            // left out. The narrower quarter of a line's widths (its two
            // arms; a marking lies in one quadrant, beside one arm of each
            // line) is the bar's own width.
            if design.kind == DesignKind::Cross {
                for (l, widths) in measured.iter_mut().enumerate() {
                    *widths = on_line(&arms, l, |a| &a.widths);
                    let own = pr::quantile(widths, 0.25);
                    let most = own * (1.0 + p.max_widening) + 0.5;
                    for arm in [l, l + 2] {
                        let arm = &mut arms[arm];
                        let keep: Vec<bool> = arm.widths.iter().map(|w| *w <= most).collect();
                        let mut k = keep.iter();
                        arm.points
                            .retain(|_| *k.next().expect("one width per point"));
                        let mut k = keep.iter();
                        arm.widths
                            .retain(|_| *k.next().expect("one width per point"));
                    }
                }
            }
            for (l, line) in lines.iter_mut().enumerate() {
                let (fitted, inliers) =
                    pr::robust_line(&on_line(&arms, l, |a| &a.points)).ok_or(Rejection::LineFit)?;
                rms[l] = pr::line_rms(&inliers, fitted);
                if pass == 1 && rms[l] > p.max_fit_rms_px.max(p.max_fit_rms_share * c.size) {
                    return Err(Rejection::LineFit);
                }
                // A checker's boundary is one edge through the centre, not
                // two parallel ones (a stripe's sides, two stripes
                // crossing). A cross's points are already its bar's
                // middles, and taped bars may sit a little apart.
                if pass == 1
                    && design.kind == DesignKind::Checker
                    && arms_offset(&arms[l], &arms[l + 2], fitted) > p.max_arm_offset_px
                {
                    return Err(Rejection::ArmsOffset);
                }
                *line = fitted;
            }
            centre = intersect(lines[0], lines[1]).ok_or(Rejection::LineFit)?;
            if geometry::dist(centre, c.centre) > 0.3 * c.size {
                return Err(Rejection::LineFit);
            }
            dirs = [orient(lines[0].1, dirs[0]), orient(lines[1].1, dirs[1])];
            if design.kind == DesignKind::Cross {
                let all: Vec<f64> = arms.iter().flat_map(|a| a.widths.iter().copied()).collect();
                width = pr::quantile(&all, 0.5);
            }
            // The ring's range mixes shadow and ground in; the profiles
            // near the centre measure the design's own contrast.
            let seen: Vec<f64> = arms
                .iter()
                .flat_map(|a| a.contrasts.iter().copied())
                .collect();
            if !seen.is_empty() {
                contrast = pr::quantile(&seen, 0.5);
            }
        }
        let lengths = [0, 1, 2, 3].map(|i| arms[i].length);
        // A printed bar has one width along its length (perspective
        // changes it by a few percent); a chain of paving's squares
        // touching at their corners, taken for a bar, widens and narrows
        // (judged on every width measured: a marking beside a bar widens
        // it by less).
        if design.kind == DesignKind::Cross {
            for w in &measured {
                if w.len() >= 5 {
                    let spread =
                        (pr::quantile(w, 0.9) - pr::quantile(w, 0.1)) / pr::quantile(w, 0.5);
                    if spread > p.max_width_spread {
                        return Err(Rejection::UnevenBar);
                    }
                }
            }
        }
        let bar = match design.kind {
            DesignKind::Cross => [0, 1].map(|l| {
                let w = on_line(&arms, l, |a| &a.widths);
                if w.is_empty() {
                    width
                } else {
                    pr::quantile(&w, 0.5)
                }
            }),
            // A checker (the detector holds crosses and checkers only).
            _ => [0.0; 2],
        };
        let fit = Fit {
            centre,
            dirs,
            lengths,
            bar,
        };
        let size = fit.size();
        let slack = p.size_slack;
        if size < self.sizes.min_px / slack
            || size > self.sizes.max_px * slack
            || (design.kind == DesignKind::Checker && size < p.min_checker_px)
        {
            return Err(Rejection::Proportions);
        }
        if let Some(range) = design.bar_width {
            // Blur widens the narrowest bars' profiles a little: 20% slack
            // above, 5% below for the measurement's own error.
            let ratio = 0.5 * (bar[0] + bar[1]) / size;
            if ratio < range.0 / 1.05 || ratio > range.1 * 1.2 {
                return Err(Rejection::Proportions);
            }
        }
        // A target's structure ends at its board's sides; a lattice's or
        // paving's runs on past them. A frame's or tile's edge within reach
        // leaves that arm untold.
        let feature = match design.kind {
            DesignKind::Cross => Feature::Bar { sign },
            // A checker (the detector holds crosses and checkers only).
            _ => Feature::Step { sign: 1.0 },
        };
        let running = (0..4)
            .filter(|&i| {
                let l = lengths[i];
                let from = l + 1.5 * bar[0].max(bar[1]).max(width) + 2.0;
                let to = 1.6 * l;
                to > from
                    && continuation(
                        img,
                        feature,
                        centre,
                        arm_dir(&dirs, i),
                        width,
                        contrast,
                        (from, to, (l / 30.0).max(0.75)),
                        p,
                    )
                    .is_some_and(|share| share >= p.max_continuation)
            })
            .count();
        if running >= 2 {
            return Err(Rejection::RunsPastBoard);
        }
        let verdict = verify(img, design, &fit).ok_or(Rejection::AtTileEdge)?;
        if verdict.contrast < p.min_contrast || verdict.score < p.min_score {
            return Err(Rejection::NoMatch);
        }
        if verdict.levels.0 + 1.0 < p.min_light_ratio * (verdict.levels.1 + 1.0) {
            return Err(Rejection::NotInk);
        }
        if verdict.salience < p.min_salience {
            return Err(Rejection::Texture);
        }
        if design.kind == DesignKind::Checker
            && paving_around(img, &fit, p.side_share * contrast, 0.3 * contrast)
        {
            return Err(Rejection::Paving);
        }
        if design.kind == DesignKind::Cross && lattice_around(img, &fit, &verdict, sign, p) {
            return Err(Rejection::Lattice);
        }
        if repeats(img, design, &fit, &verdict, p) {
            return Err(Rejection::Repeats);
        }
        // The centre placed by the whole drawn target (see `modelfit`),
        // when that explains the pixels and stays near the lines' crossing.
        let lines = Lines {
            centre,
            dirs,
            lengths,
            bar,
        };
        let refitted = match design.kind {
            DesignKind::Cross => fit_cross(
                img,
                &lines,
                sign > 0.0,
                verdict.levels,
                &FitParams::default(),
            ),
            // A checker (the detector holds crosses and checkers only).
            _ => fit_checker(img, &lines, &FitParams::default()),
        }
        .filter(|f| {
            f.residual <= MAX_RESIDUAL_SHARE * f.contrast
                && geometry::dist(f.centre, centre) <= p.max_refit_move_px
        });
        let (centre, fit) = match &refitted {
            Some(f) => (
                f.centre,
                Fit {
                    centre: f.centre,
                    dirs: f.dirs,
                    ..fit
                },
            ),
            None => (centre, fit),
        };
        tracing::debug!(
            x = centre.0,
            y = centre.1,
            size,
            design = %design.name,
            score = verdict.score,
            contrast = verdict.contrast,
            salience = verdict.salience,
            light = verdict.levels.0,
            dark = verdict.levels.1,
            refitted = refitted.is_some(),
            blur = refitted.map(|f| f.blur_px),
            "printed candidate accepted"
        );
        Ok(Found {
            centre,
            corners: fit.corners(),
            size,
            shift: geometry::dist(centre, c.centre),
            rms: (0.5 * (rms[0] * rms[0] + rms[1] * rms[1])).sqrt(),
            confidence: verdict.score.clamp(0.0, 1.0),
        })
    }
}

/// Whether the design, verified under `fit`, matches again about one board
/// further along either line: a target is one instance of its design on
/// the ground, while paving, a panel grid or any lattice repeats it at its
/// own pitch. The pitch is searched from [`REPEAT_PITCH`] of the board's
/// side, since an arm of a lattice ends at the next line's near edge.
fn repeats(img: &GreyView, design: &TargetDesign, fit: &Fit, own: &Verdict, p: &Params) -> bool {
    let tol = REPEAT_LEVELS * own.contrast;
    let alike = |v: &Verdict| {
        v.score >= p.max_repeat_score
            && (v.levels.0 - own.levels.0).abs() <= tol
            && (v.levels.1 - own.levels.1).abs() <= tol
    };
    for k in 0..2 {
        let board = fit.lengths[k] + fit.lengths[k + 2];
        let step = (board / 40.0).max(0.75);
        for sense in [-1.0, 1.0] {
            let mut t = REPEAT_PITCH.0 * board;
            while t <= REPEAT_PITCH.1 * board {
                let mut shifted = *fit;
                shifted.centre = add(fit.centre, fit.dirs[k], sense * t);
                if verify(img, design, &shifted).is_some_and(|v| alike(&v)) {
                    return true;
                }
                t += step;
            }
        }
    }
    false
}

/// Whether a saddle like the checker's own lies at any of the board's four
/// corners or its sides' middles: paving's tiles meet there, while a 2x2
/// checker's quadrants meet the ground (one or two quadrants and the ground
/// around each, never two pairs alternating). A saddle counts when its
/// light and dark pairs are the checker's own two levels (within `tol` in
/// log grey) and apart by `need`: paving repeats its two colours, while a
/// shadow's edge over the ground beside a side makes other levels.
fn paving_around(img: &GreyView, fit: &Fit, need: f64, tol: f64) -> bool {
    let Some(own) = saddle_levels(img, fit, (0.0, 0.0)) else {
        return false;
    };
    let around = [
        (1.0, 0.0),
        (0.0, 1.0),
        (-1.0, 0.0),
        (0.0, -1.0),
        (1.0, 1.0),
        (-1.0, 1.0),
        (-1.0, -1.0),
        (1.0, -1.0),
    ];
    around.iter().any(|&at| {
        saddle_levels(img, fit, at).is_some_and(|(light, dark)| {
            light.0.min(light.1) - dark.0.max(dark.1) >= need
                && [light.0, light.1].iter().all(|l| {
                    (l - own.0 .0.max(own.0 .1)).abs() <= tol
                        || (l - own.0 .0.min(own.0 .1)).abs() <= tol
                })
                && [dark.0, dark.1].iter().all(|d| {
                    (d - own.1 .0.max(own.1 .1)).abs() <= tol
                        || (d - own.1 .0.min(own.1 .1)).abs() <= tol
                })
        })
    })
}

/// The four patches a quarter side around design point (u, v) of `fit`, in
/// log grey, as the lighter diagonal pair and the darker one.
type Pair = (f64, f64);
fn saddle_levels(img: &GreyView, fit: &Fit, (u, v): (f64, f64)) -> Option<(Pair, Pair)> {
    const PATCH: [f64; 3] = [-0.08, 0.0, 0.08];
    let mut q = [0.0f64; 4];
    for (k, (su, sv)) in [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)]
        .iter()
        .enumerate()
    {
        let (cu, cv) = (u + 0.25 * su, v + 0.25 * sv);
        let mut sum = 0.0;
        for du in PATCH {
            for dv in PATCH {
                let p = fit.at(cu + du, cv + dv);
                sum += img.sample(p.0, p.1)?;
            }
        }
        q[k] = harmonic::log_grey(sum / 9.0);
    }
    let (a, b) = ((q[0], q[2]), (q[1], q[3]));
    Some(if a.0 + a.1 >= b.0 + b.1 {
        (a, b)
    } else {
        (b, a)
    })
}

/// Whether a crossing like the cross's own lies where an arm ends (past
/// the next line's near edge, at its middle) or at a board corner: a
/// lattice's lines cross there, while a target's bars end at the board's
/// side with the ground past it. A crossing counts when its bars and the
/// patches between them are the target's own two levels within
/// [`REPEAT_LEVELS`] of its contrast, the bars lighter (for `sign` +1) by
/// `side_share` of it.
fn lattice_around(img: &GreyView, fit: &Fit, own: &Verdict, sign: f64, p: &Params) -> bool {
    let (bar_level, board_level) = if sign > 0.0 {
        own.levels
    } else {
        (own.levels.1, own.levels.0)
    };
    let tol = REPEAT_LEVELS * own.contrast;
    let need = p.side_share * own.contrast;
    // The next lines' middles, in design units past each arm's end.
    let past = |k: usize| 1.0 + 0.5 * fit.bar[1 - k % 2] / fit.lengths[k].max(1.0);
    let (pu, nu, pv, nv) = (past(0), -past(2), past(1), -past(3));
    let nodes = [
        (pu, 0.0),
        (0.0, pv),
        (nu, 0.0),
        (0.0, nv),
        (pu, pv),
        (nu, pv),
        (nu, nv),
        (pu, nv),
    ];
    let mean = |pts: &[(f64, f64)]| -> Option<f64> {
        let mut sum = 0.0;
        for &(u, v) in pts {
            let q = fit.at(u, v);
            sum += img.sample(q.0, q.1)?;
        }
        Some(sum / pts.len() as f64)
    };
    nodes.iter().any(|&(u, v)| {
        let crossing = || -> Option<bool> {
            let (a, b) = (0.3, 0.2);
            let bars = [
                mean(&[(u + b, v), (u + a, v)])?,
                mean(&[(u - b, v), (u - a, v)])?,
                mean(&[(u, v + b), (u, v + a)])?,
                mean(&[(u, v - b), (u, v - a)])?,
            ];
            let quads = [
                mean(&[(u + a, v + a)])?,
                mean(&[(u - a, v + a)])?,
                mean(&[(u - a, v - a)])?,
                mean(&[(u + a, v - a)])?,
            ];
            let signed = |x: f64| sign * x;
            let bar_min = bars.iter().map(|&x| signed(x)).fold(f64::MAX, f64::min);
            let quad_max = quads.iter().map(|&x| signed(x)).fold(f64::MIN, f64::max);
            Some(
                bar_min - quad_max >= need
                    && bars.iter().all(|x| (x - bar_level).abs() <= tol)
                    && quads.iter().all(|x| (x - board_level).abs() <= tol),
            )
        };
        crossing() == Some(true)
    })
}

/// A copy one board away counts when its light and dark levels are the
/// target's own within this share of its contrast: a lattice or paving
/// repeats its colours, while other paving beside a target has its own.
const REPEAT_LEVELS: f64 = 0.3;

/// Pitches, in board sides, at which a lattice's next copy of the design
/// is looked for.
const REPEAT_PITCH: (f64, f64) = (0.95, 1.3);

/// Whether `p`, a point on or past the tile's edge, lies beyond a side that
/// is a seam with another tile (left, top, right, bottom).
fn crosses_seam(img: &GreyView, p: Pt, seams: [bool; 4]) -> bool {
    let (w, h) = ((img.width - 1) as f64, (img.height - 1) as f64);
    (seams[0] && p.0 <= 0.0)
        || (seams[1] && p.1 <= 0.0)
        || (seams[2] && p.0 >= w)
        || (seams[3] && p.1 >= h)
}

/// Distance between the median signed offsets of arms `a` and `b` (opposite
/// arms) from their common fitted `line`: near zero when both follow one
/// line through the centre, a bar width for a stripe's two sides.
fn arms_offset(a: &Arm, b: &Arm, line: (Pt, Pt)) -> f64 {
    let ((px, py), (dx, dy)) = line;
    let median = |arm: &Arm| {
        let r: Vec<f64> = arm
            .points
            .iter()
            .map(|&(x, y)| (x - px) * dy - (y - py) * dx)
            .collect();
        (!r.is_empty()).then(|| pr::quantile(&r, 0.5))
    };
    match (median(a), median(b)) {
        (Some(ma), Some(mb)) => (ma - mb).abs(),
        _ => 0.0,
    }
}

/// Opposite arms `l` and `l + 2` of a cross's bar whose lengths differ
/// more than `max_ratio`: the longer one ends where its bar was last seen,
/// when that evens them out. Past a bar's end one side of the profile may
/// stay at board level (a shadow's edge, dark ground against one side),
/// which keeps the walk on the "board" with no bar in it.
fn even_out(arms: &mut [Arm; 4], l: usize, max_ratio: f64, max_cut_ratio: f64) {
    let (a, b) = (arms[l].length, arms[l + 2].length);
    if a.max(b) <= max_ratio * a.min(b) {
        return;
    }
    let (long, short) = if a > b { (l, l + 2) } else { (l + 2, l) };
    if let Some(end) = arms[long].bar_end {
        let s = arms[short].length;
        if end < arms[long].length && end.max(s) <= max_cut_ratio * end.min(s) {
            arms[long].length = end;
        }
    }
}

/// What arms `l` and `l + 2` (one line) measured, together.
fn on_line<T: Copy>(arms: &[Arm; 4], l: usize, of: impl Fn(&Arm) -> &Vec<T>) -> Vec<T> {
    of(&arms[l])
        .iter()
        .chain(of(&arms[l + 2]))
        .copied()
        .collect()
}

/// Direction of arm `i` (0..4): the two lines' directions and their opposites.
fn arm_dir(dirs: &[Pt; 2], i: usize) -> Pt {
    let d = dirs[i % 2];
    if i >= 2 {
        (-d.0, -d.1)
    } else {
        d
    }
}

/// `d` or its opposite, whichever points along `like`.
fn orient(d: Pt, like: Pt) -> Pt {
    if d.0 * like.0 + d.1 * like.1 >= 0.0 {
        d
    } else {
        (-d.0, -d.1)
    }
}

/// A cross's bar width from its four light arcs on a ring of radius `r`
/// (`ring` as sampled, `sign` +1 for light bars), the bars' directions at
/// `a0` and every quarter turn from it. Each arc is cut at the level
/// halfway between its own peak and the board beside it, in log grey, so a
/// shadow over part of the ring moves no cut; an arc of angle a is a chord
/// of 2 r sin(a/2), the bar's width. The median of the four, since a
/// marking beside a bar widens its arc.
fn bar_width_on_ring(ring: &[f64], sign: f64, r: f64, a0: f64) -> f64 {
    let n = ring.len() as isize;
    let l: Vec<f64> = ring.iter().map(|v| sign * harmonic::log_grey(*v)).collect();
    let at = |i: isize| l[i.rem_euclid(n) as usize];
    let mut widths: Vec<f64> = (0..4)
        .map(|k| {
            let c =
                ((a0 + k as f64 * FRAC_PI_2) / std::f64::consts::TAU * n as f64).round() as isize;
            let near = n / 16;
            let peak_i = (c - near..=c + near)
                .max_by(|a, b| at(*a).total_cmp(&at(*b)))
                .expect("non-empty");
            let low = (c - n / 8..=c + n / 8).map(at).fold(f64::MAX, f64::min);
            let mid = 0.5 * (at(peak_i) + low);
            // Samples above the cut on each side of the peak, the last
            // step interpolated to the crossing.
            let reach = |dir: isize| {
                let mut i = peak_i;
                let mut run = 0.0;
                while (i - peak_i).abs() < n / 4 {
                    let next = at(i + dir);
                    if next <= mid {
                        run += (at(i) - mid) / (at(i) - next).max(1e-9);
                        break;
                    }
                    run += 1.0;
                    i += dir;
                }
                run
            };
            let arc = (reach(-1) + reach(1)) * std::f64::consts::TAU / n as f64;
            2.0 * r * (0.5 * arc.min(0.9 * std::f64::consts::PI)).sin()
        })
        .collect();
    widths.sort_by(f64::total_cmp);
    (0.5 * (widths[1] + widths[2])).max(2.0)
}

/// Checker boundary `i`'s polarity: +1 when its +normal side is the
/// lighter quadrant, from samples in the two quadrants beside it a few
/// widths out.
fn checker_side(img: &GreyView, c: Pt, dirs: &[Pt; 2], i: usize, width: f64) -> Option<f64> {
    let a = arm_dir(dirs, i);
    let t = 3.0 * width;
    let n = pr::perp(a);
    let q = |s: f64| img.sample(c.0 + a.0 * t + n.0 * s, c.1 + a.1 * t + n.1 * s);
    let (plus, minus) = (q(width)?, q(-width)?);
    Some(if plus > minus { 1.0 } else { -1.0 })
}

impl Detector for PrintedDetector {
    fn marker_type(&self) -> MarkerType {
        self.marker_type
    }

    fn detect(
        &mut self,
        tile: &Mat,
        origin: (usize, usize),
        seams: [bool; 4],
    ) -> Result<Vec<Detection>, DetectError> {
        let err = DetectError::at(origin);
        let free = if self.designs.iter().any(|d| d.free == FreeArea::Quadrants) {
            harmonic::Quadrants::Free
        } else {
            harmonic::Quadrants::Plain
        };
        let candidates = harmonic::candidates(tile, self.sizes, free).map_err(err)?;
        let img = grey_view(tile).map_err(err)?;
        let mut found: Vec<Found> = Vec::new();
        for c in &candidates {
            // A candidate on a target already found (another pyramid level's
            // response to it) is not analysed again.
            if found
                .iter()
                .any(|f| geometry::dist(f.centre, c.centre) < 0.25 * f.size)
            {
                continue;
            }
            for design in self.designs_for(c.symmetry) {
                match self.analyse(&img, c, design, seams) {
                    Ok(f) => {
                        found.push(f);
                        break;
                    }
                    Err(why) => tracing::trace!(
                        x = c.centre.0 + origin.0 as f64,
                        y = c.centre.1 + origin.1 as f64,
                        size = c.size,
                        design = %design.name,
                        ?why,
                        "printed candidate rejected"
                    ),
                }
            }
        }
        let (w, h) = (tile.cols() as f64, tile.rows() as f64);
        Ok(one_per_board(&mut found)
            .into_iter()
            .map(|f| to_detection(self.marker_type, f, origin, w, h, seams))
            .collect())
    }
}
