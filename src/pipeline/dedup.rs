//! Overlapping tiles see targets near seams twice: keep one copy of each
//! physical target, the one seen farthest from a seam.

use super::detect::geometry::dist;
use super::detect::Detection;

/// Two detections of the same type and id whose centres are closer than this
/// fraction of the target size are the same target.
const SAME_TARGET_FRACTION: f64 = 0.5;
/// Copies of one target measure within a few percent of each other's size;
/// a detection this much larger than another on it is a different target
/// that contains it.
const NESTED_SIZE_RATIO: f64 = 1.5;

/// Removes duplicates in place. The result is sorted by (type, id, y, x) and
/// independent of the order detections arrived in.
pub fn remove_duplicates(detections: &mut Vec<Detection>) {
    // Best copy first: larger seam margin wins; position breaks exact ties.
    detections.sort_by(|a, b| {
        (a.marker_type, a.marker_id)
            .cmp(&(b.marker_type, b.marker_id))
            .then(b.tile_margin.total_cmp(&a.tile_margin))
            .then(a.center.1.total_cmp(&b.center.1))
            .then(a.center.0.total_cmp(&b.center.0))
    });
    let mut kept: Vec<Detection> = Vec::with_capacity(detections.len());
    for d in detections.drain(..) {
        let duplicate = kept.iter().position(|k| {
            k.marker_type == d.marker_type
                && k.marker_id == d.marker_id
                && dist(k.center, d.center) < SAME_TARGET_FRACTION * k.size_px.max(d.size_px)
        });
        match duplicate {
            None => kept.push(d),
            // A much larger target around a kept one: the kept one is a
            // detail of its board (a printed target's marking) seen from a
            // tile that did not hold the whole board.
            Some(i) if d.size_px > NESTED_SIZE_RATIO * kept[i].size_px => kept[i] = d,
            Some(_) => {}
        }
    }
    kept.sort_by(|a, b| {
        (a.marker_type, a.marker_id)
            .cmp(&(b.marker_type, b.marker_id))
            .then(a.center.1.total_cmp(&b.center.1))
            .then(a.center.0.total_cmp(&b.center.0))
    });
    *detections = kept;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::detect::{MarkerType, Refinement};

    fn det(id: u32, x: f64, margin: f64) -> Detection {
        Detection {
            marker_type: MarkerType::AprilTag,
            marker_id: Some(id),
            center: (x, 100.0),
            corners: [(0.0, 0.0); 4],
            size_px: 40.0,
            refine_shift_px: 0.0,
            refinement: Refinement::Refined,
            bit_errors: Some(0),
            decision_margin: Some(0.4),
            fit_rms_px: None,
            confidence: 1.0,
            tile_margin: margin,
        }
    }

    #[test]
    fn keeps_copy_farthest_from_seam() {
        let mut v = vec![
            det(3, 100.02, 5.0),
            det(3, 100.0, 80.0),
            det(3, 900.0, 10.0),
            det(4, 100.0, 1.0),
        ];
        remove_duplicates(&mut v);
        let got: Vec<_> = v.iter().map(|d| (d.marker_id, d.center.0)).collect();
        assert_eq!(
            got,
            vec![(Some(3), 100.0), (Some(3), 900.0), (Some(4), 100.0)]
        );
    }
}
