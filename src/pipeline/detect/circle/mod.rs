//! Printed circular targets, found from their [`TargetDesign`]s: bullseyes
//! (a centre disc and rings of alternating colour, their edges at the
//! design's ring radii) and a disc on a square board of the other colour.
//!
//! 1. Candidates: every dark region or hole from [`blobs`] whose contour is
//!    an ellipse (OpenCV `fitEllipse`), taken as the innermost edge and
//!    refined on rays.
//! 2. Which design: the median radial profile around it, in the ellipse's
//!    own frame, gives the edges' radii and polarities; a ring design
//!    matches when they alternate as it says and their ratios lie within
//!    its ranges ([`rings`]). Otherwise a disc design is checked: a uniform
//!    board of the other colour that ends in a square of the design's
//!    proportions ([`board`]).
//! 3. Subpixel: the midpoint crossing on every ray gives edge points; OpenCV's
//!    direct least-squares ellipse fit (Fitzgibbon) runs on them, twice
//!    ([`rings`]).
//! 4. Perspective moves an ellipse's centre off the circle's projected centre.
//!    With two concentric rings the true centre is recovered exactly: for the
//!    conics C1, C3 of the inner and outer ring, it is the eigenvector of
//!    C1^-1 C3 for its single eigenvalue (the other two are equal). For a
//!    disc seen on all four sides of its board, the sides give the plane's
//!    vanishing line, and the centre is that line's pole with respect to the
//!    disc's conic; two opposite or two adjacent sides place it too, and
//!    a board with fewer sides fitted keeps the ellipse's centre ([`centre`]).

use opencv::core::{Mat, Point2f, RotatedRect, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use super::design::{DesignKind, Polarity, TargetDesign};
use super::fiducial::grey_view;
use super::found::{best_per_target, to_detection, Found};
use super::geometry::{self, Pt};
use super::profile as pr;
use super::refine::{intersect, GreyView};
use super::shadow;
use super::{arcs, blobs};
use super::{DetectError, Detection, Detector, MarkerType, SizeRange};

mod board;
mod centre;
mod params;
mod rings;
#[cfg(test)]
mod tests;

use board::board_sides;
use centre::{concentric_centre, perspective_centre};
use rings::{bullseye_on_board, fit, fit_robust, is_bullseye, match_layout, radial_edges};
use rings::{rays, rms, RingLayout};

pub use params::Params;

/// Largest board side over disc diameter searched for a disc target: the
/// widest a design may give (see `TargetDesign::validate`).
const MAX_BOARD_TO_DISC: f64 = 3.0;
/// Turn of a side tried either way when its board is found by levels.
const LEVEL_TILT_DEG: f64 = 3.0;
/// Most Newton steps for the centre from two adjacent board sides (it moves
/// less than 1e-6 px after 4 on the test frames and the unit test, 5 for a
/// board off the disc).
const ADJACENT_ITERATIONS: usize = 20;
/// Radius, in candidate radii, searched for a shadow edge across a failed
/// candidate: a disc's board (corners at 2.8) and a 1:2:3 bullseye's rings
/// (3). Searching farther for bullseyes with smaller centre discs (5
/// radii for 1:2.5:5) found other edges than the shadow's: 3 discs of
/// 180 lost on seeds 400, 401 and 900, no bullseye gained.
const SHADOW_SEARCH: f64 = 3.5;
/// Half side, in radii (the candidate's, then the found target's if
/// larger), of the copy with a shadow lifted: the rays walk to where a
/// board ends, up to 4.5 radii out.
const SHADOW_COPY: f64 = 4.8;

/// Why a candidate is not a target of the circular designs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rejection {
    /// No design's size fits the candidate, or the target as measured.
    Size,
    /// The rays found too few points on an edge.
    NoEdges,
    /// No ellipse fits the innermost edge's points.
    InnerFit,
    /// No ring design matches the edges along the rays (and no disc is
    /// searched).
    NoRings,
    /// The rings' edges do not alternate as the design says on enough rays.
    RingsNotSeen,
    /// No ellipse fits the outer ring's points.
    OuterFit,
    /// A middle ring's points are not an ellipse.
    RingFit,
    /// The rings are not ellipses of one shape around one centre.
    RingsNotConcentric,
    /// The centre disc's radius over the outer ring's is outside the
    /// design's range.
    RingRatio,
    /// No board of the ring's colour past the outer ring.
    NoBoard,
    /// The drawn rings do not match the image all round.
    RingsNotUniform,
    /// A disc of a polarity no design searched has.
    DiscPolarity,
    /// Too few rays saw an edge.
    Coverage,
    /// The light side is too little brighter than the dark one for two
    /// inks.
    NotInk,
    /// The edge points scatter about their ellipse.
    FitRms,
    /// A disc's board is not of one level around it.
    BoardNotUniform,
    /// A disc's board does not end within the design's proportions.
    BoardDoesNotEnd,
    /// A disc's board does not end in a square centred on it.
    BoardNotSquare,
    /// A side of a disc's board fits no line.
    BoardSide,
}

impl Rejection {
    /// Whether a shadow's edge across the target can cause this rejection,
    /// so a second look with the shadow lifted is worth taking. Most
    /// rejections on a cluttered frame (1172 of 1430 on clutter seeds
    /// 700-701) are dark blobs without a uniform ring of board around them;
    /// on 12 frames of printed circles every target a second look found had
    /// first failed on its board's square. A candidate of no size a design
    /// could have keeps its size in the copy.
    fn shadow_may_cause(self) -> bool {
        !matches!(
            self,
            Rejection::BoardNotUniform
                | Rejection::NoEdges
                | Rejection::InnerFit
                | Rejection::NoRings
                | Rejection::Size
        )
    }
}

/// An ellipse: centre, semi-axes and the direction of `a`.
#[derive(Debug, Clone, Copy)]
struct Ellipse {
    c: Pt,
    a: f64,
    b: f64,
    u: Pt,
}

impl Ellipse {
    fn from_rect(r: RotatedRect) -> Ellipse {
        let t = (r.angle as f64).to_radians();
        Ellipse {
            c: (r.center.x as f64, r.center.y as f64),
            a: r.size.width as f64 / 2.0,
            b: r.size.height as f64 / 2.0,
            u: (t.cos(), t.sin()),
        }
    }
    /// Radius of the circle of equal area.
    fn radius(&self) -> f64 {
        (self.a * self.b).sqrt()
    }
    /// Vector from the centre to the point at parameter `phi` (s = 1).
    fn ray(&self, phi: f64) -> Pt {
        let v = (-self.u.1, self.u.0);
        let (ca, sb) = (self.a * phi.cos(), self.b * phi.sin());
        (ca * self.u.0 + sb * v.0, ca * self.u.1 + sb * v.1)
    }
    /// Half the ellipse's width along the unit vector `n`.
    fn half_width(&self, n: Pt) -> f64 {
        let v = (-self.u.1, self.u.0);
        let (p, q) = (n.0 * self.u.0 + n.1 * self.u.1, n.0 * v.0 + n.1 * v.1);
        (self.a * self.a * p * p + self.b * self.b * q * q).sqrt()
    }
    /// Radial distance (pixels, approximately) of `p` from the ellipse.
    fn distance(&self, p: Pt) -> f64 {
        let v = (-self.u.1, self.u.0);
        let (dx, dy) = (p.0 - self.c.0, p.1 - self.c.1);
        let (x, y) = (
            (dx * self.u.0 + dy * self.u.1) / self.a,
            (dx * v.0 + dy * v.1) / self.b,
        );
        (x.hypot(y) - 1.0) * self.radius()
    }
    /// The conic matrix (row-major 3x3) in coordinates relative to `origin`.
    fn conic(&self, origin: Pt) -> [f64; 9] {
        let v = (-self.u.1, self.u.0);
        let (ia, ib) = (1.0 / (self.a * self.a), 1.0 / (self.b * self.b));
        let q = [
            ia * self.u.0 * self.u.0 + ib * v.0 * v.0,
            ia * self.u.0 * self.u.1 + ib * v.0 * v.1,
            ia * self.u.1 * self.u.1 + ib * v.1 * v.1,
        ];
        let (cx, cy) = (self.c.0 - origin.0, self.c.1 - origin.1);
        let (qcx, qcy) = (q[0] * cx + q[1] * cy, q[1] * cx + q[2] * cy);
        [
            q[0],
            q[1],
            -qcx,
            q[1],
            q[2],
            -qcy,
            -qcx,
            -qcy,
            cx * qcx + cy * qcy - 1.0,
        ]
    }
}

/// Detector of bullseyes and boarded discs within a size range.
pub struct CircleDetector {
    sizes: SizeRange,
    /// Ring designs, most edges first (a five-edge bullseye's inner three
    /// edges would pass for a three-edge one).
    rings: Vec<RingLayout>,
    /// Disc designs: dark discs, light discs, and the boards' proportions
    /// accepted (side over the disc's diameter).
    dark_discs: bool,
    light_discs: bool,
    board: (f64, f64),
    mask: Mat,
    params: Params,
}

/// What one pass of rays found.
struct RayPass {
    /// Edge points per edge searched.
    edges: Vec<Vec<Pt>>,
    /// Sum of edge polarities (+1 light outside) per edge.
    polarity: Vec<f64>,
    /// Median contrast of the innermost edge.
    contrast: f64,
    /// Median ratio of the light side's grey to the dark side's across the
    /// innermost edge.
    light_ratio: f64,
    rays: usize,
}

impl CircleDetector {
    /// A detector of `designs` (rings and discs; others are ignored).
    pub fn new(mut sizes: SizeRange, designs: &[TargetDesign]) -> Self {
        // Printed targets are told from the ground by shape alone: below
        // this a disc is the size of a blob of foliage (a 17 px one on the
        // real photos of the README passed every check).
        sizes.min_px = sizes.min_px.max(super::printed::MIN_PRINTED_PX);
        let mut rings: Vec<RingLayout> =
            designs.iter().filter_map(RingLayout::from_design).collect();
        rings.sort_by_key(|l| std::cmp::Reverse(l.radii.len()));
        let discs: Vec<&TargetDesign> = designs
            .iter()
            .filter(|d| d.kind == DesignKind::Disc)
            .collect();
        let board = discs
            .iter()
            .map(|d| d.board.unwrap_or(super::design::DEFAULT_DISC_BOARD))
            .fold((f64::INFINITY, 0.0f64), |(lo, hi), r| {
                (lo.min(r.0), hi.max(r.1))
            });
        CircleDetector {
            sizes,
            rings,
            dark_discs: discs.iter().any(|d| d.polarity == Polarity::DarkOnLight),
            light_discs: discs.iter().any(|d| d.polarity == Polarity::LightOnDark),
            board,
            mask: Mat::default(),
            params: Params::default(),
        }
    }

    /// The same detector with other thresholds.
    pub fn with_params(self, params: Params) -> Self {
        CircleDetector { params, ..self }
    }

    /// Smallest radius, over the least size searched, of a candidate: a
    /// bullseye's centre disc or a disc.
    fn least_candidate(&self) -> f64 {
        let disc = if self.dark_discs || self.light_discs {
            1.0
        } else {
            f64::INFINITY
        };
        self.rings.iter().map(|l| l.radii[0].0).fold(disc, f64::min)
    }

    /// The ring designs whose centre disc a candidate of radius `r.0` to
    /// `r.1` may be (the target's size then within the sizes searched), and
    /// whether it may be a disc.
    fn possible(&self, r: (f64, f64)) -> (Vec<&RingLayout>, bool) {
        let fits = |lo: f64, hi: f64| {
            hi >= self.sizes.min_px / self.params.early_size_slack.below
                && lo <= self.sizes.max_px * self.params.early_size_slack.above
        };
        let rings = self
            .rings
            .iter()
            .filter(|l| fits(2.0 * r.0 / l.radii[0].1, 2.0 * r.1 / l.radii[0].0))
            .collect();
        let disc = (self.dark_discs || self.light_discs) && fits(2.0 * r.0, 2.0 * r.1);
        (rings, disc)
    }

    fn analyse(&self, img: &GreyView, start: Ellipse) -> Result<Found, Rejection> {
        // A contour's radius is within a pixel or two of the edge's.
        let r = start.radius();
        let (rings, disc) = self.possible(((r - 2.0).max(1.0), r + 2.0));
        if rings.is_empty() && !disc {
            return Err(Rejection::Size);
        }
        // The candidate's own edge: the threshold's contour can miss a
        // small centre disc's edge by a pixel or two.
        let mut e = start;
        for _ in 0..2 {
            let pass = rays(img, &e, &[1.0], 1.0, &self.params).ok_or(Rejection::NoEdges)?;
            let refined = fit(&pass.edges[0]).ok_or(Rejection::InnerFit)?;
            let moved = geometry::dist(refined.c, e.c) + (refined.radius() - e.radius()).abs();
            e = refined;
            if moved < 0.25 {
                break;
            }
        }
        let (rings, disc) = self.possible((e.radius(), e.radius()));
        if rings.is_empty() && !disc {
            return Err(Rejection::Size);
        }
        let reach = rings.iter().map(|l| l.reach()).fold(0.0, f64::max);
        let measured = if rings.is_empty() {
            Vec::new()
        } else {
            radial_edges(img, &e, 1.2 * reach.max(1.0), &self.params)
        };
        let matched = rings
            .into_iter()
            .find_map(|l| match_layout(l, &measured, &self.params).map(|pos| (l, pos)));
        let discs = disc;
        match matched {
            // A disc's board and the ground past it can show edges like a
            // bullseye's: a disc is still tried when the rings fail.
            Some((layout, pos)) => self.bullseye(img, start, e, layout, &pos).or_else(|why| {
                if discs {
                    self.disc(img, start, e)
                } else {
                    Err(why)
                }
            }),
            None if discs => self.disc(img, start, e),
            None => Err(Rejection::NoRings),
        }
    }

    fn bullseye(
        &self,
        img: &GreyView,
        start: Ellipse,
        e: Ellipse,
        layout: &RingLayout,
        pos: &[f64],
    ) -> Result<Found, Rejection> {
        let last = pos.len() - 1;
        if !self
            .sizes
            .accepts(2.0 * pos[last] * e.radius(), self.params.early_size_slack)
        {
            return Err(Rejection::Size);
        }
        let gap = pos[last] - if last == 0 { 0.0 } else { pos[last - 1] };
        let pass = rays(img, &e, pos, gap.min(0.55 * pos[last]), &self.params)
            .ok_or(Rejection::NoEdges)?;
        if !is_bullseye(&pass, layout, &self.params) {
            return Err(Rejection::RingsNotSeen);
        }
        let coverage = self.coverage(&pass, pass.edges.len())?;
        let (inner, inliers) = fit_robust(&pass.edges[0]).ok_or(Rejection::InnerFit)?;
        let rms = rms(&inner, &inliers);
        let outer = fit_robust(&pass.edges[last])
            .map(|(e, _)| e)
            .ok_or(Rejection::OuterFit)?;
        // Every ring is an ellipse of the outer one's shape around nearly
        // its centre (concentric circles in one plane); the rings a lattice
        // of squares or a paving shows around one of its cells are not.
        for points in &pass.edges[1..] {
            let (ring, inliers) = fit_robust(points).ok_or(Rejection::RingFit)?;
            if (inliers.len() as f64) < self.params.min_ring_inliers * points.len() as f64
                || rings::rms(&ring, &inliers) > self.params.max_fit_rms_px + 0.01 * ring.radius()
            {
                return Err(Rejection::RingFit);
            }
        }
        for ring in [&inner, &outer] {
            let aspect = |e: &Ellipse| e.a.min(e.b) / e.a.max(e.b);
            if (aspect(ring) - aspect(&outer)).abs()
                > self.params.max_aspect_gap + 0.5 / ring.radius()
                || geometry::dist(ring.c, outer.c)
                    > self.params.max_ring_offset * outer.radius() + 0.5
            {
                return Err(Rejection::RingsNotConcentric);
            }
        }
        let (lo, hi) = layout.radii[0];
        let ratio = inner.radius() / outer.radius();
        if !((lo - 0.05)..=(hi + 0.05)).contains(&ratio) {
            return Err(Rejection::RingRatio);
        }
        if !bullseye_on_board(img, &inner, pos, &self.params) {
            return Err(Rejection::NoBoard);
        }
        let score = rings::rings_score(img, &inner, pos, layout.dark_centre);
        if score < self.params.min_rings_score {
            return Err(Rejection::RingsNotUniform);
        }
        let c = concentric_centre(&inner, &outer)
            .filter(|c| geometry::dist(*c, inner.c) < 0.1 * inner.radius() + 0.5)
            .unwrap_or(inner.c);
        self.found(
            start,
            c,
            2.0 * outer.radius(),
            (&inner, rms),
            coverage,
            &pass,
        )
    }

    fn disc(&self, img: &GreyView, start: Ellipse, e: Ellipse) -> Result<Found, Rejection> {
        // Most candidates are a bullseye's possible centre disc, far too
        // small to be a disc: they end here, before the board's search.
        if !self
            .sizes
            .accepts(2.0 * e.radius(), self.params.early_size_slack)
        {
            return Err(Rejection::Size);
        }
        let pass = rays(img, &e, &[1.0], 1.0, &self.params).ok_or(Rejection::NoEdges)?;
        let coverage = self.coverage(&pass, 1)?;
        // Light outside: a dark disc.
        let dark = pass.polarity[0] > 0.0;
        if !(if dark {
            self.dark_discs
        } else {
            self.light_discs
        }) {
            return Err(Rejection::DiscPolarity);
        }
        let (e, inliers) = fit_robust(&pass.edges[0]).ok_or(Rejection::InnerFit)?;
        let rms = rms(&e, &inliers);
        // The ellipse's own centre is biased under perspective; the
        // board's subpixel sides tell where the disc's centre lies.
        // Without a pair of opposite ones (sides faint against the
        // ground, or hidden), the ellipse's centre.
        let sides = board_sides(img, &e, pass.polarity[0], self.board, &self.params)?;
        let c = perspective_centre(&e, &sides, &self.params)
            .filter(|c| geometry::dist(*c, e.c) < 0.1 * e.radius() + 0.5)
            .unwrap_or(e.c);
        self.found(start, c, 2.0 * e.radius(), (&e, rms), coverage, &pass)
    }

    /// The least share of rays that saw each of the first `edges` edges.
    fn coverage(&self, pass: &RayPass, edges: usize) -> Result<f64, Rejection> {
        let n = pass.rays as f64;
        let coverage = pass.edges[..edges]
            .iter()
            .map(|v| v.len() as f64 / n)
            .fold(1.0, f64::min);
        if coverage < self.params.min_coverage {
            return Err(Rejection::Coverage);
        }
        Ok(coverage)
    }

    #[allow(clippy::too_many_arguments)]
    /// The detection, once its size, ink and fit pass: `e` is the ellipse
    /// the fit RMS was measured on, `pass` the rays that found it.
    fn found(
        &self,
        start: Ellipse,
        centre: Pt,
        size: f64,
        (e, rms): (&Ellipse, f64),
        coverage: f64,
        pass: &RayPass,
    ) -> Result<Found, Rejection> {
        if !self.sizes.accepts(size, self.params.size_slack) {
            return Err(Rejection::Size);
        }
        if pass.light_ratio < self.params.min_light_ratio {
            return Err(Rejection::NotInk);
        }
        if rms > self.params.max_fit_rms_px + 0.01 * e.radius() {
            return Err(Rejection::FitRms);
        }
        let confidence = (coverage
            * (1.0 / (1.0 + (rms / 0.25).powi(2)))
            * (pass.contrast / 40.0).clamp(0.0, 1.0))
        .powf(1.0 / 3.0);
        let r = size / 2.0;
        Ok(Found {
            centre,
            corners: [(-r, -r), (r, -r), (r, r), (-r, r)]
                .map(|(dx, dy)| (centre.0 + dx, centre.1 + dy)),
            size,
            shift: geometry::dist(centre, start.c),
            rms,
            confidence,
        })
    }

    /// The candidate analysed again with the shadow edge across it (if one
    /// is found) lifted: a shadow's edge across a board or the rings breaks
    /// their uniform levels.
    fn analyse_lifted(
        &self,
        img: &GreyView,
        start: Ellipse,
    ) -> Result<Found, shadow::SecondLook<Rejection>> {
        let r = start.radius();
        // Reach: within three quarters of the size (the disc's diameter or
        // the bullseye's), through the disc or the rings' board.
        shadow::second_look(
            img,
            start.c,
            SHADOW_SEARCH * r,
            (SHADOW_COPY * r, |size: f64| SHADOW_COPY * size / 2.0),
            |size| 0.75 * size,
            |view, at| self.analyse(view, Ellipse { c: at, ..start }),
        )
    }
}

impl Detector for CircleDetector {
    fn marker_type(&self) -> MarkerType {
        MarkerType::Circle
    }

    fn detect(
        &mut self,
        tile: &Mat,
        origin: (usize, usize),
        seams: [bool; 4],
    ) -> Result<Vec<Detection>, DetectError> {
        let err = DetectError::at(origin);
        // Innermost edges: a bullseye's centre disc, as small as its
        // designs allow. Candidates are searched down to min_px / 1.15,
        // below the sizes accepted (SizeRange::accepts), and a thresholded
        // disc's contour runs inside its edge: a 40 px 1:2:3 bullseye's
        // centre disc fell below a bound of min_px / 6.
        let r_min = (self.sizes.min_px / 1.15 / 2.0 * self.least_candidate()).max(2.5);
        let r_max = self.sizes.max_px / 2.0;
        // A disc's own radius (its size is its diameter): the least radius
        // an arc of a shadow-split disc is looked for at.
        let disc_r_min = self.sizes.min_px / 1.15 / 2.0;
        let area = (
            0.8 * std::f64::consts::PI * r_min * r_min,
            1.2 * std::f64::consts::PI * r_max * r_max,
        );
        let blobs = blobs::find_blobs(tile, area, &mut self.mask).map_err(err)?;
        let img = grey_view(tile).map_err(err)?;
        let mut starts: Vec<Ellipse> = Vec::new();
        let mut arcs_seen: Vec<arcs::Circle> = Vec::new();
        for blob in &blobs {
            if blob.points.len() < 12 {
                continue;
            }
            let e = Ellipse::from_rect(imgproc::fit_ellipse(&blob.points).map_err(err)?);
            let fill = blob.area / (std::f64::consts::PI * e.a * e.b);
            if e.a.min(e.b) / e.a.max(e.b) >= 0.6
                && (self.params.roundness.0..=self.params.roundness.1).contains(&fill)
            {
                starts.push(e);
            } else {
                let points: Vec<Pt> = blob
                    .points
                    .iter()
                    .map(|p| (p.x as f64, p.y as f64))
                    .collect();
                arcs_seen.extend(arcs::arc_circles(&points, (disc_r_min, r_max)));
            }
        }
        // A disc split by a shadow: its pieces' arcs, one start per circle
        // (both pieces give it), none where a round start is already.
        let mut known: Vec<arcs::Circle> = starts
            .iter()
            .map(|e| arcs::Circle {
                c: e.c,
                r: e.radius(),
            })
            .collect();
        for c in arcs_seen {
            if !known.iter().any(|k| arcs::same(&c, k)) {
                known.push(c);
                starts.push(Ellipse {
                    c: c.c,
                    a: c.r,
                    b: c.r,
                    u: (1.0, 0.0),
                });
            }
        }
        starts.sort_by(|p, q| {
            (p.c.1, p.c.0, p.a)
                .partial_cmp(&(q.c.1, q.c.0, q.a))
                .expect("finite")
        });
        let mut found: Vec<Found> = starts
            .iter()
            .filter_map(|e| {
                let verdict = shadow::with_second_look(
                    self.analyse(&img, *e),
                    Rejection::shadow_may_cause,
                    || self.analyse_lifted(&img, *e),
                );
                verdict
                    .map_err(|(why, lifted)| {
                        tracing::trace!(
                            x = e.c.0 + origin.0 as f64,
                            y = e.c.1 + origin.1 as f64,
                            size = 2.0 * e.radius(),
                            why = ?why,
                            lifted = ?lifted,
                            "circle candidate rejected"
                        )
                    })
                    .ok()
            })
            .collect();
        let (w, h) = (tile.cols() as f64, tile.rows() as f64);
        Ok(best_per_target(&mut found)
            .into_iter()
            .map(|f| to_detection(MarkerType::Circle, f, origin, w, h, seams))
            .collect())
    }
}
