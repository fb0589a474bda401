use super::*;
use crate::pipeline::detect::geometry;
use crate::pipeline::detect::test_image::{gaussian_blurred, render_image};
use crate::pipeline::detect::DetectorConfig;

/// Tag `id` of `family` drawn as libapriltag draws it, `cell` px a cell,
/// turned by `angle` about `centre`, on a light ground; returns the image
/// and where the corners of the reported square (the border's) are.
fn draw(
    family: AprilTagFamily,
    id: u32,
    w: usize,
    centre: Pt,
    cell: f64,
    angle: f64,
) -> (Vec<u8>, [Pt; 4]) {
    draw_lit(family, id, w, centre, cell, angle, |_, _| 1.0)
}

/// As [`draw`], with the light at each point scaled by `light(x, y)`.
fn draw_lit(
    family: AprilTagFamily,
    id: u32,
    w: usize,
    centre: Pt,
    cell: f64,
    angle: f64,
    light: impl Fn(f64, f64) -> f64,
) -> (Vec<u8>, [Pt; 4]) {
    let tag = tag_cells(family, id).unwrap();
    let n = tag.cells.len() as f64;
    let (s, c) = angle.sin_cos();
    let data = render_image(w, |x, y| {
        let (dx, dy) = (x - centre.0, y - centre.1);
        let (u, v) = ((c * dx + s * dy) / cell, (-s * dx + c * dy) / cell);
        let (col, row) = ((u + n / 2.0).floor(), (v + n / 2.0).floor());
        let grey = if col < 0.0 || row < 0.0 || col >= n || row >= n {
            120.0
        } else if tag.cells[row as usize][col as usize] {
            215.0
        } else {
            20.0
        };
        grey * light(x, y)
    });
    let half = tag.width_at_border as f64 / 2.0 * cell;
    let corner = |u: f64, v: f64| (centre.0 + c * u - s * v, centre.1 + s * u + c * v);
    let corners = [
        corner(-half, -half),
        corner(half, -half),
        corner(half, half),
        corner(-half, half),
    ];
    (data, corners)
}

fn detect(family: AprilTagFamily, data: &[u8], w: usize) -> Vec<Detection> {
    let mat = Mat::from_slice(data)
        .and_then(|m| m.reshape(1, w as i32)?.try_clone())
        .unwrap();
    let config = DetectorConfig {
        apriltag_family: family,
        ..DetectorConfig::default()
    };
    AprilTagDetector::new(family, &config)
        .detect(&mat, (0, 0), [false; 4])
        .unwrap()
}

#[test]
fn every_family_is_read_with_its_id_centre_and_corner_order() {
    for (name, id, cell) in [
        ("36h11", 17, 5.3),
        ("36h10", 3, 5.3),
        ("25h9", 30, 6.1),
        ("16h5", 29, 7.2),
        ("Standard41h12", 1234, 5.7),
        ("Custom48h12", 999, 5.1),
        ("Circle21h7", 37, 6.4),
    ] {
        let family: AprilTagFamily = name.parse().unwrap();
        let w = 160;
        let centre = (80.37, 78.81);
        let (data, corners) = draw(family, id, w, centre, cell, 0.4);
        let found = detect(family, &data, w);
        assert_eq!(found.len(), 1, "{name}: {found:?}");
        let d = &found[0];
        assert_eq!(d.marker_id, Some(id), "{name}");
        assert_eq!(d.bit_errors, Some(0), "{name}");
        let err = geometry::dist(d.center, centre);
        // Classic tags: our edge-line fit; the others: libapriltag's own
        // edge refinement (data cells outside the border).
        let limit = if tag_cells(family, id).unwrap().classic {
            0.05
        } else {
            0.35
        };
        assert!(err < limit, "{name}: centre off by {err:.3} px");
        assert!(
            geometry::dist(d.corners[0], corners[0]) < limit * 3.0,
            "{name}: first corner {:?}, drawn {:?}",
            d.corners[0],
            corners[0]
        );
    }
}

#[test]
fn family_names_are_taken_as_users_write_them() {
    for (given, name) in [
        ("36h11", "36h11"),
        ("tag36h11", "36h11"),
        ("DICT_APRILTAG_36h11", "36h11"),
        ("tagStandard41h12", "Standard41h12"),
        ("circle21h7", "Circle21h7"),
        ("CUSTOM48H12", "Custom48h12"),
    ] {
        assert_eq!(given.parse::<AprilTagFamily>().unwrap().name(), name);
    }
    let e = "36h12".parse::<AprilTagFamily>().unwrap_err();
    assert!(e.contains("36h12") && e.contains("Standard41h12"), "{e}");
}

#[test]
fn an_id_past_the_family_is_refused_by_name() {
    let e = tag_cells("16h5".parse().unwrap(), 30)
        .unwrap_err()
        .to_string();
    assert!(e.contains("16h5") && e.contains("0..29"), "{e}");
}

/// A hard shadow edge across a tag (a pole's): the shadowed part of the
/// white quiet zone is darker than the lit ground, and a threshold midway
/// between the lit white and the black cuts the tag's outline there. On
/// the search scale (see `KNEE`) the tag is found, and the corners, fitted
/// to the edges' local levels, keep the centre.
#[test]
fn a_tag_half_in_hard_shadow_is_found_and_centred() {
    let family = AprilTagFamily::default();
    let w = 120;
    let centre = (60.4, 59.7);
    for (angle, offset) in [(0.3, 0.0), (1.1, 6.0), (2.0, -9.0)] {
        let (s, c) = f64::sin_cos(angle);
        let (data, _) = draw_lit(family, 44, w, centre, 3.4, 0.2, |x, y| {
            // Shadow on one side of a line through the tag, 45% light,
            // one pixel of penumbra.
            let d = -s * (x - centre.0) + c * (y - centre.1) - offset;
            0.45 + 0.55 * (d + 0.5).clamp(0.0, 1.0)
        });
        let found = detect(family, &data, w);
        assert_eq!(found.len(), 1, "angle {angle}: {found:?}");
        let err = geometry::dist(found[0].center, centre);
        assert!(err < 0.1, "angle {angle}: centre off by {err:.3} px");
    }
}

#[test]
fn families_correct_as_many_bits_as_keep_false_reads_rare() {
    let bits = |name: &str| {
        let handle = FamilyHandle::new(name.parse().unwrap());
        let f = handle.get();
        corrected_bits(f.ncodes, f.nbits)
    };
    for (name, want) in [
        ("16h5", 0),
        ("25h9", 0),
        ("36h10", 1),
        ("36h11", 2),
        ("Standard41h12", 1),
        ("Circle21h7", 0),
        ("Custom48h12", 0),
    ] {
        assert_eq!(bits(name), want, "{name}");
    }
}

/// Tags of 18-20 px (cells of 2.3-2.5 px) under a blur of 1.2 px: on the
/// search scale a blurred black cell falls on the white side of the
/// threshold (two of these six are found on it alone), so the
/// tile is also searched on its own greys.
#[test]
fn the_smallest_blurred_tags_are_found() {
    let family = AprilTagFamily::default();
    let w = 64;
    let mut missed = Vec::new();
    for k in 0..6 {
        let cell = [2.3, 2.4, 2.5][k % 3];
        let angle = 0.37 * k as f64;
        let id = 5 + 31 * k as u32;
        let centre = (31.6 + 0.13 * k as f64, 32.3 - 0.17 * k as f64);
        let (sharp, _) = draw(family, id, w, centre, cell, angle);
        let data = gaussian_blurred(&sharp, w, 1.2);
        let found = detect(family, &data, w);
        match found.as_slice() {
            [d] if d.marker_id == Some(id) && geometry::dist(d.center, centre) < 0.3 => {}
            _ => missed.push((cell, angle, found)),
        }
    }
    assert!(missed.is_empty(), "missed: {missed:?}");
}
