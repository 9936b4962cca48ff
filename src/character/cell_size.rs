//! The default lattice cell size of a character file that does not set `[bind]
//! cell_size_m`: from the skeleton (the shortest bone that carries a marker, so every
//! marked segment spans at least a cell), kept within a window of control-mesh sizes
//! estimated from the mesh's volume and area, so that neither a figure of a few hundred
//! vertices nor a scanned body gets a lattice of tens of thousands of vertices, and a
//! hand's fingers are not one cell thick. The reason is said in `rigless bake`'s summary.

use super::mesh::welded_outward;
use super::skeleton::Skeleton;
use super::MarkerDef;
use glam::DVec3;

/// Fewest and most control vertices a default cell size aims for (the targets: about
/// 500 to 1,000 for a hand, 1,500 to 3,000 for a body).
pub const MIN_CONTROL_VERTICES: f64 = 500.0;
pub const MAX_CONTROL_VERTICES: f64 = 3000.0;
/// Control vertices aimed for when no marker says how fine the lattice must be.
pub const UNMARKED_CONTROL_VERTICES: f64 = 1500.0;
/// Control vertices per cell of the estimate `K (V/c³ + A/c²)`: with it the estimate is
/// within 10 % of the control vertices the MakeHuman body gets (3,622 against 4,000 at
/// 0.036 m cells) and 5 % of the WebXR hand's (3,811 against 4,000 at 6 mm); the mesh
/// with all MakeHuman's overlapping parts counts their area twice and gets fewer.
const NODES_PER_CELL: f64 = 1.6;

/// A default cell size and why it was chosen.
#[derive(Clone, Debug, PartialEq)]
pub struct CellChoice {
    pub cell_size_m: f64,
    /// The control vertices the estimate expects with it.
    pub estimated_control_vertices: f64,
    /// How it was chosen, for the summary.
    pub reason: String,
}

/// The mesh's enclosed volume (its parts oriented outward, m³) and its area (m²).
fn volume_and_area(vertices: &[DVec3], triangles: &[[u32; 3]]) -> (f64, f64) {
    let (unique, oriented, _) = welded_outward(vertices, triangles);
    let (mut volume, mut area) = (0.0, 0.0);
    for t in &oriented {
        let [a, b, c] = t.map(|i| unique[i as usize]);
        volume += a.dot(b.cross(c)) / 6.0;
        area += 0.5 * (b - a).cross(c - a).length();
    }
    (volume.abs(), area)
}

/// The cell size for which the estimate gives `nodes` control vertices (bisection on
/// `log c`; the estimate decreases with `c`).
fn cell_for(nodes: f64, volume: f64, area: f64, size_m: f64) -> f64 {
    let estimate = |c: f64| NODES_PER_CELL * (volume / c.powi(3) + area / c.powi(2));
    let (mut lo, mut hi) = (size_m * 1e-4, size_m);
    for _ in 0..100 {
        let mid = (lo * hi).sqrt();
        if estimate(mid) > nodes {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (lo * hi).sqrt()
}

/// The default cell size of a character (metres, world frame; `size_m` its largest
/// extent).
pub fn default_cell_size(
    vertices: &[DVec3],
    triangles: &[[u32; 3]],
    skeleton: &Skeleton,
    markers: &[MarkerDef],
    size_m: f64,
) -> CellChoice {
    let (volume, area) = volume_and_area(vertices, triangles);
    let estimate = |c: f64| NODES_PER_CELL * (volume / c.powi(3) + area / c.powi(2));
    let finest = cell_for(MAX_CONTROL_VERTICES, volume, area, size_m);
    let coarsest = cell_for(MIN_CONTROL_VERTICES, volume, area, size_m);
    // The shortest segment leaving a joint that carries a marker.
    let shortest = markers
        .iter()
        .filter_map(|m| m.joint)
        .flat_map(|j| {
            let rest = skeleton.joints[j].rest;
            skeleton
                .joints
                .iter()
                .filter(move |c| c.parent == Some(j))
                .map(move |c| ((c.rest - rest).length(), j))
        })
        .filter(|(len, _)| *len > 0.0)
        .min_by(|a, b| a.0.total_cmp(&b.0));
    let (wanted, why) = match shortest {
        Some((len, j)) => (
            len,
            format!(
                "the shortest bone carrying a marker ({}, {len:.3} m)",
                skeleton.joints[j].name
            ),
        ),
        None => (
            cell_for(UNMARKED_CONTROL_VERTICES, volume, area, size_m),
            format!(
                "no marker on a bone: sized for about {UNMARKED_CONTROL_VERTICES} control vertices"
            ),
        ),
    };
    let (cell, reason) = if wanted < finest {
        (
            finest,
            format!("{why}, raised to keep the control mesh near {MAX_CONTROL_VERTICES} vertices at most"),
        )
    } else if wanted > coarsest {
        (
            coarsest,
            format!("{why}, lowered to keep the control mesh near {MIN_CONTROL_VERTICES} vertices at least"),
        )
    } else {
        (wanted, why)
    };
    // Never below what a character file may set (1/400 of the size), whatever the
    // estimate says of a thin or degenerate mesh.
    let (cell, reason) = if cell < size_m / 400.0 {
        (
            size_m / 400.0,
            format!("{reason}; raised to 1/400 of the character's size"),
        )
    } else {
        (cell, reason)
    };
    CellChoice {
        cell_size_m: cell,
        estimated_control_vertices: estimate(cell),
        reason,
    }
}
