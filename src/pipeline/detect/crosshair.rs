//! Printed crosshair targets: a white cross on a black square, and the 2x2
//! checker ("X" / diagonal target).
//!
//! 1. Candidates: dark quadrants from [`blobs`] (a checker's two dark
//!    quadrants may merge at the centre; a cross has four). The centroid of
//!    every blob and the midpoint of every pair of similar blobs placed like
//!    diagonal quadrants is a candidate centre.
//! 2. A ring of samples at two radii classifies the candidate: four narrow
//!    bright arcs (cross bars) or four alternating quadrants (checker), and
//!    gives the four arm directions.
//! 3. Each arm is measured outward until its structure ends; a structure that
//!    runs on (panel grids, paving, road markings) is rejected.
//! 4. Subpixel centre: the two cross bars' centre lines (midpoints of both
//!    bar edges on profiles across the bar, every half pixel along both arms
//!    of each bar) or the checker's two quadrant boundaries (edge crossings
//!    along their whole length) are fitted as straight lines; the centre is
//!    their intersection: the saddle point of a checker, the bars' crossing
//!    for a cross, exact under perspective since lines stay lines.

use std::f64::consts::{PI, TAU};

use opencv::core::Mat;
use opencv::prelude::*;

use super::blobs::{self, Blob};
use super::fiducial::grey_view;
use super::found::{best_per_target, to_detection, Found};
use super::geometry::{self, Pt};
use super::profile::{self as pr, add, perp, unit};
use super::refine::{fit_line, intersect, GreyView};
use super::{DetectError, Detection, Detector, MarkerType, SizeRange};

/// Ring samples: 2.8 degrees apart.
const RING_SAMPLES: usize = 128;
/// Added before taking logarithms of grey levels, so sensor noise near
/// black does not swing the log.
const LOG_OFFSET: f64 = 10.0;
/// Fewest grey levels between a target's dark and light parts.
const MIN_CONTRAST: f64 = 15.0;
/// Candidates closer than this fraction of their size are one candidate.
const SAME_CANDIDATE: f64 = 0.12;
/// Fraction of an arm's profiles that must give an edge or bar centre.
const MIN_COVERAGE: f64 = 0.6;
/// Arms of one target may differ this much in length (perspective, shadow).
const MAX_ARM_RATIO: f64 = 1.6;
/// Bar length over width (each arm is half the square minus nothing): the
/// designs in use have bars of 1/12 to 1/3 of the side, so 1.5..6.
const ARM_TO_BAR: (f64, f64) = (1.2, 7.0);
/// Largest RMS distance of edge points from their fitted line: above it the
/// "lines" are not straight (a fold, an object on the target, clutter).
const MAX_FIT_RMS_PX: f64 = 0.45;

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
    mask: Mat,
}

impl CrosshairDetector {
    pub fn new(sizes: SizeRange) -> Self {
        CrosshairDetector {
            sizes,
            mask: Mat::default(),
        }
    }

    /// Candidate centres with a size guess from one polarity's regions.
    fn candidates(&self, blobs: &[Blob]) -> Vec<(Pt, f64)> {
        let mut regions: Vec<&Blob> = blobs.iter().filter(|b| !b.hole).collect();
        regions.sort_by(|a, b| a.centre.0.total_cmp(&b.centre.0));
        let mut out: Vec<(Pt, f64)> = Vec::new();
        for (i, a) in regions.iter().enumerate() {
            let sa = a.area.sqrt();
            // A checker whose regions quadrants touch: one bow-tie blob.
            out.push((a.centre, (2.0 * a.area).sqrt()));
            for b in &regions[i + 1..] {
                if b.centre.0 - a.centre.0 > 2.6 * sa * 1.7 {
                    break;
                }
                let sb = b.area.sqrt();
                let ratio = sa / sb;
                if !(0.6..=1.7).contains(&ratio) {
                    continue;
                }
                let s = (sa + sb) / 2.0;
                let d = geometry::dist(a.centre, b.centre);
                // Diagonal quadrants: d = (q + bar) * sqrt 2, bar in 0..0.6 q.
                if !(1.15 * s..=2.6 * s).contains(&d) {
                    continue;
                }
                let mid = (
                    (a.centre.0 + b.centre.0) / 2.0,
                    (a.centre.1 + b.centre.1) / 2.0,
                );
                out.push((mid, s + d / std::f64::consts::SQRT_2));
            }
        }
        out.retain(|(_, s)| *s >= 0.7 * self.sizes.min_px && *s <= 1.4 * self.sizes.max_px);
        out
    }

    fn analyse(&self, img: &GreyView, start: Pt, size_guess: f64) -> Result<Found, &'static str> {
        let (r1, r2) = (0.28 * size_guess, 0.4 * size_guess);
        if r1 < 3.0 {
            return Err("too small");
        }
        let ring1 = pr::ring(img, start, r1, RING_SAMPLES).ok_or("inner ring")?;
        let p1 = classify_ring(&ring1).ok_or("inner ring")?;
        let p2 = classify_ring(&pr::ring(img, start, r2, RING_SAMPLES).ok_or("outer ring")?)
            .ok_or("outer ring")?;
        if p1.kind != p2.kind {
            return Err("rings disagree");
        }
        let kind = p1.kind;
        let arms2 = match_arms(&p1.arms, &p2.arms).ok_or("arms do not match")?;
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
        let max_reach = 0.75 * self.sizes.max_px;
        // Every arm must end: a grid or paving runs on. (Letting one arm run
        // on, for a path or shadow edge past the target, raised recall by 4
        // points and let panel grids through.)
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
                ArmEnd::RunsOn => return Err("structure runs on"),
                ArmEnd::Unknown => return Err("arm leaves the tile"),
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
        let (lmin, lmax) = lengths
            .iter()
            .fold((f64::MAX, 0f64), |(lo, hi), &l| (lo.min(l), hi.max(l)));
        let size = lengths.iter().sum::<f64>() / 2.0;
        let strength = arms.iter().map(|a| a.strength).fold(f64::MAX, f64::min);
        let cos = (dirs[0].0 * dirs[1].0 + dirs[0].1 * dirs[1].1).abs();
        if lmax / lmin > MAX_ARM_RATIO
            || !self.sizes.accepts(size)
            || cos > (35f64).to_radians().sin()
            || geometry::dist(centre, start) > 0.3 * size
            || fit.coverage < MIN_COVERAGE
            || fit.rms > MAX_FIT_RMS_PX + 0.005 * size
        {
            return Err("structure check");
        }
        let quadrants = quadrant_levels(img, centre, &dirs, &lengths).ok_or("structure check")?;
        match kind {
            Kind::Cross => {
                // A printed bar keeps its width; the zig-zag "bars" along a
                // checker paving's diagonals do not.
                let (w10, w90) = (
                    pr::quantile(&fit.widths, 0.1),
                    pr::quantile(&fit.widths, 0.9),
                );
                if w90 - w10 > 0.5 * bar {
                    return Err("structure check");
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
                let ratio = size / 2.0 / bar;
                let (lo, hi) = quadrants
                    .iter()
                    .fold((f64::MAX, f64::MIN), |(a, b), &q| (a.min(q), b.max(q)));
                if !(ARM_TO_BAR.0..=ARM_TO_BAR.1).contains(&ratio) || hi - lo > 0.6 * strength {
                    return Err("structure check");
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
            }
        }
        let confidence = (fit.coverage
            * (1.0 / (1.0 + (fit.rms / 0.25).powi(2)))
            * (strength / 40.0).clamp(0.0, 1.0)
            * (1.0 - (lmax / lmin - 1.0) / (MAX_ARM_RATIO - 1.0) * 0.5))
            .powf(0.25);
        let corners: [Pt; 4] = std::array::from_fn(|k| {
            let (a, b) = (arm_dir(&dirs, k), arm_dir(&dirs, (k + 1) % 4));
            add(add(centre, a, lengths[k]), b, lengths[(k + 1) % 4])
        });
        Ok(Found {
            centre,
            corners,
            size,
            shift: geometry::dist(centre, start),
            rms: fit.rms,
            confidence,
        })
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
        // Quadrants of a cross are ~0.4 of the side; a checker's merged dark
        // quadrants are half its area.
        let area = (
            (0.25 * self.sizes.min_px).powi(2),
            (0.75 * self.sizes.max_px).powi(2),
        );
        let mut candidates = Vec::new();
        for polarity in [blobs::Polarity::Dark, blobs::Polarity::Bright] {
            let blobs = blobs::find_blobs(tile, polarity, area, &mut self.mask).map_err(err)?;
            candidates.extend(self.candidates(&blobs));
        }
        candidates.sort_by(|a, b| {
            (a.0 .1, a.0 .0)
                .partial_cmp(&(b.0 .1, b.0 .0))
                .expect("finite")
        });
        let candidates = dedup_points(candidates, SAME_CANDIDATE);
        let img = grey_view(tile).map_err(err)?;
        let mut found: Vec<Found> = candidates
            .into_iter()
            .filter_map(|(c, s)| match self.analyse(&img, c, s) {
                Ok(f) => Some(f),
                Err(why) => {
                    tracing::trace!(
                        x = c.0 + origin.0 as f64,
                        y = c.1 + origin.1 as f64,
                        size = s,
                        why,
                        "crosshair candidate rejected"
                    );
                    None
                }
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
/// four narrow bright arcs on dark (cross).
fn classify_ring(v: &[f64]) -> Option<RingPattern> {
    let (lo, hi) = (pr::quantile(v, 0.1), pr::quantile(v, 0.9));
    if hi - lo < MIN_CONTRAST {
        return None;
    }
    let n = v.len();
    // Classified in log intensity, where a shadow is an offset rather than a
    // factor: a white quadrant in shadow still reads light. A [1 2 1]
    // smoothing and a hysteresis band keep noise near the middle level from
    // adding transitions; each one is placed where the smoothed ring last
    // crossed the middle before leaving the band.
    let log = |x: f64| (x + LOG_OFFSET).ln();
    let v: Vec<f64> = (0..n)
        .map(|i| log((v[(i + n - 1) % n] + 2.0 * v[i] + v[(i + 1) % n]) / 4.0))
        .collect();
    let (lo, hi) = (log(lo), log(hi));
    let m = (lo + hi) / 2.0;
    let band = 0.15 * (hi - lo);
    let start = (0..n).find(|&i| (v[i] - m).abs() > band)?;
    let mut high = v[start] > m;
    let mut tr: Vec<(f64, bool)> = Vec::new();
    for step in 1..=n {
        let i = (start + step) % n;
        let flips = if high {
            v[i] < m - band
        } else {
            v[i] > m + band
        };
        if !flips {
            continue;
        }
        // Walk back to the middle crossing.
        let mut j = i;
        for _ in 0..n {
            let prev = (j + n - 1) % n;
            if (v[prev] > m) == high {
                break;
            }
            j = prev;
        }
        let prev = (j + n - 1) % n;
        let (a, b) = (v[prev], v[j]);
        let idx = (prev as f64 + (m - a) / (b - a)).rem_euclid(n as f64);
        high = !high;
        tr.push((idx * TAU / n as f64, high));
    }
    tr.sort_by(|a, b| a.0.total_cmp(&b.0));
    let span = |k: usize| (tr[(k + 1) % tr.len()].0 - tr[k].0).rem_euclid(TAU);
    let deg = |d: f64| d.to_radians();
    match tr.len() {
        4 => {
            if (0..4).all(|k| (deg(35.0)..=deg(145.0)).contains(&span(k))) {
                Some(RingPattern {
                    kind: Kind::Checker,
                    arms: [tr[0].0, tr[1].0, tr[2].0, tr[3].0],
                    bar_rad: 0.0,
                })
            } else {
                None
            }
        }
        8 => {
            let mut arms = Vec::with_capacity(4);
            let mut bright = 0.0;
            for (k, &(angle, rising)) in tr.iter().enumerate() {
                let s = span(k);
                if rising {
                    // A bright arc, from a rising to a falling transition
                    // (a bar of 0.3 of the side spans 60° at 0.3 of the side).
                    if s > deg(100.0) {
                        return None;
                    }
                    arms.push((angle + s / 2.0).rem_euclid(TAU));
                    bright += s / 4.0;
                } else if s < deg(15.0) {
                    return None;
                }
            }
            arms.sort_by(f64::total_cmp);
            let gaps_ok = (0..4).all(|k| {
                let g = (arms[(k + 1) % 4] - arms[k]).rem_euclid(TAU);
                (deg(50.0)..=deg(130.0)).contains(&g)
            });
            gaps_ok.then(|| RingPattern {
                kind: Kind::Cross,
                arms: [arms[0], arms[1], arms[2], arms[3]],
                bar_rad: bright,
            })
        }
        _ => None,
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
    /// The structure continues past any target size: a grid, paving, road.
    RunsOn,
    /// The arm leaves the tile before it can be judged.
    Unknown,
}

/// Feature strength at `t` along arm `a`: for a cross, how much brighter the
/// bar's centre line is than both sides; for a checker, the edge contrast
/// with the arm's polarity. Averaged over three points one pixel apart.
fn feature(img: &GreyView, kind: Kind, c: Pt, a: Pt, t: f64, o: f64, polarity: f64) -> Option<f64> {
    let n = perp(a);
    let mut sum = 0.0;
    for dt in [-1.0, 0.0, 1.0] {
        let base = add(c, a, t + dt);
        let at = |s: f64| {
            let p = add(base, n, s);
            img.sample(p.0, p.1)
        };
        sum += match kind {
            Kind::Cross => {
                let centre = at(0.0)?;
                (centre - at(-o)?).min(centre - at(o)?)
            }
            Kind::Checker => polarity * (at(o)? - at(-o)?),
        };
    }
    Some(sum / 3.0)
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
    let mut t = t0;
    let mut below = 0;
    let mut length = None;
    let mut strength = 0.0;
    while t <= max_reach {
        let Some(f) = feature(img, kind, c, a, t, o, polarity) else {
            return ArmEnd::Unknown;
        };
        if t <= reference_end {
            near.push(f);
        } else {
            if strength == 0.0 {
                strength = pr::quantile(&near, 0.5);
                if strength < 0.7 * MIN_CONTRAST {
                    return ArmEnd::Unknown;
                }
            }
            // 0.4: a shadow edge across the arm (x 0.55) is not its end.
            if f < 0.4 * strength {
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
        return ArmEnd::RunsOn;
    };
    // Beyond the end: ground, not more of the same pattern (either polarity
    // for a checker: paving flips colours at each tile).
    // From a gap past the end (a panel grid's cross line or a blurred square
    // edge must not count) out to twice the arm.
    let (from, to) = (length + (0.3 * length).max(3.0), 2.0 * length.max(6.0));
    let mut active = 0;
    let mut total = 0;
    let mut t = from;
    while t <= to {
        let Some(f) = feature(img, kind, c, a, t, o, polarity) else {
            break;
        };
        // Either sign: a dark bar between light sides continues a pattern too.
        active += (f.abs() >= 0.5 * strength) as usize;
        total += 1;
        t += 1.0;
    }
    if total > 0 && active * 2 > total {
        return ArmEnd::RunsOn;
    }
    ArmEnd::Ends(Arm {
        length: length + 0.5,
        strength,
        polarity,
    })
}

/// Result of fitting the two centre lines.
struct LineFit {
    centre: Pt,
    dirs: [Pt; 2],
    /// Median bar width (cross only).
    bar: Option<f64>,
    /// Every bar width measured (cross only).
    widths: Vec<f64>,
    /// Smallest fraction of usable profiles over the four arms.
    coverage: f64,
    /// Largest RMS point-to-line distance of the two lines.
    rms: f64,
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
    let mut coverage = 1f64;
    let mut rms = 0f64;
    let mut profile = Vec::new();
    for (li, line) in lines.iter_mut().enumerate() {
        let mut points = Vec::new();
        for k in [li, li + 2] {
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
                        Kind::Checker => edge_offset(&profile, half, arm.polarity, arm.strength),
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
        let fitted = fit_line(&points)?;
        rms = rms.max(pr::line_rms(&points, fitted));
        *line = (fitted.0, orient(fitted.1, dirs[li]));
    }
    let centre = intersect(lines[0], lines[1])?;
    let bar = (!widths.is_empty()).then(|| pr::quantile(&widths, 0.5));
    Some(LineFit {
        centre,
        dirs: [lines[0].1, lines[1].1],
        bar,
        widths,
        coverage,
        rms,
    })
}

/// Centre offset and width of a bright bar across a profile (dark on both
/// ends): the midpoint of its rising and falling midpoint crossings.
fn bar_centre(p: &[f64], half: f64, bar: f64, strength: f64) -> Option<(f64, Option<f64>)> {
    let k = (p.len() / 7).max(1);
    let dark = (pr::mean(p, 0, k) + pr::mean(p, p.len() - k, p.len())) / 2.0;
    let mid = p.len() / 2;
    let span = ((bar / 2.0) / pr::STEP_PX) as usize;
    let bright = p[mid.saturating_sub(span / 2)..(mid + span / 2 + 1).min(p.len())]
        .iter()
        .fold(f64::MIN, |a, &b| a.max(b));
    if bright - dark < 0.5 * strength {
        return None;
    }
    let level = (dark + bright) / 2.0;
    let centre_idx = half / pr::STEP_PX;
    let w = bar / 2.0 / pr::STEP_PX;
    let up = pr::crossing(p, level, true, centre_idx - w)?;
    let down = pr::crossing(p, level, false, centre_idx + w)?;
    let width = (down - up) * pr::STEP_PX;
    if down <= up || !(0.5 * bar..=1.6 * bar).contains(&width) {
        return None;
    }
    Some((pr::offset((up + down) / 2.0, half), Some(width)))
}

/// Offset of a checker boundary across a profile, rising toward the light
/// side given by `polarity`.
fn edge_offset(p: &[f64], half: f64, polarity: f64, strength: f64) -> Option<(f64, Option<f64>)> {
    let k = (p.len() / 5).max(1);
    let (first, last) = (pr::mean(p, 0, k), pr::mean(p, p.len() - k, p.len()));
    if polarity * (last - first) < 0.5 * strength {
        return None;
    }
    let level = (first + last) / 2.0;
    let idx = pr::crossing(p, level, polarity > 0.0, half / pr::STEP_PX)?;
    Some((pr::offset(idx, half), None))
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

/// Mean grey level of each quadrant, between arm k and arm k+1, sampled on
/// a small patch halfway along the bisector.
fn quadrant_levels(img: &GreyView, c: Pt, dirs: &[Pt; 2], lengths: &[f64; 4]) -> Option<[f64; 4]> {
    let mut out = [0.0; 4];
    for (k, q) in out.iter_mut().enumerate() {
        let (a, b) = (arm_dir(dirs, k), arm_dir(dirs, (k + 1) % 4));
        let centre = add(add(c, a, 0.55 * lengths[k]), b, 0.55 * lengths[(k + 1) % 4]);
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
        let p = classify_ring(&checker).expect("checker");
        assert_eq!(p.kind, Kind::Checker);
        let cross = ring_of(|a| {
            let d = ((a - 0.2).rem_euclid(PI / 2.0) - PI / 4.0).abs();
            if d > PI / 4.0 - 0.2 {
                210.0
            } else {
                20.0
            }
        });
        let p = classify_ring(&cross).expect("cross");
        assert_eq!(p.kind, Kind::Cross);
        for (k, arm) in p.arms.iter().enumerate() {
            let want = 0.2 + k as f64 * PI / 2.0;
            assert!((arm - want).abs() < 0.03, "arm {k}: {arm} vs {want}");
        }
        // A plain edge (two halves) and a flat ring are neither.
        assert!(classify_ring(&ring_of(|a| if a < PI { 200.0 } else { 30.0 })).is_none());
        assert!(classify_ring(&ring_of(|_| 120.0)).is_none());
    }
}
