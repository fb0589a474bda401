//! Scene rendering on a float grey canvas (0 = black, 1 = white).

use super::canvas::{bbox_of, paint, paint_over, square_corners, Canvas, Truth};
use super::canvas::{PAPER_BLACK, PAPER_WHITE};
use super::geometry::{mean_side, Homography, Pt};
use super::printed::Lookalike;
use super::tags::{marker_cells, TargetKind};
use super::Error;

use super::printed::{self, PrintedSpec};
use super::Rng;

/// A grey image, row-major, values in [0, 1].
#[derive(Debug, Clone)]
pub struct GreyImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl GreyImage {
    /// The `width` x `height` window whose top left corner is (`x0`, `y0`):
    /// a scene's neighbourhood of one object, for a test.
    pub fn window(&self, x0: usize, y0: usize, width: usize, height: usize) -> GreyImage {
        GreyImage {
            width,
            height,
            data: (y0..y0 + height)
                .flat_map(|y| self.data[y * self.width + x0..][..width].iter().copied())
                .collect(),
        }
    }
}

/// One marker to place.
#[derive(Debug, Clone)]
pub struct MarkerSpec {
    pub kind: TargetKind,
    /// AprilTag family or ArUco dictionary name.
    pub dictionary: String,
    pub id: u32,
    /// Centre in pixels (before perspective jitter of the corners).
    pub center: Pt,
    /// Side of the black outer border, in pixels.
    pub side_px: f64,
    pub rotation_deg: f64,
    /// Corners are moved by up to this fraction of the side: mild perspective.
    pub perspective: f64,
}

/// Look-alike objects that are not targets.
#[derive(Debug, Clone, Copy, Default)]
pub struct Clutter {
    /// Dark squares with light insides and light squares (windows, panels).
    pub squares: usize,
    /// Discs and rings (manholes, tanks).
    pub circles: usize,
    /// Long bright bars (road markings).
    pub stripes: usize,
    /// Look-alikes of printed targets: solar-panel grids, paving checkers,
    /// road-marking crosses, manholes with rims, pyramid roofs, tanks on
    /// roofs, cars (see `printed::lookalike`).
    pub lookalikes: usize,
}

/// A frame to render.
#[derive(Debug, Clone)]
pub struct Scene {
    pub width: usize,
    pub height: usize,
    pub seed: u64,
    /// Gaussian blur applied to the whole frame, in pixels.
    pub blur_sigma: f64,
    /// Gaussian noise, in 8-bit grey levels.
    pub noise_sigma: f64,
    /// Left-to-right brightness ramp: multiplies by 1-g/2 .. 1+g/2.
    pub gradient: f64,
    /// Shadow bands (intensity x 0.55) crossing the frame.
    pub shadows: usize,
    pub clutter: Clutter,
    pub markers: Vec<MarkerSpec>,
    /// Printed targets without a code (crosshair, checker, circles).
    pub printed: Vec<PrintedSpec>,
    /// Linear motion blur: length in pixels (0 = none) and direction in degrees.
    pub motion_blur: (f64, f64),
    /// Share of the coded markers crossed by a hard-edged shadow (a pole's
    /// or a branch's: a band through the tag, see `shadow_across`).
    pub tag_shadows: f64,
}

/// Renders `scene`; returns the image and the markers' truth.
pub fn render(scene: &Scene) -> Result<(GreyImage, Vec<Truth>), Error> {
    render_with_lookalikes(scene).map(|(img, truths, _)| (img, truths))
}

/// [`render`], and the look-alikes painted (tests that no detection comes
/// from a look-alike first check that it is in the frame).
pub fn render_with_lookalikes(
    scene: &Scene,
) -> Result<(GreyImage, Vec<Truth>, Vec<Lookalike>), Error> {
    render_window(scene, 0, 0, scene.width, scene.height)
}

/// The `width` x `height` window of `scene` from (`x0`, `y0`), exactly as
/// in the whole frame's render but drawn on the window and a margin only;
/// the truths and look-alikes of the whole frame, in frame pixels.
pub fn render_window(
    scene: &Scene,
    x0: usize,
    y0: usize,
    width: usize,
    height: usize,
) -> Result<(GreyImage, Vec<Truth>, Vec<Lookalike>), Error> {
    assert!(
        x0 + width <= scene.width && y0 + height <= scene.height,
        "window outside the frame"
    );
    // The filters' reach: the Gaussian's radius, the motion blur's half
    // length and its bilinear neighbour, each side, with a pixel to spare.
    let margin = blur_radius(scene.blur_sigma).max(0) as usize
        + (scene.motion_blur.0 / 2.0).ceil() as usize
        + 3;
    let (rx0, ry0) = (x0.saturating_sub(margin), y0.saturating_sub(margin));
    let (rx1, ry1) = (
        (x0 + width + margin).min(scene.width),
        (y0 + height + margin).min(scene.height),
    );
    let mut img = Canvas {
        frame: (scene.width, scene.height),
        x0: rx0,
        y0: ry0,
        width: rx1 - rx0,
        height: ry1 - ry0,
        data: vec![0.0; (rx1 - rx0) * (ry1 - ry0)],
    };
    let (truths, lookalikes) = draw(scene, &mut img)?;
    let region = GreyImage {
        width: img.width,
        height: img.height,
        data: img.data,
    };
    // The whole frame (no margin to cut) is returned as drawn, not copied.
    let image = if (rx0, ry0, region.width, region.height) == (x0, y0, width, height) {
        region
    } else {
        region.window(x0 - rx0, y0 - ry0, width, height)
    };
    Ok((image, truths, lookalikes))
}

/// Draws `scene` on `img`'s region.
fn draw(scene: &Scene, img: &mut Canvas) -> Result<(Vec<Truth>, Vec<Lookalike>), Error> {
    let mut rng = Rng::new(scene.seed);
    ground_texture(img, &mut rng);
    let mut lookalikes = Vec::new();
    clutter(img, &scene.clutter, &mut rng, &mut lookalikes);
    let mut truths = Vec::with_capacity(scene.markers.len());
    for spec in &scene.markers {
        truths.push(place_marker(img, spec, &mut rng)?);
    }
    if scene.tag_shadows > 0.0 {
        for t in &truths {
            if rng.uniform() < scene.tag_shadows {
                shadow_across(img, t.center, t.side_px, &mut rng);
            }
        }
    }
    for (i, spec) in scene.printed.iter().enumerate() {
        truths.push(printed::place(img, spec, i as u32, &mut rng));
    }
    for _ in 0..scene.shadows {
        shadow(img, &mut rng);
    }
    if scene.gradient != 0.0 {
        let w = scene.width as f64;
        for (i, v) in img.data.iter_mut().enumerate() {
            let x = (img.x0 + i % img.width) as f64;
            *v *= (1.0 - scene.gradient / 2.0 + scene.gradient * x / w) as f32;
        }
    }
    if scene.blur_sigma > 0.0 {
        gaussian_blur(img, scene.blur_sigma);
    }
    if scene.motion_blur.0 > 0.0 {
        motion_blur(img, scene.motion_blur.0, scene.motion_blur.1);
    }
    if scene.noise_sigma > 0.0 {
        // One normal deviate per frame pixel in raster order, each two
        // draws: the region's rows jump to their place in that sequence.
        let s = (scene.noise_sigma / 255.0) as f32;
        for (row, y) in img.ys().enumerate() {
            let mut r = rng.clone();
            r.skip(2 * (y * scene.width + img.x0) as u64);
            for v in &mut img.data[row * img.width..][..img.width] {
                *v += s * r.normal() as f32;
            }
        }
    }
    for v in img.data.iter_mut() {
        *v = v.clamp(0.0, 1.0);
    }
    Ok((truths, lookalikes))
}

/// Soil and grass: two octaves of value noise plus grain.
fn ground_texture(img: &mut Canvas, rng: &mut Rng) {
    let (w, h) = img.frame;
    let coarse = ValueNoise::new(w, h, 96.0, rng);
    let fine = ValueNoise::new(w, h, 7.0, rng);
    for y in img.ys() {
        for x in img.xs() {
            let v = 0.40 + 0.22 * (coarse.at(x, y) - 0.5) + 0.12 * (fine.at(x, y) - 0.5);
            *img.px(x, y) = v as f32;
        }
    }
}

/// Random values on a grid, bilinearly interpolated.
struct ValueNoise {
    cols: usize,
    cell: f64,
    values: Vec<f64>,
}

impl ValueNoise {
    fn new(w: usize, h: usize, cell: f64, rng: &mut Rng) -> ValueNoise {
        let cols = (w as f64 / cell) as usize + 2;
        let rows = (h as f64 / cell) as usize + 2;
        ValueNoise {
            cols,
            cell,
            values: (0..cols * rows).map(|_| rng.uniform()).collect(),
        }
    }
    fn at(&self, x: usize, y: usize) -> f64 {
        let (fx, fy) = (x as f64 / self.cell, y as f64 / self.cell);
        let (ix, iy) = (fx as usize, fy as usize);
        let (tx, ty) = (fx - ix as f64, fy - iy as f64);
        let v = |c: usize, r: usize| self.values[r * self.cols + c];
        let top = v(ix, iy) * (1.0 - tx) + v(ix + 1, iy) * tx;
        let bottom = v(ix, iy + 1) * (1.0 - tx) + v(ix + 1, iy + 1) * tx;
        top * (1.0 - ty) + bottom * ty
    }
}

/// The marker's outer-border corners for its centre, size, rotation and
/// perspective jitter.
fn marker_corners(spec: &MarkerSpec, rng: &mut Rng) -> [Pt; 4] {
    square_corners(
        spec.center,
        spec.side_px,
        spec.rotation_deg,
        spec.perspective,
        rng,
    )
}

/// Renders a marker with a one-cell white quiet zone, as printed targets have.
fn place_marker(img: &mut Canvas, spec: &MarkerSpec, rng: &mut Rng) -> Result<Truth, Error> {
    let bits = marker_cells(spec.kind, &spec.dictionary, spec.id)?;
    let n = bits.len();
    let corners = marker_corners(spec, rng);
    let h = Homography::from_unit_square(&corners);
    let inv = h.inverse();
    let q = 1.0 / n as f64;
    let outer = [(-q, -q), (1.0 + q, -q), (1.0 + q, 1.0 + q), (-q, 1.0 + q)].map(|p| h.apply(p));
    paint(img, bbox_of(&outer), |x, y| {
        let (u, v) = inv.apply((x, y));
        if !(-q..1.0 + q).contains(&u) || !(-q..1.0 + q).contains(&v) {
            return None;
        }
        if !(0.0..1.0).contains(&u) || !(0.0..1.0).contains(&v) {
            return Some(PAPER_WHITE);
        }
        let (col, row) = ((u * n as f64) as usize, (v * n as f64) as usize);
        Some(if bits[row.min(n - 1)][col.min(n - 1)] {
            PAPER_WHITE
        } else {
            PAPER_BLACK
        })
    });
    Ok(Truth {
        kind: spec.kind,
        id: spec.id,
        center: h.apply((0.5, 0.5)),
        corners,
        side_px: mean_side(&corners),
    })
}

fn clutter(img: &mut Canvas, clutter: &Clutter, rng: &mut Rng, lookalikes: &mut Vec<Lookalike>) {
    let (w, h) = (img.frame.0 as f64, img.frame.1 as f64);
    for _ in 0..clutter.squares {
        let side = rng.range(20.0, 90.0);
        let c = (rng.range(0.0, w), rng.range(0.0, h));
        let angle = rng.range(0.0, std::f64::consts::PI);
        let (dark, light) = if rng.uniform() < 0.5 {
            (0.08f32, 0.85f32)
        } else {
            (0.85, 0.15)
        };
        let inner = rng.range(0.3, 0.7);
        let (s, co) = angle.sin_cos();
        let r = side * 0.75;
        paint(img, (c.0 - r, c.1 - r, c.0 + r, c.1 + r), |x, y| {
            let (dx, dy) = (x - c.0, y - c.1);
            let (u, v) = ((co * dx + s * dy) / side, (-s * dx + co * dy) / side);
            if u.abs() > 0.5 || v.abs() > 0.5 {
                None
            } else if u.abs() < inner / 2.0 && v.abs() < inner / 2.0 {
                Some(light)
            } else {
                Some(dark)
            }
        });
    }
    for _ in 0..clutter.circles {
        let radius = rng.range(10.0, 45.0);
        let c = (rng.range(0.0, w), rng.range(0.0, h));
        let ring = rng.uniform() < 0.5;
        let (a, b) = if rng.uniform() < 0.5 {
            (0.1f32, 0.9f32)
        } else {
            (0.9, 0.1)
        };
        paint(
            img,
            (c.0 - radius, c.1 - radius, c.0 + radius, c.1 + radius),
            |x, y| {
                let d = (x - c.0).hypot(y - c.1) / radius;
                if d > 1.0 {
                    None
                } else if ring && d < 0.5 {
                    Some(b)
                } else {
                    Some(a)
                }
            },
        );
    }
    for _ in 0..clutter.lookalikes {
        lookalikes.push(printed::lookalike(img, rng));
    }
    for _ in 0..clutter.stripes {
        let (len, width) = (rng.range(150.0, 600.0), rng.range(8.0, 20.0));
        let c = (rng.range(0.0, w), rng.range(0.0, h));
        let (s, co) = rng.range(0.0, std::f64::consts::PI).sin_cos();
        let r = len / 2.0 + width;
        paint(img, (c.0 - r, c.1 - r, c.0 + r, c.1 + r), |x, y| {
            let (dx, dy) = (x - c.0, y - c.1);
            let (u, v) = (co * dx + s * dy, -s * dx + co * dy);
            (u.abs() <= len / 2.0 && v.abs() <= width / 2.0).then_some(0.88)
        });
    }
}

/// A straight-edged shadow band across the frame.
fn shadow(img: &mut Canvas, rng: &mut Rng) {
    let (w, h) = (img.frame.0 as f64, img.frame.1 as f64);
    let c = (rng.range(0.0, w), rng.range(0.0, h));
    let (s, co) = rng.range(0.0, std::f64::consts::PI).sin_cos();
    let half = rng.range(40.0, 300.0);
    for y in img.ys() {
        for x in img.xs() {
            let d = -s * (x as f64 - c.0) + co * (y as f64 - c.1);
            // Penumbra of one pixel: coverage of the band edge.
            let cover = (half + 0.5 - d.abs()).clamp(0.0, 1.0) as f32;
            if cover > 0.0 {
                *img.px(x, y) *= 1.0 - 0.45 * cover;
            }
        }
    }
}

/// A shadow band with hard edges across a tag: through a point within a
/// quarter side of its centre, a third to two sides wide, darkening to
/// 40-60%, ending three sides from the tag.
fn shadow_across(img: &mut Canvas, centre: Pt, side: f64, rng: &mut Rng) {
    let through = (
        centre.0 + rng.range(-0.25, 0.25) * side,
        centre.1 + rng.range(-0.25, 0.25) * side,
    );
    let (s, c) = rng.range(0.0, std::f64::consts::PI).sin_cos();
    let half = rng.range(0.17, 1.0) * side;
    let keep = rng.range(0.4, 0.6) as f32;
    let reach = 3.0 * side;
    paint_over(img, centre, reach, |x, y| {
        let d = -s * (x - through.0) + c * (y - through.1);
        // Penumbra of one pixel, as the band edge's coverage.
        let cover = (half + 0.5 - d.abs()).clamp(0.0, 1.0) as f32;
        1.0 - (1.0 - keep) * cover
    });
}

/// The Gaussian's radius in pixels.
fn blur_radius(sigma: f64) -> i64 {
    (3.0 * sigma).ceil() as i64
}

/// Separable Gaussian blur of the region, its edges clamped.
fn gaussian_blur(img: &mut Canvas, sigma: f64) {
    let radius = blur_radius(sigma);
    let kernel: Vec<f32> = (-radius..=radius)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let norm: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / norm).collect();
    let (w, h) = (img.width as i64, img.height as i64);
    let mut tmp = vec![0f32; img.data.len()];
    for y in 0..h {
        let row = &img.data[(y * w) as usize..((y + 1) * w) as usize];
        for x in 0..w {
            let mut acc = 0.0;
            for (k, kv) in kernel.iter().enumerate() {
                let xx = (x + k as i64 - radius).clamp(0, w - 1);
                acc += kv * row[xx as usize];
            }
            tmp[(y * w + x) as usize] = acc;
        }
    }
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0.0;
            for (k, kv) in kernel.iter().enumerate() {
                let yy = (y + k as i64 - radius).clamp(0, h - 1);
                acc += kv * tmp[(yy * w + x) as usize];
            }
            img.data[(y * w + x) as usize] = acc;
        }
    }
}

/// Linear motion blur: the mean of `length` px of positions along `angle_deg`
/// (bilinear), a symmetric kernel like a camera moving during exposure.
fn motion_blur(img: &mut Canvas, length: f64, angle_deg: f64) {
    let (s, c) = angle_deg.to_radians().sin_cos();
    let n = (length.ceil() as usize).max(1) * 2 + 1;
    let offsets: Vec<Pt> = (0..n)
        .map(|k| {
            let t = -length / 2.0 + length * k as f64 / (n - 1) as f64;
            (c * t, s * t)
        })
        .collect();
    let (w, h) = (img.width, img.height);
    let src = img.data.clone();
    let at = |x: f64, y: f64| -> f32 {
        let x = x.clamp(0.0, (w - 1) as f64);
        let y = y.clamp(0.0, (h - 1) as f64);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let top = src[y0 * w + x0] * (1.0 - fx) + src[y0 * w + x1] * fx;
        let bottom = src[y1 * w + x0] * (1.0 - fx) + src[y1 * w + x1] * fx;
        top * (1.0 - fy) + bottom * fy
    };
    for y in 0..h {
        for x in 0..w {
            let sum: f32 = offsets
                .iter()
                .map(|o| at(x as f64 + o.0, y as f64 + o.1))
                .sum();
            img.data[y * w + x] = sum / n as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{clutter_scene, printed_scene, random_scene, TargetKind};

    /// A window drawn alone equals the same window of the whole frame, bit
    /// for bit: inside, at the frame's edges and corners, with motion blur.
    #[test]
    fn a_window_is_the_whole_frames_window() {
        let mut moving = printed_scene(900, 700, 6, TargetKind::Crosshair, (40.0, 90.0), 5);
        moving.motion_blur = (2.5, 30.0);
        let scenes = [
            clutter_scene(900, 700, 1407),
            random_scene(900, 700, 5, 3),
            printed_scene(900, 700, 6, TargetKind::Circle, (40.0, 90.0), 4),
            moving,
        ];
        for scene in &scenes {
            let (whole, truths, lookalikes) = render_with_lookalikes(scene).unwrap();
            for (x0, y0, w, h) in [(0, 0, 200, 150), (350, 260, 240, 200), (640, 500, 260, 200)] {
                let (part, t, l) = render_window(scene, x0, y0, w, h).unwrap();
                let expected = whole.window(x0, y0, w, h);
                let same = part
                    .data
                    .iter()
                    .zip(&expected.data)
                    .all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "scene {}: window at {x0},{y0} differs", scene.seed);
                assert_eq!(t, truths);
                assert_eq!(l, lookalikes);
            }
        }
    }
}
