//! Candidate centres of crosshair targets from ring harmonics.
//!
//! Around the centre of a 2x2 checker, a ring of samples is a square wave
//! with two periods per turn (its 2nd harmonic is strong, its 4th is zero);
//! around the centre of a cross, the ring crosses four bars (4th harmonic
//! strong, 2nd zero). Both are point-symmetric: opposite samples are equal.
//! In log intensity a shadow edge through the centre is a step, which has
//! odd harmonics only, and a shadow's dimming is an offset, so the response
//! below holds under partial shadow and low print contrast.
//!
//! The tile is reduced in an image pyramid (OpenCV `pyrDown`); at each
//! level a fixed ring of [`RING_PX`] pixels matches targets of about
//! [`RING_PX`] / [`RING_TO_SIZE`] level pixels, so every size from the
//! smallest searched up is seen at some level. The response is
//! `a2 - a4 - asym` (checker) or `a4 - a2 - asym` (cross), with `ak` the
//! amplitude of harmonic k and `asym` what is left of the odd part
//! (opposite samples' difference) once a straight shadow edge is allowed
//! for; a bright line (both harmonics) and an edge (odd) score low. Local maxima above [`MIN_SCORE`] are candidates; the detector then
//! verifies each on the full-resolution tile.

use opencv::core::{Mat, Size, BORDER_REFLECT101};
use opencv::imgproc;
use opencv::prelude::*;

use super::geometry::Pt;
use super::SizeRange;

/// Ring radius at every pyramid level, in that level's pixels.
pub const RING_PX: f64 = 4.0;
/// Ring samples: 22.5 degrees apart.
const SAMPLES: usize = 16;
/// A ring at this fraction of a target's side lies inside it and crosses
/// its structure (bars, quadrant boundaries) away from the centre.
pub const RING_TO_SIZE: f64 = 0.3;
/// Fractions of the side a ring may have and still respond: the size band
/// one level covers.
const RING_FRACTIONS: (f64, f64) = (0.18, 0.42);
/// Smallest response, in natural-log units (0.1 is a 10% modulation): below
/// the ~0.4 of a 40%-contrast print in shadow, above ground grain.
pub const MIN_SCORE: f64 = 0.1;
/// Added to grey levels before taking logarithms, so sensor noise near
/// black does not swing the log.
pub const LOG_OFFSET: f64 = 10.0;

/// Which symmetry a candidate shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Symmetry {
    /// 2-fold: a checker's alternating quadrants.
    Checker,
    /// 4-fold: a cross's four bars.
    Cross,
}

/// A candidate centre, in tile pixels.
#[derive(Debug, Clone, Copy)]
pub struct Candidate {
    pub centre: Pt,
    /// Target side the responding ring suggests (within a factor 1.5).
    pub size: f64,
    /// Pyramid scale (1, 2, 4...): the centre is good to about half of it
    /// (to one pixel on the full-resolution level, searched every 2 px).
    pub scale: f64,
    pub symmetry: Symmetry,
}

/// Cosines and sines of a ring's sample angles (1st, 2nd and 4th
/// harmonics), computed once per sample count.
#[derive(Debug, Clone)]
pub struct RingBasis {
    n: usize,
    /// (cos, sin) of k * angle for k = 1, 2, 4.
    h1: Vec<(f64, f64)>,
    h2: Vec<(f64, f64)>,
    h4: Vec<(f64, f64)>,
}

impl RingBasis {
    /// A basis for `n` samples, `n` divisible by 4.
    pub fn new(n: usize) -> RingBasis {
        assert!(n >= 8 && n.is_multiple_of(4), "ring of {n} samples");
        let h = |k: f64| {
            (0..n)
                .map(|i| {
                    let a = k * std::f64::consts::TAU * i as f64 / n as f64;
                    (a.cos(), a.sin())
                })
                .collect()
        };
        RingBasis {
            n,
            h1: h(1.0),
            h2: h(2.0),
            h4: h(4.0),
        }
    }

    pub fn len(&self) -> usize {
        self.n
    }

    /// Unit vector of sample `i`'s direction.
    pub fn direction(&self, i: usize) -> (f64, f64) {
        self.h1[i]
    }

    fn harmonic(table: &[(f64, f64)], s: &[f64]) -> (f64, f64) {
        table
            .iter()
            .zip(s)
            .fold((0.0, 0.0), |(c, si), ((co, sn), v)| {
                (c + v * co, si + v * sn)
            })
    }

    /// Amplitudes of the 2nd and 4th harmonics of ring `s`.
    #[cfg(test)]
    pub fn amplitudes(&self, s: &[f64]) -> (f64, f64) {
        let (c2, s2) = Self::harmonic(&self.h2, s);
        let (c4, s4) = Self::harmonic(&self.h4, s);
        let k = 2.0 / self.n as f64;
        (
            k * (c2 * c2 + s2 * s2).sqrt(),
            k * (c4 * c4 + s4 * s4).sqrt(),
        )
    }

    /// Amplitudes of the 2nd and 4th harmonics of ring `s` and its
    /// asymmetry beyond a straight step.
    #[cfg(test)]
    pub fn response(&self, s: &[f64]) -> (f64, f64, f64) {
        let (a2, a4) = self.amplitudes(s);
        (a2, a4, self.asymmetry(s))
    }

    /// What is left of the ring's odd part once a straight step through
    /// the centre is allowed for (see [`score`]).
    pub fn asymmetry(&self, s: &[f64]) -> f64 {
        let n = self.n;
        // The odd part (half the difference of opposite samples) less its
        // first harmonic: a shadow edge through the centre is mostly that
        // harmonic, a corner or an off-centre ring leaves much more.
        let half = n / 2;
        let d = |i: usize| (s[i] - s[i + half]) / 2.0;
        let (mut c1, mut s1) = (0.0, 0.0);
        for i in 0..half {
            c1 += d(i) * self.h1[i].0;
            s1 += d(i) * self.h1[i].1;
        }
        let (c1, s1) = (c1 * 2.0 / half as f64, s1 * 2.0 / half as f64);
        (0..half)
            .map(|i| (d(i) - c1 * self.h1[i].0 - s1 * self.h1[i].1).abs())
            .sum::<f64>()
            / half as f64
    }

    /// Phase of harmonic 2 or 4 of `s` (the angle of its maximum, times k).
    pub fn phase(&self, k: u32, s: &[f64]) -> f64 {
        let (c, si) = match k {
            2 => Self::harmonic(&self.h2, s),
            4 => Self::harmonic(&self.h4, s),
            _ => unreachable!("harmonic {k}"),
        };
        si.atan2(c)
    }

    /// How clearly the ring alternates as the symmetry says, in log units.
    ///
    /// Checker: at the four directions its 2nd harmonic puts light and
    /// dark, the differences light - dark between ring neighbours. A
    /// straight shadow edge through the centre darkens one light and one
    /// dark direction, which lowers one difference and raises another; a
    /// square's corner (one light quarter, the harmonic's other "light"
    /// direction dark) leaves two near zero. So the second smallest counts.
    /// Cross: the same over its four bars and the four dark directions
    /// between them, third smallest of eight (a shadow edge crosses the
    /// ring twice).
    pub fn alternation(&self, symmetry: Symmetry, s: &[f64]) -> f64 {
        let n = self.n;
        let k = match symmetry {
            Symmetry::Checker => 2,
            Symmetry::Cross => 4,
        };
        // Light at phase / k + m * 2pi / k; dark halfway between.
        let light = self.phase(k, s) / k as f64;
        let count = 2 * k as usize;
        let at = |a: f64| {
            let i = (a / std::f64::consts::TAU * n as f64).round() as i64;
            s[i.rem_euclid(n as i64) as usize]
        };
        let mut diffs = [0.0; 8];
        for (m, d) in diffs.iter_mut().enumerate().take(count) {
            let step = std::f64::consts::PI / k as f64;
            let (a, b) = (
                at(light + m as f64 * step),
                at(light + (m + 1) as f64 * step),
            );
            *d = if m % 2 == 0 { a - b } else { b - a };
        }
        let diffs = &mut diffs[..count];
        diffs.sort_by(f64::total_cmp);
        diffs[match symmetry {
            Symmetry::Checker => 1,
            Symmetry::Cross => 2,
        }]
    }
}

/// The response of one symmetry from [`RingBasis::response`]'s figures.
pub fn score(symmetry: Symmetry, (a2, a4, asym): (f64, f64, f64)) -> f64 {
    match symmetry {
        Symmetry::Checker => a2 - a4 - asym,
        Symmetry::Cross => a4 - a2 - asym,
    }
}

/// How the candidate search treats a cross's quadrants.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quadrants {
    /// Plain: the ring must be point-symmetric and alternate.
    Plain,
    /// Free to hold markings, which break the ring's point symmetry: a
    /// cross responds by its 4th harmonic over its 2nd only.
    Free,
}

/// Natural log of (grey + [`LOG_OFFSET`]) for every 8-bit value, built once
/// per process.
fn log_table() -> &'static [f64; 256] {
    static TABLE: std::sync::LazyLock<[f64; 256]> =
        std::sync::LazyLock::new(|| std::array::from_fn(|v| (v as f64 + LOG_OFFSET).ln()));
    &TABLE
}

/// ln(grey + [`LOG_OFFSET`]) of a grey level, fractional ones (bilinear
/// samples) interpolated between the table's entries.
pub fn log_grey(v: f64) -> f64 {
    let lut = log_table();
    let v = v.clamp(0.0, 255.0);
    let i = (v as usize).min(254);
    let f = v - i as f64;
    lut[i] * (1.0 - f) + lut[i + 1] * f
}

/// Candidates in `tile` (8-bit grey) for targets of `sizes`, ordered by
/// position (deterministic).
pub fn candidates(
    tile: &Mat,
    sizes: SizeRange,
    quadrants: Quadrants,
) -> opencv::Result<Vec<Candidate>> {
    let lut = log_table();
    let mut out = Vec::new();
    // Level 0 is the tile itself (borrowed); the others are pyrDown's.
    let mut reduced: Option<Mat> = None;
    let mut scale = 1.0;
    loop {
        let level = reduced.as_ref().unwrap_or(tile);
        let band = (
            RING_PX / RING_FRACTIONS.1 * scale,
            RING_PX / RING_FRACTIONS.0 * scale,
        );
        if band.0 > sizes.max_px * 1.15 || level.cols() < 16 || level.rows() < 16 {
            break;
        }
        if band.1 >= sizes.min_px / 1.15 {
            level_candidates(level, scale, lut, quadrants, &mut out)?;
        }
        let mut next = Mat::default();
        let size = Size::new((level.cols() + 1) / 2, (level.rows() + 1) / 2);
        imgproc::pyr_down(level, &mut next, size, BORDER_REFLECT101)?;
        reduced = Some(next);
        scale *= 2.0;
    }
    out.sort_by(|a, b| {
        (a.centre.1, a.centre.0, a.scale)
            .partial_cmp(&(b.centre.1, b.centre.0, b.scale))
            .expect("finite")
    });
    Ok(out)
}

/// Responses on one pyramid level and their local maxima.
fn level_candidates(
    level: &Mat,
    scale: f64,
    lut: &[f64; 256],
    quadrants: Quadrants,
    out: &mut Vec<Candidate>,
) -> opencv::Result<()> {
    let (w, h) = (level.cols() as usize, level.rows() as usize);
    let mut logs = vec![0f32; w * h];
    for y in 0..h {
        let row = level.at_row::<u8>(y as i32)?;
        for (x, v) in row.iter().enumerate() {
            logs[y * w + x] = lut[*v as usize] as f32;
        }
    }
    // Bilinear taps of each ring sample: offset of the top-left pixel and
    // the four weights.
    let basis = RingBasis::new(SAMPLES);
    // Samples at the nearest pixel to each ring direction (the level is
    // already smoothed by pyrDown): one load each, in f32, so the harmonic
    // sums vectorise.
    let offsets: [isize; SAMPLES] = std::array::from_fn(|i| {
        let (c, s) = basis.direction(i);
        (RING_PX * s).round() as isize * w as isize + (RING_PX * c).round() as isize
    });
    let table = |k: f64| -> ([f32; SAMPLES], [f32; SAMPLES]) {
        let a = |i: usize| k * std::f64::consts::TAU * i as f64 / SAMPLES as f64;
        (
            std::array::from_fn(|i| a(i).cos() as f32),
            std::array::from_fn(|i| a(i).sin() as f32),
        )
    };
    let ((cos2, sin2), (cos4, sin4)) = (table(2.0), table(4.0));
    let margin = RING_PX.ceil() as usize + 1;
    if w <= 2 * margin || h <= 2 * margin {
        return Ok(());
    }
    // The response peak is several pixels wide: on the full-resolution
    // level every other pixel and row is enough (and 4x cheaper).
    let stride = if scale == 1.0 { 2 } else { 1 };
    let mut resp = [vec![f32::MIN; w * h], vec![f32::MIN; w * h]];
    let mut ring = [0f64; SAMPLES];
    let norm = 2.0 / SAMPLES as f32;
    for y in (margin..h - margin).step_by(stride) {
        for x in (margin..w - margin).step_by(stride) {
            let base = (y * w + x) as isize;
            let v: [f32; SAMPLES] = std::array::from_fn(|i| logs[(base + offsets[i]) as usize]);
            let (mut c2, mut s2, mut c4, mut s4) = (0f32, 0f32, 0f32, 0f32);
            for i in 0..SAMPLES {
                c2 += v[i] * cos2[i];
                s2 += v[i] * sin2[i];
                c4 += v[i] * cos4[i];
                s4 += v[i] * sin4[i];
            }
            let a2 = norm * (c2 * c2 + s2 * s2).sqrt();
            let a4 = norm * (c4 * c4 + s4 * s4).sqrt();
            // The asymmetry only lowers a score: skip it where neither
            // symmetry could reach the floor.
            if ((a2 - a4).abs() as f64) < MIN_SCORE {
                continue;
            }
            for (r, x) in ring.iter_mut().zip(v) {
                *r = x as f64;
            }
            let (a2, a4) = (a2 as f64, a4 as f64);
            let r = (a2, a4, basis.asymmetry(&ring));
            for (map, symmetry) in resp.iter_mut().zip([Symmetry::Checker, Symmetry::Cross]) {
                let free = quadrants == Quadrants::Free && symmetry == Symmetry::Cross;
                let mut v = if free { r.1 - r.0 } else { score(symmetry, r) };
                if v >= MIN_SCORE && !free {
                    v = v.min(basis.alternation(symmetry, &ring));
                }
                map[y * w + x] = v as f32;
            }
        }
    }
    let nms = 2 * stride;
    for (map, symmetry) in resp.iter().zip([Symmetry::Checker, Symmetry::Cross]) {
        for y in (margin..h - margin).step_by(stride) {
            for x in (margin..w - margin).step_by(stride) {
                let v = map[y * w + x];
                if (v as f64) < MIN_SCORE {
                    continue;
                }
                // Strict maximum over earlier neighbours, not below later
                // ones: one peak per plateau.
                let mut is_max = true;
                'n: for yy in (y.saturating_sub(nms)..=(y + nms).min(h - 1)).step_by(stride) {
                    for xx in (x.saturating_sub(nms)..=(x + nms).min(w - 1)).step_by(stride) {
                        let u = map[yy * w + xx];
                        if (yy, xx) < (y, x) && u >= v || (yy, xx) > (y, x) && u > v {
                            is_max = false;
                            break 'n;
                        }
                    }
                }
                if !is_max {
                    continue;
                }
                let peak = |a: f32, b: f32, c: f32| {
                    let d = a - 2.0 * b + c;
                    if d < 0.0 {
                        (0.5 * (a - c) / d).clamp(-0.5, 0.5) as f64
                    } else {
                        0.0
                    }
                };
                let s = stride;
                let dx = peak(map[y * w + x - s], v, map[y * w + x + s]) * s as f64;
                let dy = peak(map[(y - s) * w + x], v, map[(y + s) * w + x]) * s as f64;
                // pyrDown keeps level pixel i centred on pixel 2i below.
                out.push(Candidate {
                    centre: ((x as f64 + dx) * scale, (y as f64 + dy) * scale),
                    size: RING_PX / RING_TO_SIZE * scale,
                    scale,
                    symmetry,
                });
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{PI, TAU};

    fn ring(f: impl Fn(f64) -> f64) -> Vec<f64> {
        (0..64).map(|i| f(TAU * i as f64 / 64.0)).collect()
    }

    #[test]
    fn checkers_and_crosses_score_on_their_own_symmetry_only() {
        let checker = ring(|a| {
            if (a + 0.3).sin() * (a + 0.3).cos() > 0.0 {
                5.0
            } else {
                4.0
            }
        });
        let cross = ring(|a| {
            let d = ((a - 0.2).rem_euclid(PI / 2.0) - PI / 4.0).abs();
            if d > PI / 4.0 - 0.25 {
                5.0
            } else {
                4.0
            }
        });
        let line = ring(|a| {
            if (a.rem_euclid(PI) - 1.0).abs() < 0.2 {
                5.0
            } else {
                4.0
            }
        });
        let edge = ring(|a| if a < PI { 5.0 } else { 4.0 });
        let basis = RingBasis::new(64);
        let r = |v: &Vec<f64>| basis.response(v);
        assert!(score(Symmetry::Checker, r(&checker)) > 0.5);
        assert!(score(Symmetry::Cross, r(&checker)) < 0.0);
        assert!(score(Symmetry::Cross, r(&cross)) > 0.3);
        assert!(score(Symmetry::Checker, r(&cross)) < 0.0);
        for clutter in [&line, &edge] {
            assert!(score(Symmetry::Checker, r(clutter)) < MIN_SCORE);
            assert!(score(Symmetry::Cross, r(clutter)) < MIN_SCORE);
        }
        // A shadow edge through the centre (a step in log) leaves the
        // checker's response as it was.
        let shadowed: Vec<f64> = checker
            .iter()
            .enumerate()
            .map(|(i, v)| v - if i < 32 { 0.6 } else { 0.0 })
            .collect();
        let (a2, a4, _) = r(&shadowed);
        let (b2, b4, _) = r(&checker);
        assert!((a2 - b2).abs() < 1e-9 && (a4 - b4).abs() < 1e-9);
    }
}
