//! Synthetic frames with exact ground truth, for tests, the benchmark and
//! the README's demo: real markers from OpenCV's dictionaries placed through
//! known homographies, rendered with area anti-aliasing onto textured ground,
//! then blurred, shaded and noised. Deterministic for a given seed.
//!
//! Pixel convention: pixel (i, j) covers [i-0.5, i+0.5] x [j-0.5, j+0.5], so
//! truth is in OpenCV coordinates (centre of the top-left pixel is 0,0).

mod canvas;
mod exif;
mod geometry;
mod printed;
mod render;
mod tags;
mod write;

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

pub use canvas::Truth;
pub use exif::{write_drone_meta, DroneMeta};
pub use geometry::{dist, Homography, Pt};
pub use printed::{Lookalike, LookalikeKind, Marking, PrintedDesign, PrintedSpec};
pub use render::{
    render, render_window, render_with_lookalikes, Clutter, GreyImage, MarkerSpec, Scene,
};
pub use tags::{marker_cells, TargetKind};
pub use write::{write_image, GeoSpec, SampleFormat};

/// What can go wrong making a frame.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("unknown marker dictionary {0:?}")]
    UnknownDictionary(String),
    #[error("{dictionary} has {count} ids, not {id}")]
    NoSuchId {
        dictionary: String,
        id: u32,
        count: u32,
    },
    #[error("unknown target kind {0:?} (apriltag, aruco, crosshair, circle)")]
    UnknownKind(String),
    #[error("{0} targets carry no code")]
    NoCode(TargetKind),
    #[error("OpenCV cannot draw the marker: {0}")]
    OpenCv(String),
    #[error("unknown sample kind {0:?} (jpeg, png, gtiff, gtiff16)")]
    UnknownFileKind(String),
    #[error("cannot write {path}: {source}")]
    Gdal {
        path: PathBuf,
        source: gdal::errors::GdalError,
    },
    #[error("cannot {action} {path}: {source}")]
    Io {
        action: &'static str,
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{0} is not a JPEG")]
    NotJpeg(PathBuf),
    #[error("a metadata segment of {0} bytes does not fit a JPEG APP1 segment")]
    SegmentTooLong(usize),
}

impl Error {
    /// `action` ("read", "write", "create") failed on `path`.
    fn io<'a>(action: &'static str, path: &'a Path) -> impl FnOnce(std::io::Error) -> Error + 'a {
        move |source| Error::Io {
            action,
            path: path.to_path_buf(),
            source,
        }
    }
}

/// splitmix64: small, fast, and the same on every platform.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed ^ 0x9E37_79B9_7F4A_7C15)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Moves on as `draws` calls of [`Rng::next_u64`] would (the state is
    /// a counter: O(1)).
    pub fn skip(&mut self, draws: u64) {
        self.0 = self
            .0
            .wrapping_add(0x9E37_79B9_7F4A_7C15u64.wrapping_mul(draws));
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-12);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// File types the generator writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileKind {
    Jpeg,
    Png,
    /// 8-bit RGB GeoTIFF in UTM zone 11N.
    Gtiff,
    /// 16-bit 4-band (R, G, B, NIR) GeoTIFF in UTM zone 11N, as
    /// multispectral cameras write.
    Gtiff16,
}

impl FileKind {
    pub fn extension(self) -> &'static str {
        match self {
            FileKind::Jpeg => "jpg",
            FileKind::Png => "png",
            FileKind::Gtiff | FileKind::Gtiff16 => "tif",
        }
    }
}

impl FromStr for FileKind {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self, Error> {
        match s.to_ascii_lowercase().as_str() {
            "jpeg" | "jpg" => Ok(FileKind::Jpeg),
            "png" => Ok(FileKind::Png),
            "gtiff" | "tif" | "tiff" => Ok(FileKind::Gtiff),
            "gtiff16" => Ok(FileKind::Gtiff16),
            other => Err(Error::UnknownFileKind(other.to_string())),
        }
    }
}

impl fmt::Display for FileKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FileKind::Gtiff16 => "gtiff16",
            other => other.extension(),
        })
    }
}

/// A flight of similar frames with randomly placed AprilTag 36h11 markers.
#[derive(Debug, Clone)]
pub struct FlightSpec {
    pub frames: usize,
    pub width: usize,
    pub height: usize,
    pub markers: usize,
    pub kind: FileKind,
    pub seed: u64,
    /// Frames of [`hard_scene`] instead of [`random_scene`].
    pub hard: bool,
}

/// The georeference sample GeoTIFFs carry: UTM 11N, 2 cm pixels.
pub fn sample_geo(frame_index: usize) -> GeoSpec {
    GeoSpec {
        geotransform: [
            500_000.0 + 80.0 * frame_index as f64,
            0.02,
            0.0,
            4_100_000.0,
            0.0,
            -0.02,
        ],
        epsg: 32611,
    }
}

/// Clutter of the coded-tag scenes: squares, discs and bars, no printed
/// look-alikes.
const TAG_CLUTTER: Clutter = Clutter {
    squares: 30,
    circles: 20,
    stripes: 6,
    lookalikes: 0,
};

/// A scene with `markers` non-overlapping markers of 30-60 px at random
/// positions (some near seams of the default 2048 px tiles), moderate blur
/// and noise, a brightness gradient, shadows and clutter.
pub fn random_scene(width: usize, height: usize, markers: usize, seed: u64) -> Scene {
    let mut rng = Rng::new(seed);
    let markers = place_tags(width, height, markers, (30.0, 60.0), 0.06, seed, &mut rng);
    Scene {
        width,
        height,
        seed,
        blur_sigma: 0.8,
        noise_sigma: 3.0,
        gradient: 0.25,
        shadows: 2,
        clutter: TAG_CLUTTER,
        markers,
        printed: Vec::new(),
        motion_blur: (0.0, 0.0),
        tag_shadows: 0.0,
    }
}

/// The hard cases of aerial AprilTag frames: tags of 18-60 px (half of them
/// under 40), perspective up to 10% of the side, defocus blur 0.6-1.3 px,
/// motion blur of 1-3 px on half the frames, a hard-edged shadow across a
/// third of the tags, noise 2-5 grey levels, shadows and clutter.
pub fn hard_scene(width: usize, height: usize, markers: usize, seed: u64) -> Scene {
    let mut rng = Rng::new(seed);
    let markers = place_tags(width, height, markers, (18.0, 60.0), 0.1, seed, &mut rng);
    let moving = rng.uniform() < 0.5;
    Scene {
        width,
        height,
        seed,
        blur_sigma: rng.range(0.6, 1.3),
        noise_sigma: rng.range(2.0, 5.0),
        gradient: 0.3,
        shadows: 2,
        clutter: TAG_CLUTTER,
        markers,
        printed: Vec::new(),
        motion_blur: if moving {
            (rng.range(1.0, 3.0), rng.range(0.0, 180.0))
        } else {
            (0.0, 0.0)
        },
        tag_shadows: 1.0 / 3.0,
    }
}

/// `count` AprilTag 36h11 markers of `sides` px at random positions, at
/// least three sides apart.
fn place_tags(
    width: usize,
    height: usize,
    count: usize,
    sides: (f64, f64),
    perspective: f64,
    seed: u64,
    rng: &mut Rng,
) -> Vec<MarkerSpec> {
    let mut specs: Vec<MarkerSpec> = Vec::new();
    let mut attempts = 0;
    while specs.len() < count && attempts < count * 200 {
        attempts += 1;
        let side = rng.range(sides.0, sides.1);
        let margin = side * 1.2;
        let c = (
            rng.range(margin, width as f64 - margin),
            rng.range(margin, height as f64 - margin),
        );
        if specs
            .iter()
            .any(|m| dist(m.center, c) < 3.0 * (m.side_px + side))
        {
            continue;
        }
        specs.push(MarkerSpec {
            kind: TargetKind::AprilTag,
            dictionary: "36h11".to_string(),
            id: (specs.len() as u32 * 7 + seed as u32) % 587,
            center: c,
            side_px: side,
            rotation_deg: rng.range(0.0, 360.0),
            perspective: rng.range(0.0, perspective),
        });
    }
    specs
}

/// `count` cells laid over a frame in near-square rows and columns, one
/// target per cell.
#[derive(Debug, Clone, Copy)]
pub struct Grid {
    cols: usize,
    cell: (f64, f64),
}

impl Grid {
    pub fn new(width: usize, height: usize, count: usize) -> Grid {
        let cols = ((count as f64 * width as f64 / height as f64).sqrt().ceil() as usize).max(1);
        let rows = count.div_ceil(cols);
        Grid {
            cols,
            cell: (width as f64 / cols as f64, height as f64 / rows as f64),
        }
    }

    /// Centre of cell `i`, moved by up to `jitter` of the cell each way.
    pub fn position(&self, i: usize, jitter: f64, rng: &mut Rng) -> (f64, f64) {
        let (c, r) = ((i % self.cols) as f64, (i / self.cols) as f64);
        let (cw, ch) = self.cell;
        (
            cw * (c + 0.5) + rng.range(-jitter, jitter) * cw,
            ch * (r + 0.5) + rng.range(-jitter, jitter) * ch,
        )
    }
}

/// A frame of `count` printed targets of `mode` (crosshair: crosses and
/// checkers; circle: bullseyes of several ring ratios and discs) with sizes in `sizes`, on a grid
/// with jitter, under the conditions aerial frames show: any rotation, mild
/// perspective, print contrast down to 40%, a shadow edge across a quarter
/// of the targets, defocus blur 0.6-1.4 px, motion blur up to 3 px on odd
/// seeds, noise 2-5 grey levels, textured ground and look-alike clutter.
pub fn printed_scene(
    width: usize,
    height: usize,
    count: usize,
    mode: TargetKind,
    sizes: (f64, f64),
    seed: u64,
) -> Scene {
    let mut rng = Rng::new(seed);
    let grid = Grid::new(width, height, count);
    let printed = (0..count)
        .map(|i| {
            let design = match (mode, i % 2) {
                (TargetKind::Circle, 0) => {
                    // Ring ratios of the designs in use: 1:2:3, a wide
                    // centre disc, a thin outer ring, and between.
                    let inner = rng.range(0.25, 0.45);
                    PrintedDesign::Bullseye {
                        inner,
                        middle: rng.range(inner + 0.2, (inner + 0.4).min(0.8)),
                    }
                }
                (TargetKind::Circle, _) => PrintedDesign::Disc {
                    white_on_black: rng.uniform() < 0.5,
                },
                (_, 0) => PrintedDesign::Cross {
                    bar: rng.range(0.12, 0.3),
                    marking: Marking::ALL[(rng.uniform() * 6.0) as usize % 6],
                },
                _ => PrintedDesign::Checker,
            };
            PrintedSpec {
                design,
                center: grid.position(i, 0.12, &mut rng),
                size_px: rng.range(sizes.0, sizes.1),
                rotation_deg: rng.range(0.0, 360.0),
                perspective: rng.range(0.0, 0.05),
                contrast: if rng.uniform() < 0.3 {
                    rng.range(0.4, 0.6)
                } else {
                    rng.range(0.8, 1.0)
                },
                shadow: rng.uniform() < 0.25,
            }
        })
        .collect();
    Scene {
        width,
        height,
        seed,
        blur_sigma: rng.range(0.6, 1.4),
        noise_sigma: rng.range(2.0, 5.0),
        gradient: 0.3,
        shadows: 1,
        clutter: Clutter {
            squares: 10,
            circles: 8,
            stripes: 3,
            lookalikes: 6,
        },
        markers: Vec::new(),
        printed,
        motion_blur: if seed % 2 == 1 {
            (rng.range(1.5, 3.0), rng.range(0.0, 180.0))
        } else {
            (0.0, 0.0)
        },
        tag_shadows: 0.0,
    }
}

/// A frame of look-alikes only: no target, every kind of clutter.
pub fn clutter_scene(width: usize, height: usize, seed: u64) -> Scene {
    let area = (width * height) as f64 / 1e6;
    Scene {
        width,
        height,
        seed,
        blur_sigma: 0.9,
        noise_sigma: 3.0,
        gradient: 0.3,
        shadows: 2,
        clutter: Clutter {
            squares: (25.0 * area) as usize,
            circles: (20.0 * area) as usize,
            stripes: (4.0 * area) as usize,
            lookalikes: (40.0 * area) as usize,
        },
        markers: Vec::new(),
        printed: Vec::new(),
        motion_blur: (0.0, 0.0),
        tag_shadows: 0.0,
    }
}

/// Writes a flight of frames and `truth.csv` to `dir`; returns the count.
pub fn write_flight(dir: &Path, spec: &FlightSpec) -> Result<usize, Error> {
    std::fs::create_dir_all(dir).map_err(Error::io("create", dir))?;
    let mut truth = String::from("image,marker_type,marker_id,px_x,px_y,size_px\n");
    for i in 0..spec.frames {
        let seed = spec.seed * 1000 + i as u64;
        let scene = if spec.hard {
            hard_scene(spec.width, spec.height, spec.markers, seed)
        } else {
            random_scene(spec.width, spec.height, spec.markers, seed)
        };
        let (image, truths) = render(&scene)?;
        let name = format!("frame_{i:04}.{}", spec.kind.extension());
        let geo = matches!(spec.kind, FileKind::Gtiff | FileKind::Gtiff16).then(|| sample_geo(i));
        let format = match spec.kind {
            FileKind::Jpeg => SampleFormat::Jpeg,
            FileKind::Png => SampleFormat::Png,
            FileKind::Gtiff => SampleFormat::GtiffRgb8,
            FileKind::Gtiff16 => SampleFormat::Gtiff16Rgbn,
        };
        write_image(&dir.join(&name), &image, format, geo.as_ref())?;
        for t in truths {
            truth.push_str(&format!(
                "{name},{},{},{:.4},{:.4},{:.2}\n",
                t.kind, t.id, t.center.0, t.center.1, t.side_px
            ));
        }
    }
    let csv = dir.join("truth.csv");
    std::fs::write(&csv, truth).map_err(Error::io("write", &csv))?;
    Ok(spec.frames)
}
