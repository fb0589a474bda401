//! Test images for the detectors' unit tests: a grey function rendered to
//! 8-bit pixels, each the mean of 4x4 subsamples (box-filtered edges).

/// A w x w image: each pixel the mean of 4x4 subsamples of `grey`.
pub fn render_image(w: usize, grey: impl Fn(f64, f64) -> f64) -> Vec<u8> {
    let mut data = vec![0u8; w * w];
    for y in 0..w {
        for x in 0..w {
            let mut sum = 0.0;
            for j in 0..4 {
                for i in 0..4 {
                    let (u, v) = (-0.375 + 0.25 * i as f64, -0.375 + 0.25 * j as f64);
                    sum += grey(x as f64 + u, y as f64 + v);
                }
            }
            data[y * w + x] = (sum / 16.0).round() as u8;
        }
    }
    data
}

/// `data` (w x w) blurred by a Gaussian of `sigma` px (OpenCV's): a lens's
/// and a sensor's blur.
pub fn gaussian_blurred(data: &[u8], w: usize, sigma: f64) -> Vec<u8> {
    use opencv::core::{Mat, Size};
    use opencv::prelude::*;
    let src = Mat::from_slice(data)
        .and_then(|m| m.reshape(1, w as i32)?.try_clone())
        .unwrap();
    let mut out = Mat::default();
    opencv::imgproc::gaussian_blur_def(&src, &mut out, Size::new(0, 0), sigma).unwrap();
    out.data_bytes().unwrap().to_vec()
}

/// A cross target: a black square with white bars across it, both in the
/// print's greys, on ground whose grey is a function of the position.
pub struct Cross {
    pub centre: (f64, f64),
    pub side: f64,
    pub bar: f64,
    pub white: f64,
    pub black: f64,
}

impl Cross {
    /// The cross on `ground`, in a w x w image, with the light scaled by
    /// `factor` where `n . (p - centre) < off` (a shadow's straight edge).
    pub fn render(
        &self,
        w: usize,
        ground: impl Fn(f64, f64) -> f64,
        n: (f64, f64),
        off: f64,
        factor: f64,
    ) -> Vec<u8> {
        render_image(w, |x, y| {
            let (dx, dy) = (x - self.centre.0, y - self.centre.1);
            let (half, half_bar) = (self.side / 2.0, self.bar / 2.0);
            let grey = if dx.abs() < half && dy.abs() < half {
                if dx.abs() < half_bar || dy.abs() < half_bar {
                    self.white
                } else {
                    self.black
                }
            } else {
                ground(x, y)
            };
            let lit = n.0 * dx + n.1 * dy - off >= 0.0;
            grey * if lit { 1.0 } else { factor }
        })
    }
}
