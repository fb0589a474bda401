//! Pictures of what was found, made while the frame streams past so the
//! frame is never decoded twice nor held whole:
//!
//! - a **chip** per detection: a crop of the strip around it (three times
//!   its size, at least [`MIN_CHIP_PX`]), enlarged to at least
//!   [`CHIP_VIEW_PX`] by whole pixels (no smoothing; the page shows them
//!   larger), with the fitted outline in yellow and the reported centre as
//!   a red cross whose lines pass through it (drawn at 1/256 px);
//! - a **preview**: the frame reduced by block averages to at most
//!   [`PREVIEW_PX`] a side, built up strip by strip, with every detection
//!   circled and labelled.
//!
//! Pictures are grey (the pipeline reads one luminance band) with colour
//! drawings; chips are PNG, previews JPEG (the `png` and `jpeg-encoder`
//! crates).

use opencv::core::{Mat, Point, Scalar, Size, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use super::detect::{Detection, MarkerType};

/// Least side of a chip's crop, in frame pixels.
pub const MIN_CHIP_PX: usize = 96;
/// Least side of a chip as stored: small crops are enlarged to it.
pub const CHIP_VIEW_PX: usize = 128;
/// Largest side of a preview.
pub const PREVIEW_PX: usize = 1280;
/// Fractional bits of OpenCV's drawing coordinates (1/256 px).
const SHIFT: i32 = 8;

/// The colours drawn, RGB (pictures are drawn in RGB, the encoders' order).
const CENTRE: (f64, f64, f64) = (255.0, 0.0, 0.0);
const OUTLINE: (f64, f64, f64) = (255.0, 255.0, 0.0);

fn colour(c: (f64, f64, f64)) -> Scalar {
    Scalar::new(c.0, c.1, c.2, 0.0)
}

/// A crop of the frame's grey pixels: `side` x `side` from (`x0`, `y0`),
/// frame pixels outside the strip it was cut from left mid-grey.
#[derive(Debug, Clone)]
pub struct Crop {
    pub x0: i64,
    pub y0: i64,
    pub side: usize,
    pub grey: Vec<u8>,
}

/// The window of a detection's chip in frame pixels: (x0, y0, side).
pub fn chip_window(d: &Detection) -> (i64, i64, usize) {
    let side = ((3.0 * d.size_px).ceil() as usize).max(MIN_CHIP_PX);
    let x0 = (d.center.0 - 0.5 * side as f64).round() as i64;
    let y0 = (d.center.1 - 0.5 * side as f64).round() as i64;
    (x0, y0, side)
}

/// Cuts `d`'s chip from a strip of `w`-pixel rows starting at frame row
/// `strip_y0`.
pub fn crop(strip: &[u8], w: usize, strip_y0: usize, d: &Detection) -> Crop {
    let (x0, y0, side) = chip_window(d);
    let rows = strip.len() / w;
    let mut grey = vec![128u8; side * side];
    for r in 0..side {
        let y = y0 + r as i64 - strip_y0 as i64;
        if y < 0 || y >= rows as i64 {
            continue;
        }
        let row = &strip[y as usize * w..(y as usize + 1) * w];
        for c in 0..side {
            let x = x0 + c as i64;
            if (0..w as i64).contains(&x) {
                grey[r * side + c] = row[x as usize];
            }
        }
    }
    Crop { x0, y0, side, grey }
}

/// How much a chip of `side` frame pixels is enlarged.
pub fn chip_zoom(side: usize) -> usize {
    CHIP_VIEW_PX.div_ceil(side).max(1)
}

/// Where frame position `p` lands in an enlarged chip: pixel centres at
/// integers, the chip's top-left frame pixel covering 0..zoom.
pub fn to_chip(crop: &Crop, zoom: usize, p: (f64, f64)) -> (f64, f64) {
    let z = zoom as f64;
    (
        (p.0 - crop.x0 as f64 + 0.5) * z - 0.5,
        (p.1 - crop.y0 as f64 + 0.5) * z - 0.5,
    )
}

fn fixed(p: (f64, f64)) -> Point {
    let s = (1 << SHIFT) as f64;
    Point::new((p.0 * s).round() as i32, (p.1 * s).round() as i32)
}

/// Grey bytes as an RGB Mat, each pixel repeated `zoom` x `zoom`.
fn rgb(grey: &[u8], w: usize, h: usize, zoom: usize) -> opencv::Result<Mat> {
    let grey = Mat::new_rows_cols_with_data(h as i32, w as i32, grey)?;
    let mut colour = Mat::default();
    imgproc::cvt_color_def(&grey, &mut colour, imgproc::COLOR_GRAY2RGB)?;
    if zoom == 1 {
        return Ok(colour);
    }
    let mut zoomed = Mat::default();
    let side = Size::new((w * zoom) as i32, (h * zoom) as i32);
    imgproc::resize(&colour, &mut zoomed, side, 0.0, 0.0, imgproc::INTER_NEAREST)?;
    Ok(zoomed)
}

/// Why a chip or a preview could not be made.
#[derive(Debug, thiserror::Error)]
pub enum PictureError {
    #[error("drawing {what}: {source}")]
    Draw {
        what: &'static str,
        source: opencv::Error,
    },
    #[error("encoding a PNG: {0}")]
    Png(png::EncodingError),
    #[error("encoding a JPEG: {0}")]
    Jpeg(jpeg_encoder::EncodingError),
    #[error("a {0} px side is too large for JPEG")]
    TooLargeForJpeg(u32),
}

/// The chip of `d` from its crop, as PNG bytes.
pub fn chip_png(crop: &Crop, d: &Detection) -> Result<Vec<u8>, PictureError> {
    let zoom = chip_zoom(crop.side);
    let draw = || -> opencv::Result<Mat> {
        let mut m = rgb(&crop.grey, crop.side, crop.side, zoom)?;
        let corners: Vector<Point> = d
            .corners
            .iter()
            .map(|&c| fixed(to_chip(crop, zoom, c)))
            .collect();
        let mut poly = Vector::<Vector<Point>>::new();
        poly.push(corners);
        imgproc::polylines(
            &mut m,
            &poly,
            true,
            colour(OUTLINE),
            1,
            imgproc::LINE_AA,
            SHIFT,
        )?;
        // The centre: two one-pixel lines crossing at it, a gap around it
        // so the target's own crossing stays visible.
        let c = to_chip(crop, zoom, d.center);
        let arm = (0.25 * d.size_px * zoom as f64).max(12.0);
        let gap = (0.04 * d.size_px * zoom as f64).max(3.0);
        for (dx, dy) in [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)] {
            imgproc::line(
                &mut m,
                fixed((c.0 + dx * gap, c.1 + dy * gap)),
                fixed((c.0 + dx * arm, c.1 + dy * arm)),
                colour(CENTRE),
                1,
                imgproc::LINE_8,
                SHIFT,
            )?;
        }
        Ok(m)
    };
    let m = draw().map_err(|source| PictureError::Draw {
        what: "a chip",
        source,
    })?;
    encode(&m, Format::Png)
}

/// How a picture is stored.
enum Format {
    /// Lossless, zlib's fast level (chips: the drawing stays exact).
    Png,
    /// Quality 85 (previews).
    Jpeg,
}

/// Encodes an RGB Mat (the `png` and `jpeg-encoder` crates).
fn encode(m: &Mat, format: Format) -> Result<Vec<u8>, PictureError> {
    let bytes = m.data_bytes().map_err(|source| PictureError::Draw {
        what: "a picture's pixels",
        source,
    })?;
    let (w, h) = (m.cols() as u32, m.rows() as u32);
    let mut out = Vec::new();
    match format {
        Format::Png => {
            let mut encoder = png::Encoder::new(&mut out, w, h);
            encoder.set_color(png::ColorType::Rgb);
            encoder.set_depth(png::BitDepth::Eight);
            encoder.set_compression(png::Compression::Fast);
            encoder
                .write_header()
                .and_then(|mut writer| writer.write_image_data(bytes))
                .map_err(PictureError::Png)?;
        }
        Format::Jpeg => {
            let side = |v: u32| u16::try_from(v).map_err(|_| PictureError::TooLargeForJpeg(v));
            jpeg_encoder::Encoder::new(&mut out, 85)
                .encode(bytes, side(w)?, side(h)?, jpeg_encoder::ColorType::Rgb)
                .map_err(PictureError::Jpeg)?;
        }
    }
    Ok(out)
}

/// A frame reduced by block averages as its rows stream past.
pub struct Preview {
    frame_width: usize,
    width: usize,
    height: usize,
    /// Frame pixels per preview pixel, each way.
    factor: usize,
    sums: Vec<u32>,
    /// The frame rows of the preview row being built, summed column by
    /// column (vectorises; reduced to blocks once per preview row).
    acc: Vec<u32>,
    acc_row: usize,
    /// Frame rows added to each preview row (a frame cut off part-way
    /// leaves the last ones short).
    rows: Vec<u32>,
    /// The next frame row expected.
    next_row: usize,
}

impl Preview {
    /// A preview of a `width` x `height` frame.
    pub fn new(width: usize, height: usize) -> Preview {
        let factor = width.max(height).div_ceil(PREVIEW_PX).max(1);
        let (pw, ph) = (width.div_ceil(factor), height.div_ceil(factor));
        Preview {
            frame_width: width,
            width: pw,
            height: ph,
            factor,
            sums: vec![0; pw * ph],
            acc: vec![0; width],
            acc_row: 0,
            rows: vec![0; ph],
            next_row: 0,
        }
    }

    /// Adds frame rows `y0..` from `rows` (`w`-pixel rows); rows already
    /// added (strips overlap) are skipped.
    pub fn add_rows(&mut self, rows: &[u8], w: usize, y0: usize) {
        let n = rows.len() / w;
        for r in 0..n {
            let y = y0 + r;
            if y < self.next_row {
                continue;
            }
            let py = y / self.factor;
            if py >= self.height {
                break;
            }
            if py != self.acc_row {
                self.flush();
                self.acc_row = py;
            }
            for (a, v) in self.acc.iter_mut().zip(&rows[r * w..(r + 1) * w]) {
                *a += *v as u32;
            }
            self.rows[py] += 1;
            self.next_row = y + 1;
        }
    }

    /// The preview with `targets` circled and labelled, as JPEG bytes.
    pub fn jpeg(mut self, targets: &[&Detection]) -> Result<Vec<u8>, PictureError> {
        let grey = self.grey();
        drop(self.sums);
        let f = self.factor as f64;
        let draw = || -> opencv::Result<Mat> {
            let mut m = rgb(&grey, self.width, self.height, 1)?;
            for d in targets {
                let c = ((d.center.0 + 0.5) / f - 0.5, (d.center.1 + 0.5) / f - 0.5);
                let r = (0.75 * d.size_px / f).max(8.0);
                imgproc::circle(
                    &mut m,
                    fixed(c),
                    (r * (1 << SHIFT) as f64) as i32,
                    colour(OUTLINE),
                    2,
                    imgproc::LINE_AA,
                    SHIFT,
                )?;
                let label = label(d);
                let at = Point::new((c.0 + r + 3.0) as i32, (c.1 - r).max(12.0) as i32);
                for (thick, col) in [(3, (0.0, 0.0, 0.0)), (1, OUTLINE)] {
                    imgproc::put_text(
                        &mut m,
                        &label,
                        at,
                        imgproc::FONT_HERSHEY_SIMPLEX,
                        0.5,
                        colour(col),
                        thick,
                        imgproc::LINE_AA,
                        false,
                    )?;
                }
            }
            Ok(m)
        };
        let m = draw().map_err(|source| PictureError::Draw {
            what: "a preview",
            source,
        })?;
        encode(&m, Format::Jpeg)
    }
}

impl Preview {
    /// Reduces the accumulated frame rows into their preview row's sums.
    fn flush(&mut self) {
        let base = self.acc_row * self.width;
        for (sum, block) in self.sums[base..base + self.width]
            .iter_mut()
            .zip(self.acc.chunks(self.factor))
        {
            *sum += block.iter().sum::<u32>();
        }
        self.acc.fill(0);
    }

    /// The block means (the sums are freed by the caller).
    fn grey(&mut self) -> Vec<u8> {
        self.flush();
        // Frame columns in each preview column: `factor`, the last fewer.
        let cols = |px: usize| (self.frame_width - px * self.factor).min(self.factor) as u32;
        let mut grey = vec![0u8; self.sums.len()];
        for py in 0..self.height {
            for px in 0..self.width {
                let n = cols(px) * self.rows[py];
                let i = py * self.width + px;
                grey[i] = self.sums[i].checked_div(n).unwrap_or(0) as u8;
            }
        }
        grey
    }

    /// Bytes a preview of a `width` x `height` frame holds at most: the
    /// sums while the frame streams, then the grey, colour and encoding
    /// copies (the strip is freed by then).
    pub fn bytes(width: usize, height: usize) -> u64 {
        let factor = width.max(height).div_ceil(PREVIEW_PX).max(1);
        let pixels = (width.div_ceil(factor) * height.div_ceil(factor)) as u64;
        PREVIEW_BYTES_PER_PIXEL * pixels
    }
}

/// What a preview holds per pixel, with margin: u32 sums (4) and the row
/// accumulator while the frame streams, then grey (1), the RGB drawing (3)
/// and the encoder's buffers and file (~2).
const PREVIEW_BYTES_PER_PIXEL: u64 = 12;

/// What making a frame's pictures adds to its working set (see
/// [`super::memory::estimate_frame_bytes`]).
pub fn reserve_bytes(width: usize, height: usize, max_target_px: usize) -> u64 {
    Preview::bytes(width, height) + chips_bytes(max_target_px)
}

/// Bytes the chips of a frame may hold: crops of up to three times the
/// largest target, for up to [`CHIPS_RESERVED`] detections.
pub fn chips_bytes(max_target_px: usize) -> u64 {
    let side = (3 * max_target_px).max(MIN_CHIP_PX) as u64;
    CHIPS_RESERVED * side * side
}

/// Detections per frame whose crops the reservation covers; a frame with
/// more (a clutter-heavy printed search) holds more, briefly.
const CHIPS_RESERVED: u64 = 16;

/// A detection's label: its id, or its kind for printed targets.
pub fn label(d: &Detection) -> String {
    match (d.marker_type, d.marker_id) {
        (_, Some(id)) => format!("{} {id}", d.marker_type),
        (MarkerType::Crosshair, None) => "cross".into(),
        (m, None) => m.to_string(),
    }
}

/// A frame's pictures: one chip per target, in the result's order, and
/// the preview.
#[derive(Debug, Clone, Default)]
pub struct Pictures {
    pub chips: Vec<Vec<u8>>,
    pub preview: Vec<u8>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_preview_averages_blocks_and_skips_rows_seen_twice() {
        let (w, h) = (2 * PREVIEW_PX, 10);
        let mut p = Preview::new(w, h);
        assert_eq!(p.factor, 2);
        let rows: Vec<u8> = (0..w * 6)
            .map(|i| if i % w < w / 2 { 10 } else { 200 })
            .collect();
        p.add_rows(&rows, w, 0);
        // Rows 4..10, of which 4 and 5 were added already.
        p.add_rows(&rows, w, 4);
        assert_eq!(p.rows[..5], [2, 2, 2, 2, 2]);
        let grey = p.grey();
        let p = &p;
        assert_eq!(grey[0], 10);
        assert_eq!(grey[p.width - 1], 200);
        assert_eq!(grey[4 * p.width + 1], 10);
    }
}
