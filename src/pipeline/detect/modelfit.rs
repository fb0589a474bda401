//! Subpixel fit of a known black-and-white pattern to the image: once a
//! coded tag is decoded, every one of its cells is known, so the whole tag
//! (border, data cells and quiet zone) can be drawn and compared with the
//! pixels. The fit moves the pattern's four corners (a homography), the
//! blur and the two grey levels until the drawn pattern matches the image
//! in least squares, pixels that do not fit (clutter over the quiet zone, a
//! shadow over part of the tag) weighted down by a robust (Tukey) weight.
//!
//! Against fitting lines to the outer edges only ([`super::refine`]), every
//! cell edge inside the tag takes part: a small blurred tag has four
//! short outer edges but dozens of inner ones.
//!
//! The model, in pattern coordinates `(u, v)` (cells; cell `(i, j)` covers
//! `[i, i+1] x [j, j+1]`): `grey = a + b * P(u, v)`, where `P` is the
//! pattern (1 white, 0 black) blurred by a Gaussian of `sigma` cells. The
//! blur is separable, so `P(u, v) = sum_ij cell_ij X_i(u) Y_j(v)` with
//! `X_i(u) = Phi((u - i) / sigma) - Phi((u - i - 1) / sigma)`.

use super::geometry::{apply, invert3, square_to_quad, Pt};
use super::refine::GreyView;

/// A black-and-white pattern of square cells, true for white, and the
/// square of it whose corners the fit reports.
#[derive(Debug, Clone)]
pub struct Pattern {
    /// Cells a side.
    side: usize,
    /// Row-major, `side * side`.
    white: Vec<bool>,
    /// The reported square: from cell `first` to cell `first + cells`
    /// (exclusive) on both axes.
    first: usize,
    cells: usize,
}

impl Pattern {
    /// A pattern from rows of cells (true for white), its corners those of
    /// the `cells`-wide square centred in it; the pattern continues in
    /// white past its outer cells (a classic tag's quiet zone).
    pub fn new(rows: &[Vec<bool>], cells: usize) -> Option<Pattern> {
        let side = rows.len();
        if side == 0 || cells == 0 || cells > side || rows.iter().any(|r| r.len() != side) {
            return None;
        }
        Some(Pattern {
            side,
            white: rows.iter().flatten().copied().collect(),
            first: (side - cells) / 2,
            cells,
        })
    }

    fn at(&self, i: i64, j: i64) -> f64 {
        if i < 0 || j < 0 || i >= self.side as i64 || j >= self.side as i64 {
            return 1.0;
        }
        if self.white[j as usize * self.side + i as usize] {
            1.0
        } else {
            0.0
        }
    }
}

/// Settings of [`fit`].
#[derive(Debug, Clone, Copy)]
pub struct FitParams {
    /// Gauss-Newton iterations at most.
    pub max_iterations: usize,
    /// Pixels are taken from the pattern's square out to this many cells
    /// inside its outer side (the quiet zone's far part meets the ground).
    pub inset_cells: f64,
    /// At most this many pixels are used (a regular subsample of larger
    /// tags): the fit's precision is long past its need there.
    pub max_pixels: usize,
    /// Tukey's constant, in robust standard deviations of the residuals.
    pub tukey: f64,
}

impl Default for FitParams {
    fn default() -> Self {
        FitParams {
            max_iterations: 20,
            inset_cells: 0.15,
            max_pixels: 3000,
            tukey: 4.685,
        }
    }
}

/// The fitted pattern.
#[derive(Debug, Clone, Copy)]
pub struct Fitted {
    /// The reported square's corners, in the order of the corners given.
    pub corners: [Pt; 4],
    /// The blur's standard deviation, in cells.
    pub blur_cells: f64,
    /// Grey levels of black and white.
    pub black: f64,
    pub white: f64,
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

/// The blurred pattern at `(u, v)` and its derivatives by u, v and sigma.
fn blurred(p: &Pattern, u: f64, v: f64, sigma: f64) -> [f64; 4] {
    // Cells farther than 3.5 sigma from the point weigh under 1/4000.
    let reach = 3.5 * sigma;
    let (iu, iv) = ((u - reach).floor() as i64, (v - reach).floor() as i64);
    let n = (((u + reach).floor() as i64 - iu).max((v + reach).floor() as i64 - iv) + 1) as usize;
    // Per axis: weight of each cell, its derivative by the coordinate and
    // by sigma.
    let axis = |x: f64, i: i64| {
        let (a, b) = ((x - i as f64) / sigma, (x - i as f64 - 1.0) / sigma);
        let ((ca, pa), (cb, pb)) = (normal(a), normal(b));
        (ca - cb, (pa - pb) / sigma, (-pa * a + pb * b) / sigma)
    };
    let mut xs = [(0.0, 0.0, 0.0); 16];
    let mut ys = [(0.0, 0.0, 0.0); 16];
    let n = n.min(16);
    for k in 0..n {
        xs[k] = axis(u, iu + k as i64);
        ys[k] = axis(v, iv + k as i64);
    }
    let mut out = [0.0; 4];
    for (ky, y) in ys.iter().enumerate().take(n) {
        let j = iv + ky as i64;
        for (kx, x) in xs.iter().enumerate().take(n) {
            let c = p.at(iu + kx as i64, j);
            if c == 0.0 {
                continue;
            }
            out[0] += x.0 * y.0;
            out[1] += x.1 * y.0;
            out[2] += x.0 * y.1;
            out[3] += x.2 * y.0 + x.0 * y.2;
        }
    }
    out
}

/// Maps image points to pattern coordinates for the reported square's
/// corners `c`.
struct ToPattern {
    inv: [f64; 9],
    first: f64,
    cells: f64,
}

impl ToPattern {
    fn new(c: &[Pt; 4], p: &Pattern) -> Option<ToPattern> {
        Some(ToPattern {
            inv: invert3(&square_to_quad(c))?,
            first: p.first as f64,
            cells: p.cells as f64,
        })
    }

    fn map(&self, x: Pt) -> Pt {
        let (s, t) = apply(&self.inv, x);
        (self.first + s * self.cells, self.first + t * self.cells)
    }
}

/// Unknowns: 8 corner coordinates, sigma (cells), black, contrast.
const N: usize = 11;

/// Solves the symmetric system `a x = b` (Cholesky); None when not
/// positive definite.
fn solve(a: &[[f64; N]; N], b: &[f64; N]) -> Option<[f64; N]> {
    let mut l = [[0.0; N]; N];
    for i in 0..N {
        for j in 0..=i {
            let s = a[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>();
            if i == j {
                if s <= 0.0 {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    let mut y = [0.0; N];
    for i in 0..N {
        y[i] = (b[i] - (0..i).map(|k| l[i][k] * y[k]).sum::<f64>()) / l[i][i];
    }
    let mut x = [0.0; N];
    for i in (0..N).rev() {
        x[i] = (y[i] - (i + 1..N).map(|k| l[k][i] * x[k]).sum::<f64>()) / l[i][i];
    }
    Some(x)
}

fn median(v: &mut [f64]) -> f64 {
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// Fits `pattern` to `img` from the reported square's corners `init`
/// (tile pixels, pixel centres on integers). None when the pattern leaves
/// the image, the system is singular, or the levels come out reversed.
pub fn fit(
    img: &GreyView,
    pattern: &Pattern,
    init: &[Pt; 4],
    params: &FitParams,
) -> Option<Fitted> {
    let to = ToPattern::new(init, pattern)?;
    let lo = params.inset_cells;
    let hi = pattern.side as f64 - params.inset_cells;
    // The pixels whose pattern coordinates lie in the fitted area: the
    // bounding box of the pattern's outline, scanned.
    let outline = square_to_quad(init);
    let scale = pattern.cells as f64;
    let first = pattern.first as f64;
    let corner = |u: f64, v: f64| apply(&outline, ((u - first) / scale, (v - first) / scale));
    let box_pts = [
        corner(lo, lo),
        corner(hi, lo),
        corner(hi, hi),
        corner(lo, hi),
    ];
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for (x, y) in box_pts {
        x0 = x0.min(x);
        y0 = y0.min(y);
        x1 = x1.max(x);
        y1 = y1.max(y);
    }
    if x0 < 0.0 || y0 < 0.0 || x1 > (img.width - 1) as f64 || y1 > (img.height - 1) as f64 {
        return None;
    }
    let (x0, y0, x1, y1) = (
        x0.floor() as usize,
        y0.floor() as usize,
        x1.ceil() as usize,
        y1.ceil() as usize,
    );
    let area = ((x1 - x0 + 1) * (y1 - y0 + 1)) as f64;
    let stride = ((area / params.max_pixels as f64).sqrt().ceil() as usize).max(1);
    let cell_px = super::geometry::mean_side(init) / pattern.cells as f64;
    let sigma0 = (0.8 / cell_px).clamp(0.05, 1.5);
    // The geometry is in the pixels near the cells' edges; of those inside
    // a cell, farther than the blur and the start's error from any edge,
    // one in FLAT is enough for the levels.
    const FLAT: usize = 4;
    let near = 0.02 * sigma0.recip().min(4.0);
    let mut pixels: Vec<(Pt, f64)> = Vec::new();
    let mut flat = 0;
    for y in (y0..=y1).step_by(stride) {
        for x in (x0..=x1).step_by(stride) {
            let p = (x as f64, y as f64);
            let (u, v) = to.map(p);
            if u >= lo && u <= hi && v >= lo && v <= hi {
                let b = blurred(pattern, u, v, 2.0 * sigma0);
                if b[1].abs() + b[2].abs() < near {
                    flat += 1;
                    if flat % FLAT != 0 {
                        continue;
                    }
                }
                pixels.push((p, img.data[y * img.stride + x] as f64));
            }
        }
    }
    if pixels.len() < 4 * N {
        return None;
    }
    // Starting levels: the darkest and lightest tenth of the pixels.
    let mut greys: Vec<f64> = pixels.iter().map(|p| p.1).collect();
    greys.sort_by(f64::total_cmp);
    let tenth = greys.len() / 10;
    let black0 = greys[..tenth.max(1)].iter().sum::<f64>() / tenth.max(1) as f64;
    let white0 = greys[greys.len() - tenth.max(1)..].iter().sum::<f64>() / tenth.max(1) as f64;
    if white0 - black0 < 10.0 {
        return None;
    }
    let mut theta = [0.0; N];
    for (k, c) in init.iter().enumerate() {
        theta[2 * k] = c.0;
        theta[2 * k + 1] = c.1;
    }
    theta[8] = sigma0;
    theta[9] = black0;
    theta[10] = white0 - black0;

    let corners_of = |t: &[f64; N]| -> [Pt; 4] { [0, 1, 2, 3].map(|k| (t[2 * k], t[2 * k + 1])) };
    // Residuals and their robust scale at `t`.
    let residuals = |t: &[f64; N]| -> Option<Vec<f64>> {
        let to = ToPattern::new(&corners_of(t), pattern)?;
        Some(
            pixels
                .iter()
                .map(|(x, g)| {
                    let (u, v) = to.map(*x);
                    g - (t[9] + t[10] * blurred(pattern, u, v, t[8])[0])
                })
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

    let mut r = residuals(&theta)?;
    // The residuals' scale starts wide (an eighth of the contrast: the
    // starting corners and blur put the edges' pixels off by that much)
    // and narrows each iteration to the residuals' own, so that pixels are
    // weighted out for not fitting the pattern, not for not fitting the
    // start.
    let mut wide = theta[10] / 8.0;
    let mut s = robust_scale(&r).max(wide);
    let mut lambda = 1e-3;
    const EPS: f64 = 1e-3;
    for _ in 0..params.max_iterations {
        let c = corners_of(&theta);
        let base = ToPattern::new(&c, pattern)?;
        // Pattern coordinates with each corner coordinate nudged by EPS.
        let nudged: Vec<ToPattern> = (0..8)
            .map(|k| {
                let mut t = theta;
                t[k] += EPS;
                ToPattern::new(&corners_of(&t), pattern)
            })
            .collect::<Option<_>>()?;
        let mut jtj = [[0.0; N]; N];
        let mut jtr = [0.0; N];
        for (k, (x, _)) in pixels.iter().enumerate() {
            let w = tukey(r[k], s);
            if w == 0.0 {
                continue;
            }
            let (u, v) = base.map(*x);
            let [p0, pu, pv, ps] = blurred(pattern, u, v, theta[8]);
            let mut j = [0.0; N];
            for (q, to) in nudged.iter().enumerate() {
                let (u2, v2) = to.map(*x);
                j[q] = theta[10] * (pu * (u2 - u) + pv * (v2 - v)) / EPS;
            }
            j[8] = theta[10] * ps;
            j[9] = 1.0;
            j[10] = p0;
            for a in 0..N {
                if j[a] == 0.0 {
                    continue;
                }
                jtr[a] += w * j[a] * r[k];
                for b in 0..=a {
                    jtj[a][b] += w * j[a] * j[b];
                }
            }
        }
        // The upper triangle from the lower.
        for (a, b) in (0..N).flat_map(|a| (0..a).map(move |b| (a, b))) {
            jtj[b][a] = jtj[a][b];
        }
        let before = cost(&r, s);
        let mut moved = None;
        for _ in 0..6 {
            let mut damped = jtj;
            for (a, row) in damped.iter_mut().enumerate() {
                row[a] += lambda * jtj[a][a].max(1e-9);
            }
            let Some(step) = solve(&damped, &jtr) else {
                lambda *= 10.0;
                continue;
            };
            let mut t = theta;
            for a in 0..N {
                t[a] += step[a];
            }
            // Wider blurs reach past the cells `blurred` sums.
            t[8] = t[8].clamp(0.02, 1.5);
            if let Some(r2) = residuals(&t) {
                if cost(&r2, s) < before {
                    let most = (0..8).map(|a| step[a].abs()).fold(0.0, f64::max);
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
    if theta[10] <= 0.0 {
        return None;
    }
    let corners = corners_of(&theta);
    Some(Fitted {
        corners,
        blur_cells: theta[8],
        black: theta[9],
        white: theta[9] + theta[10],
        residual: s,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 6x6 pattern: white ring, black border, a 2x2 code.
    fn pattern() -> Pattern {
        let code = [[true, false], [false, false]];
        let rows: Vec<Vec<bool>> = (0..6)
            .map(|j| {
                (0..6)
                    .map(|i| {
                        if i == 0 || j == 0 || i == 5 || j == 5 {
                            true
                        } else if i == 1 || j == 1 || i == 4 || j == 4 {
                            false
                        } else {
                            code[j - 2][i - 2]
                        }
                    })
                    .collect()
            })
            .collect();
        Pattern::new(&rows, 4).unwrap()
    }

    /// Draws the pattern blurred by `blur` px under the square `c`,
    /// supersampled, with levels 40 and 200.
    fn draw(p: &Pattern, c: &[Pt; 4], blur_px: f64, w: usize) -> Vec<u8> {
        let to = ToPattern::new(c, p).unwrap();
        let cell = super::super::geometry::mean_side(c) / p.cells as f64;
        (0..w * w)
            .map(|k| {
                let (x, y) = ((k % w) as f64, (k / w) as f64);
                let (u, v) = to.map((x, y));
                let g = 40.0 + 160.0 * blurred(p, u, v, blur_px / cell)[0];
                g.round() as u8
            })
            .collect()
    }

    #[test]
    fn a_blurred_tag_is_placed_to_a_hundredth_of_a_pixel_from_a_rough_start() {
        let p = pattern();
        let truth = [(30.3, 28.7), (62.1, 31.2), (59.4, 63.9), (27.8, 60.6)];
        let data = draw(&p, &truth, 1.3, 96);
        let img = GreyView {
            data: &data,
            width: 96,
            height: 96,
            stride: 96,
        };
        let start = [(30.0, 29.2), (62.5, 31.0), (59.0, 64.3), (28.3, 60.1)];
        let f = fit(&img, &p, &start, &FitParams::default()).expect("fitted");
        for (a, b) in f.corners.iter().zip(truth) {
            assert!(
                super::super::geometry::dist(*a, b) < 0.01,
                "{:?} vs {truth:?}",
                f.corners
            );
        }
        let cell = super::super::geometry::mean_side(&truth) / 4.0;
        assert!((f.blur_cells * cell - 1.3).abs() < 0.05, "{}", f.blur_cells);
    }

    #[test]
    fn clutter_over_the_quiet_zone_is_weighted_out() {
        let p = pattern();
        let truth = [(30.3, 28.7), (62.1, 31.2), (59.4, 63.9), (27.8, 60.6)];
        let mut data = draw(&p, &truth, 1.0, 96);
        // A dark object over the left quiet zone, up to the border (whose
        // outer side runs from x = 30.3 to 27.8).
        for y in 35..55 {
            for x in 20..29 {
                data[y * 96 + x] = 25;
            }
        }
        let img = GreyView {
            data: &data,
            width: 96,
            height: 96,
            stride: 96,
        };
        let f = fit(&img, &p, &truth, &FitParams::default()).expect("fitted");
        let centre = super::super::geometry::diagonal_intersection(&f.corners);
        let want = super::super::geometry::diagonal_intersection(&truth);
        assert!(
            super::super::geometry::dist(centre, want) < 0.03,
            "{centre:?} vs {want:?}"
        );
    }
}
