//! What the printed-target detectors hand back: verified targets in tile
//! pixels, reduced to one per physical target and turned into [`Detection`]s.

use super::geometry::{self, Pt};
use super::{Detection, MarkerType, Refinement};

/// A verified target in tile pixels.
pub struct Found {
    pub centre: Pt,
    /// Outline of the target (square corners, or a circle's bounding square).
    pub corners: [Pt; 4],
    pub size: f64,
    /// Distance from the candidate's first centre to the refined one.
    pub shift: f64,
    pub rms: f64,
    pub confidence: f64,
}

/// One detection per physical target: candidates that converged on the same
/// centre keep the most confident.
pub fn best_per_target(found: &mut Vec<Found>) -> Vec<Found> {
    found.sort_by(|a, b| {
        b.confidence
            .total_cmp(&a.confidence)
            .then(a.centre.1.total_cmp(&b.centre.1))
            .then(a.centre.0.total_cmp(&b.centre.0))
    });
    let mut kept: Vec<Found> = Vec::new();
    for f in found.drain(..) {
        if !kept
            .iter()
            .any(|k| geometry::dist(k.centre, f.centre) < 0.3 * k.size.min(f.size))
        {
            kept.push(f);
        }
    }
    kept
}

/// One detection per board: a verified target whose centre lies on a
/// larger verified target's board is a detail of it (a marking's corner, a
/// quadrant's texture). The larger is kept: it was verified on more of the
/// image. Copies of one target (similar sizes) keep the most confident.
pub fn one_per_board(found: &mut Vec<Found>) -> Vec<Found> {
    found.sort_by(|a, b| {
        b.size
            .total_cmp(&a.size)
            .then(b.confidence.total_cmp(&a.confidence))
            .then(a.centre.1.total_cmp(&b.centre.1))
            .then(a.centre.0.total_cmp(&b.centre.0))
    });
    let mut kept: Vec<Found> = Vec::new();
    for f in found.drain(..) {
        match kept
            .iter()
            .position(|k| geometry::dist(k.centre, f.centre) < 0.5 * k.size)
        {
            None => kept.push(f),
            Some(i) if kept[i].size < 1.5 * f.size && f.confidence > kept[i].confidence => {
                kept[i] = f
            }
            Some(_) => {}
        }
    }
    kept
}

/// Of a target found as it is and (maybe) found again with a shadow lifted,
/// the one whose edges fit their lines or ellipse better.
pub fn better_fit<E>(first: Found, second: Result<Found, E>) -> Found {
    match second {
        Ok(second) if second.rms < first.rms => second,
        _ => first,
    }
}

pub fn to_detection(
    marker_type: MarkerType,
    f: Found,
    origin: (usize, usize),
    w: f64,
    h: f64,
    seams: [bool; 4],
) -> Detection {
    let (ox, oy) = (origin.0 as f64, origin.1 as f64);
    Detection {
        marker_type,
        marker_id: None,
        center: (f.centre.0 + ox, f.centre.1 + oy),
        corners: f.corners.map(|(x, y)| (x + ox, y + oy)),
        size_px: f.size,
        refine_shift_px: f.shift,
        refinement: Refinement::Refined,
        bit_errors: None,
        decision_margin: None,
        fit_rms_px: Some(f.rms),
        confidence: f.confidence,
        tile_margin: geometry::seam_margin(&f.corners, w, h, seams),
    }
}
