//! A decoded tag drawn cell by cell: its pattern in pattern coordinates
//! `(u, v)` (cells; cell `(i, j)` covers `[i, i+1] x [j, j+1]`), placed by
//! the homography of its reported square's four corners. The blur is
//! separable there, so `P(u, v) = sum_ij cell_ij X_i(u) Y_j(v)` with
//! `X_i(u) = Phi((u - i) / sigma) - Phi((u - i - 1) / sigma)`, sigma in cells.

use super::super::geometry::{apply, invert3, mean_side, square_to_quad, Pt};
use super::super::refine::GreyView;
use super::{normal, robust_fit, FitParams, Shape};

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

/// A tag's fitted square.
#[derive(Debug, Clone, Copy)]
pub struct FittedTag {
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

/// Unknowns: the 8 corner coordinates, then sigma in cells.
struct TagShape<'a> {
    pattern: &'a Pattern,
    base: Option<ToPattern>,
    /// The map with each corner coordinate nudged by EPS.
    nudged: Vec<ToPattern>,
    sigma: f64,
}

/// Corner coordinates are nudged by this for their derivatives.
const EPS: f64 = 1e-3;

fn corners_of(t: &[f64]) -> [Pt; 4] {
    [0, 1, 2, 3].map(|k| (t[2 * k], t[2 * k + 1]))
}

impl Shape for TagShape<'_> {
    fn prepare(&mut self, theta: &[f64]) -> Option<()> {
        self.base = Some(ToPattern::new(&corners_of(theta), self.pattern)?);
        self.nudged = (0..8)
            .map(|k| {
                let mut t = theta.to_vec();
                t[k] += EPS;
                ToPattern::new(&corners_of(&t), self.pattern)
            })
            .collect::<Option<_>>()?;
        self.sigma = theta[8];
        Some(())
    }

    fn value(&self, x: Pt, grad: Option<&mut [f64]>) -> f64 {
        let base = self.base.as_ref().expect("prepared");
        let (u, v) = base.map(x);
        let [p0, pu, pv, ps] = blurred(self.pattern, u, v, self.sigma);
        if let Some(grad) = grad {
            for (q, to) in self.nudged.iter().enumerate() {
                let (u2, v2) = to.map(x);
                grad[q] = (pu * (u2 - u) + pv * (v2 - v)) / EPS;
            }
            grad[8] = ps;
        }
        p0
    }

    fn bound(&self, theta: &mut [f64]) {
        // Wider blurs reach past the cells `blurred` sums.
        theta[8] = theta[8].clamp(0.02, 1.5);
    }
}

/// Pixels are taken from the pattern's square out to this many cells
/// inside its outer side (the quiet zone's far part meets the ground).
const INSET_CELLS: f64 = 0.15;

/// Fits `pattern` to `img` from the reported square's corners `init`
/// (tile pixels, pixel centres on integers). None when the pattern leaves
/// the image, the system is singular, or the levels come out reversed.
pub fn fit_tag(
    img: &GreyView,
    pattern: &Pattern,
    init: &[Pt; 4],
    params: &FitParams,
) -> Option<FittedTag> {
    let to = ToPattern::new(init, pattern)?;
    let lo = INSET_CELLS;
    let hi = pattern.side as f64 - INSET_CELLS;
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
    let cell_px = mean_side(init) / scale;
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
    if pixels.is_empty() {
        return None;
    }
    // Starting levels: the darkest and lightest tenth of the pixels.
    let mut greys: Vec<f64> = pixels.iter().map(|p| p.1).collect();
    greys.sort_by(f64::total_cmp);
    let tenth = (greys.len() / 10).max(1);
    let black0 = greys[..tenth].iter().sum::<f64>() / tenth as f64;
    let white0 = greys[greys.len() - tenth..].iter().sum::<f64>() / tenth as f64;
    if white0 - black0 < 10.0 {
        return None;
    }
    let mut theta: Vec<f64> = init.iter().flat_map(|c| [c.0, c.1]).collect();
    theta.push(sigma0);
    let mut shape = TagShape {
        pattern,
        base: None,
        nudged: Vec::new(),
        sigma: sigma0,
    };
    let solved = robust_fit(
        &mut shape,
        &pixels,
        theta,
        (black0, white0 - black0),
        &[0, 1, 2, 3, 4, 5, 6, 7],
        params,
    )?;
    if solved.contrast <= 0.0 {
        return None;
    }
    Some(FittedTag {
        corners: corners_of(&solved.theta),
        blur_cells: solved.theta[8],
        black: solved.black,
        white: solved.black + solved.contrast,
        residual: solved.residual,
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
        let cell = super::super::super::geometry::mean_side(c) / p.cells as f64;
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
        let f = fit_tag(&img, &p, &start, &FitParams::default()).expect("fitted");
        for (a, b) in f.corners.iter().zip(truth) {
            assert!(
                super::super::super::geometry::dist(*a, b) < 0.01,
                "{:?} vs {truth:?}",
                f.corners
            );
        }
        let cell = super::super::super::geometry::mean_side(&truth) / 4.0;
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
        let f = fit_tag(&img, &p, &truth, &FitParams::default()).expect("fitted");
        let centre = super::super::super::geometry::diagonal_intersection(&f.corners);
        let want = super::super::super::geometry::diagonal_intersection(&truth);
        assert!(
            super::super::super::geometry::dist(centre, want) < 0.03,
            "{centre:?} vs {want:?}"
        );
    }
}
