use super::board::{board_by_levels, board_centre, Levels};
use super::centre::{centre_between, centre_from_sides, cross3};
use super::*;
use crate::pipeline::detect::geometry::{apply, square_to_quad};

/// Samples a projected circle of radius r around the origin of the unit
/// square's centre through homography h, and fits an exact conic to it.
fn projected(h: &[f64; 9], r: f64) -> Ellipse {
    let pts: Vec<Pt> = (0..200)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / 200.0;
            apply(h, (0.5 + r * a.cos(), 0.5 + r * a.sin()))
        })
        .collect();
    fit(&pts).expect("ellipse")
}

/// The unit square's image under a strong perspective, so that ellipse
/// centres are visibly biased.
const STRONG_PERSPECTIVE: [Pt; 4] = [
    (100.0, 100.0),
    (400.0, 130.0),
    (380.0, 420.0),
    (90.0, 360.0),
];

#[test]
fn concentric_rings_recover_the_projected_centre() {
    let h = square_to_quad(&STRONG_PERSPECTIVE);
    let truth = apply(&h, (0.5, 0.5));
    let (inner, outer) = (projected(&h, 0.1), projected(&h, 0.3));
    let bias = geometry::dist(outer.c, truth);
    assert!(bias > 0.5, "outer ellipse centre bias only {bias}");
    let c = concentric_centre(&inner, &outer).expect("centre");
    assert!(
        geometry::dist(c, truth) < 0.02,
        "{c:?} vs {truth:?} (bias was {bias})"
    );
}

/// A disc of radius 0.2 on the unit square under [`STRONG_PERSPECTIVE`]:
/// its homography, ellipse and projected centre, the ellipse's centre
/// visibly off it.
fn disc_in_strong_perspective() -> ([f64; 9], Ellipse, Pt) {
    let h = square_to_quad(&STRONG_PERSPECTIVE);
    let truth = apply(&h, (0.5, 0.5));
    let disc = projected(&h, 0.2);
    let bias = geometry::dist(disc.c, truth);
    assert!(bias > 0.5, "ellipse centre bias only {bias}");
    (h, disc, truth)
}

/// A board side through points `p`, `q` of the unit square under `h`,
/// as a homogeneous line relative to the ellipse's centre.
fn side_line(h: &[f64; 9], disc: &Ellipse, p: Pt, q: Pt) -> [f64; 3] {
    let (p, q, o) = (apply(h, p), apply(h, q), disc.c);
    cross3([p.0 - o.0, p.1 - o.1, 1.0], [q.0 - o.0, q.1 - o.1, 1.0])
}

/// The sides of a board of half side 0.4 around the disc, in order
/// around it: left, top, right, bottom.
const BOARD_SIDES: [(Pt, Pt); 4] = [
    ((0.1, 0.0), (0.1, 1.0)),
    ((0.0, 0.1), (1.0, 0.1)),
    ((0.9, 0.0), (0.9, 1.0)),
    ((0.0, 0.9), (1.0, 0.9)),
];

#[test]
fn two_opposite_board_sides_recover_the_projected_centre() {
    let (h, disc, truth) = disc_in_strong_perspective();
    let [left, top, right, bottom] = BOARD_SIDES.map(|(p, q)| side_line(&h, &disc, p, q));
    for (a, b) in [(left, right), (top, bottom), (right, left)] {
        let c = centre_between(&disc, &a, &b).expect("centre");
        assert!(geometry::dist(c, truth) < 0.02, "{c:?} vs {truth:?}");
    }
    // Sides of a board off the disc's centre give another point.
    let off = side_line(&h, &disc, (0.2, 0.0), (0.2, 1.0));
    let c = centre_between(&disc, &off, &right).expect("centre");
    assert!(geometry::dist(c, truth) > 0.5, "{c:?} vs {truth:?}");
    // All four sides and any one opposite pair agree.
    let all = perspective_centre(
        &disc,
        &[Some(left), Some(top), Some(right), Some(bottom)],
        &Params::default(),
    );
    let pair = perspective_centre(
        &disc,
        &[None, Some(top), None, Some(bottom)],
        &Params::default(),
    );
    for c in [all, pair] {
        assert!(geometry::dist(c.expect("centre"), truth) < 0.02);
    }
}

#[test]
fn two_adjacent_board_sides_recover_the_projected_centre() {
    let (h, disc, truth) = disc_in_strong_perspective();
    let sides = BOARD_SIDES.map(|(p, q)| Some(side_line(&h, &disc, p, q)));
    for k in 0..4 {
        let mut seen = [None; 4];
        seen[k] = sides[k];
        seen[(k + 1) % 4] = sides[(k + 1) % 4];
        let c = perspective_centre(&disc, &seen, &Params::default()).expect("centre");
        assert!(
            geometry::dist(c, truth) < 0.02,
            "sides {k}, {}: {c:?} vs {truth:?}",
            (k + 1) % 4
        );
    }
    // A board off the disc's centre (its sides at 0.2 and 0.1 from the
    // disc's edge) gives no centre near the disc's; one side alone none.
    let off = Some(side_line(&h, &disc, (0.2, 0.0), (0.2, 1.0)));
    let c = perspective_centre(&disc, &[off, sides[1], None, None], &Params::default());
    assert!(c.is_none_or(|c| geometry::dist(c, truth) > 0.5), "{c:?}");
    assert!(perspective_centre(&disc, &[sides[0], None, None, None], &Params::default()).is_none());
}

#[test]
fn a_side_found_on_clutter_is_left_out_or_no_correction_is_made() {
    let (h, disc, truth) = disc_in_strong_perspective();
    let sides = BOARD_SIDES.map(|(p, q)| Some(side_line(&h, &disc, p, q)));
    // The top side found on the edge of something lying against the
    // board, turned against it: it moves the pole by 3.0 px (radius 57).
    let mut clutter = sides;
    clutter[1] = Some(side_line(&h, &disc, (0.0, 0.0), (1.0, 0.2)));
    let moved = centre_from_sides(&disc, &clutter).expect("centre");
    assert!(geometry::dist(moved, truth) > 2.5, "{moved:?} vs {truth:?}");
    // The other three agree: the centre from them.
    let c = perspective_centre(&disc, &clutter, &Params::default()).expect("centre");
    assert!(geometry::dist(c, truth) < 0.02, "{c:?} vs {truth:?}");
    // With three sides seen, one of them wrong, nothing tells which: no
    // correction (the ellipse's own centre is used).
    clutter[3] = None;
    assert_eq!(
        perspective_centre(&disc, &clutter, &Params::default()),
        None
    );
}

/// A white disc (radius 20) on a black board (half side 40, turned 20
/// degrees) centred `tank` px off the disc (along the board's axes), on
/// ground that has the board's grey on every other diagonal band, and
/// all of it past the board's +u side when `hidden`: 4x4-supersampled
/// 8-bit.
fn board_on_ground_of_its_grey(tank: Pt, hidden: bool) -> (Vec<u8>, usize, Pt) {
    let side = 240;
    let disc = (120.3, 119.6);
    let (sin, cos) = 0.35f64.sin_cos();
    let board = (
        disc.0 + tank.0 * cos - tank.1 * sin,
        disc.1 + tank.0 * sin + tank.1 * cos,
    );
    let mut data = vec![0u8; side * side];
    for y in 0..side {
        for x in 0..side {
            let mut sum = 0.0f64;
            for s in 0..16 {
                let px = x as f64 - 0.375 + (s % 4) as f64 * 0.25;
                let py = y as f64 - 0.375 + (s / 4) as f64 * 0.25;
                let (dx, dy) = (px - board.0, py - board.1);
                let (u, v) = (dx * cos + dy * sin, -dx * sin + dy * cos);
                sum += if (px - disc.0).hypot(py - disc.1) < 20.0 {
                    200.0
                } else if (u.abs() < 40.0 && v.abs() < 40.0) || (hidden && u >= 40.0) {
                    70.0
                } else if ((px + py) / 9.0).floor().rem_euclid(2.0) == 0.0 {
                    72.0
                } else {
                    120.0
                };
            }
            data[y * side + x] = (sum / 16.0).round() as u8;
        }
    }
    (data, side, disc)
}

#[test]
fn a_board_on_ground_of_its_grey_is_found_by_its_level() {
    // The board by levels around the disc of board_on_ground_of_its_grey.
    let find = |tank: Pt, hidden: bool| {
        let (data, side, disc) = board_on_ground_of_its_grey(tank, hidden);
        let img = GreyView {
            data: &data,
            width: side,
            height: side,
            stride: side,
        };
        let e = Ellipse {
            c: disc,
            a: 20.0,
            b: 20.0,
            u: (1.0, 0.0),
        };
        board_by_levels(&Levels::new(&img, &e, 130.0, 1.0, &Params::default()), 0.35)
    };
    let square = find((0.0, 0.0), false).expect("board found by levels");
    assert!(
        (square.half - 40.0).abs() < 1.0,
        "half side {}",
        square.half
    );
    // To about a pixel, well inside what acceptance allows (3.4 px here):
    // board_side then refines each side to subpixel precision.
    let centre = board_centre(&square.sides).expect("centre");
    assert!(centre.0.hypot(centre.1) < 1.0, "board centre {centre:?}");
    // The same board 8 px off the disc (a tank off a roof's centre).
    assert!(find((8.0, 0.0), false).is_none());
    // Ground of the board's grey all along one side: three sides.
    let square = find((0.0, 0.0), true).expect("board found on three sides");
    assert_eq!(square.sides.iter().filter(|s| s.is_none()).count(), 1);
    assert!(
        (square.half - 40.0).abs() < 1.0,
        "half side {}",
        square.half
    );
    // Off the disc towards the hidden side or along it: the third side
    // or the pair across the hidden one is farther.
    for tank in [(-4.0, 0.0), (0.0, 4.0)] {
        assert!(find(tank, true).is_none(), "tank {tank:?}");
    }
}

/// The circle detector run on a w x w 8-bit image as one tile, sizes
/// from `min_px` to 200 px.
fn detect_in(data: &[u8], w: usize, min_px: f64) -> Vec<Detection> {
    let tile = Mat::from_slice(data)
        .and_then(|m| m.reshape(1, w as i32)?.try_clone())
        .expect("tile");
    let designs: Vec<TargetDesign> = crate::pipeline::detect::design::presets()
        .into_iter()
        .filter(|d| d.marker_type() == MarkerType::Circle)
        .collect();
    let mut detector = CircleDetector::new(
        SizeRange {
            min_px,
            max_px: 200.0,
            reach_px: 200.0,
        },
        &designs,
    );
    detector.detect(&tile, (0, 0), [false; 4]).expect("detect")
}

/// Bullseye rings (outer radius 30) with a shadow's straight edge
/// across them a little off the centre, on a white board 1.25x their
/// diameter or on bare grey ground.
fn bullseye(on_board: bool) -> (Vec<u8>, usize, Pt) {
    let (w, c, r) = (200usize, (100.4, 99.7), 30.0);
    let data = crate::pipeline::detect::test_image::render_image(w, |x, y| {
        let (dx, dy) = (x - c.0, y - c.1);
        let d = dx.hypot(dy) / r;
        let grey = if d < 1.0 / 3.0 || (2.0 / 3.0..1.0).contains(&d) {
            25.0
        } else if d < 1.0 || (on_board && dx.abs().max(dy.abs()) < 1.25 * r) {
            225.0
        } else {
            115.0 + 8.0 * (0.21 * x).sin() * (0.13 * y).cos()
        };
        grey * if 0.8 * dx + 0.6 * dy < 6.0 { 1.0 } else { 0.55 }
    });
    (data, w, c)
}

#[test]
fn bullseye_rings_need_their_light_board() {
    let (data, w, c) = bullseye(true);
    let found = detect_in(&data, w, 40.0);
    assert_eq!(found.len(), 1, "{found:?}");
    let d = &found[0];
    assert!(
        (d.center.0 - c.0).hypot(d.center.1 - c.1) < 0.1,
        "centre {:?}",
        d.center
    );
    // The same rings on grey ground: concentric clutter, not a target.
    let (data, w, _) = bullseye(false);
    assert!(detect_in(&data, w, 40.0).is_empty());
}

/// A white disc (radius 34) on a black board turned 30 degrees, printed
/// at low contrast on textured ground, with a shadow's straight edge
/// across the disc a third of the way down: the adaptive threshold
/// leaves a dark band along the edge inside the disc and parts it into a
/// lit cap and a shadowed rest, neither of them round.
#[test]
fn a_disc_split_by_a_shadow_is_found_from_its_arcs() {
    let (w, c, r) = (300usize, (151.3, 147.6), 34.0);
    let (cos, sin) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
    let n = (0.17f64, 0.985);
    let n = (n.0 / n.0.hypot(n.1), n.1 / n.0.hypot(n.1));
    let data = crate::pipeline::detect::test_image::render_image(w, |x, y| {
        let (dx, dy) = (x - c.0, y - c.1);
        let (u, v) = (dx * cos + dy * sin, -dx * sin + dy * cos);
        let grey = if dx.hypot(dy) < r {
            150.0
        } else if u.abs() < 2.0 * r && v.abs() < 2.0 * r {
            80.0
        } else {
            115.0 + 12.0 * (0.21 * x).sin() * (0.13 * y).cos()
        };
        grey * if n.0 * dx + n.1 * dy < -12.0 {
            1.0
        } else {
            0.45
        }
    });
    let found = detect_in(&data, w, 40.0);
    assert_eq!(found.len(), 1, "{found:?}");
    let error = geometry::dist(found[0].center, c);
    assert!(
        error < 0.3,
        "centre {:?}, {error:.2} px off",
        found[0].center
    );
}

/// A white disc (radius 20) in a black ring twice its radius (a round
/// board: a tank's rim, a clutter ring) on textured ground, with a dark
/// bump on the ring where a square's corner would be: the rays there
/// end far enough out for the loose square a ring fits to look cornered.
#[test]
fn a_disc_on_a_round_board_is_not_a_target() {
    let (w, c, r) = (220usize, (109.6, 111.2), 20.0);
    let data = crate::pipeline::detect::test_image::render_image(w, |x, y| {
        let (dx, dy) = (x - c.0, y - c.1);
        let d = dx.hypot(dy);
        let (s, co) = 45f64.to_radians().sin_cos();
        let bump = (dx - 2.1 * r * co).hypot(dy - 2.1 * r * s) < 0.55 * r;
        if d < r {
            210.0
        } else if d < 2.0 * r || bump {
            35.0
        } else {
            125.0 + 10.0 * (0.23 * x).sin() * (0.17 * y).cos()
        }
    });
    assert_eq!(detect_in(&data, w, 30.0), vec![]);
}

/// A white disc (radius 20) centred on a black board turned 20 degrees,
/// 80 px wide one way and `long` px the other, on textured ground: a
/// square board is a target; one 40% longer than wide (a flat roof with
/// a tank on it) is not, though its sides lie within the range a board
/// may have (1.4 to 3 radii from the disc).
#[test]
fn a_disc_on_an_oblong_board_is_not_a_target() {
    for (long, target) in [(80.0, true), (112.0, false)] {
        let (w, c, r) = (260usize, (129.4, 131.7), 20.0);
        let (s, co) = 20f64.to_radians().sin_cos();
        let data = crate::pipeline::detect::test_image::render_image(w, |x, y| {
            let (dx, dy) = (x - c.0, y - c.1);
            let (u, v) = (dx * co + dy * s, -dx * s + dy * co);
            if dx.hypot(dy) < r {
                205.0
            } else if u.abs() < 40.0 && v.abs() < long / 2.0 {
                40.0
            } else {
                125.0 + 10.0 * (0.23 * x).sin() * (0.17 * y).cos()
            }
        });
        let found = detect_in(&data, w, 30.0);
        assert_eq!(found.len(), target as usize, "board {long} px: {found:?}");
    }
}

/// The white disc in a dark ring that passed in clutter scene 1407: at
/// the frame's edge, a dark square lying against the ring. Its board
/// by levels had three sides, all arcs of the ring.
#[test]
fn a_disc_in_a_ring_at_the_frames_edge_is_not_a_target() {
    let (img, _) = gcp_synth::render(&gcp_synth::clutter_scene(2400, 1800, 1407)).expect("render");
    let w = 256usize;
    let data: Vec<u8> = img
        .window(0, 1098 - 128, w, w)
        .data
        .iter()
        .map(|v| (v * 255.0).round().clamp(0.0, 255.0) as u8)
        .collect();
    assert_eq!(detect_in(&data, w, 40.0), vec![]);
}

/// Rings of `edges` (radii over the outer radius, dark centre when
/// `dark_centre`) of outer radius 36 on a board 1.25x their diameter of
/// the colour past the last edge, on textured grey ground.
fn rings_image(edges: &[f64], dark_centre: bool) -> (Vec<u8>, usize, Pt) {
    let (w, c, r) = (220usize, (110.3, 109.6), 36.0);
    let (dark, light) = (30.0, 220.0);
    let data = crate::pipeline::detect::test_image::render_image(w, |x, y| {
        let (dx, dy) = (x - c.0, y - c.1);
        let d = dx.hypot(dy) / r;
        let crossed = edges.iter().filter(|&&e| d >= e).count();
        if d >= 1.0 && dx.abs().max(dy.abs()) >= 1.25 * r {
            return 120.0 + 8.0 * (0.21 * x).sin() * (0.13 * y).cos();
        }
        if (crossed % 2 == 0) == dark_centre {
            dark
        } else {
            light
        }
    });
    (data, w, c)
}

/// The detector of `designs` (preset names or JSON) on one tile.
fn detect_designs(data: &[u8], w: usize, designs: &[&str]) -> Vec<Detection> {
    detect_with(data, w, designs, Params::default())
}

/// The same with other thresholds.
fn detect_with(data: &[u8], w: usize, designs: &[&str], params: Params) -> Vec<Detection> {
    let tile = Mat::from_slice(data)
        .and_then(|m| m.reshape(1, w as i32)?.try_clone())
        .expect("tile");
    let designs: Vec<TargetDesign> = designs
        .iter()
        .map(|d| TargetDesign::preset(d).unwrap_or_else(|| TargetDesign::from_json(d).unwrap()))
        .collect();
    let sizes = SizeRange {
        min_px: 40.0,
        max_px: 200.0,
        reach_px: 200.0,
    };
    CircleDetector::new(sizes, &designs)
        .with_params(params)
        .detect(&tile, (0, 0), [false; 4])
        .expect("detect")
}

#[test]
fn thresholds_are_settable() {
    // Inks of 220 and 30 grey levels: 7.3 times as bright. Asking for 8
    // rejects the print as not ink; asking for a ring fit the rendered
    // edges cannot meet rejects it too.
    let (data, w, _) = rings_image(&[1.0 / 3.0, 2.0 / 3.0, 1.0], true);
    assert_eq!(detect_designs(&data, w, &["bullseye"]).len(), 1);
    let ink = Params {
        min_light_ratio: 8.0,
        ..Params::default()
    };
    assert_eq!(detect_with(&data, w, &["bullseye"], ink), vec![]);
    let exact = Params {
        max_fit_rms_px: -1.0,
        ..Params::default()
    };
    assert_eq!(detect_with(&data, w, &["bullseye"], exact), vec![]);
}

#[test]
fn bullseyes_of_other_ring_ratios_are_found_from_their_design() {
    let light_centre = r#"{"name":"halo","kind":"rings","polarity":"light_on_dark","ring_radii":[[0.3,0.5],[0.6,0.8],1]}"#;
    for (edges, dark, design) in [
        (&[1.0 / 3.0, 2.0 / 3.0, 1.0][..], true, "bullseye"),
        (&[0.45, 0.8, 1.0][..], true, "bullseye"),
        (&[0.25, 0.5, 1.0][..], true, "bullseye"),
        (&[0.2, 0.4, 0.6, 0.8, 1.0][..], true, "bullseye-5"),
        (&[0.4, 0.7, 1.0][..], false, light_centre),
    ] {
        let (data, w, c) = rings_image(edges, dark);
        let found = detect_designs(&data, w, &[design]);
        assert_eq!(found.len(), 1, "{edges:?}: {found:?}");
        let d = &found[0];
        assert!(
            geometry::dist(d.center, c) < 0.1,
            "{edges:?}: {:?}",
            d.center
        );
        assert!(
            (d.size_px - 72.0).abs() < 1.5,
            "{edges:?}: size {}",
            d.size_px
        );
    }
    // Rings outside a design's ranges are not that design: a 1:2:3
    // bullseye is not the five-ring one, nor a light-centred one.
    let (data, w, _) = rings_image(&[1.0 / 3.0, 2.0 / 3.0, 1.0], true);
    assert_eq!(detect_designs(&data, w, &["bullseye-5"]), vec![]);
    assert_eq!(detect_designs(&data, w, &[light_centre]), vec![]);
    // Five rings found as themselves, not as their inner three, when both
    // designs are searched.
    let (data, w, _) = rings_image(&[0.2, 0.4, 0.6, 0.8, 1.0], true);
    let found = detect_designs(&data, w, &["bullseye", "bullseye-5"]);
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(
        (found[0].size_px - 72.0).abs() < 1.5,
        "size {}",
        found[0].size_px
    );
}
