//! Lattice control meshes: the cells of a regular grid that touch or lie inside a
//! triangle mesh (closed, or open and made of many parts: inside is decided by the
//! generalized winding number), each split into six tetrahedra (Freudenthal/Kuhn split along the
//! main diagonal, identical in every cell, so neighbouring cells share faces exactly).
//!
//! Why a lattice and not a Delaunay mesh of the cage: every tet is a Kuhn simplex
//! (dihedral angles 45°, 60° and 90° only), so no cotangent weight is ever negative and
//! the solver can never be pushed into inverting tets by slivers; building it is linear
//! in the number of cells (milliseconds), and the boundary of the kept cells is a closed
//! cage that encloses every mesh vertex by construction (each vertex lies in a kept cell).
//! Markers and skeleton samples are bound to it as barycentric rows of the tet holding
//! them.

use super::tetmesh::{TetMesh, TetMeshError};
use crate::geom::lattice::{Grid, KUHN};
use crate::geom::winding::WindingNumber;
use glam::DVec3;
use std::collections::VecDeque;

/// Points on every triangle at most half a cell apart (the vertices themselves included,
/// exactly), passed to `visit`.
pub fn sample_surface(
    cell_size: f64,
    vertices: &[DVec3],
    triangles: &[[u32; 3]],
    mut visit: impl FnMut(DVec3),
) {
    for t in triangles {
        let [a, b, c] = t.map(|i| vertices[i as usize]);
        let longest = (b - a).length().max((c - b).length()).max((a - c).length());
        let steps = ((longest / (0.5 * cell_size)).ceil() as usize).max(1);
        for i in 0..=steps {
            for j in 0..=steps - i {
                let (u, v) = (i as f64 / steps as f64, j as f64 / steps as f64);
                visit(a + (b - a) * u + (c - a) * v);
            }
        }
    }
}

/// How many points [`sample_surface`] visits at `cell_size` (in `f64`, so a count that
/// would overflow an integer is still a number to compare with a limit).
pub fn surface_samples(cell_size: f64, vertices: &[DVec3], triangles: &[[u32; 3]]) -> f64 {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| vertices[i as usize]);
            let longest = (b - a).length().max((c - b).length()).max((a - c).length());
            let steps = (longest / (0.5 * cell_size)).ceil().max(1.0);
            (steps + 1.0) * (steps + 2.0) / 2.0
        })
        .sum()
}

/// Marks the cells touched by the surface (triangles sampled at most half a cell apart)
/// and the cells enclosed by it (everything the outside flood fill does not reach).
pub fn cells_of_closed_surface(
    grid: &Grid,
    vertices: &[DVec3],
    triangles: &[[u32; 3]],
) -> Vec<bool> {
    enclosed_or(grid, &surface_cells(grid, vertices, triangles))
}

/// Cells touched by the surface.
pub fn surface_cells(grid: &Grid, vertices: &[DVec3], triangles: &[[u32; 3]]) -> Vec<bool> {
    let mut surface = vec![false; grid.n_cells()];
    sample_surface(grid.cell_size, vertices, triangles, |p| {
        surface[grid.cell_index(grid.cell_of(p))] = true
    });
    surface
}

/// `surface` plus every cell the outside flood fill (from the grid's boundary) cannot reach.
pub fn enclosed_or(grid: &Grid, surface: &[bool]) -> Vec<bool> {
    // Flood the outside from every boundary cell of the grid (the grid is padded).
    let mut outside = vec![false; grid.n_cells()];
    let mut queue = VecDeque::new();
    let [nx, ny, nz] = grid.dims;
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                if x == 0 || y == 0 || z == 0 || x == nx - 1 || y == ny - 1 || z == nz - 1 {
                    let k = grid.cell_index([x, y, z]);
                    if !surface[k] && !outside[k] {
                        outside[k] = true;
                        queue.push_back([x, y, z]);
                    }
                }
            }
        }
    }
    while let Some(c) = queue.pop_front() {
        for (axis, delta) in [(0, -1i64), (0, 1), (1, -1), (1, 1), (2, -1), (2, 1)] {
            let v = c[axis] as i64 + delta;
            if v < 0 || v >= grid.dims[axis] as i64 {
                continue;
            }
            let mut nb = c;
            nb[axis] = v as usize;
            let k = grid.cell_index(nb);
            if !surface[k] && !outside[k] {
                outside[k] = true;
                queue.push_back(nb);
            }
        }
    }
    outside.iter().map(|o| !o).collect()
}

/// `surface` plus every cell it encloses: those the outside flood fill cannot reach, and
/// (given a `winding` number) those whose centre has a generalized winding number
/// `|w| ≥ 1/2` (see [`crate::geom::winding`]), so that a body whose surface is open
/// (open eyes, a shirt over it, a missing triangle) still gets a solid interior. For a
/// closed surface the two agree; the union only adds what the flood fill leaked out of.
pub fn solid_or(grid: &Grid, surface: &[bool], winding: Option<&WindingNumber>) -> Vec<bool> {
    let mut keep = enclosed_or(grid, surface);
    let Some(winding) = winding else {
        return keep;
    };
    let [nx, ny, nz] = grid.dims;
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let k = grid.cell_index([x, y, z]);
                if !keep[k] {
                    let centre = grid.node_position([x, y, z]) + DVec3::splat(0.5 * grid.cell_size);
                    keep[k] = winding.at(centre).abs() >= 0.5;
                }
            }
        }
    }
    keep
}

/// A lattice tet mesh plus, for each of its tets, the grid cell it came from.
pub struct LatticeMesh {
    pub mesh: TetMesh,
    pub grid: Grid,
    /// For each grid cell, the index of its first tet (six consecutive), or `u32::MAX`.
    pub cell_first_tet: Vec<u32>,
}

impl LatticeMesh {
    /// Tets the cell holding `p` contributes, if that cell is kept.
    pub fn tets_near(&self, p: DVec3) -> Option<std::ops::Range<usize>> {
        let c = self.grid.cell_of(p);
        let first = self.cell_first_tet[self.grid.cell_index(c)];
        (first != u32::MAX).then(|| first as usize..first as usize + 6)
    }
}

/// Tetrahedralizes the kept cells of `grid` (six Kuhn tets each), numbering only the grid
/// nodes in use.
pub fn tetrahedralize(grid: &Grid, keep: &[bool]) -> Result<LatticeMesh, TetMeshError> {
    let mut node_id = vec![u32::MAX; (grid.dims[0] + 1) * (grid.dims[1] + 1) * (grid.dims[2] + 1)];
    let mut positions = Vec::new();
    let mut tets = Vec::new();
    let mut cell_first_tet = vec![u32::MAX; grid.n_cells()];
    for z in 0..grid.dims[2] {
        for y in 0..grid.dims[1] {
            for x in 0..grid.dims[0] {
                let k = grid.cell_index([x, y, z]);
                if !keep[k] {
                    continue;
                }
                let corner =
                    |bits: usize| [x + (bits & 1), y + ((bits >> 1) & 1), z + ((bits >> 2) & 1)];
                let mut ids = [0u32; 8];
                for (bits, id) in ids.iter_mut().enumerate() {
                    let c = corner(bits);
                    let ni = grid.node_index(c);
                    if node_id[ni] == u32::MAX {
                        node_id[ni] = positions.len() as u32;
                        positions.push(grid.node_position(c));
                    }
                    *id = node_id[ni];
                }
                cell_first_tet[k] = tets.len() as u32;
                for kt in KUHN {
                    tets.push(kt.map(|b| ids[b]));
                }
            }
        }
    }
    Ok(LatticeMesh {
        mesh: TetMesh::new(positions, tets)?,
        grid: *grid,
        cell_first_tet,
    })
}

/// A box of `n` cells per axis (for tests and examples).
pub fn box_lattice(lo: DVec3, hi: DVec3, cells: [usize; 3]) -> LatticeMesh {
    let ext = hi - lo;
    let cell_size = (ext.x / cells[0] as f64)
        .max(ext.y / cells[1] as f64)
        .max(ext.z / cells[2] as f64);
    let grid = Grid {
        origin: lo,
        cell_size,
        dims: cells,
    };
    tetrahedralize(&grid, &vec![true; grid.n_cells()]).expect("box lattice is valid")
}

/// Barycentric coordinates of `p` in tet `x` (they sum to one; all non-negative inside).
pub fn barycentric(x: [DVec3; 4], p: DVec3) -> [f64; 4] {
    use super::tetmesh::signed_volume6;
    let v = signed_volume6(x[0], x[1], x[2], x[3]);
    let b1 = signed_volume6(x[0], p, x[2], x[3]) / v;
    let b2 = signed_volume6(x[0], x[1], p, x[3]) / v;
    let b3 = signed_volume6(x[0], x[1], x[2], p) / v;
    [1.0 - b1 - b2 - b3, b1, b2, b3]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kuhn_split_fills_box_without_slivers() {
        let lm = box_lattice(DVec3::ZERO, DVec3::new(2.0, 1.0, 1.0), [4, 2, 2]);
        assert_eq!(lm.mesh.tets.len(), 16 * 6);
        assert_eq!(lm.mesh.positions.len(), 5 * 3 * 3);
        let vol = lm.mesh.volume(&lm.mesh.positions);
        assert!((vol - 2.0).abs() < 1e-12, "volume {vol}");
        let (lo, hi) = lm.mesh.dihedral_range_deg();
        assert!(lo > 44.9 && hi < 90.1, "dihedral range {lo}..{hi}");
    }

    #[test]
    fn barycentric_reproduces_point() {
        let x = [DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::Z];
        let p = DVec3::new(0.1, 0.2, 0.3);
        let b = barycentric(x, p);
        let q: DVec3 = (0..4).map(|k| x[k] * b[k]).sum();
        assert!((q - p).length() < 1e-15);
        assert!((b.iter().sum::<f64>() - 1.0).abs() < 1e-15);
    }
}
