//! Frame dimensions read from the first bytes of a JPEG, PNG or TIFF
//! without decoding anything, so a "decompression bomb" (a small file that
//! claims 100000 x 100000 pixels) is refused in milliseconds, in the server
//! process, before any image library sees it. Reads are bounded: at most a
//! few kilobytes from known offsets.

use crate::error_code::ErrorCode;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

use crate::pipeline::layout::{first_ifd, IfdError};

/// Limits on what a frame may claim.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelLimits {
    pub max_pixels: u64,
    pub max_side: u32,
}

/// Why a frame's header cannot be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Unreadable {
    #[error("{0}")]
    Io(String),
    #[error("PNG without an IHDR header")]
    PngWithoutIhdr,
    #[error("the header is cut short")]
    Cut,
    #[error("broken JPEG marker")]
    JpegMarker,
    #[error("broken JPEG segment")]
    JpegSegment,
    #[error("no JPEG frame header in the first 64 segments")]
    NoJpegFrame,
    #[error(transparent)]
    Tiff(#[from] IfdError),
    #[error("the TIFF's first image has two {name} entries ({first} and {second})")]
    TiffRepeated {
        name: &'static str,
        first: u32,
        second: u32,
    },
    #[error("the TIFF's first image has no width or height")]
    TiffNoSize,
    #[error("not a JPEG, PNG or TIFF")]
    Unknown,
}

/// A frame claims more than the limits: what it `does` ("claims", "opens
/// as") and both figures.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "the frame {does} {width} x {height} pixels ({:.0} MP); the limits are {max_side} px a side and {:.0} MP",
    *width as f64 * *height as f64 / 1e6,
    *max_pixels as f64 / 1e6
)]
pub struct TooLarge {
    pub does: &'static str,
    pub width: u32,
    pub height: u32,
    pub max_side: u32,
    pub max_pixels: u64,
}

/// A frame's claimed size, or why it cannot be read.
pub fn dimensions(path: &Path) -> Result<(u32, u32), Unreadable> {
    let mut f = File::open(path).map_err(|e| Unreadable::Io(e.to_string()))?;
    let mut head = [0u8; 32];
    let n = read_up_to(&mut f, &mut head)?;
    let head = &head[..n];
    if head.starts_with(b"\x89PNG\r\n\x1a\n") {
        if n < 24 || &head[12..16] != b"IHDR" {
            return Err(Unreadable::PngWithoutIhdr);
        }
        let w = u32::from_be_bytes(head[16..20].try_into().expect("4 bytes"));
        let h = u32::from_be_bytes(head[20..24].try_into().expect("4 bytes"));
        return Ok((w, h));
    }
    if head.starts_with(&[0xFF, 0xD8]) {
        return jpeg(&mut f);
    }
    if head.starts_with(b"II") || head.starts_with(b"MM") {
        return tiff(&mut f, head);
    }
    Err(Unreadable::Unknown)
}

/// Why a frame's header is refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum HeaderError {
    #[error("unreadable header: {0}")]
    Unreadable(#[from] Unreadable),
    #[error(transparent)]
    TooLarge(#[from] TooLarge),
}

impl HeaderError {
    /// The job error code.
    pub fn code(&self) -> ErrorCode {
        match self {
            HeaderError::Unreadable(_) => ErrorCode::UnreadableFrame,
            HeaderError::TooLarge(_) => ErrorCode::FrameTooLarge,
        }
    }
}

impl PixelLimits {
    /// Whether a frame of `w` x `h` pixels is within the limits; the error
    /// says what the frame `does` ("claims", "opens as") and both figures.
    pub fn admit(&self, w: u32, h: u32, does: &'static str) -> Result<(), TooLarge> {
        let pixels = w as u64 * h as u64;
        if w > self.max_side || h > self.max_side || pixels > self.max_pixels {
            return Err(TooLarge {
                does,
                width: w,
                height: h,
                max_side: self.max_side,
                max_pixels: self.max_pixels,
            });
        }
        Ok(())
    }
}

/// Checks a frame's claimed size against `limits`; the error names both.
pub fn check(path: &Path, limits: PixelLimits) -> Result<(u32, u32), HeaderError> {
    let (w, h) = dimensions(path)?;
    limits.admit(w, h, "claims")?;
    Ok((w, h))
}

fn read_up_to(f: &mut File, buf: &mut [u8]) -> Result<usize, Unreadable> {
    let mut n = 0;
    while n < buf.len() {
        match f.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) => return Err(Unreadable::Io(e.to_string())),
        }
    }
    Ok(n)
}

fn read_exact_at(f: &mut File, at: u64, buf: &mut [u8]) -> Result<(), Unreadable> {
    f.seek(SeekFrom::Start(at))
        .map_err(|e| Unreadable::Io(e.to_string()))?;
    f.read_exact(buf).map_err(|_| Unreadable::Cut)
}

/// Walks JPEG segments to the first start-of-frame marker (at most 64
/// segments, so a file of empty segments cannot keep us reading).
fn jpeg(f: &mut File) -> Result<(u32, u32), Unreadable> {
    let mut at = 2u64;
    for _ in 0..64 {
        let mut m = [0u8; 4];
        read_exact_at(f, at, &mut m)?;
        if m[0] != 0xFF {
            return Err(Unreadable::JpegMarker);
        }
        let marker = m[1];
        let len = u16::from_be_bytes([m[2], m[3]]) as u64;
        let is_sof = (0xC0..=0xCF).contains(&marker) && ![0xC4, 0xC8, 0xCC].contains(&marker);
        if is_sof {
            let mut sof = [0u8; 5];
            read_exact_at(f, at + 4, &mut sof)?;
            let h = u16::from_be_bytes([sof[1], sof[2]]) as u32;
            let w = u16::from_be_bytes([sof[3], sof[4]]) as u32;
            return Ok((w, h));
        }
        if len < 2 {
            return Err(Unreadable::JpegSegment);
        }
        at += 2 + len;
    }
    Err(Unreadable::NoJpegFrame)
}

/// ImageWidth (256) and ImageLength (257) of a TIFF's or BigTIFF's first IFD.
fn tiff(f: &mut File, head: &[u8]) -> Result<(u32, u32), Unreadable> {
    let (mut w, mut h) = (None, None);
    for e in first_ifd(f, head)? {
        let v = u32::try_from(e.value).unwrap_or(u32::MAX);
        let (slot, name) = match e.tag {
            256 => (&mut w, "ImageWidth"),
            257 => (&mut h, "ImageLength"),
            _ => continue,
        };
        // Readers differ on which of two entries they use (libtiff the
        // first, others the last): a size check on one would let the
        // other through.
        if let Some(first) = *slot {
            return Err(Unreadable::TiffRepeated {
                name,
                first,
                second: v,
            });
        }
        *slot = Some(v);
    }
    match (w, h) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(Unreadable::TiffNoSize),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(bytes: &[u8]) -> tempfile::NamedTempFile {
        let mut f = tempfile::NamedTempFile::new().unwrap();
        std::io::Write::write_all(&mut f, bytes).unwrap();
        f
    }

    #[test]
    fn sizes_come_from_headers_and_bombs_are_refused() {
        let mut png = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
        png.extend_from_slice(&100_000u32.to_be_bytes());
        png.extend_from_slice(&100_000u32.to_be_bytes());
        let f = file(&png);
        assert_eq!(dimensions(f.path()), Ok((100_000, 100_000)));
        let limits = PixelLimits {
            max_pixels: 400_000_000,
            max_side: 60_000,
        };
        let e = check(f.path(), limits).unwrap_err();
        assert_eq!(e.code(), ErrorCode::FrameTooLarge);
        assert!(e.to_string().contains("100000 x 100000"), "{e}");

        // JPEG: APP0 then SOF0 with 3000 rows of 4000 columns.
        let jpg = [
            &[0xFF, 0xD8, 0xFF, 0xE0, 0, 4, 0, 0][..],
            &[0xFF, 0xC0, 0, 11, 8, 0x0B, 0xB8, 0x0F, 0xA0, 3][..],
        ]
        .concat();
        assert_eq!(dimensions(file(&jpg).path()), Ok((4000, 3000)));

        // Little-endian TIFF with ImageWidth (SHORT) and ImageLength (LONG).
        let mut tif = b"II*\0\x08\0\0\0".to_vec();
        tif.extend_from_slice(&2u16.to_le_bytes());
        tif.extend_from_slice(&[0, 1, 3, 0, 1, 0, 0, 0, 0x40, 0x1F, 0, 0]);
        tif.extend_from_slice(&[1, 1, 4, 0, 1, 0, 0, 0, 0x70, 0x17, 0, 0]);
        assert_eq!(dimensions(file(&tif).path()), Ok((8000, 6000)));

        // The same with a second, small ImageWidth after them: refused
        // whichever entry a reader would use.
        let mut twice = b"II*\0\x08\0\0\0".to_vec();
        twice.extend_from_slice(&3u16.to_le_bytes());
        twice.extend_from_slice(&[0, 1, 4, 0, 1, 0, 0, 0, 0x30, 0x75, 0, 0]);
        twice.extend_from_slice(&[1, 1, 4, 0, 1, 0, 0, 0, 0x30, 0x75, 0, 0]);
        twice.extend_from_slice(&[0, 1, 3, 0, 1, 0, 0, 0, 100, 0, 0, 0]);
        let e = check(file(&twice).path(), limits).unwrap_err();
        assert_eq!(e.code(), ErrorCode::UnreadableFrame);
        assert!(
            e.to_string()
                .contains("two ImageWidth entries (30000 and 100)"),
            "{e}"
        );

        assert!(dimensions(file(b"II*\0\xff\xff\0\0").path()).is_err());
        assert!(dimensions(file(&[0xFF, 0xD8, 0xFF]).path()).is_err());
        assert!(dimensions(file(b"hello").path()).is_err());
    }
}
