//! AprilTag families through libapriltag, the reference AprilTag 3
//! implementation (Debian `libapriltag-dev`): quads from line fits to
//! clustered edges on a decimated image, decoded at full resolution with
//! Hamming-distance correction. Our edge-line refiner then places the
//! corners and centre at full resolution.
//!
//! Every call into libapriltag lives in this module (`sys` holds the
//! generated bindings).

mod sys;

use std::fmt;
use std::ptr::NonNull;
use std::str::FromStr;

use opencv::core::{self, Mat};
use opencv::prelude::*;

use super::fiducial::{coded_detection, grey_view, refine_corners, shift_limit, CodedRead};
use super::geometry::{self, dist, Pt};
use super::modelfit::{self, FitParams, Pattern, MAX_RESIDUAL_SHARE};
use super::refine::GreyView;
use super::{DetectError, Detection, Detector, MarkerType, Refinement};

type Create = unsafe extern "C" fn() -> *mut sys::apriltag_family_t;
type Destroy = unsafe extern "C" fn(*mut sys::apriltag_family_t);

/// One family libapriltag ships: its name as users give it, constructor
/// and destructor.
struct FamilyEntry {
    name: &'static str,
    create: Create,
    destroy: Destroy,
}

/// Largest chance that a random quad (ground, clutter) decodes as some
/// code of the family within the corrected bits: ncodes x (codes within t
/// bits of one) / 2^nbits. At most this, a frame's few thousand quads give
/// a false tag about once in twenty frames.
const MAX_FALSE_READ: f64 = 1e-5;
/// Most entries of libapriltag's decoding table (every code within the
/// corrected bits; about 48 bytes each, one table per worker thread).
const MAX_TABLE_ENTRIES: f64 = 500_000.0;

/// Bits libapriltag corrects for a family (0 to 2, its default being 2):
/// the most for which a random quad rarely reads as a code
/// ([`MAX_FALSE_READ`]) and the table stays small ([`MAX_TABLE_ENTRIES`]).
/// 36h11: 2 (6e-6, 391k entries); 36h10 and Standard41h12: 1; 16h5, 25h9,
/// Circle21h7 and Custom48h12: 0 (16h5 and Circle21h7 even then read
/// random quads as codes more often: 5e-4 and 2e-5).
fn corrected_bits(ncodes: u32, nbits: u32) -> i32 {
    let ball = |t: u32| -> f64 {
        // Codes within t bits of one: sum of C(nbits, i), i <= t.
        (0..=t)
            .map(|i| (0..i).fold(1.0, |c, j| c * (nbits - j) as f64 / (j + 1) as f64))
            .sum()
    };
    (1..=2u32)
        .take_while(|&t| {
            let entries = ncodes as f64 * ball(t);
            entries / 2f64.powi(nbits as i32) <= MAX_FALSE_READ && entries <= MAX_TABLE_ENTRIES
        })
        .last()
        .unwrap_or(0) as i32
}

const FAMILIES: &[FamilyEntry] = &[
    FamilyEntry {
        name: "16h5",
        create: sys::tag16h5_create,
        destroy: sys::tag16h5_destroy,
    },
    FamilyEntry {
        name: "25h9",
        create: sys::tag25h9_create,
        destroy: sys::tag25h9_destroy,
    },
    FamilyEntry {
        name: "36h10",
        create: sys::tag36h10_create,
        destroy: sys::tag36h10_destroy,
    },
    FamilyEntry {
        name: "36h11",
        create: sys::tag36h11_create,
        destroy: sys::tag36h11_destroy,
    },
    FamilyEntry {
        name: "Standard41h12",
        create: sys::tagStandard41h12_create,
        destroy: sys::tagStandard41h12_destroy,
    },
    FamilyEntry {
        name: "Circle21h7",
        create: sys::tagCircle21h7_create,
        destroy: sys::tagCircle21h7_destroy,
    },
    FamilyEntry {
        name: "Custom48h12",
        create: sys::tagCustom48h12_create,
        destroy: sys::tagCustom48h12_destroy,
    },
];

/// A validated AprilTag family name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AprilTagFamily(usize);

impl AprilTagFamily {
    pub fn name(self) -> &'static str {
        FAMILIES[self.0].name
    }
    fn entry(self) -> &'static FamilyEntry {
        &FAMILIES[self.0]
    }
}

impl Default for AprilTagFamily {
    fn default() -> Self {
        "36h11".parse().expect("36h11 is in the table")
    }
}

impl FromStr for AprilTagFamily {
    type Err = String;
    /// Accepts "36h11", "tag36h11", "DICT_APRILTAG_36h11", "standard41h12",
    /// "tagStandard41h12", any case.
    fn from_str(s: &str) -> Result<Self, String> {
        let trimmed = s.trim();
        let lower = trimmed.to_ascii_lowercase();
        let wanted = lower
            .trim_start_matches("dict_")
            .trim_start_matches("apriltag_")
            .trim_start_matches("tag");
        FAMILIES
            .iter()
            .position(|f| f.name.eq_ignore_ascii_case(wanted))
            .map(AprilTagFamily)
            .ok_or_else(|| {
                let names: Vec<_> = FAMILIES.iter().map(|f| f.name).collect();
                format!(
                    "unknown AprilTag family {trimmed:?} (expected one of: {})",
                    names.join(", ")
                )
            })
    }
}

impl fmt::Display for AprilTagFamily {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A family object created by libapriltag, destroyed with it.
struct FamilyHandle {
    family: AprilTagFamily,
    ptr: NonNull<sys::apriltag_family_t>,
    destroy: Destroy,
}

impl FamilyHandle {
    fn new(family: AprilTagFamily) -> FamilyHandle {
        let entry = family.entry();
        // SAFETY: the constructor allocates and fills a static table's copy;
        // it returns null only when out of memory.
        let ptr = NonNull::new(unsafe { (entry.create)() }).expect("libapriltag: out of memory");
        FamilyHandle {
            family,
            ptr,
            destroy: entry.destroy,
        }
    }
    fn get(&self) -> &sys::apriltag_family_t {
        // SAFETY: valid from create until drop; libapriltag never writes it
        // after creation.
        unsafe { self.ptr.as_ref() }
    }
}

impl Drop for FamilyHandle {
    fn drop(&mut self) {
        // SAFETY: created by the matching constructor, destroyed once, after
        // the detector that referred to it.
        unsafe { (self.destroy)(self.ptr.as_ptr()) }
    }
}

/// Why a tag's cells cannot be drawn.
#[derive(Debug, thiserror::Error)]
pub enum TagCellsError {
    #[error("AprilTag {family} has ids 0..{last}, not {id}")]
    NoSuchId {
        family: &'static str,
        last: u32,
        id: u32,
    },
    #[error("libapriltag: out of memory drawing a tag")]
    OutOfMemory,
}

/// The cells of tag `id` of `family` as libapriltag draws it
/// (`apriltag_to_image`), true for white: `total_width` cells a side,
/// including the white ring outside a classic tag's black border. Also
/// returns `width_at_border` (the side of the square the detector reports)
/// and whether the family is classic (black border, white outside).
pub fn tag_cells(family: AprilTagFamily, id: u32) -> Result<TagCells, TagCellsError> {
    draw(&FamilyHandle::new(family), id)
}

/// [`tag_cells`] of a family already made.
fn draw(handle: &FamilyHandle, id: u32) -> Result<TagCells, TagCellsError> {
    let family = handle.family;
    let fam = handle.get();
    if id >= fam.ncodes {
        return Err(TagCellsError::NoSuchId {
            family: family.name(),
            last: fam.ncodes - 1,
            id,
        });
    }
    // SAFETY: a valid family and an id below ncodes; the image is ours to
    // read and destroy.
    let img = unsafe { sys::apriltag_to_image(handle.ptr.as_ptr(), id as i32) };
    let img = NonNull::new(img).ok_or(TagCellsError::OutOfMemory)?;
    let cells = {
        // SAFETY: width x height bytes at row stride `stride` from buf.
        let im = unsafe { img.as_ref() };
        let (w, h, stride) = (im.width as usize, im.height as usize, im.stride as usize);
        let data = unsafe { std::slice::from_raw_parts(im.buf, (h - 1) * stride + w) };
        (0..h)
            .map(|r| (0..w).map(|c| data[r * stride + c] > 127).collect())
            .collect()
    };
    // SAFETY: created by apriltag_to_image above (pixels and struct each
    // from calloc), freed once. `image_u8_destroy`, which does the same,
    // is not exported by the packaged libapriltag.
    unsafe {
        libc::free(img.as_ref().buf as *mut libc::c_void);
        libc::free(img.as_ptr() as *mut libc::c_void);
    }
    Ok(TagCells {
        cells,
        width_at_border: fam.width_at_border as usize,
        classic: !fam.reversed_border,
    })
}

/// A tag as drawn: see [`tag_cells`].
#[derive(Debug, Clone)]
pub struct TagCells {
    pub cells: Vec<Vec<bool>>,
    pub width_at_border: usize,
    pub classic: bool,
}

/// The search image is the tile's grey mapped through `ln(1 + v / KNEE)`
/// (scaled to 0..255): linear in the dark, where noise is, and a ratio
/// scale in the light. A shadow multiplies the light, so on this scale it
/// moves a tag's shadowed white and black by the same step, and
/// libapriltag's local threshold (midway between a neighbourhood's least
/// and greatest grey) still parts them; on the linear scale a shadow edge
/// across a tag put the shadowed quiet zone below the threshold set by the
/// lit one, and the tag's outline was lost. Decoding reads the same image.
///
/// Calibrated on generated hard frames (`gcp-tagger sample --hard`, seeds
/// 31 and 32, JPEG/16-bit GeoTIFF; the bench's seeds 13 and 14 were not
/// used), `min_white_black_diff` 40: knee 32 found 0.911/0.952 of the
/// tags, 64 0.973/0.976 (the same at 50), 96 0.938/0.929, 128 0.929/0.857,
/// the linear scale 0.768/0.667.
///
/// The mapped scale loses the smallest blurred tags (cells of 2.3-2.9 px):
/// it moves the local threshold toward the dark, and a blurred black cell's
/// grey, halfway up, falls on the white side. So each tile is searched on
/// both scales and the two lists merged (see [`AprilTagDetector::search`])
/// when the smallest target asks for a full-resolution search: on the
/// bench's hard set (seeds 13 and 14) recall 0.933 -> 0.982, no false or
/// wrong read, at 1.5-1.7x the time per frame on the bench and the real
/// photos, about 6x on pure noise.
const KNEE: f64 = 64.0;

/// libapriltag's `min_white_black_diff` on the mapped scale: a pixel whose
/// 12 px neighbourhood spans fewer levels takes no part in the search. 50
/// levels are a light/dark ratio of 1.37 in the light and about 20 grey
/// levels in the dark, far below a print's inks (10:1) and above most
/// ground texture: at 30 the generated ground passes and the search takes
/// four times as long, with the same recall.
const MIN_CONTRAST: i32 = 50;

/// `quad_decimate`: the quads are searched in an image decimated by this
/// factor (decoding and our corners use the full-resolution tile). A tag
/// needs about 20 px a side in the decimated image: on the generated hard
/// frames, tags of 24-32 px were all found at 1.5 and 1 but 88-92% at 2;
/// tags of 40 px and more 96-100% at each.
fn decimation_for(min_target_px: f64) -> f32 {
    if min_target_px >= 40.0 {
        2.0
    } else if min_target_px >= 30.0 {
        1.5
    } else {
        1.0
    }
}

/// `lut[v]` = the mapped grey of `v` (see [`KNEE`]).
fn search_scale() -> [u8; 256] {
    let top = (1.0 + 255.0 / KNEE).ln();
    std::array::from_fn(|v| (255.0 * (1.0 + v as f64 / KNEE).ln() / top).round() as u8)
}

/// A libapriltag detector with its family added: building the family's
/// decoding table (every code within the corrected bits) takes 20-100 ms,
/// so each thread keeps its engines for the next frame (see [`POOL`]).
struct Engine {
    td: NonNull<sys::apriltag_detector_t>,
    /// Kept alive (declared after `td`, so dropped after it) because the
    /// detector points to it; also draws a decoded tag's cells.
    handle: FamilyHandle,
    family: AprilTagFamily,
    decimate: f32,
}

impl Engine {
    fn new(family: AprilTagFamily, decimate: f32) -> Engine {
        let handle = FamilyHandle::new(family);
        // SAFETY: create returns an initialised detector (null only when
        // out of memory); we set plain fields before any detection.
        let td = NonNull::new(unsafe { sys::apriltag_detector_create() })
            .expect("libapriltag: out of memory");
        unsafe {
            let d = &mut *td.as_ptr();
            // We parallelise over frames; libapriltag starts no threads.
            d.nthreads = 1;
            d.quad_decimate = decimate;
            d.quad_sigma = 0.0;
            d.refine_edges = true;
            d.decode_sharpening = 0.25;
            d.qtp.min_white_black_diff = MIN_CONTRAST;
            let fam = handle.get();
            sys::apriltag_detector_add_family_bits(
                td.as_ptr(),
                handle.ptr.as_ptr(),
                corrected_bits(fam.ncodes, fam.nbits),
            );
        }
        Engine {
            td,
            handle,
            family,
            decimate,
        }
    }
}

impl Drop for Engine {
    fn drop(&mut self) {
        // SAFETY: created in `new`, destroyed once; the family outlives it.
        unsafe { sys::apriltag_detector_destroy(self.td.as_ptr()) }
    }
}

thread_local! {
    /// Engines this thread built, returned by detectors when they are
    /// dropped: one per family and decimation the thread has used.
    static POOL: std::cell::RefCell<Vec<Engine>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Detector for one AprilTag family (single-threaded: we parallelise over
/// frames).
pub struct AprilTagDetector {
    /// Always Some until drop hands it back to the thread's pool.
    engine: Option<Engine>,
    /// Cells across the square libapriltag reports (the black border's).
    cells: f64,
    /// Black border with white outside: our edge refiner applies.
    classic: bool,
    max_shift_px: Option<f64>,
    /// See [`search_scale`].
    lut: [u8; 256],
    /// The tile on the search scale.
    scaled: Vec<u8>,
}

impl AprilTagDetector {
    pub fn new(family: AprilTagFamily, config: &super::DetectorConfig) -> AprilTagDetector {
        let decimate = decimation_for(config.min_target_px);
        let pooled = POOL.with_borrow_mut(|pool| {
            let i = pool
                .iter()
                .position(|e| e.family == family && e.decimate == decimate)?;
            Some(pool.swap_remove(i))
        });
        let engine = pooled.unwrap_or_else(|| Engine::new(family, decimate));
        let fam = engine.handle.get();
        AprilTagDetector {
            cells: fam.width_at_border as f64,
            classic: !fam.reversed_border,
            engine: Some(engine),
            max_shift_px: config.max_refine_shift_px,
            lut: search_scale(),
            scaled: Vec::new(),
        }
    }
}

impl AprilTagDetector {
    /// The whole tag, its cells now known, fitted from the edge-refined
    /// corners (or libapriltag's, when those were rejected): see
    /// [`modelfit`]. Kept when it explains the tag (see
    /// [`MAX_RESIDUAL_SHARE`]) and its corners lie within the refinement's
    /// tolerance of libapriltag's; else `edges` stand.
    fn fit_whole(
        &self,
        img: &GreyView,
        raw: &Raw,
        edges: ([Pt; 4], f64, Refinement),
    ) -> ([Pt; 4], f64, Refinement) {
        let engine = self.engine.as_ref().expect("engine until drop");
        let Ok(cells) = draw(&engine.handle, raw.id) else {
            return edges;
        };
        let Some(pattern) = Pattern::new(&cells.cells, cells.width_at_border) else {
            return edges;
        };
        let start = if edges.2 == Refinement::Refined {
            edges.0
        } else {
            raw.corners
        };
        let Some(fitted) = modelfit::fit_tag(img, &pattern, &start, &FitParams::default()) else {
            return edges;
        };
        let shift = (0..4)
            .map(|i| dist(fitted.corners[i], raw.corners[i]))
            .fold(0.0, f64::max);
        // Blurred by more than a cell, the cells' edges no longer place it.
        let explained = fitted.residual <= MAX_RESIDUAL_SHARE * (fitted.white - fitted.black)
            && fitted.blur_cells < 1.0;
        if explained && shift <= shift_limit(&raw.corners, self.cells, self.max_shift_px) {
            (fitted.corners, shift, Refinement::Refined)
        } else {
            edges
        }
    }
}

impl Drop for AprilTagDetector {
    fn drop(&mut self) {
        if let Some(engine) = self.engine.take() {
            // During thread exit the pool may be gone: the engine is then
            // simply dropped.
            let _ = POOL.try_with(|pool| pool.borrow_mut().push(engine));
        }
    }
}

/// One tag as libapriltag reports it, copied out of its structures.
struct Raw {
    id: u32,
    hamming: u32,
    margin: f64,
    /// Corners in OpenCV pixel coordinates, top-left first, clockwise.
    corners: [Pt; 4],
}

impl Raw {
    /// Whether the two reads are one tag: their centres lie within a
    /// quarter of the smaller one's side (two tags never overlap so).
    fn same_place(&self, other: &Raw) -> bool {
        let side = geometry::mean_side(&self.corners).min(geometry::mean_side(&other.corners));
        geometry::dist(
            geometry::mean(&self.corners),
            geometry::mean(&other.corners),
        ) < 0.25 * side
    }
}

/// The grey scale a tile is searched on.
#[derive(Clone, Copy)]
enum Scale {
    /// Through [`search_scale`]: tags under shadow edges.
    Mapped,
    /// The tile's own greys: the smallest blurred tags.
    Linear,
}

impl AprilTagDetector {
    /// The tags libapriltag finds in the tile on the search scale (see
    /// [`KNEE`]) and on the linear one; a tag found on both is reported
    /// once, as read on the search scale.
    fn search(&mut self, view: &GreyView) -> opencv::Result<Vec<Raw>> {
        let mut found = self.search_on(view, Scale::Mapped)?;
        // Only tags with cells under 3 px need the linear scale, and those
        // are searched at full resolution only (see `decimation_for`).
        if self.engine.as_ref().is_some_and(|e| e.decimate > 1.0) {
            return Ok(found);
        }
        let mapped = found.len();
        for raw in self.search_on(view, Scale::Linear)? {
            let seen = found[..mapped]
                .iter()
                .any(|m| m.id == raw.id && m.same_place(&raw));
            if !seen {
                found.push(raw);
            }
        }
        Ok(found)
    }

    fn search_on(&mut self, view: &GreyView, scale: Scale) -> opencv::Result<Vec<Raw>> {
        // The tile copied on the scale (libapriltag takes one contiguous
        // buffer), reused from tile to tile.
        let scaled = &mut self.scaled;
        scaled.resize(view.width * view.height, 0);
        for (y, row) in scaled.chunks_exact_mut(view.width).enumerate() {
            let src = &view.data[y * view.stride..][..view.width];
            match scale {
                Scale::Mapped => {
                    for (d, &v) in row.iter_mut().zip(src) {
                        *d = self.lut[v as usize];
                    }
                }
                Scale::Linear => row.copy_from_slice(src),
            }
        }
        let mut im = sys::image_u8_t {
            width: view.width as i32,
            height: view.height as i32,
            stride: view.width as i32,
            // libapriltag reads the input image and never writes it (it
            // decimates and filters into copies).
            buf: scaled.as_mut_ptr(),
        };
        // SAFETY: `im` describes the tile's own pixels for the call's length;
        // the returned array and detections are ours, destroyed below.
        let td = self.engine.as_ref().expect("engine until drop").td;
        let list = unsafe { sys::apriltag_detector_detect(td.as_ptr(), &mut im) };
        let Some(list) = NonNull::new(list) else {
            return Err(opencv::Error::new(
                core::StsNoMem,
                "libapriltag: out of memory",
            ));
        };
        let found = unsafe {
            let z = list.as_ref();
            // An empty array has no storage (data is null).
            let dets: &[*mut sys::apriltag_detection_t] = if z.size <= 0 || z.data.is_null() {
                &[]
            } else {
                std::slice::from_raw_parts(z.data as *const _, z.size as usize)
            };
            let out = dets
                .iter()
                .map(|&d| {
                    let d = &*d;
                    // libapriltag's corners wrap counter-clockwise from the
                    // tag's bottom-left, and put pixel centres at +0.5.
                    let p = |i: usize| (d.p[i][0] - 0.5, d.p[i][1] - 0.5);
                    Raw {
                        id: d.id as u32,
                        hamming: d.hamming as u32,
                        margin: d.decision_margin as f64,
                        corners: [p(3), p(2), p(1), p(0)],
                    }
                })
                .collect();
            sys::apriltag_detections_destroy(list.as_ptr());
            out
        };
        Ok(found)
    }
}

impl Detector for AprilTagDetector {
    fn marker_type(&self) -> MarkerType {
        MarkerType::AprilTag
    }

    fn detect(
        &mut self,
        tile: &Mat,
        origin: (usize, usize),
        seams: [bool; 4],
    ) -> Result<Vec<Detection>, DetectError> {
        let err = DetectError::at(origin);
        let (w, h) = (tile.cols() as f64, tile.rows() as f64);
        let img = grey_view(tile).map_err(err)?;
        let raws = self.search(&img).map_err(err)?;
        let mut out = Vec::with_capacity(raws.len());
        for raw in raws {
            let (corners, shift, refinement) = if self.classic {
                let edges = refine_corners(&img, &raw.corners, self.cells, self.max_shift_px);
                self.fit_whole(&img, &raw, edges)
            } else {
                // Data cells lie outside a reversed border: no clean edge to
                // fit; libapriltag's own edge-refined corners stand.
                (raw.corners, 0.0, Refinement::Refined)
            };
            out.push(coded_detection(
                MarkerType::AprilTag,
                CodedRead {
                    id: raw.id,
                    corners,
                    shift,
                    refinement,
                    bit_errors: raw.hamming,
                    margin: raw.margin,
                    // libapriltag's mean distance of the data bits from
                    // their threshold, in grey levels of the search scale:
                    // clean prints read 100-180.
                    clear_margin: 50.0,
                },
                origin,
                (w, h),
                seams,
            ));
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests;
