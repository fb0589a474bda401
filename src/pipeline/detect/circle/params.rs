//! The circle detector's thresholds, each with where it was measured.

use super::super::SizeSlack;

/// Thresholds of the circle detector ([`super::CircleDetector`]). The
/// defaults were checked on generated frames (`tools/src/bin/printed_misses.rs`
/// `circle SEED N` and look-alike scenes) and on the real photos of the
/// README, as each field says.
#[derive(Debug, Clone, PartialEq)]
pub struct Params {
    /// Fewest grey levels between a target's dark and light parts.
    pub min_contrast: f64,
    /// Fraction of rays that must find each edge. Something across a
    /// bullseye's rings (clutter, a shadow edge) hides some of them: 0.75 lost
    /// two bullseyes in partial shadow on seeds 900-903; the ring ratios,
    /// alternating polarity and fit RMS still reject look-alikes.
    pub min_coverage: f64,
    /// Least ratio of the light side's grey to the dark side's across the
    /// innermost edge: a print's inks differ in reflectance by 5 to 15 times,
    /// which gamma and haze bring down to 2 and more (as for crosses, see
    /// `printed::Params::min_light_ratio`); blobs of foliage differ by less.
    pub min_light_ratio: f64,
    /// Least correlation of the drawn rings with the image (see
    /// `rings::rings_score`). On the generated target frames of seeds 400,
    /// 401, 900 and 5100 (535 candidates reached it) the 5th percentile is
    /// 0.81; the few under 0.65 (0.596-0.607) were a lattice in one frame's
    /// clutter, and 0.65 lost no target there nor on seed 5200. Cells of
    /// window and panel lattices on the look-alike scenes scored 0.59-0.61.
    pub min_rings_score: f64,
    /// Least share of a ring's edge points its robust ellipse fit keeps.
    pub min_ring_inliers: f64,
    /// Largest difference of a ring's axis ratio from the outer ring's, plus
    /// half a pixel over its radius: concentric circles in one plane project
    /// to nearly the same shape (mild perspective); the edges a lattice shows
    /// around one of its squares differed by 0.21 (0.99 against 0.77, clutter
    /// scene 1400).
    pub max_aspect_gap: f64,
    /// Largest distance of a ring's ellipse centre from the outer one's, as a
    /// share of the outer radius (plus half a pixel): perspective moves them
    /// apart by a few hundredths.
    pub max_ring_offset: f64,
    /// Largest RMS distance of edge points from their ellipse.
    pub max_fit_rms_px: f64,
    /// Unless all four sides hold, the share of all rays whose end must lie on
    /// the square.
    pub min_end_agreement: f64,
    /// Share of a side's rays whose end must lie on it for the side to hold.
    pub min_side_support: f64,
    /// An end point lies on its side within this fraction of the side's distance.
    pub square_tolerance: f64,
    /// Held sides' distances from the disc's centre may differ this much (mild
    /// perspective); a roof with a tank off its centre differs by 25% and more.
    pub max_side_ratio: f64,
    /// A board's width across one pair of sides over the other's, each over
    /// the disc's width the same way, is within this factor of 1 (it is 1 for
    /// a square and its disc in one plane). Measured on the candidates of the
    /// eleven circle sets: 0.964-1.036 (1st-99th percentile); two roofs with a
    /// tank that passed as targets: 1.31 and 1.45.
    pub max_board_aspect: f64,
    /// A board's side found by levels lies on a line: its points bow from one
    /// by no more than this (pixels). Arcs of a dark ring around a disc, taken
    /// for three sides of a board, bowed 2.2 and 4.6 px.
    pub max_side_bow_px: f64,
    /// A board seen on all four sides is centred on its disc within this
    /// fraction of its half side (plus a pixel): pixel-level side lines place
    /// its centre to ~1 px; a tank off a flat roof's centre is off by 15%+.
    pub max_centre_offset: f64,
    /// The centres placed by each pair of a board's sides agree within this
    /// fraction of the disc's radius (at least the pixels below). Measured on
    /// true discs: pairs of adjacent sides scatter up to 0.03 of the radius
    /// (0.9 px on a 53 px radius); a side found on clutter moved them by 0.1 of
    /// it and more (2.5 px on 26 px, 6 px on 42 px).
    pub max_pair_spread: f64,
    /// The same agreement in pixels, for small discs: the tolerance is the
    /// larger of this and `max_pair_spread` of the radius.
    pub max_pair_spread_px: f64,
    /// Largest turn of a board's side off the square's normal (degrees): mild
    /// perspective turns opposite sides by a few degrees each.
    pub max_side_tilt_deg: i32,
    /// Least drop in the share of columns at the board's level where a side
    /// found by levels ends.
    pub min_level_drop: f64,
    /// A board found by levels on three sides: how far (as a fraction) the two
    /// opposite sides' distances from the disc, and the third's from theirs,
    /// may differ.
    pub three_side_tolerance: f64,
    /// A bullseye's board past its outer ring: at least this share of the way
    /// from the black ring's level to the white ring's, on at least
    /// [`min_board_share`](Params::min_board_share) of the rays that see the rings.
    pub board_level: f64,
    /// Share of the rays that see the rings on which the board must reach
    /// [`board_level`](Params::board_level).
    pub min_board_share: f64,
    /// Largest RMS distance of a board side's subpixel edge points from their
    /// line (a clean side: 0.3-0.6 px).
    pub max_side_rms_px: f64,
    /// The slack on a measured size (the outer edge's ellipse): measured over
    /// true size on the hits of the ten circle sets (`printed_misses circle
    /// SEED 4` with `RMS=1`, 2026-12-04) ran 0.941-1.045. Below, 1.10 (a 40 px
    /// target measured down to 36.4 px) is half as wide again as the worst.
    pub size_slack: SizeSlack,
    /// The slack on a size known before the subpixel fits (the refined
    /// candidate's radius, the rings' measured radii): wider than
    /// [`size_slack`](Params::size_slack), which the final size must meet.
    pub early_size_slack: SizeSlack,
    /// A contour is an ellipse when its area is this close to its fit's.
    pub roundness: (f64, f64),
    /// Towards a board's corners: end points more than 30 degrees off their
    /// side's normal (sine 0.5). A square's sides hold a third of their points
    /// there (rays at even angles, sides reaching 45 degrees); a round board's
    /// ring keeps within [`square_tolerance`](Params::square_tolerance) of one distance only to about 22
    /// degrees, so only clutter beyond it puts points there.
    pub corner_sine: f64,
    /// Share of the end points on a board's sides that must lie towards its
    /// corners: 0.25 at least on the boards fitted in seeds 400-401; 0.13 and
    /// 0.16 on two clutter rings (a black ring around a white disc) whose rays
    /// ended on other clutter here and there, enough to pass the reach test
    /// alone.
    pub min_corner_share: f64,
    /// Ratios measured off a design's ranges by this much still match: the
    /// measured edges are the blurred midpoints, within half a pixel.
    pub ratio_tolerance: f64,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            min_contrast: 15.0,
            min_coverage: 0.55,
            min_light_ratio: 1.8,
            min_rings_score: 0.65,
            min_ring_inliers: 0.8,
            max_aspect_gap: 0.05,
            max_ring_offset: 0.08,
            max_fit_rms_px: 0.45,
            min_end_agreement: 0.6,
            min_side_support: 0.6,
            square_tolerance: 0.07,
            max_side_ratio: 1.15,
            max_board_aspect: 1.15,
            max_side_bow_px: 4.0,
            max_centre_offset: 0.06,
            max_pair_spread: 0.05,
            max_pair_spread_px: 0.5,
            max_side_tilt_deg: 6,
            min_level_drop: 0.4,
            three_side_tolerance: 0.05,
            board_level: 0.6,
            min_board_share: 0.5,
            max_side_rms_px: 0.8,
            size_slack: SizeSlack {
                below: 1.10,
                above: 1.15,
            },
            early_size_slack: SizeSlack {
                below: 1.25,
                above: 1.3,
            },
            roundness: (0.85, 1.15),
            corner_sine: 0.5,
            min_corner_share: 0.2,
            ratio_tolerance: 0.03,
        }
    }
}
