//! The one verification every printed candidate passes: the design, drawn
//! under the fitted geometry, is compared with the image on the design's
//! non-free area by normalised cross-correlation. The score does not depend
//! on brightness or print contrast, and a look-alike that matches the
//! design's parts one by one (a bar here, a dark patch there) rarely
//! matches them all at once.

use super::super::design::{DesignKind, FreeArea, Polarity, TargetDesign};
use super::super::geometry::Pt;
use super::super::profile::add;
use super::super::refine::GreyView;

/// The fitted geometry of a cross or checker: a centre, the two lines'
/// directions (arm 0 along `dirs[0]`, arm 1 along `dirs[1]`, arms 2 and 3
/// opposite) and each arm's length to the board's side. Between the arms
/// the board is mapped piecewise affinely, which follows mild perspective.
#[derive(Debug, Clone, Copy)]
pub struct Fit {
    pub centre: Pt,
    pub dirs: [Pt; 2],
    pub lengths: [f64; 4],
    /// Cross: the two bars' widths (along `dirs[0]`, along `dirs[1]`).
    pub bar: [f64; 2],
}

impl Fit {
    /// Image point of design coordinates (u, v) in [-1, 1]^2.
    pub fn at(&self, u: f64, v: f64) -> Pt {
        let lu = if u >= 0.0 {
            self.lengths[0]
        } else {
            self.lengths[2]
        };
        let lv = if v >= 0.0 {
            self.lengths[1]
        } else {
            self.lengths[3]
        };
        add(add(self.centre, self.dirs[0], u * lu), self.dirs[1], v * lv)
    }

    /// Board corners, clockwise in image axes from (-1, -1).
    pub fn corners(&self) -> [Pt; 4] {
        [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].map(|(u, v)| self.at(u, v))
    }

    /// The board's mean side.
    pub fn size(&self) -> f64 {
        0.5 * (self.lengths.iter().sum::<f64>())
    }
}

/// The comparison's outcome.
#[derive(Debug, Clone, Copy)]
pub struct Verdict {
    /// Normalised cross-correlation of design and image, -1..1.
    pub score: f64,
    /// Mean grey level of the design's light parts less its dark parts.
    pub contrast: f64,
    /// The contrast over the ground's own texture around the board (see
    /// `ground_texture`); the contrast itself when too little ground lies
    /// in the tile to tell (the texture then counts as one grey level).
    pub salience: f64,
    /// Mean grey levels of the lighter and the darker parts.
    pub levels: (f64, f64),
}

/// Design samples per side of the board.
const GRID: usize = 40;
/// Samples this close to an edge of the drawn design (in image pixels) are
/// left out: blur makes them neither colour.
const EDGE_PX: f64 = 1.2;
/// Samples this close to the board's side (design units) are left out: the
/// side is where the arms' ends put it, good to a pixel or two.
const SIDE_MARGIN: f64 = 0.06;

/// Compares `design` drawn under `fit` with `img`; None when more than a
/// fifth of the board lies outside the image or too few samples remain.
pub fn verify(img: &GreyView, design: &TargetDesign, fit: &Fit) -> Option<Verdict> {
    let lines = [(fit.centre, fit.dirs[0]), (fit.centre, fit.dirs[1])];
    // Distance of p from line k (signed; used as a magnitude).
    let dist = |p: Pt, k: usize| {
        let (c, d) = lines[k];
        (p.0 - c.0) * d.1 - (p.1 - c.1) * d.0
    };
    let mut light = (0.0, 0usize);
    let mut dark = (0.0, 0usize);
    let mut samples: Vec<(f64, f64)> = Vec::with_capacity(GRID * GRID);
    let band = 1.0 - design.border_band;
    let mut total = 0usize;
    for j in 0..GRID {
        let v = -1.0 + (2.0 * j as f64 + 1.0) / GRID as f64;
        for i in 0..GRID {
            let u = -1.0 + (2.0 * i as f64 + 1.0) / GRID as f64;
            if u.abs() > 1.0 - SIDE_MARGIN || v.abs() > 1.0 - SIDE_MARGIN {
                continue;
            }
            let p = fit.at(u, v);
            // Distances from bar A's centre line (along dirs[0]) and bar B's.
            let (da, db) = (dist(p, 0).abs(), dist(p, 1).abs());
            let is_light = match design.kind {
                DesignKind::Cross => {
                    let (ha, hb) = (0.5 * fit.bar[0], 0.5 * fit.bar[1]);
                    if (da - ha).abs() < EDGE_PX || (db - hb).abs() < EDGE_PX {
                        continue;
                    }
                    let in_bar = da < ha || db < hb;
                    if !in_bar
                        && design.free == FreeArea::Quadrants
                        && u.abs() < band
                        && v.abs() < band
                    {
                        continue;
                    }
                    in_bar == (design.polarity == Polarity::LightOnDark)
                }
                // A checker (the detector holds crosses and checkers only).
                _ => {
                    if da < EDGE_PX || db < EDGE_PX {
                        continue;
                    }
                    // Quadrants (+,+) and (-,-) light; the sign of the score
                    // is ignored below, so either pair may be the light one.
                    u * v > 0.0
                }
            };
            total += 1;
            // The frame's edge may cut a board's rim: samples past it are
            // left out (a tile seam never cuts one; see the detector).
            let Some(g) = img.sample(p.0, p.1) else {
                continue;
            };
            let t = if is_light { 1.0 } else { 0.0 };
            samples.push((t, g));
            if is_light {
                light.0 += g;
                light.1 += 1;
            } else {
                dark.0 += g;
                dark.1 += 1;
            }
        }
    }
    if light.1 < 8 || dark.1 < 8 || samples.len() * 5 < total * 4 {
        return None;
    }
    let n = samples.len() as f64;
    let (mt, mg) = samples
        .iter()
        .fold((0.0, 0.0), |(a, b), (t, g)| (a + t / n, b + g / n));
    let (mut stg, mut stt, mut sgg) = (0.0, 0.0, 0.0);
    for (t, g) in &samples {
        stg += (t - mt) * (g - mg);
        stt += (t - mt) * (t - mt);
        sgg += (g - mg) * (g - mg);
    }
    let mut score = if sgg > 0.0 {
        stg / (stt * sgg).sqrt()
    } else {
        0.0
    };
    let (light_mean, dark_mean) = (light.0 / light.1 as f64, dark.0 / dark.1 as f64);
    let mut contrast = light_mean - dark_mean;
    if design.kind == DesignKind::Checker {
        score = score.abs();
        contrast = contrast.abs();
    }
    let salience = contrast / ground_texture(img, fit).max(1.0);
    Some(Verdict {
        score,
        contrast,
        salience,
        levels: (light_mean.max(dark_mean), light_mean.min(dark_mean)),
    })
}

/// Distance of the ground ring outside the board, in half-sides.
const GROUND_RING: f64 = 1.35;
/// Samples on the ground ring.
const GROUND_SAMPLES: usize = 64;

/// The ground's texture around the board: the median step between
/// neighbouring samples on a square ring just outside it. A printed target
/// stands out from the ground it lies on; a look-alike in foliage, gravel
/// or rubble is no stronger than the texture it is part of.
fn ground_texture(img: &GreyView, fit: &Fit) -> f64 {
    let mut values = Vec::with_capacity(GROUND_SAMPLES);
    for k in 0..GROUND_SAMPLES {
        // Side k / (n / 4) of the ring, position f along it.
        let side = k * 4 / GROUND_SAMPLES;
        let quarter = GROUND_SAMPLES / 4;
        let f = -1.0 + 2.0 * ((k % quarter) as f64 + 0.5) / quarter as f64;
        let r = GROUND_RING;
        let (u, v) = match side {
            0 => (f * r, -r),
            1 => (r, f * r),
            2 => (-f * r, r),
            _ => (-r, -f * r),
        };
        let p = fit.at(u, v);
        if let Some(g) = img.sample(p.0, p.1) {
            values.push(g);
        }
    }
    if values.len() < GROUND_SAMPLES / 2 {
        return 0.0;
    }
    // Steps between neighbours on the ring: an object's or a shadow's edge
    // crossing the ring makes two of them, texture makes them all.
    let mut steps: Vec<f64> = values.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
    steps.sort_by(f64::total_cmp);
    steps[steps.len() / 2]
}
