//! The generator's own plane geometry: points and the homography that maps
//! a target's unit square onto its corners in the frame. Written apart from
//! the detector's, so that the truth never shares code with what it checks.

/// A point in pixels (x right, y down).
pub type Pt = (f64, f64);

pub fn dist(a: Pt, b: Pt) -> f64 {
    (a.0 - b.0).hypot(a.1 - b.1)
}

/// Mean side length of a quadrilateral.
pub fn mean_side(c: &[Pt; 4]) -> f64 {
    (0..4).map(|i| dist(c[i], c[(i + 1) % 4])).sum::<f64>() / 4.0
}

/// A plane projective map, row-major 3x3.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Homography([f64; 9]);

impl Homography {
    /// The map taking the unit square's corners (0,0), (1,0), (1,1), (0,1)
    /// onto `corners`: the eight unknowns (the last entry fixed at 1) from
    /// the eight equations of the four correspondences, solved by Gaussian
    /// elimination with partial pivoting.
    pub fn from_unit_square(corners: &[Pt; 4]) -> Homography {
        const SQUARE: [Pt; 4] = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
        let mut a = [[0.0f64; 9]; 8];
        for (i, (&(u, v), &(x, y))) in SQUARE.iter().zip(corners).enumerate() {
            a[2 * i] = [u, v, 1.0, 0.0, 0.0, 0.0, -u * x, -v * x, x];
            a[2 * i + 1] = [0.0, 0.0, 0.0, u, v, 1.0, -u * y, -v * y, y];
        }
        for col in 0..8 {
            let pivot = (col..8)
                .max_by(|&p, &q| a[p][col].abs().total_cmp(&a[q][col].abs()))
                .expect("rows left");
            a.swap(col, pivot);
            let p = a[col][col];
            assert!(p.abs() > 1e-12, "degenerate target corners {corners:?}");
            let pivot_row = a[col];
            for (r, row) in a.iter_mut().enumerate() {
                if r != col {
                    let f = row[col] / p;
                    for (v, pv) in row[col..].iter_mut().zip(&pivot_row[col..]) {
                        *v -= f * pv;
                    }
                }
            }
        }
        let mut h = [1.0; 9];
        for (i, row) in a.iter().enumerate() {
            h[i] = row[8] / row[i];
        }
        Homography(h)
    }

    /// The inverse map (the adjugate over the determinant).
    pub fn inverse(&self) -> Homography {
        let m = &self.0;
        let cof = |r0: usize, r1: usize, c0: usize, c1: usize| {
            m[3 * r0 + c0] * m[3 * r1 + c1] - m[3 * r0 + c1] * m[3 * r1 + c0]
        };
        // adj[i][j] = cofactor of m[j][i].
        let adj = [
            cof(1, 2, 1, 2),
            -cof(0, 2, 1, 2),
            cof(0, 1, 1, 2),
            -cof(1, 2, 0, 2),
            cof(0, 2, 0, 2),
            -cof(0, 1, 0, 2),
            cof(1, 2, 0, 1),
            -cof(0, 2, 0, 1),
            cof(0, 1, 0, 1),
        ];
        let det = m[0] * adj[0] + m[1] * adj[3] + m[2] * adj[6];
        assert!(
            det.abs() > 1e-300,
            "a target's homography is never singular"
        );
        Homography(adj.map(|v| v / det))
    }

    pub fn apply(&self, p: Pt) -> Pt {
        let h = &self.0;
        let w = h[6] * p.0 + h[7] * p.1 + h[8];
        (
            (h[0] * p.0 + h[1] * p.1 + h[2]) / w,
            (h[3] * p.0 + h[4] * p.1 + h[5]) / w,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_unit_square_lands_on_the_corners_and_back() {
        let corners = [(10.0, 20.0), (52.0, 18.5), (55.5, 61.0), (8.0, 58.0)];
        let h = Homography::from_unit_square(&corners);
        let inv = h.inverse();
        for (s, c) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
            .iter()
            .zip(corners)
        {
            let p = h.apply(*s);
            assert!(dist(p, c) < 1e-9, "{s:?} -> {p:?}, expected {c:?}");
            assert!(dist(inv.apply(c), *s) < 1e-12);
        }
    }
}
