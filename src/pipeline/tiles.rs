//! The tile grid: square tiles of a fixed size stepping by `size - overlap`,
//! the last row and column pulled back to end flush with the frame, so every
//! target smaller than the overlap lies whole inside at least one tile.

/// Tile geometry for one frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TileGrid {
    pub width: usize,
    pub height: usize,
    /// Left edges of tile columns, ascending.
    pub xs: Vec<usize>,
    /// Top edges of tile rows (strips), ascending.
    pub ys: Vec<usize>,
    pub tile_w: usize,
    pub tile_h: usize,
}

/// Starting offsets covering `len` with windows of `size` overlapping by at
/// least `overlap`.
fn starts(len: usize, size: usize, overlap: usize) -> Vec<usize> {
    if len <= size {
        return vec![0];
    }
    let step = size - overlap;
    let mut out: Vec<usize> = (0..)
        .map(|i| i * step)
        .take_while(|&x| x + size < len)
        .collect();
    out.push(len - size);
    out
}

impl TileGrid {
    /// Plans tiles of `size` px overlapping by `overlap` px (`overlap < size`).
    pub fn new(width: usize, height: usize, size: usize, overlap: usize) -> TileGrid {
        assert!(overlap < size, "tile overlap must be smaller than the tile");
        TileGrid {
            width,
            height,
            xs: starts(width, size, overlap),
            ys: starts(height, size, overlap),
            tile_w: size.min(width),
            tile_h: size.min(height),
        }
    }

    pub fn count(&self) -> usize {
        self.xs.len() * self.ys.len()
    }

    /// Which sides of tile (col, row) are seams shared with another tile
    /// (left, top, right, bottom), rather than frame borders.
    pub fn seams(&self, col: usize, row: usize) -> [bool; 4] {
        [
            col > 0,
            row > 0,
            col + 1 < self.xs.len(),
            row + 1 < self.ys.len(),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_frame_with_overlap() {
        let g = TileGrid::new(6000, 4000, 2048, 256);
        assert_eq!(g.xs, vec![0, 1792, 3584, 3952]);
        assert_eq!(g.ys, vec![0, 1792, 1952]);
        for w in g.xs.windows(2) {
            assert!(w[0] + 2048 >= w[1] + 256, "overlap kept");
        }
        assert_eq!(*g.xs.last().unwrap() + g.tile_w, 6000);
        assert_eq!(g.seams(0, 0), [false, false, true, true]);
        assert_eq!(g.seams(3, 2), [true, true, false, false]);
    }

    #[test]
    fn small_frame_is_one_tile() {
        let g = TileGrid::new(640, 480, 2048, 256);
        assert_eq!(
            (g.xs.clone(), g.ys.clone(), g.tile_w, g.tile_h),
            (vec![0], vec![0], 640, 480)
        );
        assert_eq!(g.count(), 1);
    }
}
