//! Each arm measured outward until its structure ends, and what lies
//! past its end (ground, an object against the board, paving, a grid).

use super::fit::edge_offset;
use super::*;

/// Direction of arm k: arms 0 and 2 lie on line A, 1 and 3 on line B.
pub(super) fn arm_dir(dirs: &[Pt; 2], k: usize) -> Pt {
    let d = dirs[k % 2];
    if k >= 2 {
        (-d.0, -d.1)
    } else {
        d
    }
}

/// The shorter and the longer of the two arms across arm k (k+1 and k+3).
pub(super) fn across(lengths: &[f64; 4], k: usize) -> (f64, f64) {
    let (p, q) = (lengths[(k + 1) % 4], lengths[(k + 3) % 4]);
    (p.min(q), p.max(q))
}

/// The mean length of the two arms across arm k, when they agree within
/// [`MAX_ARM_RATIO`] and `long` exceeds both by more than it: arm k's bar
/// lies on a stripe, and its length is the board's, as across.
pub(super) fn across_if_longer(arms: &[Arm; 4], k: usize, long: f64) -> Option<f64> {
    let (lo, hi) = across(&arms.map(|a| a.length), k);
    (hi / lo <= MAX_ARM_RATIO && long > MAX_ARM_RATIO * hi).then_some((lo + hi) / 2.0)
}

/// The eight half-sides of a target's square, each quadrant's two outer
/// sides: per arm k and each neighbouring arm, arm k's direction and length
/// (the side lies that far out along it) and the neighbour's direction and
/// length (how far the side runs).
pub(super) fn half_sides<'a>(
    dirs: &'a [Pt; 2],
    lengths: &'a [f64; 4],
) -> impl Iterator<Item = (Pt, f64, Pt, f64)> + 'a {
    (0..4).flat_map(move |k| {
        [(k + 1) % 4, (k + 3) % 4].map(|side| {
            (
                arm_dir(dirs, k),
                lengths[k],
                arm_dir(dirs, side),
                lengths[side],
            )
        })
    })
}

/// +1 when the left (+normal) side of a checker arm is the light quadrant.
pub(super) fn checker_polarity(img: &GreyView, c: Pt, a: Pt, t: f64) -> Option<f64> {
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

pub(super) enum ArmEnd {
    Ends(Arm),
    /// The structure continues past the arm's end (with the arm as far as
    /// its own structure went, if it ended at all): a grid, paving, a road,
    /// or something lying against the target.
    RunsOn(Option<Arm>),
    /// A checker's boundary continues with the colours swapped: paving.
    Flips,
    /// Past a checker arm's end, an edge of the other polarity off the
    /// arm's line that does not cross the whole target (a shadow's edge
    /// does): something lying beside the target, or a junction of
    /// unrelated regions. With the arm as far as its own structure went.
    Beside(Arm),
    /// The arm leaves the tile before it can be judged.
    Unknown,
}

/// Feature strength at `t` along arm `a`: for a cross, how much brighter the
/// bar's centre line is than both sides; for a checker, the edge contrast
/// with the arm's polarity. Averaged over three points one pixel apart.
/// Second, for a cross, the same with the bar's brightness taken as the
/// least of its centre line and `width` either side of it (a bar keeps its
/// width; a narrower stripe does not); the first again for a checker.
pub(super) fn feature(
    img: &GreyView,
    kind: Kind,
    (c, a): (Pt, Pt),
    t: f64,
    o: f64,
    polarity: f64,
    width: f64,
) -> Option<(f64, f64)> {
    let n = perp(a);
    let (mut sum, mut narrow) = (0.0, 0.0);
    for dt in [-1.0, 0.0, 1.0] {
        let base = add(c, a, t + dt);
        let at = |s: f64| {
            let p = add(base, n, s);
            img.sample(p.0, p.1)
        };
        match kind {
            Kind::Cross => {
                let centre = at(0.0)?;
                let side = at(-o)?.max(at(o)?);
                sum += centre - side;
                narrow += if width > 0.0 {
                    centre.min(at(-width)?).min(at(width)?) - side
                } else {
                    centre - side
                };
            }
            Kind::Checker => {
                let f = polarity * (at(o)? - at(-o)?);
                sum += f;
                narrow += f;
            }
        }
    }
    Some((sum / 3.0, narrow / 3.0))
}

/// Walks arm `a` outward: where its structure fades, and whether anything
/// like it continues beyond.
#[allow(clippy::too_many_arguments)]
pub(super) fn measure_arm(
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
    // Checker: the quadrants' levels either side of the arm near the centre.
    let mut sides = (Vec::new(), Vec::new());
    let level = |t: f64, s: f64| beside_arm(img, (c, a), t, s);
    let mut t = t0;
    let mut below = 0;
    let mut length = None;
    let mut strength = 0.0;
    // A cross's bar keeps its width: bright a third of the way to either
    // edge too, so an arm ends where its bar goes on as a narrower stripe
    // (a road marking under the target, a short stripe across a long one).
    // The arm's strength stays the plain bar's contrast.
    let width = 0.3 * bar;
    let (mut near_w, mut strength_w) = (Vec::new(), 0.0);
    while t <= max_reach {
        let Some((f, fw)) = feature(img, kind, (c, a), t, o, polarity, width) else {
            return ArmEnd::Unknown;
        };
        if t <= reference_end {
            near.push(f);
            near_w.push(fw);
            if kind == Kind::Checker {
                if let (Some(l), Some(r)) = (level(t, o), level(t, -o)) {
                    sides.0.push(l);
                    sides.1.push(r);
                }
            }
        } else {
            if strength == 0.0 {
                strength = pr::quantile(&near, 0.5);
                if strength < 0.7 * MIN_CONTRAST {
                    return ArmEnd::Unknown;
                }
                strength_w = pr::quantile(&near_w, 0.5);
            }
            // 0.4: a shadow edge across the arm (x 0.55) is not its end.
            if fw < 0.4 * strength_w {
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
        return ArmEnd::RunsOn(None);
    };
    let arm = Arm {
        length: length + 0.5,
        strength,
        polarity,
    };
    // Paving cut short by something lying over it: only the tiles right
    // past the end may show, inside the gap below.
    if kind == Kind::Checker
        && !sides.0.is_empty()
        && tiles_swap_past_end(
            img,
            (c, a),
            length,
            o,
            polarity,
            strength,
            (pr::quantile(&sides.0, 0.5), pr::quantile(&sides.1, 0.5)),
        )
    {
        return ArmEnd::Flips;
    }
    // Beyond the end: ground, not more of the same pattern. From a gap past
    // the end (a panel grid's cross line or a blurred square edge must not
    // count), for 0.6 of the arm: a repeating pattern continues right after
    // the gap; something else beside the target (a path, a car, a stripe)
    // further out does not make it part of a pattern.
    let from = length + (0.3 * length).max(3.0);
    let to = from + (0.6 * length).max(6.0);
    let mut active = 0;
    let mut flipped = 0;
    // Flipped samples in a row from the gap on: a tile of paving right
    // past the arm's end, however far the paving goes beyond it.
    let mut lead = 0;
    let mut total = 0;
    // Paving's boundary flips between the same two tiles, lit or in shadow
    // alike (a shadow scales both, so their log ratio holds); a shadow edge
    // or a stripe continuing a target's boundary separates ground from
    // something else, at another ratio. Checkers only.
    let ratio = if sides.0.is_empty() {
        0.0
    } else {
        harmonic::log_grey(pr::quantile(&sides.0, 0.5))
            - harmonic::log_grey(pr::quantile(&sides.1, 0.5))
    };
    let flips_tiles = |t: f64| match (level(t, o), level(t, -o)) {
        (Some(l), Some(r)) => {
            let flipped = harmonic::log_grey(r) - harmonic::log_grey(l);
            (flipped - ratio).abs() < FLIP_RATIO * ratio.abs()
        }
        _ => false,
    };
    let mut t = from;
    while t <= to {
        let Some((f, _)) = feature(img, kind, (c, a), t, o, polarity, 0.0) else {
            break;
        };
        // A cross's bar continues as a bright bar (a grid line); a checker's
        // boundary continues as the same edge (a long straight edge) or, in
        // paving, flipped at the tile corner, often fainter than the
        // junction measured near the centre.
        let continues = match kind {
            Kind::Cross => f >= 0.5 * strength,
            Kind::Checker => f >= 0.5 * strength || f <= -0.4 * strength,
        };
        active += continues as usize;
        // A flip as strong as the junction is paving whatever its levels.
        let paving = kind == Kind::Checker
            && (f <= -0.7 * strength || (f <= -0.4 * strength && flips_tiles(t)));
        flipped += paving as usize;
        if paving && lead == total {
            lead += 1;
        }
        total += 1;
        t += 1.0;
    }
    if total > 0 && (flipped * 2 > total || lead >= MIN_LEAD_FLIPS) {
        // Paving continues the boundary on the arm's own line; an edge of
        // something else crosses the profiles wherever it happens to lie.
        let (mut aligned, mut tried) = (0, 0);
        let mut profile = Vec::new();
        let mut edge = Vec::new();
        let mut t = from;
        while t <= to {
            tried += 1;
            if pr::line(img, add(c, a, t), perp(a), o, &mut profile).is_some() {
                if let Some((s, _)) = edge_offset(&profile, o, -polarity, 0.7 * strength) {
                    aligned += (s.abs() <= (0.05 * length).max(1.0)) as usize;
                    edge.push(add(add(c, a, t), perp(a), s));
                }
            }
            t += 1.0;
        }
        if aligned * 2 > tried {
            // Ground right past the arm's end (across the gap no edge on
            // the arm's line, at neither quadrant's level) and the pattern
            // only further out: paving lying near the target along the
            // arm's line, not tiles meeting the target's at the arm's end
            // (crosshair frame 2701: a paving block 16 px past a checker's
            // corner).
            if lead == 0
                && !sides.0.is_empty()
                && gap_is_ground(
                    img,
                    (c, a),
                    (length, from),
                    o,
                    (pr::quantile(&sides.0, 0.5), pr::quantile(&sides.1, 0.5)),
                )
            {
                return ArmEnd::Ends(arm);
            }
            return ArmEnd::Flips;
        }
        if edge_crosses_target(img, c, &edge, size_guess, o, 0.7 * strength) {
            return ArmEnd::Ends(arm);
        }
        return ArmEnd::Beside(arm);
    }
    if total > 0 && active * 2 > total {
        return ArmEnd::RunsOn(Some(arm));
    }
    ArmEnd::Ends(arm)
}

/// Whether a checker arm's line shows ground from 3 px past the arm's end
/// at `length` to `to` px from `c`, on 2 samples at least: either side `o`
/// px off the line at one level (no edge), and that level unlike both
/// quadrants' beside the arm, `(left, right)` (by a quarter of their
/// difference; paving rows set off from each other put a tile there).
pub(super) fn gap_is_ground(
    img: &GreyView,
    (c, a): (Pt, Pt),
    (length, to): (f64, f64),
    o: f64,
    (left, right): (f64, f64),
) -> bool {
    let diff = (left - right).abs();
    let mut n = 0;
    let mut t = length + 3.0;
    while t < to {
        let (Some(l), Some(r)) = (
            beside_arm(img, (c, a), t, o),
            beside_arm(img, (c, a), t, -o),
        ) else {
            return false;
        };
        let level = (l + r) / 2.0;
        if (l - r).abs() >= 0.3 * diff
            || (level - left).abs() < 0.25 * diff
            || (level - right).abs() < 0.25 * diff
        {
            return false;
        }
        n += 1;
        t += 1.0;
    }
    n >= 2
}

/// The grey level `t` px out along the arm `a` from `c` and `s` px across
/// it (towards `perp(a)`).
pub(super) fn beside_arm(img: &GreyView, (c, a): (Pt, Pt), t: f64, s: f64) -> Option<f64> {
    let p = add(add(c, a, t), perp(a), s);
    img.sample(p.0, p.1)
}

/// The least and largest of `v`.
pub(super) fn extent(v: &[f64]) -> (f64, f64) {
    v.iter()
        .fold((f64::MAX, f64::MIN), |(lo, hi), &x| (lo.min(x), hi.max(x)))
}

/// Whether a checker arm that runs on past the board (from `board` to
/// `end` px from the centre `c` along `a`) is the edge of something lying
/// against the board: one side keeps its quadrant's level all along (a dark
/// object against a dark quadrant), the other is ground of one level,
/// unlike its quadrant's; or each side is of one level of its own, the two
/// apart and not the quadrants' levels swapped (an object darker than the
/// dark quadrant, beside ground). Paving's boundary running on passes
/// tiles of both levels.
pub(super) fn object_against_board(img: &GreyView, c: Pt, a: Pt, board: f64, end: f64) -> bool {
    let o = (0.1 * board).max(3.0);
    // Either side at `o` and `2 o` from the line: a level taken off an
    // edge that leaves the arm's line at a small angle is the edge's blur
    // (clutter scene 1400: a dark triangle's corner at paving's edge, its
    // edge read 3 px out as ground of one level).
    let levels = |from: f64, to: f64, s: f64| -> Vec<f64> {
        let mut v = Vec::new();
        let mut t = from;
        while t <= to {
            v.extend(
                [s, 2.0 * s]
                    .into_iter()
                    .filter_map(|off| beside_arm(img, (c, a), t, off)),
            );
            t += 1.0;
        }
        v
    };
    let near = (
        levels(0.3 * board, 0.8 * board, o),
        levels(0.3 * board, 0.8 * board, -o),
    );
    let past = (
        levels(board + 3.0, end - 3.0, o),
        levels(board + 3.0, end - 3.0, -o),
    );
    if near.0.is_empty() || near.1.is_empty() || past.0.len() < 6 || past.1.len() < 6 {
        return false;
    }
    let q = (pr::quantile(&near.0, 0.5), pr::quantile(&near.1, 0.5));
    let contrast = (q.0 - q.1).abs();
    let keeps = |v: &[f64], level: f64| {
        [0.1, 0.9]
            .iter()
            .all(|&f| (pr::quantile(v, f) - level).abs() < 0.25 * contrast)
    };
    // One level: its spread under a quarter of the quadrants' difference.
    let uniform = |v: &[f64]| pr::quantile(v, 0.9) - pr::quantile(v, 0.1) < 0.25 * contrast;
    let ground =
        |v: &[f64], level: f64| (pr::quantile(v, 0.5) - level).abs() > 0.4 * contrast && uniform(v);
    if (keeps(&past.0, q.0) && ground(&past.1, q.1))
        || (keeps(&past.1, q.1) && ground(&past.0, q.0))
    {
        return true;
    }
    // An object of its own level (a dark disc darker than the dark
    // quadrant) on one side and ground on the other: both sides of one
    // level each, apart, and not the quadrants swapped (paving's next tiles).
    let m = (pr::quantile(&past.0, 0.5), pr::quantile(&past.1, 0.5));
    let swapped = (m.0 - q.1).abs() < 0.25 * contrast && (m.1 - q.0).abs() < 0.25 * contrast;
    uniform(&past.0) && uniform(&past.1) && (m.0 - m.1).abs() > 0.4 * contrast && !swapped
}

/// Whether a checker arm's boundary runs on, right past its end, between
/// the same two tiles swapped: paving, its continuation perhaps cut short
/// by something lying over it. Each side must show the level of the
/// quadrant across the arm (within [`TILE_LEVEL_TOLERANCE`] of the
/// quadrants' difference) near the line and a third of the arm from it
/// (a narrow stripe along the line is not a tile), and the edge between
/// them must lie on the arm's line, for [`MIN_LEAD_FLIPS`] samples in a
/// row from just past the end. `(left, right)`: the quadrants' levels on
/// the arm's two sides near the centre.
pub(super) fn tiles_swap_past_end(
    img: &GreyView,
    (c, a): (Pt, Pt),
    length: f64,
    o: f64,
    polarity: f64,
    strength: f64,
    (left, right): (f64, f64),
) -> bool {
    let level = |t: f64, s: f64| beside_arm(img, (c, a), t, s);
    let tolerance = TILE_LEVEL_TOLERANCE * (left - right).abs();
    let swapped = |t: f64, s: f64| match (level(t, s), level(t, -s)) {
        (Some(l), Some(r)) => (l - right).abs() < tolerance && (r - left).abs() < tolerance,
        _ => false,
    };
    let mut profile = Vec::new();
    let mut t = length + (0.1 * length).max(2.0);
    let mut lead = 0;
    while t <= 1.5 * length && lead < MIN_LEAD_FLIPS {
        let on_line = swapped(t, o)
            && swapped(t, 0.3 * length)
            && pr::line(img, add(c, a, t), perp(a), o, &mut profile).is_some()
            && edge_offset(&profile, o, -polarity, 0.7 * strength)
                .is_some_and(|(s, _)| s.abs() <= (0.05 * length).max(1.0));
        if !on_line {
            return false;
        }
        lead += 1;
        t += 1.0;
    }
    lead >= MIN_LEAD_FLIPS
}

/// Whether the edge found past an arm's end (its points in `edge`) is a
/// straight edge that crosses the whole target: the same side lighter on
/// the target's far side, beyond its square, as here. A shadow's edge or a
/// boundary of the ground runs under the target like that; something lying
/// against the target ends at it, and paving's edges lie on the arms' lines
/// (found before this is asked).
pub(super) fn edge_crosses_target(
    img: &GreyView,
    c: Pt,
    edge: &[Pt],
    size: f64,
    o: f64,
    strength: f64,
) -> bool {
    if edge.len() < 6 {
        return false;
    }
    let Some(((p0, d), inliers)) = pr::robust_line(edge) else {
        return false;
    };
    if inliers.len() * 3 < edge.len() * 2 || pr::line_rms(&inliers, (p0, d)) > 1.0 {
        return false;
    }
    let m = perp(d);
    let across = |p: Pt| -> Option<f64> {
        let (a, b) = (add(p, m, o), add(p, m, -o));
        Some(img.sample(a.0, a.1)? - img.sample(b.0, b.1)?)
    };
    let near: Vec<f64> = inliers.iter().filter_map(|&p| across(p)).collect();
    if near.len() < 6 {
        return false;
    }
    let contrast = pr::quantile(&near, 0.5);
    if contrast.abs() < strength {
        return false;
    }
    // Along the line from its point nearest the centre, away from the
    // near side's points, starting where it leaves the target's square.
    let u0 = (c.0 - p0.0) * d.0 + (c.1 - p0.1) * d.1;
    let foot = add(p0, d, u0);
    let mid = inliers
        .iter()
        .fold((0.0, 0.0), |s, p| (s.0 + p.0, s.1 + p.1));
    let mid = (mid.0 / inliers.len() as f64, mid.1 / inliers.len() as f64);
    let side = -((mid.0 - foot.0) * d.0 + (mid.1 - foot.1) * d.1).signum();
    let off = geometry::dist(foot, c);
    let reach = 0.75 * size;
    let start = (reach * reach - off * off).max(0.0).sqrt();
    // As far as the edge was followed past the arm's end.
    let (mut same, mut total) = (0, 0);
    let mut u = start;
    while u <= start + edge.len() as f64 {
        if let Some(v) = across(add(foot, d, side * u)) {
            same += (v * contrast.signum() >= 0.5 * contrast.abs()) as usize;
        }
        total += 1;
        u += 1.0;
    }
    same * 3 >= total * 2
}
