//! Rings around a candidate's ellipse: which ring design they show (edges
//! measured on the median radial profile and matched against each design's
//! ring radii), the ring edges each ray crosses, the subpixel ellipse fits,
//! and what makes a bullseye (every edge seen with alternating polarity, a
//! board past its outer ring).

use super::*;
use crate::pipeline::detect::design::{Polarity, TargetDesign};

/// A ring design in the units rays use: edge positions as multiples of
/// the centre disc's radius.
#[derive(Debug, Clone)]
pub(super) struct RingLayout {
    /// Ring radii ranges over the outermost edge, from the design.
    pub radii: Vec<(f64, f64)>,
    /// The centre disc is dark (its edge rises going outward).
    pub dark_centre: bool,
}

impl RingLayout {
    pub fn from_design(d: &TargetDesign) -> Option<RingLayout> {
        Some(RingLayout {
            radii: d.ring_radii.as_ref()?.iter().map(|r| (r.0, r.1)).collect(),
            dark_centre: d.polarity == Polarity::DarkOnLight,
        })
    }
    /// Farthest the outermost edge may lie, in centre-disc radii.
    pub fn reach(&self) -> f64 {
        1.0 / self.radii[0].0
    }
    /// Expected sign of edge `k` (+1: lighter outside).
    fn sign(&self, k: usize) -> f64 {
        let first = if self.dark_centre { 1.0 } else { -1.0 };
        if k.is_multiple_of(2) {
            first
        } else {
            -first
        }
    }
}

/// Past a bullseye's outer edge, no other edge within this multiple of
/// its radius (the board's margin; designs have 1.1 and more).
const BOARD_MARGIN: f64 = 1.1;

/// Edges of the median radial profile around `e` out to `s_max` (in
/// multiples of `e`'s radii): positions and signed contrasts (+: lighter
/// outside). The median over rays ignores what crosses a few of them (a
/// shadow's edge over less than half of the rings, clutter).
pub(super) fn radial_edges(
    img: &GreyView,
    e: &Ellipse,
    s_max: f64,
    params: &Params,
) -> Vec<(f64, f64)> {
    let rays = 64;
    let ds = 0.5 / e.radius().max(1.0);
    let len = (s_max / ds) as usize + 1;
    let mut columns: Vec<Vec<f64>> = vec![Vec::with_capacity(rays); len];
    for i in 0..rays {
        let d = e.ray(std::f64::consts::TAU * i as f64 / rays as f64);
        for (j, column) in columns.iter_mut().enumerate() {
            let s = j as f64 * ds;
            match img.sample(e.c.0 + d.0 * s, e.c.1 + d.1 * s) {
                Some(v) => column.push(v),
                None => break,
            }
        }
    }
    // Where fewer than half the rays still see the image, the profile ends.
    let m: Vec<f64> = columns
        .iter_mut()
        .take_while(|c| c.len() >= rays / 2)
        .map(|c| {
            let mid = c.len() / 2;
            *c.select_nth_unstable_by(mid, f64::total_cmp).1
        })
        .collect();
    profile_edges(&m, ds, params)
}

/// Edges of a profile sampled every `ds`: extremes of its slope over a
/// pixel either side, neighbours of one sign merged, and then, weakest
/// first, edges whose levels either side differ by less than the least
/// contrast dropped.
fn profile_edges(m: &[f64], ds: f64, params: &Params) -> Vec<(f64, f64)> {
    let w = 2;
    if m.len() < 2 * w + 3 {
        return Vec::new();
    }
    let g: Vec<f64> = (0..m.len())
        .map(|j| {
            if j < w || j + w >= m.len() {
                0.0
            } else {
                m[j + w] - m[j - w]
            }
        })
        .collect();
    // (index, slope) of each local extreme of the slope's size.
    let mut edges: Vec<(usize, f64)> = Vec::new();
    for j in 1..g.len() - 1 {
        if g[j].abs() >= 0.25 * params.min_contrast
            && g[j].abs() >= g[j - 1].abs()
            && g[j].abs() > g[j + 1].abs()
        {
            match edges.last_mut() {
                Some(last) if last.1.signum() == g[j].signum() => {
                    if g[j].abs() > last.1.abs() {
                        *last = (j, g[j]);
                    }
                }
                _ => edges.push((j, g[j])),
            }
        }
    }
    loop {
        // Levels of the stretches between edges (their middle halves).
        let mut bounds = vec![0usize];
        bounds.extend(edges.iter().map(|e| e.0));
        bounds.push(m.len() - 1);
        let level = |a: usize, b: usize| {
            let (lo, hi) = (a + (b - a) / 4, b - (b - a) / 4);
            pr::quantile(&m[lo..=hi.max(lo)], 0.5)
        };
        let steps: Vec<f64> = (0..edges.len())
            .map(|k| level(bounds[k + 1], bounds[k + 2]) - level(bounds[k], bounds[k + 1]))
            .collect();
        let weakest = steps
            .iter()
            .enumerate()
            .filter(|(k, step)| {
                step.abs() < 0.7 * params.min_contrast || step.signum() != edges[*k].1.signum()
            })
            .min_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
            .map(|(k, _)| k);
        match weakest {
            Some(k) => {
                edges.remove(k);
                // Neighbours of one sign are one edge: keep the steeper.
                if k > 0 && k < edges.len() && edges[k - 1].1.signum() == edges[k].1.signum() {
                    let drop = if edges[k - 1].1.abs() < edges[k].1.abs() {
                        k - 1
                    } else {
                        k
                    };
                    edges.remove(drop);
                }
            }
            None => {
                return edges
                    .iter()
                    .zip(&steps)
                    .map(|(e, step)| (e.0 as f64 * ds, *step))
                    .collect()
            }
        }
    }
}

/// The edge positions (centre-disc radii) of `layout` when the measured
/// `edges` show it: the first at the candidate's own edge (s = 1), then
/// one per ring radius with alternating polarity and the radii's ratios
/// within the design's ranges, then no edge within the board's margin.
pub(super) fn match_layout(
    layout: &RingLayout,
    edges: &[(f64, f64)],
    params: &Params,
) -> Option<Vec<f64>> {
    let first = edges.iter().position(|&(s, _)| (0.8..=1.25).contains(&s))?;
    let e = &edges[first..];
    let n = layout.radii.len();
    if e.len() < n {
        return None;
    }
    let outer = e[n - 1].0;
    for (k, &(s, step)) in e[..n].iter().enumerate() {
        let (lo, hi) = layout.radii[k];
        if step.signum() != layout.sign(k)
            || !((lo - params.ratio_tolerance)..=(hi + params.ratio_tolerance))
                .contains(&(s / outer))
        {
            return None;
        }
    }
    if e.get(n).is_some_and(|next| next.0 < BOARD_MARGIN * outer) {
        return None;
    }
    Some(e[..n].iter().map(|x| x.0).collect())
}

/// Bullseye: every edge seen on most rays, each with its design's polarity.
pub(super) fn is_bullseye(pass: &RayPass, layout: &RingLayout, params: &Params) -> bool {
    let n = pass.rays as f64;
    pass.edges.iter().enumerate().all(|(k, v)| {
        v.len() as f64 >= params.min_coverage * n
            && pass.polarity[k] * layout.sign(k) > 0.8 * v.len() as f64
    })
}

/// Whether a bullseye's outer ring lies on a board: along most rays the
/// level just past it comes back at least [`board_level`](Params::board_level) of the way from
/// the outer ring's level to the level of the ring inside it (a shadow
/// scales all alike). Rings that happen to be concentric on bare ground
/// are not a printed target (held-out clutter scene 2302: black disc,
/// white ring and black ring at 1/3, 2/3 and 1 on grey ground, 48 px,
/// where the clutter generator paints no bullseye: two of its circles
/// lying one on the other). `e` is the centre disc's edge (s = 1), `pos`
/// the edges' positions.
pub(super) fn bullseye_on_board(img: &GreyView, e: &Ellipse, pos: &[f64], params: &Params) -> bool {
    let n = 64;
    let k = pos.len();
    let start = |i: usize| if i == 0 { 0.0 } else { pos[i - 1] };
    // Middle stretches of the outer ring and of the ring inside it.
    let band = |i: usize| {
        let (a, b) = (start(i), pos[i]);
        (a + 0.35 * (b - a), a + 0.65 * (b - a))
    };
    let (inside, outer) = (band(k - 2), band(k - 1));
    let out = pos[k - 1];
    let past = (out * (1.0 + 0.4 * (BOARD_MARGIN - 1.0)), out * BOARD_MARGIN);
    let (mut seen, mut board) = (0, 0);
    for i in 0..n {
        let d = e.ray(std::f64::consts::TAU * i as f64 / n as f64);
        let level = |(from, to): (f64, f64)| -> Option<f64> {
            let mut sum = 0.0;
            for k in 0..4 {
                let s = from + (to - from) * k as f64 / 3.0;
                sum += img.sample(e.c.0 + d.0 * s, e.c.1 + d.1 * s)?;
            }
            Some(sum / 4.0)
        };
        let (Some(inside), Some(outer), Some(past)) = (level(inside), level(outer), level(past))
        else {
            continue;
        };
        if (inside - outer).abs() < 0.7 * params.min_contrast {
            continue;
        }
        seen += 1;
        if (past - outer) / (inside - outer) >= params.board_level {
            board += 1;
        }
    }
    seen >= n / 2 && board as f64 >= params.min_board_share * seen as f64
}

/// How well the rings drawn at `pos` (edges in multiples of `e`'s radii,
/// the centre disc dark when `dark_centre`, the board past the last edge)
/// match the image: the normalised correlation of log grey, so a shadow's
/// scaling changes little, sampled on three circles within the middle of
/// each ring. A printed bullseye's rings are uniform all round; the
/// stretches a lattice or paving shows around one of its cells cross light
/// and dark alike.
pub(super) fn rings_score(img: &GreyView, e: &Ellipse, pos: &[f64], dark_centre: bool) -> f64 {
    let n = 64;
    let (mut xs, mut ys) = (Vec::new(), Vec::new());
    let last = pos[pos.len() - 1];
    for k in 0..=pos.len() {
        let from = if k == 0 { 0.3 * pos[0] } else { pos[k - 1] };
        let to = if k < pos.len() {
            pos[k]
        } else {
            last * BOARD_MARGIN
        };
        let light = (k % 2 == 0) != dark_centre;
        for f in [0.35, 0.5, 0.65] {
            let s = from + f * (to - from);
            for i in 0..n {
                let d = e.ray(std::f64::consts::TAU * (i as f64 + 0.5 * f) / n as f64);
                if let Some(v) = img.sample(e.c.0 + d.0 * s, e.c.1 + d.1 * s) {
                    xs.push((v + 1.0).ln());
                    ys.push(if light { 1.0 } else { 0.0 });
                }
            }
        }
    }
    correlation(&xs, &ys)
}

/// Pearson correlation of two samples (0 when either is constant).
fn correlation(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len().max(1) as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx) * (a - mx);
        syy += (b - my) * (b - my);
    }
    if sxx <= 0.0 || syy <= 0.0 {
        return 0.0;
    }
    sxy / (sxx * syy).sqrt()
}

/// Samples rays through the ellipse frame and finds each edge's midpoint
/// crossing near its position in `pos` (multiples of the ellipse's radii);
/// `beyond` is how far past the last edge its outer level may be read.
pub(super) fn rays(
    img: &GreyView,
    e: &Ellipse,
    pos: &[f64],
    beyond: f64,
    params: &Params,
) -> Option<RayPass> {
    let edges = pos.len();
    let n = ((std::f64::consts::TAU * e.a.max(e.b)).round() as usize).clamp(32, 360);
    let mut out = RayPass {
        edges: vec![Vec::new(); edges],
        polarity: vec![0.0; edges],
        contrast: 0.0,
        light_ratio: 0.0,
        rays: n,
    };
    let mut ratios = Vec::new();
    // Each edge's stretch inside and outside: the gaps to its neighbours.
    let gaps: Vec<(f64, f64)> = (0..edges)
        .map(|k| {
            let inner = pos[k] - if k == 0 { 0.0 } else { pos[k - 1] };
            let outer = if k + 1 < edges {
                pos[k + 1] - pos[k]
            } else {
                beyond
            };
            (inner, outer)
        })
        .collect();
    let mut contrasts = Vec::new();
    let s_max = pos[edges - 1] + 0.45 * beyond + 0.05;
    let mut profile = Vec::new();
    for i in 0..n {
        let phi = std::f64::consts::TAU * i as f64 / n as f64;
        let d = e.ray(phi);
        let len = d.0.hypot(d.1);
        if len < 1.0 {
            return None;
        }
        let ds = pr::STEP_PX / len;
        profile.clear();
        let mut s = 0.0;
        while s <= s_max {
            match img.sample(e.c.0 + d.0 * s, e.c.1 + d.1 * s) {
                Some(v) => profile.push(v),
                None => break,
            }
            s += ds;
        }
        let idx = |s: f64| (s / ds).round() as usize;
        for (k, (&edge, &(g_in, g_out))) in pos.iter().zip(&gaps).enumerate() {
            if idx(edge + 0.45 * g_out) >= profile.len() {
                break;
            }
            let inside = pr::mean(&profile, idx(edge - 0.45 * g_in), idx(edge - 0.2 * g_in));
            let outside = pr::mean(&profile, idx(edge + 0.2 * g_out), idx(edge + 0.45 * g_out));
            if (outside - inside).abs() < 0.7 * params.min_contrast {
                continue;
            }
            let rising = outside > inside;
            let Some(x) = pr::crossing(&profile, (inside + outside) / 2.0, rising, edge / ds)
            else {
                continue;
            };
            let s_hit = x * ds;
            if (s_hit - edge).abs() > 0.3 * g_in.min(g_out) {
                continue;
            }
            out.edges[k].push((e.c.0 + d.0 * s_hit, e.c.1 + d.1 * s_hit));
            out.polarity[k] += if rising { 1.0 } else { -1.0 };
            if k == 0 {
                contrasts.push((outside - inside).abs());
                ratios.push(outside.max(inside) / outside.min(inside).max(1.0));
            }
        }
    }
    if contrasts.is_empty() {
        return None;
    }
    out.contrast = pr::quantile(&contrasts, 0.5);
    out.light_ratio = pr::quantile(&ratios, 0.5);
    Some(out)
}

/// OpenCV's direct least-squares ellipse fit of subpixel edge points.
pub(super) fn fit(points: &[Pt]) -> Option<Ellipse> {
    if points.len() < 8 {
        return None;
    }
    let v: Vector<Point2f> = points
        .iter()
        .map(|p| Point2f::new(p.0 as f32, p.1 as f32))
        .collect();
    let r = imgproc::fit_ellipse_direct(&v).ok()?;
    let e = Ellipse::from_rect(r);
    (e.a.is_finite() && e.b.is_finite() && e.a > 1.0 && e.b > 1.0).then_some(e)
}

/// [`fit`], then again without the points farther from the first ellipse
/// than 2.5 robust standard deviations (at least 0.1 px): edge points where a
/// shadow edge or a blemish crosses the ring. Returns the inliers too.
pub(super) fn fit_robust(points: &[Pt]) -> Option<(Ellipse, Vec<Pt>)> {
    let first = fit(points)?;
    let r: Vec<f64> = points.iter().map(|p| first.distance(*p).abs()).collect();
    let inliers = pr::inliers(points, &r);
    Some((fit(&inliers)?, inliers))
}

pub(super) fn rms(e: &Ellipse, points: &[Pt]) -> f64 {
    let ss: f64 = points.iter().map(|p| e.distance(*p).powi(2)).sum();
    (ss / points.len().max(1) as f64).sqrt()
}
