//! The lattice's geometry: a regular grid of cubic cells and the Kuhn split of a cube into
//! six tetrahedra (Freudenthal/Kuhn split along the main diagonal, identical in every
//! cell, so neighbouring cells share faces exactly). Used by the binding's control mesh
//! and by the marching tetrahedra that mesh the procedural characters.

use glam::DVec3;

/// A regular grid: `dims` cells of edge `cell_size` from `origin`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    pub origin: DVec3,
    pub cell_size: f64,
    pub dims: [usize; 3],
}

impl Grid {
    /// A grid covering `lo..hi` with `pad` empty cells on each side.
    pub fn covering(lo: DVec3, hi: DVec3, cell_size: f64, pad: usize) -> Self {
        let origin = lo - DVec3::splat(cell_size * pad as f64);
        let ext = hi - origin;
        let dims = [0, 1, 2].map(|a| (ext[a] / cell_size).floor() as usize + 1 + pad);
        Self {
            origin,
            cell_size,
            dims,
        }
    }
    pub fn n_cells(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }
    #[inline]
    pub fn cell_index(&self, c: [usize; 3]) -> usize {
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }
    /// The cell holding `p` (clamped to the grid).
    #[inline]
    pub fn cell_of(&self, p: DVec3) -> [usize; 3] {
        let q = (p - self.origin) / self.cell_size;
        [0, 1, 2].map(|a| (q[a].floor().max(0.0) as usize).min(self.dims[a] - 1))
    }
    #[inline]
    pub fn node_index(&self, c: [usize; 3]) -> usize {
        c[0] + (self.dims[0] + 1) * (c[1] + (self.dims[1] + 1) * c[2])
    }
    #[inline]
    pub fn node_position(&self, c: [usize; 3]) -> DVec3 {
        self.origin + DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * self.cell_size
    }
}

/// The six Kuhn tets of a unit cube, as corner bit masks (bit 0 = +x, 1 = +y, 2 = +z):
/// one tet per axis order of the path from corner 0 to corner 7.
pub const KUHN: [[usize; 4]; 6] = [
    [0, 1, 3, 7],
    [0, 1, 5, 7],
    [0, 2, 3, 7],
    [0, 2, 6, 7],
    [0, 4, 5, 7],
    [0, 4, 6, 7],
];
