//! The subpixel centre: a cross's bar centre lines or a checker's
//! quadrant boundaries fitted as straight lines, and their crossing.

use super::*;

/// Result of fitting the two centre lines.
pub(super) struct LineFit {
    pub(super) centre: Pt,
    pub(super) dirs: [Pt; 2],
    /// Median bar width (cross only).
    pub(super) bar: Option<f64>,
    /// Every bar width measured (cross only).
    pub(super) widths: Vec<f64>,
    /// Median width of each bar (cross only; 0 without widths).
    pub(super) bar_widths: [f64; 2],
    /// Smallest fraction of usable profiles over the four arms.
    pub(super) coverage: f64,
    /// Largest RMS point-to-line distance of the two lines.
    pub(super) rms: f64,
    /// Largest angle (radians) between the two halves of a line, each
    /// fitted on its own arm's points: a printed boundary runs straight
    /// through the centre.
    pub(super) bend: f64,
}

/// Fits both lines from profiles across every arm, every half pixel.
pub(super) fn fit_lines(
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
pub(super) fn bar_centre(
    p: &[f64],
    half: f64,
    bar: f64,
    strength: f64,
) -> Option<(f64, Option<f64>)> {
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
pub(super) fn edge_offset(
    p: &[f64],
    half: f64,
    polarity: f64,
    strength: f64,
) -> Option<(f64, Option<f64>)> {
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
pub(super) fn edge_at_local_levels(p: &[f64], half: f64, s: f64, polarity: f64) -> Option<f64> {
    let inset = 2.5f64.min(0.5 * half) / pr::STEP_PX;
    let mut x = (s + half) / pr::STEP_PX;
    for _ in 0..3 {
        let level = (pr::level_near(p, x - inset) + pr::level_near(p, x + inset)) / 2.0;
        x = pr::crossing(p, level, polarity > 0.0, x)?;
    }
    Some(pr::offset(x, half))
}
