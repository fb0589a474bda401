//! Raw-drone-frame metadata for test frames: an EXIF block (GPS position
//! and altitude, focal length, focal plane resolution) and a DJI-style XMP
//! packet (altitudes, gimbal and flight angles), inserted into a JPEG as
//! APP1 segments after its SOI marker, the way cameras write them.

use std::path::Path;

use crate::Error;

/// The pose and camera a test frame claims to come from.
#[derive(Debug, Clone, PartialEq)]
pub struct DroneMeta {
    pub lat: f64,
    pub lon: f64,
    pub abs_alt_m: f64,
    pub rel_alt_m: f64,
    pub gimbal_yaw_deg: f64,
    pub gimbal_pitch_deg: f64,
    pub gimbal_roll_deg: f64,
    pub flight_yaw_deg: f64,
    pub focal_mm: f64,
    /// Sensor pixels per centimetre (EXIF FocalPlaneXResolution, unit cm).
    pub focal_plane_px_per_cm: f64,
}

/// Inserts EXIF and XMP into the JPEG at `path`.
pub fn write_drone_meta(path: &Path, meta: &DroneMeta) -> Result<(), Error> {
    let jpeg = std::fs::read(path).map_err(Error::io("read", path))?;
    if !jpeg.starts_with(&[0xFF, 0xD8]) {
        return Err(Error::NotJpeg(path.to_path_buf()));
    }
    let mut out = Vec::with_capacity(jpeg.len() + 4096);
    out.extend_from_slice(&jpeg[..2]);
    segment(&mut out, &[b"Exif\0\0".as_slice(), &tiff(meta)].concat())?;
    segment(
        &mut out,
        &[
            b"http://ns.adobe.com/xap/1.0/\0".as_slice(),
            xmp(meta).as_bytes(),
        ]
        .concat(),
    )?;
    out.extend_from_slice(&jpeg[2..]);
    std::fs::write(path, out).map_err(Error::io("write", path))
}

fn segment(out: &mut Vec<u8>, payload: &[u8]) -> Result<(), Error> {
    let len =
        u16::try_from(payload.len() + 2).map_err(|_| Error::SegmentTooLong(payload.len() + 2))?;
    out.extend_from_slice(&[0xFF, 0xE1]);
    out.extend_from_slice(&len.to_be_bytes());
    out.extend_from_slice(payload);
    Ok(())
}

fn xmp(m: &DroneMeta) -> String {
    format!(
        r#"<?xpacket begin="" id="W5M0MpCehiHzreSzNTczkc9d"?>
<x:xmpmeta xmlns:x="adobe:ns:meta/">
 <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
  <rdf:Description rdf:about="" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/"
    drone-dji:AbsoluteAltitude="{:+.2}"
    drone-dji:RelativeAltitude="{:+.2}"
    drone-dji:GimbalRollDegree="{:+.2}"
    drone-dji:GimbalYawDegree="{:+.2}"
    drone-dji:GimbalPitchDegree="{:+.2}"
    drone-dji:FlightYawDegree="{:+.2}"/>
 </rdf:RDF>
</x:xmpmeta>
<?xpacket end="w"?>"#,
        m.abs_alt_m,
        m.rel_alt_m,
        m.gimbal_roll_deg,
        m.gimbal_yaw_deg,
        m.gimbal_pitch_deg,
        m.flight_yaw_deg
    )
}

/// A TIFF value: type code, count, little-endian bytes.
struct Value(u16, u32, Vec<u8>);

fn ascii(s: &str) -> Value {
    let mut b = s.as_bytes().to_vec();
    b.push(0);
    Value(2, b.len() as u32, b)
}

fn short(v: u16) -> Value {
    Value(3, 1, v.to_le_bytes().to_vec())
}

fn long(v: u32) -> Value {
    Value(4, 1, v.to_le_bytes().to_vec())
}

fn rationals(vs: &[f64]) -> Value {
    let mut b = Vec::new();
    for v in vs {
        let den = 1_000_000u32;
        b.extend_from_slice(&((v * den as f64).round() as u32).to_le_bytes());
        b.extend_from_slice(&den.to_le_bytes());
    }
    Value(5, vs.len() as u32, b)
}

fn bytes(vs: &[u8]) -> Value {
    Value(1, vs.len() as u32, vs.to_vec())
}

/// Degrees as EXIF degrees, minutes, seconds.
fn dms(deg: f64) -> Value {
    let a = deg.abs();
    let d = a.floor();
    let m = ((a - d) * 60.0).floor();
    let s = (a - d - m / 60.0) * 3600.0;
    rationals(&[d, m, s])
}

/// Lays out an IFD at `start` (offset from the TIFF header): entries, then
/// the values that do not fit in four bytes. Returns the bytes.
fn ifd(start: u32, mut entries: Vec<(u16, Value)>) -> Vec<u8> {
    entries.sort_by_key(|e| e.0);
    let table = 2 + entries.len() as u32 * 12 + 4;
    let mut data: Vec<u8> = Vec::new();
    let mut out = (entries.len() as u16).to_le_bytes().to_vec();
    for (tag, Value(kind, count, value)) in entries {
        out.extend_from_slice(&tag.to_le_bytes());
        out.extend_from_slice(&kind.to_le_bytes());
        out.extend_from_slice(&count.to_le_bytes());
        if value.len() <= 4 {
            let mut inline = value.clone();
            inline.resize(4, 0);
            out.extend_from_slice(&inline);
        } else {
            let offset = start + table + data.len() as u32;
            out.extend_from_slice(&offset.to_le_bytes());
            data.extend_from_slice(&value);
            if data.len() % 2 == 1 {
                data.push(0);
            }
        }
    }
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&data);
    out
}

fn ifd_len(entries: &[(u16, Value)]) -> u32 {
    let data: u32 = entries
        .iter()
        .map(|(_, v)| {
            if v.2.len() <= 4 {
                0
            } else {
                (v.2.len() as u32 + 1) & !1
            }
        })
        .sum();
    2 + entries.len() as u32 * 12 + 4 + data
}

/// The TIFF structure of the EXIF block: IFD0 -> Exif IFD, GPS IFD.
fn tiff(m: &DroneMeta) -> Vec<u8> {
    let exif = vec![
        (0x920A, rationals(&[m.focal_mm])),
        (0xA20E, rationals(&[m.focal_plane_px_per_cm])),
        (0xA20F, rationals(&[m.focal_plane_px_per_cm])),
        (0xA210, short(3)),
    ];
    let gps = vec![
        (0x0000, bytes(&[2, 3, 0, 0])),
        (0x0001, ascii(if m.lat >= 0.0 { "N" } else { "S" })),
        (0x0002, dms(m.lat)),
        (0x0003, ascii(if m.lon >= 0.0 { "E" } else { "W" })),
        (0x0004, dms(m.lon)),
        (0x0005, bytes(&[u8::from(m.abs_alt_m < 0.0)])),
        (0x0006, rationals(&[m.abs_alt_m.abs()])),
    ];
    let ifd0_entries = |exif_at: u32, gps_at: u32| {
        vec![
            (0x010F, ascii("DJI")),
            (0x0110, ascii("gcp-tagger test camera")),
            (0x8769, long(exif_at)),
            (0x8825, long(gps_at)),
        ]
    };
    let ifd0_size = ifd_len(&ifd0_entries(0, 0));
    let exif_at = 8 + ifd0_size;
    let gps_at = exif_at + ifd_len(&exif);
    let mut out = b"II*\0".to_vec();
    out.extend_from_slice(&8u32.to_le_bytes());
    out.extend(ifd(8, ifd0_entries(exif_at, gps_at)));
    out.extend(ifd(exif_at, exif));
    out.extend(ifd(gps_at, gps));
    out
}
