//! Raster input: opens a frame through GDAL with an allow-list of drivers and
//! hands it out as full-width 8-bit grey strips, read strictly top to bottom.
//!
//! Reading forward matters for JPEG, where a "block" is one scanline and any
//! read above the last decoded line restarts decoding from the top of the file.
//! All selected bands come from one `GDALDatasetRasterIO` call per chunk.

use std::ffi::c_void;
use std::path::{Path, PathBuf};

use gdal::raster::{ColorInterpretation, GdalDataType};
use gdal::{Dataset, DatasetOptions, GdalOpenFlags};

use super::camera::CameraMeta;
use super::georef::Georeference;

/// GDAL drivers a frame may be opened with. Everything else (VRT, /vsi
/// handlers, network drivers) could read arbitrary files or URLs.
pub const ALLOWED_DRIVERS: &[&str] = &["GTiff", "JPEG", "PNG"];

/// Frames narrower or shorter than this cannot hold a usable target.
pub const MIN_FRAME_SIDE: usize = 32;

/// How many pixels the per-frame stretch samples at most: enough for stable
/// percentiles, small enough (4 MB of f32 per band) to ignore in the budget.
const STRETCH_SAMPLE_PIXELS: usize = 1 << 20;

/// Rows read per GDAL call when the file has no larger natural block.
const CHUNK_ROWS: usize = 256;

/// Percentiles of the grey values mapped to 0 and 255 for non-8-bit frames.
const STRETCH_LOW_PCT: f64 = 0.002;
const STRETCH_HIGH_PCT: f64 = 0.998;

/// Why a frame could not be read.
#[derive(Debug, thiserror::Error)]
pub enum RasterError {
    #[error("cannot read file: {0}")]
    Io(#[from] std::io::Error),
    #[error("empty file (0 bytes)")]
    Empty,
    #[error("refused path: {0}")]
    RefusedPath(String),
    #[error("not a supported image (JPEG, TIFF or PNG): {0}")]
    Unsupported(String),
    #[error("frame is {width}x{height} px, below the {min} px minimum side")]
    TooSmall {
        width: usize,
        height: usize,
        min: usize,
    },
    #[error("unsupported band layout: {0}")]
    Bands(String),
    #[error("decoding failed at rows {row}..{end}: {message}")]
    Decode {
        row: usize,
        end: usize,
        message: String,
    },
    /// The rows from `row` on do not decode (a file cut off or damaged
    /// part-way); `read` rows of the request were delivered before it.
    #[error("the frame does not decode from row {row} of {height} on: {message}")]
    CutOff {
        row: usize,
        height: usize,
        read: usize,
        message: String,
    },
}

/// Sample type GDAL converts pixels to while reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SampleKind {
    /// 8-bit data: used as is, no stretch.
    U8,
    /// Anything wider (16-bit multispectral, float reflectance): read as f32
    /// and stretched to 8 bits once per frame.
    F32,
}

/// What is known about a frame from its header, before any pixel is decoded.
#[derive(Debug, Clone)]
pub struct FrameHeader {
    pub width: usize,
    pub height: usize,
    /// 1-based GDAL band indices used: three (R, G, B) or one (grey).
    pub bands: Vec<i32>,
    /// Bytes per sample as GDAL delivers them to us (1 or 4).
    pub sample_bytes: usize,
    /// Natural block height of the file (1 for JPEG scanlines).
    pub block_rows: usize,
    /// What the decoder holds beyond the rows read (see [`layout`]).
    ///
    /// [`layout`]: super::layout
    pub decoder_bytes: u64,
    pub driver: String,
    pub georeference: Option<Georeference>,
    /// Why the frame has no georeference, when it has none.
    pub georeference_note: Option<String>,
    /// Camera position and orientation from EXIF/XMP (raw drone frames).
    pub camera: Option<CameraMeta>,
}

impl FrameHeader {
    /// Rows per GDAL read call: a whole number of file blocks, so no block is
    /// decoded twice, and at least `CHUNK_ROWS` to amortise the call.
    pub fn chunk_rows(&self) -> usize {
        let block = self.block_rows.clamp(1, 1024);
        CHUNK_ROWS.div_ceil(block) * block
    }

    /// Bytes of the reusable buffer one chunk read needs.
    pub fn chunk_bytes(&self) -> usize {
        self.width * self.chunk_rows() * self.bands.len() * self.sample_bytes
    }
}

/// Linear map from a grey value to 0..=255, fixed for the whole frame so a
/// target looks the same in neighbouring tiles.
#[derive(Debug, Clone, Copy)]
struct Stretch {
    low: f32,
    scale: f32,
}

/// An opened frame, ready to be read strip by strip.
pub struct RasterFrame {
    dataset: Dataset,
    header: FrameHeader,
    kind: SampleKind,
    stretch: Option<Stretch>,
    /// Next row the reader will deliver; reads never go backwards.
    next_row: usize,
    /// Reusable read buffer; f32 storage so the float view is always aligned.
    chunk: Vec<f32>,
}

/// Opens `path` with the allowed drivers only and reads its header.
pub fn open_frame(path: &Path) -> Result<RasterFrame, RasterError> {
    let path = checked_path(path)?;
    let meta = std::fs::metadata(&path)?;
    if meta.len() == 0 {
        return Err(RasterError::Empty);
    }
    let options = DatasetOptions {
        open_flags: GdalOpenFlags::GDAL_OF_RASTER | GdalOpenFlags::GDAL_OF_READONLY,
        allowed_drivers: Some(ALLOWED_DRIVERS),
        ..Default::default()
    };
    let dataset = Dataset::open_ex(&path, options)
        .map_err(|e| RasterError::Unsupported(short_gdal_message(&e.to_string())))?;
    let (width, height) = dataset.raster_size();
    if width < MIN_FRAME_SIDE || height < MIN_FRAME_SIDE {
        return Err(RasterError::TooSmall {
            width,
            height,
            min: MIN_FRAME_SIDE,
        });
    }
    let (bands, data_type) = select_bands(&dataset)?;
    let kind = if data_type == GdalDataType::UInt8 {
        SampleKind::U8
    } else {
        SampleKind::F32
    };
    let block_rows = dataset
        .rasterband(bands[0] as usize)
        .map(|b| b.block_size().1)
        .unwrap_or(1);
    let (georeference, georeference_note) = match Georeference::from_dataset(&dataset) {
        Ok(g) => (Some(g), None),
        Err(why) => (None, Some(why.to_string())),
    };
    let header = FrameHeader {
        width,
        height,
        bands,
        sample_bytes: if kind == SampleKind::U8 { 1 } else { 4 },
        block_rows,
        decoder_bytes: super::layout::decoder_bytes(&path),
        driver: dataset.driver().short_name(),
        georeference,
        georeference_note,
        camera: CameraMeta::from_dataset(&dataset),
    };
    Ok(RasterFrame {
        dataset,
        header,
        kind,
        stretch: None,
        next_row: 0,
        chunk: Vec::new(),
    })
}

/// Refuses GDAL virtual-filesystem prefixes and anything that is not a plain file.
fn checked_path(path: &Path) -> Result<PathBuf, RasterError> {
    let text = path.to_string_lossy();
    if text.starts_with("/vsi") || text.trim_start().starts_with('<') {
        return Err(RasterError::RefusedPath(text.into_owned()));
    }
    if !path.is_file() {
        return Err(RasterError::Io(std::io::Error::new(
            std::io::ErrorKind::NotFound,
            "no such file",
        )));
    }
    Ok(path.to_path_buf())
}

/// GDAL prefixes messages with the file path; keep the part that says why.
fn short_gdal_message(message: &str) -> String {
    message.lines().next().unwrap_or(message).trim().to_string()
}

/// Picks the bands that carry the picture: R, G, B by colour interpretation
/// when labelled, else the first three non-alpha bands, else the first band.
fn select_bands(dataset: &Dataset) -> Result<(Vec<i32>, GdalDataType), RasterError> {
    let count = dataset.raster_count();
    let mut interps = Vec::with_capacity(count);
    for index in 1..=count {
        let band = dataset
            .rasterband(index)
            .map_err(|e| RasterError::Bands(e.to_string()))?;
        interps.push((index as i32, band.color_interpretation(), band.band_type()));
    }
    if interps.is_empty() {
        return Err(RasterError::Bands("no raster bands".into()));
    }
    if interps
        .iter()
        .any(|(_, ci, _)| *ci == ColorInterpretation::PaletteIndex)
    {
        return Err(RasterError::Bands(
            "palette (indexed colour) images are not supported".into(),
        ));
    }
    let find = |want: ColorInterpretation| interps.iter().find(|(_, ci, _)| *ci == want);
    let chosen: Vec<i32> = match (
        find(ColorInterpretation::RedBand),
        find(ColorInterpretation::GreenBand),
        find(ColorInterpretation::BlueBand),
    ) {
        (Some(r), Some(g), Some(b)) => vec![r.0, g.0, b.0],
        _ => {
            let picture: Vec<i32> = interps
                .iter()
                .filter(|(_, ci, _)| *ci != ColorInterpretation::AlphaBand)
                .map(|(i, _, _)| *i)
                .collect();
            match picture.len() {
                0 => return Err(RasterError::Bands("only alpha bands".into())),
                1 | 2 => vec![picture[0]],
                _ => picture[..3].to_vec(),
            }
        }
    };
    let data_type = interps[(chosen[0] - 1) as usize].2;
    if chosen
        .iter()
        .any(|&i| interps[(i - 1) as usize].2 != data_type)
    {
        return Err(RasterError::Bands(
            "selected bands have different data types".into(),
        ));
    }
    if matches!(data_type, GdalDataType::Unknown) {
        return Err(RasterError::Bands("unknown sample type".into()));
    }
    Ok((chosen, data_type))
}

impl RasterFrame {
    pub fn header(&self) -> &FrameHeader {
        &self.header
    }

    /// Computes the frame-wide 8-bit stretch for non-8-bit data from a
    /// decimated read of the whole frame (one GDAL call, nearest neighbour,
    /// at most `STRETCH_SAMPLE_PIXELS` pixels). A no-op for 8-bit frames.
    pub fn prepare_stretch(&mut self) -> Result<(), RasterError> {
        if self.kind == SampleKind::U8 {
            return Ok(());
        }
        let (w, h) = (self.header.width, self.header.height);
        let step = ((w * h) as f64 / STRETCH_SAMPLE_PIXELS as f64)
            .sqrt()
            .ceil()
            .max(1.0) as usize;
        let (sw, sh) = (w.div_ceil(step), h.div_ceil(step));
        let nb = self.header.bands.len();
        let mut samples = vec![0f32; sw * sh * nb];
        self.raster_io(0, w, h, sw, sh, bytemuck_f32(&mut samples))?;
        let mut grey: Vec<f32> = (0..sw * sh)
            .map(|i| grey_f32(&samples, i, sw * sh, nb))
            .filter(|v| v.is_finite())
            .collect();
        if grey.is_empty() {
            return Err(RasterError::Bands("no finite pixel values".into()));
        }
        grey.sort_unstable_by(f32::total_cmp);
        let pick = |p: f64| grey[((grey.len() - 1) as f64 * p).round() as usize];
        let (low, high) = (pick(STRETCH_LOW_PCT), pick(STRETCH_HIGH_PCT));
        let span = if high > low { high - low } else { 1.0 };
        self.stretch = Some(Stretch {
            low,
            scale: 255.0 / span,
        });
        Ok(())
    }

    /// Reads rows `[self.next_row, self.next_row + out.len() / width)` as grey
    /// bytes into `out`. Rows must be requested in order.
    pub fn read_rows(&mut self, out: &mut [u8]) -> Result<(), RasterError> {
        let w = self.header.width;
        debug_assert_eq!(out.len() % w, 0);
        let rows = out.len() / w;
        let nb = self.header.bands.len();
        let chunk_rows = self.header.chunk_rows();
        let mut chunk = std::mem::take(&mut self.chunk);
        chunk.resize(self.header.chunk_bytes().div_ceil(4), 0.0);
        let mut done = 0;
        while done < rows {
            let n = (rows - done).min(chunk_rows);
            let bytes = w * n * nb * self.header.sample_bytes;
            let y = self.next_row;
            let raw = &mut bytemuck_f32(&mut chunk)[..bytes];
            if let Err(e) = self.raster_io(y, w, n, w, n, raw) {
                // Which of these rows still decode, one at a time: a file
                // cut off part-way keeps the rows before the cut.
                let good = self.rows_that_decode(y, n, &mut chunk, &mut out[done * w..]);
                self.chunk = chunk;
                self.next_row = y + good;
                return Err(RasterError::CutOff {
                    row: y + good,
                    height: self.header.height,
                    read: done + good,
                    message: match e {
                        RasterError::Decode { message, .. } => message,
                        other => other.to_string(),
                    },
                });
            }
            self.to_grey(&chunk, n, &mut out[done * w..(done + n) * w]);
            self.next_row += n;
            done += n;
        }
        self.chunk = chunk;
        Ok(())
    }

    /// Reads rows `y..y + n` one by one into `out` until one fails; the
    /// number read.
    fn rows_that_decode(&self, y: usize, n: usize, chunk: &mut [f32], out: &mut [u8]) -> usize {
        let w = self.header.width;
        let bytes = w * self.header.bands.len() * self.header.sample_bytes;
        for k in 0..n {
            let raw = &mut bytemuck_f32(chunk)[..bytes];
            if self.raster_io(y + k, w, 1, w, 1, raw).is_err() {
                return k;
            }
            self.to_grey(chunk, 1, &mut out[k * w..(k + 1) * w]);
        }
        n
    }

    /// Grey bytes of `n` rows read band-sequentially into `chunk`.
    fn to_grey(&self, chunk: &[f32], n: usize, dst: &mut [u8]) {
        let w = self.header.width;
        let nb = self.header.bands.len();
        match self.kind {
            SampleKind::U8 => {
                // SAFETY: a view of the same f32 storage as bytes.
                let raw = unsafe {
                    std::slice::from_raw_parts(chunk.as_ptr() as *const u8, chunk.len() * 4)
                };
                grey_u8_rows(&raw[..w * n * nb], dst, nb)
            }
            SampleKind::F32 => {
                let stretch = self.stretch.expect("prepare_stretch runs before read_rows");
                let plane = w * n;
                let samples = &chunk[..plane * nb];
                for (i, px) in dst.iter_mut().enumerate() {
                    let g = grey_f32(samples, i, plane, nb);
                    let v = (g - stretch.low) * stretch.scale;
                    *px = if v.is_finite() {
                        v.round().clamp(0.0, 255.0) as u8
                    } else {
                        0
                    };
                }
            }
        }
    }

    /// One `GDALDatasetRasterIO` call for all selected bands, band-sequential.
    fn raster_io(
        &self,
        y: usize,
        w: usize,
        h: usize,
        buf_w: usize,
        buf_h: usize,
        buf: &mut [u8],
    ) -> Result<(), RasterError> {
        let nb = self.header.bands.len();
        let (ty, bytes) = match self.kind {
            SampleKind::U8 => (gdal_sys::GDALDataType::GDT_Byte, 1),
            SampleKind::F32 => (gdal_sys::GDALDataType::GDT_Float32, 4),
        };
        assert!(
            buf.len() >= buf_w * buf_h * nb * bytes,
            "raster_io buffer too small"
        );
        let mut bands = self.header.bands.clone();
        // SAFETY: the buffer holds buf_w * buf_h * nb samples of `ty` (checked
        // above); the band list outlives the call; the dataset handle is live.
        let rv = unsafe {
            gdal_sys::GDALDatasetRasterIO(
                self.dataset.c_dataset(),
                gdal_sys::GDALRWFlag::GF_Read,
                0,
                y as i32,
                w as i32,
                h as i32,
                buf.as_mut_ptr() as *mut c_void,
                buf_w as i32,
                buf_h as i32,
                ty,
                nb as i32,
                bands.as_mut_ptr(),
                0,
                0,
                0,
            )
        };
        if rv != gdal_sys::CPLErr::CE_None {
            return Err(RasterError::Decode {
                row: y,
                end: y + h,
                message: last_gdal_error(),
            });
        }
        Ok(())
    }
}

/// The message of the last GDAL error on this thread.
fn last_gdal_error() -> String {
    // SAFETY: CPLGetLastErrorMsg returns a pointer to a thread-local,
    // NUL-terminated buffer owned by GDAL.
    let msg = unsafe { std::ffi::CStr::from_ptr(gdal_sys::CPLGetLastErrorMsg()) };
    let text = msg.to_string_lossy().trim().to_string();
    if text.is_empty() {
        "unknown GDAL error".into()
    } else {
        text
    }
}

/// Grey value of pixel `i` from band-sequential samples (ITU-R BT.601 weights,
/// the ones OpenCV's cvtColor uses).
#[inline]
fn grey_f32(samples: &[f32], i: usize, plane: usize, nb: usize) -> f32 {
    if nb == 3 {
        0.299 * samples[i] + 0.587 * samples[plane + i] + 0.114 * samples[2 * plane + i]
    } else {
        samples[i]
    }
}

/// Band-sequential 8-bit samples to grey, in fixed point (weights x 256).
fn grey_u8_rows(chunk: &[u8], dst: &mut [u8], nb: usize) {
    let plane = dst.len();
    if nb == 1 {
        dst.copy_from_slice(&chunk[..plane]);
        return;
    }
    let (r, rest) = chunk.split_at(plane);
    let (g, b) = rest.split_at(plane);
    for (i, px) in dst.iter_mut().enumerate() {
        let v = 77 * r[i] as u32 + 150 * g[i] as u32 + 29 * b[i] as u32 + 128;
        *px = (v >> 8) as u8;
    }
}

fn bytemuck_f32(v: &mut [f32]) -> &mut [u8] {
    // SAFETY: f32 has no invalid bit patterns and u8 has alignment 1.
    unsafe { std::slice::from_raw_parts_mut(v.as_mut_ptr() as *mut u8, v.len() * 4) }
}
