//! The design detector on rendered targets: markings that touch a bar
//! (which the generator's one marking never does), a lattice of the same
//! design, and texture.

use opencv::core::Mat;
use opencv::prelude::*;

use super::super::design::TargetDesign;
use super::super::test_image::render_image;
use super::super::{Detection, Detector, MarkerType, SizeRange};
use super::{Params, PrintedDetector};

/// The detector with `designs` run on a w x w image as one tile.
fn detect_in(data: &[u8], w: usize, designs: &[&str]) -> Vec<Detection> {
    detect_with(data, w, designs, Params::default())
}

/// The same with other thresholds.
fn detect_with(data: &[u8], w: usize, designs: &[&str], params: Params) -> Vec<Detection> {
    let tile = Mat::from_slice(data)
        .and_then(|m| m.reshape(1, w as i32)?.try_clone())
        .expect("tile");
    let designs = designs
        .iter()
        .map(|n| TargetDesign::preset(n).unwrap())
        .collect();
    let sizes = SizeRange {
        min_px: 16.0,
        max_px: 200.0,
        reach_px: 200.0,
    };
    PrintedDetector::new(MarkerType::Crosshair, designs, sizes)
        .with_params(params)
        .detect(&tile, (0, 0), [false; 4])
        .expect("detect")
}

/// A marking's stroke: a segment between two points of the board's frame.
type Stroke = ((f64, f64), (f64, f64));

/// Grey of the ground at (u, v) in the board's frame.
type Ground = dyn Fn(f64, f64) -> f64;

/// Distance of point (x, y) from the segment a-b.
fn to_segment((x, y): (f64, f64), a: (f64, f64), b: (f64, f64)) -> f64 {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let t = (((x - a.0) * dx + (y - a.1) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
    (x - a.0 - t * dx).hypot(y - a.1 - t * dy)
}

/// A 120 px white cross (bars 14 px) on a black board on sand-grey ground,
/// turned by `angle`, its centre at a non-integer position; `marking` draws
/// white strokes 5 px wide in the board's frame (u along bar A).
fn marked_cross(angle: f64, marking: &[Stroke]) -> (Vec<u8>, (f64, f64)) {
    cross_on(angle, marking, |_, _| 170.0)
}

/// The same cross on the ground `ground(u, v)` (grey, in the board's frame).
fn cross_on(
    angle: f64,
    marking: &[Stroke],
    ground: impl Fn(f64, f64) -> f64,
) -> (Vec<u8>, (f64, f64)) {
    let (w, c, half, half_bar) = (240usize, (120.37, 118.81), 60.0, 7.0);
    let (co, si) = (angle.cos(), angle.sin());
    let data = render_image(w, |x, y| {
        let (dx, dy) = (x - c.0, y - c.1);
        let (u, v) = (co * dx + si * dy, -si * dx + co * dy);
        if u.abs() > half || v.abs() > half {
            return ground(u, v);
        }
        let on_mark = marking
            .iter()
            .any(|(a, b)| to_segment((u, v), *a, *b) < 2.5);
        if u.abs() < half_bar || v.abs() < half_bar || on_mark {
            235.0
        } else {
            25.0
        }
    });
    (data, c)
}

#[test]
fn markings_touching_the_bars_neither_stop_nor_break_a_cross() {
    // In the (+, -) quadrant: a short bar off one arm, a hook, a triangle
    // on both bars, a diagonal bar from the crossing.
    let markings: [&[Stroke]; 5] = [
        &[],
        &[((7.0, -30.0), (30.0, -30.0))],
        &[
            ((7.0, -40.0), (25.0, -40.0)),
            ((25.0, -40.0), (25.0, -30.0)),
        ],
        &[((7.0, -45.0), (45.0, -7.0))],
        &[((10.0, -10.0), (40.0, -40.0))],
    ];
    for (k, marking) in markings.iter().enumerate() {
        for angle in [0.3, 1.1] {
            let (data, c) = marked_cross(angle, marking);
            let found = detect_in(&data, 240, &["cross"]);
            assert_eq!(found.len(), 1, "marking {k}, angle {angle}: {found:?}");
            let d = &found[0];
            let err = (d.center.0 - c.0).hypot(d.center.1 - c.1);
            assert!(
                err < 0.15,
                "marking {k}, angle {angle}: centre off by {err}"
            );
            assert!((d.size_px - 120.0).abs() < 8.0, "size {}", d.size_px);
            assert!(d.confidence > 0.9, "confidence {}", d.confidence);
        }
    }
}

#[test]
fn an_arm_ends_where_its_bar_ends_whatever_the_ground_beyond() {
    // Past the end of bar +u: ground as dark as the board on one side of
    // the bar's line (the board seems to go on there), or a light path
    // twice the bar's width running on from the end. Neither lengthens
    // that arm: the cross is found, at its centre.
    let grounds: [(&str, &Ground); 4] = [
        ("dark beside", &|u, v| {
            if u > 0.0 && v > 0.0 {
                25.0
            } else {
                170.0
            }
        }),
        ("dark band", &|u, v| {
            if u > 0.0 && v.abs() < 40.0 && v > -10.0 {
                25.0
            } else {
                170.0
            }
        }),
        // A shadow's edge along the bar's line past its end: light ground
        // on one side, shadow as dark as the board on the other, up to
        // 1.75 arms out. The walk stays "on the board" there with no bar
        // in it, and ends where the shadow does.
        ("light and shadow", &|u, v| {
            if u > 0.0 && v > 0.0 && u < 105.0 {
                25.0
            } else if u > 0.0 && v <= 0.0 {
                235.0
            } else {
                170.0
            }
        }),
        ("light path", &|u, v| {
            if u > 0.0 && v.abs() < 14.0 {
                235.0
            } else {
                170.0
            }
        }),
    ];
    for (name, ground) in grounds {
        for angle in [0.3, 1.1] {
            let (data, c) = cross_on(angle, &[], ground);
            let found = detect_in(&data, 240, &["cross"]);
            assert_eq!(found.len(), 1, "{name}, angle {angle}: {found:?}");
            let err = (found[0].center.0 - c.0).hypot(found[0].center.1 - c.1);
            assert!(err < 0.15, "{name}, angle {angle}: centre off by {err}");
        }
    }
}

#[test]
fn thresholds_are_settable() {
    // The plain cross's inks differ by 9 times (235 against 25): found by
    // default, not when inks must differ by 10 times, nor when the drawn
    // design must match better than perfectly.
    let (data, _) = marked_cross(0.3, &[]);
    assert_eq!(detect_in(&data, 240, &["cross"]).len(), 1);
    let ink = Params {
        min_light_ratio: 10.0,
        ..Params::default()
    };
    assert_eq!(detect_with(&data, 240, &["cross"], ink), vec![]);
    let perfect = Params {
        min_score: 1.01,
        ..Params::default()
    };
    assert_eq!(detect_with(&data, 240, &["cross"], perfect), vec![]);
}

#[test]
fn a_lattice_of_the_design_is_not_a_target() {
    // Light lines 8 px wide every 50 px on dark panels: each crossing is a
    // cross by itself (checked on an isolated copy), the lattice is not.
    let (w, pitch, half_line) = (300usize, 50.0, 4.0);
    let line =
        |x: f64| ((x - 12.3).rem_euclid(pitch) - pitch / 2.0).abs() > pitch / 2.0 - half_line;
    let lattice = render_image(w, |x, y| if line(x) || line(y) { 230.0 } else { 30.0 });
    assert!(detect_in(&lattice, w, &["cross"]).is_empty());
    // One cell of the same lattice cut out on plain ground is a cross.
    let one = render_image(w, |x, y| {
        let near = (x - 162.3).abs() < 46.0 && (y - 162.3).abs() < 46.0;
        if !near {
            170.0
        } else if line(x) || line(y) {
            230.0
        } else {
            30.0
        }
    });
    let found = detect_in(&one, w, &["cross"]);
    assert_eq!(found.len(), 1, "{found:?}");
}

#[test]
fn a_checker_is_found_at_its_saddle_point() {
    let (w, c) = (200usize, (99.62, 101.27));
    let (co, si) = (0.4f64.cos(), 0.4f64.sin());
    let data = render_image(w, |x, y| {
        let (dx, dy) = (x - c.0, y - c.1);
        let (u, v) = (co * dx + si * dy, -si * dx + co * dy);
        if u.abs() > 40.0 || v.abs() > 40.0 {
            150.0
        } else if u * v > 0.0 {
            225.0
        } else {
            30.0
        }
    });
    let found = detect_in(&data, w, &["checker"]);
    assert_eq!(found.len(), 1, "{found:?}");
    let err = (found[0].center.0 - c.0).hypot(found[0].center.1 - c.1);
    assert!(err < 0.1, "centre off by {err}");
}

/// `f(u, v)` drawn turned by `angle` about `c` on a w x w image of `ground`
/// grey, where `f` gives None.
fn turned(
    w: usize,
    c: (f64, f64),
    angle: f64,
    ground: f64,
    f: impl Fn(f64, f64) -> Option<f64>,
) -> Vec<u8> {
    let (co, si) = (angle.cos(), angle.sin());
    render_image(w, |x, y| {
        let (dx, dy) = (x - c.0, y - c.1);
        f(co * dx + si * dy, -si * dx + co * dy).unwrap_or(ground)
    })
}

#[test]
fn a_small_panel_grid_is_not_a_cross() {
    // Four by three dark cells 30 px wide in a light frame 6 px wide, on
    // grey ground: a grid too small for a copy of the design one board
    // away, whose lines still run on past each crossing's cell.
    let (cell, line) = (30.0, 6.0);
    let data = turned(300, (151.3, 148.6), 0.35, 120.0, |u, v| {
        let (hw, hh) = (2.0 * cell, 1.5 * cell);
        if u.abs() > hw + line / 2.0 || v.abs() > hh + line / 2.0 {
            return None;
        }
        let near = |x: f64| {
            let f = x.rem_euclid(cell);
            f < line / 2.0 || f > cell - line / 2.0
        };
        Some(if near(u + hw) || near(v + hh) {
            220.0
        } else {
            30.0
        })
    });
    let found = detect_in(&data, 300, &["cross"]);
    assert!(found.is_empty(), "{found:?}");
}

#[test]
fn checker_paving_is_neither_a_cross_nor_a_checker_inside() {
    // Five by five squares of 26 px: a light square's corners touching its
    // diagonal neighbours look like a cross turned 45 degrees, and each
    // inner corner is a saddle; but the pattern runs on past any 2x2.
    let tile = 26.0;
    let data = turned(300, (149.4, 150.7), 0.2, 120.0, |u, v| {
        let half = 2.5 * tile;
        if u.abs() > half || v.abs() > half {
            return None;
        }
        let (i, j) = (((u + half) / tile) as usize, ((v + half) / tile) as usize);
        Some(if (i + j) % 2 == 0 { 40.0 } else { 215.0 })
    });
    let found = detect_in(&data, 300, &["cross"]);
    assert!(found.is_empty(), "cross: {found:?}");
    // Every inner corner of paving has another corner of tiles one board
    // (two tiles) around it, so none is a 2x2 checker.
    let found = detect_in(&data, 300, &["checker"]);
    assert!(found.is_empty(), "checker: {found:?}");
}

#[test]
fn a_checker_beside_paving_of_other_colours_is_found() {
    // A 2x2 checker whose board's side meets paving of two other greys:
    // saddles lie past its side, but not of the checker's own levels.
    let tile = 30.0;
    let c = (121.3, 150.4);
    let data = turned(300, c, 0.0, 120.0, |u, v| {
        if u.abs() <= tile && v.abs() <= tile {
            return Some(if u * v > 0.0 { 225.0 } else { 30.0 });
        }
        if u > tile && u < 4.0 * tile && v.abs() < 2.0 * tile {
            let (i, j) = (
                ((u - tile) / tile) as usize,
                ((v + 2.0 * tile) / tile) as usize,
            );
            return Some(if (i + j) % 2 == 0 { 95.0 } else { 160.0 });
        }
        None
    });
    let found = detect_in(&data, 300, &["checker"]);
    assert!(
        found
            .iter()
            .any(|d| (d.center.0 - c.0).hypot(d.center.1 - c.1) < 0.2),
        "{found:?}"
    );
}

#[test]
fn a_stripe_is_not_a_checker() {
    // A light stripe 12 px wide across dark ground, and two crossing.
    for crossing in [false, true] {
        let data = turned(300, (150.6, 149.2), 0.6, 30.0, |u, v| {
            (v.abs() < 6.0 || (crossing && (u - 10.0).abs() < 6.0)).then_some(220.0)
        });
        let found = detect_in(&data, 300, &["checker"]);
        assert!(found.is_empty(), "crossing {crossing}: {found:?}");
    }
}

#[test]
fn a_bars_width_on_the_ring_holds_for_wide_bars_and_under_a_shadow() {
    // A cross's ring samples as the detector takes them (64 directions at
    // TAU * i / 64), its bars turned by a0, light 200 on a board of 30
    // with edges a pixel wide; the half plane x > 0 in a shadow that keeps
    // 45% of the light. Good to a tenth and one sample's spacing (the
    // old estimate, one cut at the whole ring's middle level, lost the
    // shadowed bars and gave half the width).
    let ring = |half_bar: f64, r: f64, a0: f64, shadow: bool| -> Vec<f64> {
        (0..64)
            .map(|i| {
                let t = std::f64::consts::TAU * i as f64 / 64.0;
                let (x, y) = (r * t.cos(), r * t.sin());
                let (u, v) = (x * a0.cos() + y * a0.sin(), -x * a0.sin() + y * a0.cos());
                let inside = (0.5 + half_bar - u.abs().min(v.abs())).clamp(0.0, 1.0);
                let grey = 30.0 + 170.0 * inside;
                if shadow && x > 0.0 {
                    0.45 * grey
                } else {
                    grey
                }
            })
            .collect()
    };
    for (half_bar, r) in [(9.5, 16.0), (4.0, 16.0), (6.0, 30.0)] {
        for shadow in [false, true] {
            for a0 in [0.2, 0.7] {
                let w = super::bar_width_on_ring(&ring(half_bar, r, a0, shadow), 1.0, r, a0);
                let truth = 2.0 * half_bar;
                assert!(
                    (w - truth).abs() < 0.1 * truth + std::f64::consts::TAU * r / 64.0,
                    "bar {truth} px, ring {r} px, shadow {shadow}, a0 {a0}: {w}"
                );
            }
        }
    }
}
