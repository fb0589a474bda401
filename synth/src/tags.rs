//! Coded markers as their reference libraries draw them: AprilTags by
//! libapriltag's own `apriltag_to_image`, ArUco markers by OpenCV's
//! `drawMarker`. Nothing here comes from the detector, so a decoding bug
//! there cannot hide behind the same bug in the truth.

use std::ffi::c_void;

use opencv::core::Mat;
use opencv::prelude::*;

use crate::Error;

/// The kinds of target the generator draws, named as gcp-tagger's
/// `--marker-type` names them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TargetKind {
    AprilTag,
    Aruco,
    Crosshair,
    Circle,
}

impl TargetKind {
    pub fn name(self) -> &'static str {
        match self {
            TargetKind::AprilTag => "apriltag",
            TargetKind::Aruco => "aruco",
            TargetKind::Crosshair => "crosshair",
            TargetKind::Circle => "circle",
        }
    }
}

impl std::str::FromStr for TargetKind {
    type Err = Error;
    /// The kind named `s` (`apriltag`, `aruco`, `crosshair`, `circle`).
    fn from_str(s: &str) -> Result<Self, Error> {
        [
            TargetKind::AprilTag,
            TargetKind::Aruco,
            TargetKind::Crosshair,
            TargetKind::Circle,
        ]
        .into_iter()
        .find(|k| k.name().eq_ignore_ascii_case(s.trim()))
        .ok_or_else(|| Error::UnknownKind(s.to_string()))
    }
}

impl std::fmt::Display for TargetKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The first fields of libapriltag's `apriltag_family_t` (apriltag.h,
/// 3.x), which is all the generator reads.
#[repr(C)]
struct FamilyHead {
    ncodes: u32,
    codes: *mut u64,
    width_at_border: i32,
    total_width: i32,
    reversed_border: bool,
}

/// libapriltag's `image_u8_t`.
#[repr(C)]
struct ImageU8 {
    width: i32,
    height: i32,
    stride: i32,
    buf: *mut u8,
}

#[link(name = "apriltag")]
extern "C" {
    fn tag16h5_create() -> *mut FamilyHead;
    fn tag16h5_destroy(f: *mut FamilyHead);
    fn tag25h9_create() -> *mut FamilyHead;
    fn tag25h9_destroy(f: *mut FamilyHead);
    fn tag36h10_create() -> *mut FamilyHead;
    fn tag36h10_destroy(f: *mut FamilyHead);
    fn tag36h11_create() -> *mut FamilyHead;
    fn tag36h11_destroy(f: *mut FamilyHead);
    fn apriltag_to_image(f: *mut FamilyHead, idx: i32) -> *mut ImageU8;
}

extern "C" {
    fn free(p: *mut c_void);
}

type Family = (
    &'static str,
    unsafe extern "C" fn() -> *mut FamilyHead,
    unsafe extern "C" fn(*mut FamilyHead),
);

/// The classic families (black border, white outside), the ones a square
/// of cells within the border describes.
const FAMILIES: [Family; 4] = [
    ("16h5", tag16h5_create, tag16h5_destroy),
    ("25h9", tag25h9_create, tag25h9_destroy),
    ("36h10", tag36h10_create, tag36h10_destroy),
    ("36h11", tag36h11_create, tag36h11_destroy),
];

/// The cells of a marker from its black border inward (true = white),
/// row by row, for `kind` in `dictionary` (an AprilTag family such as
/// `36h11` or `tag36h11`; an ArUco dictionary such as `4X4_50`).
pub fn marker_cells(kind: TargetKind, dictionary: &str, id: u32) -> Result<Vec<Vec<bool>>, Error> {
    match kind {
        TargetKind::AprilTag => apriltag_cells(dictionary, id),
        TargetKind::Aruco => aruco_cells(dictionary, id),
        other => Err(Error::NoCode(other)),
    }
}

fn apriltag_cells(family: &str, id: u32) -> Result<Vec<Vec<bool>>, Error> {
    let wanted = family.trim().trim_start_matches("tag");
    let &(_, create, destroy) = FAMILIES
        .iter()
        .find(|(name, _, _)| name.eq_ignore_ascii_case(wanted))
        .ok_or_else(|| Error::UnknownDictionary(family.to_string()))?;
    // SAFETY: the constructor returns a family that stays valid until its
    // destructor runs below; apriltag_to_image reads it and returns a new
    // image whose struct and pixels are each from calloc (image_u8_create),
    // ours to free. `image_u8_destroy` is not exported by the packaged library.
    unsafe {
        let fam = create();
        assert!(!fam.is_null(), "libapriltag: out of memory");
        let head = &*fam;
        let result = if id >= head.ncodes {
            Err(Error::NoSuchId {
                dictionary: family.to_string(),
                id,
                count: head.ncodes,
            })
        } else {
            let im = apriltag_to_image(fam, id as i32);
            assert!(!im.is_null(), "libapriltag: out of memory");
            let (w, h, stride) = (
                (*im).width as usize,
                (*im).height as usize,
                (*im).stride as usize,
            );
            let px = std::slice::from_raw_parts((*im).buf, (h - 1) * stride + w);
            // The image is total_width cells with the white ring outside the
            // black border; keep the border and what is inside it.
            let ring = (head.total_width - head.width_at_border) as usize / 2;
            let n = head.width_at_border as usize;
            let cells = (ring..ring + n)
                .map(|r| (ring..ring + n).map(|c| px[r * stride + c] > 127).collect())
                .collect();
            free((*im).buf as *mut c_void);
            free(im as *mut c_void);
            debug_assert!(!head.reversed_border, "classic families only");
            Ok(cells)
        };
        destroy(fam);
        result
    }
}

/// OpenCV's predefined dictionaries, in the order of its
/// `PredefinedDictionaryType` values.
const ARUCO: [&str; 17] = [
    "4X4_50",
    "4X4_100",
    "4X4_250",
    "4X4_1000",
    "5X5_50",
    "5X5_100",
    "5X5_250",
    "5X5_1000",
    "6X6_50",
    "6X6_100",
    "6X6_250",
    "6X6_1000",
    "7X7_50",
    "7X7_100",
    "7X7_250",
    "7X7_1000",
    "ARUCO_ORIGINAL",
];

fn aruco_cells(dictionary: &str, id: u32) -> Result<Vec<Vec<bool>>, Error> {
    let wanted = dictionary.trim().trim_start_matches("DICT_");
    let index = ARUCO
        .iter()
        .position(|n| n.eq_ignore_ascii_case(wanted))
        .ok_or_else(|| Error::UnknownDictionary(dictionary.to_string()))?;
    let draw = || -> opencv::Result<Vec<Vec<bool>>> {
        let dict = opencv::aruco::get_predefined_dictionary_i32(index as i32)?;
        let count = dict.bytes_list().rows() as u32;
        if id >= count {
            return Ok(Vec::new());
        }
        let n = dict.marker_size() + 2;
        let mut img = Mat::default();
        opencv::aruco::draw_marker(&dict, id as i32, n, &mut img, 1)?;
        (0..n)
            .map(|r| {
                (0..n)
                    .map(|c| img.at_2d::<u8>(r, c).map(|v| *v > 127))
                    .collect()
            })
            .collect()
    };
    let cells = draw().map_err(|e| Error::OpenCv(e.to_string()))?;
    if cells.is_empty() {
        return Err(Error::NoSuchId {
            dictionary: dictionary.to_string(),
            id,
            count: 0,
        });
    }
    Ok(cells)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tags_are_squares_of_cells_inside_a_black_border() {
        for (kind, dict, n) in [
            (TargetKind::AprilTag, "36h11", 8),
            (TargetKind::AprilTag, "tag16h5", 6),
            (TargetKind::Aruco, "4X4_50", 6),
            (TargetKind::Aruco, "DICT_6X6_250", 8),
        ] {
            let cells = marker_cells(kind, dict, 3).unwrap();
            assert_eq!(cells.len(), n, "{dict}");
            assert!(cells.iter().all(|r| r.len() == n));
            let border = (0..n)
                .all(|i| !cells[0][i] && !cells[n - 1][i] && !cells[i][0] && !cells[i][n - 1]);
            assert!(border, "{dict}: the outer ring is black");
            assert!(
                cells.iter().flatten().any(|&w| w),
                "{dict}: has white cells"
            );
        }
        assert!(matches!(
            marker_cells(TargetKind::AprilTag, "36h11", 587),
            Err(Error::NoSuchId { count: 587, .. })
        ));
        assert!(marker_cells(TargetKind::Aruco, "9X9_1", 0).is_err());
    }
}
