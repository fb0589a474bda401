//! Printed crosses and checkers drawn from their two lines. A cross is the
//! union of two straight bars through its centre, each a band whose width
//! may change linearly along it (perspective); a checker is the two
//! boundary lines through its centre, light where both sides agree. Only
//! the parts the design fixes are fitted: a cross's bars and a band of the
//! board beside them (a marking in a free quadrant that touches a bar is
//! weighted out as a misfit), a checker's board near its two lines; the
//! board's outer sides, where the ground begins, are left out.

use super::super::geometry::Pt;
use super::super::refine::GreyView;
use super::{normal, robust_fit, FitParams, Shape};

/// A printed target's two lines as found: its centre, the lines' unit
/// directions, its arms' lengths (along `dirs[0]`, `dirs[1]`, `-dirs[0]`,
/// `-dirs[1]`) and, for a cross, its bars' widths (the bar along
/// `dirs[0]`, the bar along `dirs[1]`), pixels.
#[derive(Debug, Clone, Copy)]
pub struct Lines {
    pub centre: Pt,
    pub dirs: [Pt; 2],
    pub lengths: [f64; 4],
    pub bar: [f64; 2],
}

/// The fitted lines.
#[derive(Debug, Clone, Copy)]
pub struct FittedLines {
    pub centre: Pt,
    pub dirs: [Pt; 2],
    /// The blur's standard deviation, pixels.
    pub blur_px: f64,
    /// Grey of the light parts less the dark ones.
    pub contrast: f64,
    /// Robust standard deviation of the residuals, grey levels.
    pub residual: f64,
}

/// Share of each arm fitted, from the centre: the rest reaches the board's
/// side, past which lies the ground.
const ARM_SHARE: f64 = 0.85;
/// Starting blur, pixels.
const BLUR0: f64 = 1.0;

fn unit(a: f64) -> Pt {
    (a.cos(), a.sin())
}

/// Along- and across-line coordinates of `x` for a line through `c` at
/// angle `a`: `(t, d)`.
fn local(x: Pt, c: Pt, a: f64) -> (f64, f64) {
    let (e0, e1) = unit(a);
    let (dx, dy) = (x.0 - c.0, x.1 - c.1);
    (e0 * dx + e1 * dy, -e1 * dx + e0 * dy)
}

/// Unknowns: centre x, y; per bar its angle and width; then sigma
/// (pixels). A bar's width is one along it: perspective changes it by a
/// few percent over a board, while a width free to change would follow a
/// marking merged with the bar along one arm and tilt the bar's line.
struct CrossShape {
    t: [f64; 7],
}

impl Shape for CrossShape {
    fn prepare(&mut self, theta: &[f64]) -> Option<()> {
        self.t.copy_from_slice(theta);
        Some(())
    }

    fn value(&self, x: Pt, grad: Option<&mut [f64]>) -> f64 {
        let t = &self.t;
        let c = (t[0], t[1]);
        let sigma = t[6];
        // Each bar's blurred indicator and its derivatives by the centre,
        // the bar's angle and width, and sigma.
        let bar = |k: usize| {
            let (a, w) = (t[2 + 2 * k], t[3 + 2 * k]);
            let (along, across) = local(x, c, a);
            let h = 0.5 * w;
            let (alpha, beta) = ((h - across) / sigma, (-h - across) / sigma);
            let ((ca, pa), (cb, pb)) = (normal(alpha), normal(beta));
            let db_dh = (pa + pb) / sigma;
            let db_dd = (pb - pa) / sigma;
            let n = (-a.sin(), a.cos());
            (
                ca - cb,
                (-db_dd * n.0, -db_dd * n.1),
                -db_dd * along,
                0.5 * db_dh,
                (pb * beta - pa * alpha) / sigma,
            )
        };
        let (b0, c0, a0, w0, s0) = bar(0);
        let (b1, c1, a1, w1, s1) = bar(1);
        if let Some(grad) = grad {
            // The union of the two bars: b0 + b1 - b0 b1.
            let (k0, k1) = (1.0 - b1, 1.0 - b0);
            grad[0] = k0 * c0.0 + k1 * c1.0;
            grad[1] = k0 * c0.1 + k1 * c1.1;
            grad[2] = k0 * a0;
            grad[3] = k0 * w0;
            grad[4] = k1 * a1;
            grad[5] = k1 * w1;
            grad[6] = k0 * s0 + k1 * s1;
        }
        b0 + b1 - b0 * b1
    }

    fn bound(&self, theta: &mut [f64]) {
        // Under 0.4 px the drawing, sampled at pixel centres, is sharper
        // than any pixel's own area lets an edge be.
        theta[6] = theta[6].clamp(0.4, 6.0);
        theta[3] = theta[3].max(1.0);
        theta[5] = theta[5].max(1.0);
    }
}

/// Unknowns: centre x, y; the two lines' angles; sigma (pixels).
struct CheckerShape {
    t: [f64; 5],
}

impl Shape for CheckerShape {
    fn prepare(&mut self, theta: &[f64]) -> Option<()> {
        self.t.copy_from_slice(theta);
        Some(())
    }

    fn value(&self, x: Pt, grad: Option<&mut [f64]>) -> f64 {
        let t = &self.t;
        let c = (t[0], t[1]);
        let sigma = t[4];
        let side = |k: usize| {
            let a = t[2 + k];
            let (along, across) = local(x, c, a);
            let (s, p) = normal(across / sigma);
            let ds_dd = p / sigma;
            let n = (-a.sin(), a.cos());
            (
                s,
                (-ds_dd * n.0, -ds_dd * n.1),
                -ds_dd * along,
                -p * across / (sigma * sigma),
            )
        };
        let (s0, c0, a0, sg0) = side(0);
        let (s1, c1, a1, sg1) = side(1);
        if let Some(grad) = grad {
            let (k0, k1) = (2.0 * s1 - 1.0, 2.0 * s0 - 1.0);
            grad[0] = k0 * c0.0 + k1 * c1.0;
            grad[1] = k0 * c0.1 + k1 * c1.1;
            grad[2] = k0 * a0;
            grad[3] = k1 * a1;
            grad[4] = k0 * sg0 + k1 * sg1;
        }
        s0 * s1 + (1.0 - s0) * (1.0 - s1)
    }

    fn bound(&self, theta: &mut [f64]) {
        theta[4] = theta[4].clamp(0.4, 6.0);
    }
}

/// The pixels of `img` around `lines` that `keep` (given each line's
/// along- and across-coordinates) selects, within `ARM_SHARE` of each arm;
/// a regular subsample when more than `max` are.
fn pixels_of(
    img: &GreyView,
    lines: &Lines,
    max: usize,
    keep: impl Fn([(f64, f64); 2]) -> bool,
) -> Vec<(Pt, f64)> {
    let reach = lines.lengths.iter().fold(0.0f64, |a, b| a.max(*b));
    let c = lines.centre;
    let x0 = (c.0 - reach).floor().max(0.0) as usize;
    let y0 = (c.1 - reach).floor().max(0.0) as usize;
    let x1 = ((c.0 + reach).ceil() as usize).min(img.width - 1);
    let y1 = ((c.1 + reach).ceil() as usize).min(img.height - 1);
    let angles = lines.dirs.map(|d| d.1.atan2(d.0));
    let inside = |p: Pt| {
        let l = [local(p, c, angles[0]), local(p, c, angles[1])];
        let on_board = (0..2).all(|k| {
            let (along, _) = l[k];
            along <= ARM_SHARE * lines.lengths[k] && -along <= ARM_SHARE * lines.lengths[k + 2]
        });
        on_board && keep(l)
    };
    let mut all = Vec::new();
    for y in y0..=y1 {
        for x in x0..=x1 {
            let p = (x as f64, y as f64);
            if inside(p) {
                all.push((p, img.data[y * img.stride + x] as f64));
            }
        }
    }
    if all.len() > max {
        let step = all.len().div_ceil(max);
        all = all.into_iter().step_by(step).collect();
    }
    all
}

/// Refits a cross found as `lines`, its bars `light` (on a dark board) or
/// not, from the levels `(light, dark)`.
pub fn fit_cross(
    img: &GreyView,
    lines: &Lines,
    light_bars: bool,
    levels: (f64, f64),
    params: &FitParams,
) -> Option<FittedLines> {
    // Bar k's band: its width and as much board again either side (at
    // least the blur's reach), where a free quadrant's marking may touch.
    let pixels = pixels_of(img, lines, params.max_pixels, |l| {
        (0..2).any(|k| {
            let w = lines.bar[k];
            l[k].1.abs() <= 0.5 * w + (0.5 * w).max(3.0 * BLUR0 + 1.0)
        })
    });
    let angles = lines.dirs.map(|d| d.1.atan2(d.0));
    let theta = vec![
        lines.centre.0,
        lines.centre.1,
        angles[0],
        lines.bar[0],
        angles[1],
        lines.bar[1],
        BLUR0,
    ];
    let (black, contrast) = if light_bars {
        (levels.1, levels.0 - levels.1)
    } else {
        (levels.0, levels.1 - levels.0)
    };
    let mut shape = CrossShape { t: [0.0; 7] };
    let s = robust_fit(
        &mut shape,
        &pixels,
        theta,
        (black, contrast),
        &[0, 1, 3, 5],
        params,
    )?;
    let t = &s.theta;
    Some(FittedLines {
        centre: (t[0], t[1]),
        dirs: [unit(t[2]), unit(t[4])],
        blur_px: t[6],
        contrast: s.contrast.abs(),
        residual: s.residual,
    })
}

/// Refits a checker found as `lines`: its board near the two lines.
pub fn fit_checker(img: &GreyView, lines: &Lines, params: &FitParams) -> Option<FittedLines> {
    let size = 0.5 * lines.lengths.iter().sum::<f64>();
    let near = (0.2 * size).max(4.0);
    let pixels = pixels_of(img, lines, params.max_pixels, |l| {
        l[0].1.abs() <= near || l[1].1.abs() <= near
    });
    let angles = lines.dirs.map(|d| d.1.atan2(d.0));
    let theta = vec![lines.centre.0, lines.centre.1, angles[0], angles[1], BLUR0];
    let mut shape = CheckerShape { t: [0.0; 5] };
    shape.prepare(&theta)?;
    // The levels of the drawing's 1 and 0 as the start places them.
    let (mut one, mut zero) = ((0.0, 0), (0.0, 0));
    for (x, g) in &pixels {
        if shape.value(*x, None) > 0.5 {
            one = (one.0 + g, one.1 + 1);
        } else {
            zero = (zero.0 + g, zero.1 + 1);
        }
    }
    if one.1 == 0 || zero.1 == 0 {
        return None;
    }
    let (one, zero) = (one.0 / one.1 as f64, zero.0 / zero.1 as f64);
    let s = robust_fit(
        &mut shape,
        &pixels,
        theta,
        (zero, one - zero),
        &[0, 1],
        params,
    )?;
    let t = &s.theta;
    Some(FittedLines {
        centre: (t[0], t[1]),
        dirs: [unit(t[2]), unit(t[3])],
        blur_px: t[4],
        contrast: s.contrast.abs(),
        residual: s.residual,
    })
}

#[cfg(test)]
mod tests {
    use super::super::super::geometry::dist;
    use super::super::super::test_image::{gaussian_blurred, render_image, Cross};
    use super::*;

    /// Images are rendered from 4x4 subsamples per pixel, which place an
    /// edge to a quarter of a pixel: the targets' edges lie on quarters.
    const W: usize = 96;

    /// `data` blurred by 1 px.
    fn blurred(data: Vec<u8>) -> Vec<u8> {
        gaussian_blurred(&data, W, 1.0)
    }

    fn view(data: &[u8]) -> GreyView<'_> {
        GreyView {
            data,
            width: W,
            height: W,
            stride: W,
        }
    }

    /// The lines a walk would hand over: the centre 0.5 px off, the
    /// directions a degree off, the bars' widths 5% off.
    fn rough(centre: Pt, bar: f64) -> Lines {
        let a = 1f64.to_radians();
        Lines {
            centre: (centre.0 + 0.4, centre.1 - 0.3),
            dirs: [unit(a), unit(a + std::f64::consts::FRAC_PI_2)],
            lengths: [30.0; 4],
            bar: [1.05 * bar, 0.95 * bar],
        }
    }

    /// A shadow's straight edge along the horizontal bar's lower side (a
    /// pole's shadow, the generator's hard shadows): the lower side's
    /// light is mixed with the shadow, and a fit with one pair of levels
    /// moves the bar up.
    #[test]
    fn a_cross_under_a_shadow_edge_along_a_bar_is_placed_to_a_twentieth_of_a_pixel() {
        let cross = Cross {
            centre: (48.25, 47.75),
            side: 60.0,
            bar: 12.0,
            white: 200.0,
            black: 30.0,
        };
        // Shadowed where dy > 3 (the bar's lower side is at dy = 6). With
        // the shadow's edge a pixel from the bar's (within the blur) the two
        // are barely told apart: 0.07 px off.
        let data = blurred(cross.render(W, |_, _| 120.0, (0.0, -1.0), -3.0, 0.55));
        let lines = rough(cross.centre, cross.bar);
        let with = fit_cross(
            &view(&data),
            &lines,
            true,
            (200.0, 30.0),
            &FitParams::default(),
        )
        .expect("fitted");
        assert!(
            dist(with.centre, cross.centre) < 0.05,
            "{:?} vs {:?}",
            with.centre,
            cross.centre
        );
        let params = FitParams {
            shadows: false,
            ..FitParams::default()
        };
        let without =
            fit_cross(&view(&data), &lines, true, (200.0, 30.0), &params).expect("fitted");
        assert!(
            dist(without.centre, cross.centre) > 0.2,
            "{:?}",
            without.centre
        );
    }

    /// A marking merged with a bar along most of one arm (a free
    /// quadrant's bar beside the cross's): it is outvoted, not averaged in.
    #[test]
    fn a_marking_beside_a_bar_does_not_move_the_centre() {
        let (c, side, bar) = ((47.75, 48.25), 60.0, 12.0);
        let data = blurred(render_image(W, |x, y| {
            let (dx, dy) = (x - c.0, y - c.1);
            if dx.abs() >= side / 2.0 || dy.abs() >= side / 2.0 {
                return 120.0;
            }
            let on_bar = dx.abs() < bar / 2.0 || dy.abs() < bar / 2.0;
            // Beside the right arm, below it: 6 px tall, from 8 px out.
            let marking = (8.0..27.0).contains(&dx) && (bar / 2.0..bar / 2.0 + 6.0).contains(&dy);
            if on_bar || marking {
                200.0
            } else {
                30.0
            }
        }));
        let f = fit_cross(
            &view(&data),
            &rough(c, bar),
            true,
            (200.0, 30.0),
            &FitParams::default(),
        )
        .expect("fitted");

        assert!(dist(f.centre, c) < 0.05, "{:?} vs {c:?}", f.centre);
    }

    /// A checker's centre under a shadow edge across two of its quadrants.
    #[test]
    fn a_checker_under_a_shadow_edge_is_placed_to_a_twentieth_of_a_pixel() {
        let (c, side) = ((48.25, 47.25), 60.0);
        let data = blurred(render_image(W, |x, y| {
            let (dx, dy) = (x - c.0, y - c.1);
            let grey = if dx.abs() >= side / 2.0 || dy.abs() >= side / 2.0 {
                120.0
            } else if (dx > 0.0) == (dy > 0.0) {
                200.0
            } else {
                30.0
            };
            // A diagonal shadow edge through the lower right quadrant.
            if dx + 0.5 * dy > 12.0 {
                0.5 * grey
            } else {
                grey
            }
        }));
        let mut lines = rough(c, 0.0);
        lines.bar = [0.0; 2];
        let f = fit_checker(&view(&data), &lines, &FitParams::default()).expect("fitted");
        assert!(dist(f.centre, c) < 0.05, "{:?} vs {c:?}", f.centre);
    }
}
