//! Subpixel fits of a drawn target to the image. Once a target is known
//! (a coded tag decoded: every cell; a printed cross or checker found: its
//! lines and bars), the whole of it can be drawn, blurred, and compared
//! with the pixels: the fit moves its geometry, its blur and its two grey
//! levels until the drawing matches the image in least squares (Gauss-
//! Newton with Levenberg's damping), pixels that do not fit (clutter over
//! a quiet zone, a marking beside a bar, a shadow over part of the target)
//! weighted down by Tukey's robust weight.
//!
//! Against fitting lines to profiles across single edges, every edge of
//! the target takes part at once, each pixel for what it shows: a small
//! blurred tag has four short outer edges but dozens of inner ones, and a
//! marking that widens a bar along one arm is outvoted by the bar's three
//! clean edges.
//!
//! The model: `grey = a + b * P(x)`, `P` the target's drawing (0 for its
//! dark parts, 1 for its light ones) blurred by a Gaussian of `sigma`, a
//! [`Shape`] giving `P` and its derivatives by the shape's unknowns.

mod printed;
mod tag;

pub use printed::{fit_checker, fit_cross, Lines};
pub use tag::{fit_tag, Pattern};

use super::geometry::Pt;

/// Largest robust residual of a fit, as a share of the target's contrast,
/// for the fit to stand: over it the drawing does not describe the pixels
/// (clutter over much of the target, a shadow's edge that is not straight)
/// and the detector's own centre stands. On generated hard AprilTag frames
/// never used to set it (`gcp-tagger sample --hard --seed 77`, 12 JPEG
/// frames, 162 tags) the centres' p95 was 0.109 px at 0.06, 0.107 at 0.1,
/// 0.115 at 0.2.
pub const MAX_RESIDUAL_SHARE: f64 = 0.1;

/// Settings of a fit.
#[derive(Debug, Clone, Copy)]
pub struct FitParams {
    /// Gauss-Newton iterations at most.
    pub max_iterations: usize,
    /// At most this many pixels are used (a regular subsample of larger
    /// targets): the fit's precision is long past its need there.
    pub max_pixels: usize,
    /// Tukey's constant, in robust standard deviations of the residuals.
    pub tukey: f64,
    /// Whether a straight shadow edge over the target is looked for and
    /// fitted when it explains the pixels better.
    pub shadows: bool,
}

impl Default for FitParams {
    fn default() -> Self {
        FitParams {
            max_iterations: 20,
            max_pixels: 3000,
            tukey: 4.685,
            shadows: true,
        }
    }
}

/// A drawn target whose unknowns a fit moves.
pub trait Shape {
    /// Readies the drawing for the unknowns `theta` (called before the
    /// values at that `theta` are asked for); None when they make no
    /// drawing (a degenerate quad).
    fn prepare(&mut self, theta: &[f64]) -> Option<()>;
    /// The drawing's value at `x`, 0..1, and with `grad` its derivative by
    /// each unknown.
    fn value(&self, x: Pt, grad: Option<&mut [f64]>) -> f64;
    /// Brings unknowns back into their valid range after a step.
    fn bound(&self, _theta: &mut [f64]) {}
}

/// A fit's outcome.
#[derive(Debug, Clone)]
pub struct Solved {
    /// The shape's unknowns.
    pub theta: Vec<f64>,
    /// Grey of the drawing's 0 and its 1 less its 0 (negative when the
    /// drawing's 1 is the darker part).
    pub black: f64,
    pub contrast: f64,
    /// Robust standard deviation of the residuals, grey levels.
    pub residual: f64,
}

/// The standard normal distribution tabulated over [-RANGE, RANGE] every
/// 1/STEPS (linear interpolation is good to 1e-6 there): the fit evaluates
/// it millions of times per frame.
const RANGE: f64 = 8.0;
const STEPS: f64 = 256.0;

struct Normal {
    cdf: Vec<f64>,
    pdf: Vec<f64>,
}

static NORMAL: std::sync::LazyLock<Normal> = std::sync::LazyLock::new(|| {
    let n = (2.0 * RANGE * STEPS) as usize + 2;
    let x = |k: usize| k as f64 / STEPS - RANGE;
    Normal {
        cdf: (0..n)
            .map(|k| 0.5 * libm::erfc(-x(k) * std::f64::consts::FRAC_1_SQRT_2))
            .collect(),
        pdf: (0..n)
            .map(|k| (-0.5 * x(k) * x(k)).exp() * 0.398_942_280_401_432_7)
            .collect(),
    }
});

/// Standard normal cumulative distribution and density at `x`.
fn normal(x: f64) -> (f64, f64) {
    if x <= -RANGE {
        return (0.0, 0.0);
    }
    if x >= RANGE {
        return (1.0, 0.0);
    }
    let t = (x + RANGE) * STEPS;
    let k = t as usize;
    let f = t - k as f64;
    let n = &*NORMAL;
    (
        n.cdf[k] + f * (n.cdf[k + 1] - n.cdf[k]),
        n.pdf[k] + f * (n.pdf[k + 1] - n.pdf[k]),
    )
}

/// Solves the symmetric positive definite system `a x = b` (row-major
/// `n x n`, Cholesky); None when not positive definite.
fn solve(a: &[f64], b: &[f64]) -> Option<Vec<f64>> {
    let n = b.len();
    let mut l = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            let s = a[i * n + j] - (0..j).map(|k| l[i * n + k] * l[j * n + k]).sum::<f64>();
            if i == j {
                if s <= 0.0 {
                    return None;
                }
                l[i * n + i] = s.sqrt();
            } else {
                l[i * n + j] = s / l[j * n + j];
            }
        }
    }
    let mut y = vec![0.0; n];
    for i in 0..n {
        y[i] = (b[i] - (0..i).map(|k| l[i * n + k] * y[k]).sum::<f64>()) / l[i * n + i];
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        x[i] = (y[i] - (i + 1..n).map(|k| l[k * n + i] * x[k]).sum::<f64>()) / l[i * n + i];
    }
    Some(x)
}

fn median(v: &mut [f64]) -> f64 {
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// A straight shadow edge over the target: the side past the line is
/// darkened by the factor `1 - depth`, over a penumbra of `soft` pixels.
/// Unknowns (after the shape's and the two levels): the edge's normal
/// angle, its offset from the pixels' mean position, depth, softness.
const SHADOW: usize = 4;

/// The darkening at `x` (relative to the pixels' mean) for the shadow's
/// unknowns `s`, and its derivatives by them.
fn shadow_at(x: Pt, s: &[f64]) -> (f64, [f64; SHADOW]) {
    let (angle, offset, depth, soft) = (s[0], s[1], s[2], s[3]);
    let (sn, cs) = angle.sin_cos();
    let z = (cs * x.0 + sn * x.1 - offset) / soft;
    let (c, p) = normal(z);
    let across = (-sn * x.0 + cs * x.1) / soft;
    (
        1.0 - depth * c,
        [
            -depth * p * across,
            depth * p / soft,
            -c,
            depth * p * z / soft,
        ],
    )
}

/// Fits `shape` to `pixels` (position, grey) from the unknowns `theta`
/// and the levels `(black, contrast)`; when a straight shadow edge over
/// the target explains the pixels better, fits again with it. `moves`
/// says which unknowns are positions in pixels (convergence is judged on
/// those). None when the shape cannot be drawn or the system is singular.
pub fn robust_fit<S: Shape>(
    shape: &mut S,
    pixels: &[(Pt, f64)],
    theta: Vec<f64>,
    levels: (f64, f64),
    moves: &[usize],
    params: &FitParams,
) -> Option<Solved> {
    let g = theta.len();
    if pixels.len() < 4 * (g + 2 + SHADOW) {
        return None;
    }
    let mean = pixels
        .iter()
        .fold((0.0, 0.0), |m, (x, _)| (m.0 + x.0, m.1 + x.1));
    let mean = (mean.0 / pixels.len() as f64, mean.1 / pixels.len() as f64);
    let centred: Vec<(Pt, f64)> = pixels
        .iter()
        .map(|((x, y), grey)| ((*x - mean.0, *y - mean.1), *grey))
        .collect();
    let mut t = theta;
    t.extend([levels.0, levels.1]);
    let plain = fit_pass(shape, pixels, &centred, t, None, moves, params)?;
    if !params.shadows {
        return Some(plain.0);
    }
    let Some(edge) = shadow_edge(shape, pixels, &centred, &plain.0) else {
        return Some(plain.0);
    };
    let mut t = plain.0.theta.clone();
    // The levels of the lit side.
    t.extend([plain.0.black / edge.1, plain.0.contrast / edge.1]);
    match fit_pass(shape, pixels, &centred, t, Some(edge.0), moves, params) {
        Some(shaded) if shaded.0.residual < plain.0.residual => Some(shaded.0),
        _ => Some(plain.0),
    }
}

/// The straight line that best parts the target's light pixels by how
/// much lighter or darker than the fit `solved` they are: the shadow's
/// unknowns and the lit side's brightness over the fitted levels; None
/// when no line parts them by `MIN_SHADOW` of their level.
fn shadow_edge<S: Shape>(
    shape: &mut S,
    pixels: &[(Pt, f64)],
    centred: &[(Pt, f64)],
    solved: &Solved,
) -> Option<([f64; SHADOW], f64)> {
    const MIN_SHADOW: f64 = 0.1;
    shape.prepare(&solved.theta)?;
    let (lo, hi) = if solved.contrast > 0.0 {
        (solved.black, solved.black + solved.contrast)
    } else {
        (solved.black + solved.contrast, solved.black)
    };
    // Light pixels (the drawing's light part, away from edges): their
    // grey over the light level.
    let light: Vec<(Pt, f64)> = pixels
        .iter()
        .zip(centred)
        .filter_map(|((x, grey), (c, _))| {
            let p = shape.value(*x, None);
            let level = solved.black + solved.contrast * p;
            let lightness = (level - lo) / (hi - lo);
            (lightness > 0.9 && level > 1.0).then_some((*c, grey / level))
        })
        .collect();
    let n = light.len();
    if n < 20 {
        return None;
    }
    let mut best: Option<(f64, [f64; SHADOW], f64)> = None;
    let mut proj: Vec<(f64, f64)> = Vec::with_capacity(n);
    for step in 0..36 {
        let angle = step as f64 * std::f64::consts::PI / 18.0;
        let (sn, cs) = angle.sin_cos();
        proj.clear();
        proj.extend(light.iter().map(|(c, q)| (cs * c.0 + sn * c.1, *q)));
        proj.sort_by(|a, b| a.0.total_cmp(&b.0));
        let total: f64 = proj.iter().map(|p| p.1).sum();
        let mut below = 0.0;
        for k in 0..n - 1 {
            below += proj[k].1;
            let (nb, na) = ((k + 1) as f64, (n - k - 1) as f64);
            if nb < 0.1 * n as f64 || na < 0.1 * n as f64 {
                continue;
            }
            let (mb, ma) = (below / nb, (total - below) / na);
            // Shadow past the line: the far side darker.
            if ma >= mb * (1.0 - MIN_SHADOW) {
                continue;
            }
            let score = (mb - ma) * (nb * na / n as f64).sqrt();
            if best.as_ref().is_none_or(|b| score > b.0) {
                let offset = 0.5 * (proj[k].0 + proj[k + 1].0);
                best = Some((score, [angle, offset, 1.0 - ma / mb, 1.0], mb));
            }
        }
    }
    best.map(|(_, s, lit)| (s, lit))
}

/// One robust Gauss-Newton fit of `theta` (the shape's unknowns, then the
/// two levels), with the shadow `shadow` when given (its unknowns follow).
/// Returns the solution and its final cost per pixel at the final scale.
fn fit_pass<S: Shape>(
    shape: &mut S,
    pixels: &[(Pt, f64)],
    centred: &[(Pt, f64)],
    mut theta: Vec<f64>,
    shadow: Option<[f64; SHADOW]>,
    moves: &[usize],
    params: &FitParams,
) -> Option<(Solved, f64)> {
    let g = theta.len() - 2;
    if let Some(s) = shadow {
        theta.extend(s);
    }
    let n = theta.len();
    let shaded = shadow.is_some();
    let model = |shape: &S, t: &[f64], k: usize, grad: Option<&mut [f64]>| -> f64 {
        let (x, _) = pixels[k];
        match grad {
            None => {
                let level = t[g] + t[g + 1] * shape.value(x, None);
                if shaded {
                    level * shadow_at(centred[k].0, &t[g + 2..]).0
                } else {
                    level
                }
            }
            Some(j) => {
                let p = shape.value(x, Some(&mut j[..g]));
                let level = t[g] + t[g + 1] * p;
                let (dark, ds) = if shaded {
                    shadow_at(centred[k].0, &t[g + 2..])
                } else {
                    (1.0, [0.0; SHADOW])
                };
                for v in &mut j[..g] {
                    *v *= t[g + 1] * dark;
                }
                j[g] = dark;
                j[g + 1] = p * dark;
                if shaded {
                    for q in 0..SHADOW {
                        j[g + 2 + q] = level * ds[q];
                    }
                }
                level * dark
            }
        }
    };
    let residuals = |shape: &mut S, t: &[f64]| -> Option<Vec<f64>> {
        shape.prepare(&t[..g])?;
        let shape = &*shape;
        Some(
            (0..pixels.len())
                .map(|k| pixels[k].1 - model(shape, t, k, None))
                .collect(),
        )
    };
    let robust_scale = |r: &[f64]| -> f64 {
        let mut a: Vec<f64> = r.iter().map(|v| v.abs()).collect();
        (1.4826 * median(&mut a)).max(1.0)
    };
    let tukey = |r: f64, s: f64| -> f64 {
        let z = r / (params.tukey * s);
        if z.abs() >= 1.0 {
            0.0
        } else {
            (1.0 - z * z).powi(2)
        }
    };
    let cost = |r: &[f64], s: f64| -> f64 {
        r.iter()
            .map(|v| {
                let z = (v / (params.tukey * s)).min(1.0);
                1.0 - (1.0 - z * z).powi(3)
            })
            .sum()
    };

    let mut r = residuals(shape, &theta)?;
    // The residuals' scale starts wide (an eighth of the contrast: the
    // starting geometry and blur put the edges' pixels off by that much)
    // and narrows each iteration to the residuals' own, so that pixels are
    // weighted out for not fitting the target, not for not fitting the
    // start.
    let mut wide = theta[g + 1].abs() / 8.0;
    let mut s = robust_scale(&r).max(wide);
    let mut lambda = 1e-3;
    let mut jtj = vec![0.0; n * n];
    let mut jtr = vec![0.0; n];
    let mut j = vec![0.0; n];
    for _ in 0..params.max_iterations {
        shape.prepare(&theta[..g])?;
        jtj.iter_mut().for_each(|v| *v = 0.0);
        jtr.iter_mut().for_each(|v| *v = 0.0);
        for (k, rk) in r.iter().enumerate() {
            let w = tukey(*rk, s);
            if w == 0.0 {
                continue;
            }
            model(shape, &theta, k, Some(&mut j));
            for a in 0..n {
                let ja = j[a];
                if ja == 0.0 {
                    continue;
                }
                jtr[a] += w * ja * rk;
                for b in 0..=a {
                    jtj[a * n + b] += w * ja * j[b];
                }
            }
        }
        // The upper triangle from the lower.
        for (a, b) in (0..n).flat_map(|a| (0..a).map(move |b| (a, b))) {
            jtj[b * n + a] = jtj[a * n + b];
        }
        let before = cost(&r, s);
        let mut moved = None;
        for _ in 0..6 {
            let mut damped = jtj.clone();
            for a in 0..n {
                damped[a * n + a] += lambda * jtj[a * n + a].max(1e-9);
            }
            let Some(step) = solve(&damped, &jtr) else {
                lambda *= 10.0;
                continue;
            };
            let mut t: Vec<f64> = theta.iter().zip(&step).map(|(a, b)| a + b).collect();
            shape.bound(&mut t[..g]);
            if shaded {
                t[g + 4] = t[g + 4].clamp(0.0, 0.95);
                t[g + 5] = t[g + 5].clamp(0.3, 10.0);
            }
            if let Some(r2) = residuals(shape, &t) {
                if cost(&r2, s) < before {
                    let most = moves.iter().map(|a| step[*a].abs()).fold(0.0, f64::max);
                    theta = t;
                    r = r2;
                    lambda = (lambda / 10.0).max(1e-7);
                    moved = Some(most);
                    break;
                }
            }
            lambda *= 10.0;
        }
        match moved {
            Some(most) => {
                wide /= 2.0;
                let own = robust_scale(&r);
                s = own.max(wide);
                if most < 1e-3 && wide <= own {
                    break;
                }
            }
            None if s > robust_scale(&r) => {
                wide /= 2.0;
                s = robust_scale(&r).max(wide);
            }
            None => break,
        }
    }
    let end = cost(&r, s) / r.len() as f64;
    let (black, contrast) = (theta[g], theta[g + 1]);
    theta.truncate(g);
    Some((
        Solved {
            theta,
            black,
            contrast,
            residual: s,
        },
        end,
    ))
}
