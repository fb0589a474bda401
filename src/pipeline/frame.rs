//! One frame, end to end: strips in row order, tiles with overlap, every
//! requested detector on every tile, duplicates removed, then pixel to world.

use opencv::core::{Mat, CV_8UC1};

use super::camera::CameraMeta;
use super::detect::{
    build_detectors, DetectError, Detection, DetectorConfig, MarkerType, SizeRange,
};
use super::georef::{Georeference, TargetCrs, Transformer, WGS84};
use super::pictures::{self, Crop, Pictures, Preview};
use super::raster::{FrameHeader, RasterError, RasterFrame};
use super::tiles::TileGrid;
use super::{dedup, memory};

/// Default tile side when only coded targets are searched: small tiles
/// stay in the CPU's caches. On the throughput bench's frames (2 threads)
/// 1024 px took AprilTag from 2.1 to 1.5-1.8 s against 2048 px for the same
/// detections, and libapriltag's working set per tile a quarter.
pub const CODED_TILE_SIZE: usize = 1024;

/// Default tile side when printed targets are searched too. 1024 px would
/// be faster for them as well (crosshair,circle 12.7 -> 8.4 s on the bench's
/// frames), but their context checks (repeats one board away, ground
/// around) see less of a target's surroundings near a tile's border, and
/// crosshair look-alikes on generated clutter rose from 4 to 6 (scenes
/// 700-709) and 18 to 21 (3300-3315).
pub const PRINTED_TILE_SIZE: usize = 2048;

/// The tile side for a job searching `modes`, unless it names one.
pub fn default_tile_size(modes: &[MarkerType]) -> usize {
    if modes.iter().all(|m| m.is_coded()) {
        CODED_TILE_SIZE
    } else {
        PRINTED_TILE_SIZE
    }
}

/// Default largest target side in pixels; the tile overlap is derived from it.
pub const DEFAULT_MAX_TARGET_PX: usize = 200;

/// A target within this many pixels of the frame border may be cut off.
const EDGE_MARGIN_PX: f64 = 2.0;

/// Settings for processing a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameOptions {
    pub detector: DetectorConfig,
    pub tile_size: usize,
    /// Largest target side expected, in pixels; tiles overlap by more.
    pub max_target_px: usize,
    /// The CRS world coordinates are reported in; validated beforehand.
    pub crs: TargetCrs,
}

/// A setting that cannot work, named as the API spells it (the command line
/// spells it with dashes).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field}: {message}")]
pub struct InvalidSetting {
    pub field: &'static str,
    pub message: String,
}

/// Smallest tile side accepted: below it the overlap eats most of the tile.
pub const MIN_TILE_SIZE: usize = 256;
/// Largest tile side accepted: one tile's detector buffers stay under ~1 GiB.
pub const MAX_TILE_SIZE: usize = 8192;

impl FrameOptions {
    /// Checks settings that depend on each other; every entry point (command
    /// line and service) goes through here.
    pub fn new(
        detector: DetectorConfig,
        tile_size: usize,
        max_target_px: usize,
        crs: TargetCrs,
    ) -> Result<FrameOptions, InvalidSetting> {
        let bad = |field, message: String| Err(InvalidSetting { field, message });
        if detector.modes.is_empty() {
            return bad("marker_types", "at least one marker type is needed".into());
        }
        if !(MIN_TILE_SIZE..=MAX_TILE_SIZE).contains(&tile_size) {
            return bad(
                "tile_size",
                format!("{tile_size} is outside {MIN_TILE_SIZE}..={MAX_TILE_SIZE} px"),
            );
        }
        if max_target_px < 8 || max_target_px * 2 > tile_size {
            return bad(
                "max_target_px",
                format!(
                    "{max_target_px} must be at least 8 and at most half of tile_size {tile_size}"
                ),
            );
        }
        let min = detector.min_target_px;
        if !(min.is_finite() && min >= 8.0 && min <= max_target_px as f64) {
            return bad(
                "min_target_px",
                format!("{min} must be at least 8 and at most max_target_px {max_target_px}"),
            );
        }
        for (field, value) in [
            ("target_size_m", detector.target_size_m),
            ("gsd_cm", detector.gsd_cm),
        ] {
            if let Some(v) = value {
                if !(v.is_finite() && v > 0.0) {
                    return bad(field, format!("{v} must be a positive number"));
                }
            }
        }
        if let Some(t) = detector.max_refine_shift_px {
            if !(t.is_finite() && t > 0.0 && t <= max_target_px as f64) {
                return bad(
                    "max_refine_shift_px",
                    format!("{t} must be a positive number of pixels, at most max_target_px"),
                );
            }
        }
        Ok(FrameOptions {
            detector,
            tile_size,
            max_target_px,
            crs,
        })
    }

    /// Overlap between neighbouring tiles: the largest target plus a margin
    /// for the refinement window, so any target is whole in some tile.
    pub fn overlap(&self) -> usize {
        (self.max_target_px + self.max_target_px / 4 + 8).min(self.tile_size / 2)
    }
}

/// A detection placed in the world.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Target {
    pub detection: Detection,
    /// The target touches the frame border and may be cut off.
    pub at_edge: bool,
    /// Position in the requested CRS (x = easting/longitude).
    pub world: Option<(f64, f64)>,
    /// WGS84 longitude, latitude for GeoJSON.
    pub lonlat: Option<(f64, f64)>,
}

/// Everything found in one frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameResult {
    /// The frame's name in outputs (path relative to the input given).
    pub image: String,
    pub width: usize,
    pub height: usize,
    /// Sorted by type, id, y, x.
    pub targets: Vec<Target>,
    /// Conditions worth telling the user that did not stop the frame.
    pub warnings: Vec<String>,
    pub tiles: usize,
    /// The frame's georeference, for projecting surveyed points into it.
    #[serde(default)]
    pub georeference: Option<Georeference>,
    /// Camera metadata of a raw frame (EXIF/XMP), for predicting where
    /// surveyed points appear.
    #[serde(default)]
    pub camera: Option<CameraMeta>,
}

/// Why a frame produced no result.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    #[error(transparent)]
    Raster(#[from] RasterError),
    #[error(transparent)]
    Detect(#[from] DetectError),
    #[error(transparent)]
    TooLarge(#[from] memory::TooLarge),
    #[error("OpenCV: {0}")]
    OpenCv(#[from] opencv::Error),
    #[error("canceled")]
    Canceled,
    #[error("{0}")]
    Picture(String),
}

/// What a caller learns while a frame runs, and how it can stop it.
pub trait FrameObserver {
    /// Called after each tile.
    fn tile_done(&self, _done: usize, _total: usize) {}
    /// Checked before each tile: true stops the frame with `Canceled`.
    fn should_stop(&self) -> bool {
        false
    }
}

/// An observer that watches nothing.
pub struct NoObserver;
impl FrameObserver for NoObserver {}

/// Memory a frame's run holds: [`memory::estimate_frame_bytes`], plus its
/// pictures' when they are made.
pub fn need_bytes(header: &FrameHeader, options: &FrameOptions, pictures: bool) -> u64 {
    let pictures = if pictures {
        pictures::reserve_bytes(header.width, header.height, options.max_target_px)
    } else {
        0
    };
    memory::estimate_frame_bytes(header, options.tile_size) + pictures
}

/// Runs detection over an opened frame and georeferences the results.
pub fn detect_frame(
    frame: RasterFrame,
    image: &str,
    options: &FrameOptions,
    transformer: &mut Transformer,
    observer: &dyn FrameObserver,
) -> Result<FrameResult, FrameError> {
    run_frame(frame, image, options, transformer, observer, None)
}

/// [`detect_frame`], also making the frame's [`Pictures`] (a chip per
/// target, in the result's order, and a preview) from the strips as they
/// pass.
pub fn detect_frame_pictured(
    frame: RasterFrame,
    image: &str,
    options: &FrameOptions,
    transformer: &mut Transformer,
    observer: &dyn FrameObserver,
) -> Result<(FrameResult, Pictures), FrameError> {
    let mut pictures = Pictures::default();
    let result = run_frame(
        frame,
        image,
        options,
        transformer,
        observer,
        Some(&mut pictures),
    )?;
    Ok((result, pictures))
}

fn run_frame(
    mut frame: RasterFrame,
    image: &str,
    options: &FrameOptions,
    transformer: &mut Transformer,
    observer: &dyn FrameObserver,
    pictures: Option<&mut Pictures>,
) -> Result<FrameResult, FrameError> {
    let header = frame.header().clone();
    let (w, h) = (header.width, header.height);
    let grid = TileGrid::new(w, h, options.tile_size, options.overlap());
    // The georeference's pixel size, or else the camera's height over its
    // focal length (a raw drone frame).
    let frame_gsd = header
        .georeference
        .as_ref()
        .and_then(|g| g.ground_m_per_px)
        .or_else(|| header.camera.as_ref()?.ground_m_per_px(w, h));
    let sizes = SizeRange::for_frame(&options.detector, options.max_target_px as f64, frame_gsd);
    let mut detectors = build_detectors(&options.detector, sizes)?;
    frame.prepare_stretch()?;

    let mut strip = vec![0u8; w * grid.tile_h];
    let mut found: Vec<Detection> = Vec::new();
    // Pictures: the preview grows strip by strip; each detection's crop is
    // cut while its strip is in memory (one per copy, matched after
    // duplicates are removed).
    let mut preview = pictures.as_ref().map(|_| Preview::new(w, h));
    let mut crops: Vec<(Detection, Crop)> = Vec::new();
    let mut done = 0;
    // Where the frame stops decoding, when it does (a file cut off part-way).
    let mut cut: Option<(usize, String)> = None;
    for (row, &y0) in grid.ys.iter().enumerate() {
        // Keep the rows this strip shares with the previous one and read only
        // the new ones, so the file is read strictly top to bottom.
        let kept_rows = if row == 0 {
            0
        } else {
            grid.ys[row - 1] + grid.tile_h - y0
        };
        if kept_rows > 0 {
            strip.copy_within((grid.tile_h - kept_rows) * w.., 0);
        }
        match frame.read_rows(&mut strip[kept_rows * w..]) {
            Ok(()) => {}
            // Not one row decodes: nothing to look at.
            Err(RasterError::CutOff {
                row: 0, message, ..
            }) => {
                return Err(FrameError::Raster(RasterError::Decode {
                    row: 0,
                    end: grid.tile_h,
                    message,
                }))
            }
            Err(RasterError::CutOff {
                row: at, message, ..
            }) => {
                // The rows below the cut repeat the last good one (no edge
                // there to take for a target); detections reaching past it
                // are dropped below.
                let valid = at - y0;
                cut = Some((at, message));
                if valid == 0 {
                    // The cut falls on this strip's first row.
                    break;
                }
                let last = strip[(valid - 1) * w..valid * w].to_vec();
                for r in valid..grid.tile_h {
                    strip[r * w..(r + 1) * w].copy_from_slice(&last);
                }
            }
            Err(e) => return Err(e.into()),
        }
        if let Some(p) = preview.as_mut() {
            let valid = cut.as_ref().map_or(grid.tile_h, |(at, _)| at - y0);
            p.add_rows(&strip[..valid.min(grid.tile_h) * w], w, y0);
        }
        for (col, &x0) in grid.xs.iter().enumerate() {
            if observer.should_stop() {
                return Err(FrameError::Canceled);
            }
            let tile = tile_view(&strip, w, x0, grid.tile_w, grid.tile_h)?;
            let seams = grid.seams(col, row);
            let before = found.len();
            for detector in detectors.iter_mut() {
                found.extend(detector.detect(&tile, (x0, y0), seams)?);
            }
            drop(tile);
            if pictures.is_some() {
                for d in &found[before..] {
                    crops.push((d.clone(), pictures::crop(&strip, w, y0, d)));
                }
            }
            done += 1;
            observer.tile_done(done, grid.count());
        }
        if cut.is_some() {
            break;
        }
    }
    drop(strip);
    let mut warnings = Vec::new();
    if let Some((at, message)) = &cut {
        // Keep only targets wholly in the rows that decoded.
        found.retain(|d| d.center.1 + 0.5 * d.size_px + 2.0 < *at as f64);
        warnings.push(format!(
            "partial: rows {at}..{h} do not decode ({message}); targets from rows 0..{at} only"
        ));
    }
    dedup::remove_duplicates(&mut found);
    if let (Some(out), Some(preview)) = (pictures, preview) {
        make_pictures(out, &found, &crops, preview)?;
    }

    let (world, lonlat) = georeference(&header, &found, &options.crs, transformer, &mut warnings);
    let targets = found
        .into_iter()
        .enumerate()
        .map(|(i, d)| Target {
            at_edge: touches_edge(&d, w, h),
            world: world.as_ref().map(|v| v[i]),
            lonlat: lonlat.as_ref().map(|v| v[i]),
            detection: d,
        })
        .collect();
    Ok(FrameResult {
        image: image.to_string(),
        width: w,
        height: h,
        targets,
        warnings,
        tiles: grid.count(),
        georeference: header.georeference.clone(),
        camera: header.camera.clone(),
    })
}

/// Each kept detection's chip, from the crop of the copy that was kept,
/// and the preview with every detection marked.
fn make_pictures(
    out: &mut Pictures,
    found: &[Detection],
    crops: &[(Detection, Crop)],
    preview: Preview,
) -> Result<(), FrameError> {
    let picture_error = |e: pictures::PictureError| FrameError::Picture(e.to_string());
    for d in found {
        let crop = crops
            .iter()
            .find(|(c, _)| {
                c.marker_type == d.marker_type && c.marker_id == d.marker_id && c.center == d.center
            })
            .map(|(_, crop)| crop)
            .expect("every kept detection was cropped");
        out.chips
            .push(pictures::chip_png(crop, d).map_err(picture_error)?);
    }
    let all: Vec<&Detection> = found.iter().collect();
    out.preview = preview.jpeg(&all).map_err(picture_error)?;
    Ok(())
}

/// A Mat header over columns `x0..x0 + tile_w` of the grey strip, no copy.
fn tile_view(
    strip: &[u8],
    w: usize,
    x0: usize,
    tile_w: usize,
    tile_h: usize,
) -> opencv::Result<Mat> {
    assert!(
        x0 + tile_w <= w && tile_h * w <= strip.len(),
        "tile inside strip"
    );
    // SAFETY: the header addresses tile_h rows of tile_w bytes with stride w,
    // all inside `strip` (asserted above). Detectors only read it, and the
    // caller drops it before `strip` is next written.
    unsafe {
        Mat::new_rows_cols_with_data_unsafe(
            tile_h as i32,
            tile_w as i32,
            CV_8UC1,
            strip.as_ptr().add(x0) as *mut std::ffi::c_void,
            w,
        )
    }
}

type Points = Option<Vec<(f64, f64)>>;

/// World and WGS84 positions of the detections' centres, or a warning saying
/// why there are none.
fn georeference(
    header: &super::raster::FrameHeader,
    found: &[Detection],
    crs: &TargetCrs,
    transformer: &mut Transformer,
    warnings: &mut Vec<String>,
) -> (Points, Points) {
    let Some(geo) = &header.georeference else {
        let why = header
            .georeference_note
            .as_deref()
            .unwrap_or("frame has no georeference");
        warnings.push(format!("{why}; world coordinates left empty"));
        return (None, None);
    };
    let native: Vec<(f64, f64)> = found
        .iter()
        .map(|d| geo.pixel_to_raster_crs(d.center.0, d.center.1))
        .collect();
    let mut world = native.clone();
    let mut lonlat = native;
    let result = transformer
        .transform(&geo.crs, &crs.name, &mut world)
        .and_then(|_| transformer.transform(&geo.crs, WGS84, &mut lonlat));
    match result {
        Ok(()) => (Some(world), Some(lonlat)),
        Err(e) => {
            warnings.push(format!("{e}; world coordinates left empty"));
            (None, None)
        }
    }
}

fn touches_edge(d: &Detection, w: usize, h: usize) -> bool {
    let (maxx, maxy) = (
        w as f64 - 1.0 - EDGE_MARGIN_PX,
        h as f64 - 1.0 - EDGE_MARGIN_PX,
    );
    d.corners
        .iter()
        .any(|&(x, y)| x < EDGE_MARGIN_PX || y < EDGE_MARGIN_PX || x > maxx || y > maxy)
}
