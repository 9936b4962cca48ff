//! The default lattice cell size of a character file that does not set `[bind]
//! cell_size_m`: from the skeleton (the shortest bone that carries a marker, so every
//! marked segment spans at least a cell), kept within a window of control-mesh sizes
//! estimated from the mesh's volume and area, so that neither a figure of a few hundred
//! vertices nor a scanned body gets a lattice of tens of thousands of vertices, and a
//! hand's fingers are not one cell thick. The window depends on the figure: a hand's
//! frame must fit in a quarter of a body's time. The reason is said in `rigless bake`'s
//! summary.

use super::mesh::welded_outward;
use super::roles::{Part, Role};
use super::skeleton::Skeleton;
use super::MarkerDef;
use glam::DVec3;

/// What a character is, for the size of its control mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Figure {
    /// Fingers and no legs among its roles: a hand, held to the hand's frame time
    /// (p99 ≤ 1 ms at 120 Hz).
    Hand,
    /// Anything else: a body, or a figure whose names say nothing (p99 ≤ 4 ms).
    Body,
}

impl Figure {
    /// The figure of a skeleton whose joints have `roles`.
    pub fn of(roles: &[Option<Role>]) -> Self {
        let has = |f: fn(Part) -> bool| roles.iter().flatten().any(|r| f(r.part));
        let legs = has(|p| matches!(p, Part::UpperLeg | Part::LowerLeg | Part::Foot));
        if !legs && has(|p| matches!(p, Part::Finger(..))) {
            Figure::Hand
        } else {
            Figure::Body
        }
    }

    /// How the reason names the window: a hand's is said, a body's is the default.
    fn says(self) -> &'static str {
        match self {
            Figure::Hand => " (by the estimate) for a hand",
            Figure::Body => "",
        }
    }

    /// Fewest and most control vertices, by the estimate, that a default cell aims for,
    /// and the count aimed for when no marker says how fine the lattice must be.
    ///
    /// A body: 500 to 3,000 (MakeHuman's body at the ceiling has 2,826 and replays a
    /// real take at p99 2.9–3.8 ms). A hand: 300 to 400. The estimate undercounts a
    /// hand's thin, separately instanced fingers by 1.3–1.5 times, so the WebXR hand
    /// gets 582 control vertices at the ceiling (16 mm cells): DFKI's take replays at
    /// p99 0.9–1.1 ms with 0.3 mm misfit, against 1,084 vertices and p99 1.4–1.8 ms at
    /// the 11.6 mm its shortest marked bone asks for; at the floor (20 mm, 398
    /// vertices) the misfit grows to 0.8 mm.
    pub fn window(self) -> Window {
        match self {
            Figure::Hand => Window {
                min: 300.0,
                max: 400.0,
                unmarked: 400.0,
            },
            Figure::Body => Window {
                min: 500.0,
                max: 3000.0,
                unmarked: 1500.0,
            },
        }
    }
}

/// Control-vertex counts (by the estimate) a default cell size is kept within.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Window {
    pub min: f64,
    pub max: f64,
    /// Aimed for when no marker says how fine the lattice must be.
    pub unmarked: f64,
}
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
    figure: Figure,
    size_m: f64,
) -> CellChoice {
    let (volume, area) = volume_and_area(vertices, triangles);
    let estimate = |c: f64| NODES_PER_CELL * (volume / c.powi(3) + area / c.powi(2));
    let window = figure.window();
    let finest = cell_for(window.max, volume, area, size_m);
    let coarsest = cell_for(window.min, volume, area, size_m);
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
            cell_for(window.unmarked, volume, area, size_m),
            format!(
                "no marker on a bone: sized for about {} control vertices",
                window.unmarked
            ),
        ),
    };
    let (cell, reason) = if wanted < finest {
        (
            finest,
            format!(
                "{why}, raised to keep the control mesh near {} vertices at most{}",
                window.max,
                figure.says()
            ),
        )
    } else if wanted > coarsest {
        (
            coarsest,
            format!(
                "{why}, lowered to keep the control mesh near {} vertices at least{}",
                window.min,
                figure.says()
            ),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::character::roles::{Digit, Segment};
    use crate::character::skeleton::Joint;
    use crate::geom::shapes::uv_sphere;

    fn role(part: Part) -> Option<Role> {
        Some(Role { part, side: None })
    }

    #[test]
    fn fingers_without_legs_make_a_hand() {
        let finger = role(Part::Finger(Digit::Index, Segment::Distal));
        assert_eq!(Figure::of(&[role(Part::Hand), finger]), Figure::Hand);
        // A whole body has fingers too; its legs make it a body.
        assert_eq!(
            Figure::of(&[role(Part::Hips), role(Part::UpperLeg), finger]),
            Figure::Body
        );
        // Names that say nothing: the body's window, the wider one.
        assert_eq!(Figure::of(&[None, None]), Figure::Body);
    }

    /// The same mesh and marked bone get a coarser cell as a hand than as a body, each
    /// within its window: a 10 cm ball (the estimate gives 1,008 control vertices at
    /// 1 cm) with a marker on a 2 mm bone, which asks for more than either ceiling.
    #[test]
    fn a_hand_is_held_to_its_smaller_window() {
        let (v, t) = uv_sphere(DVec3::ZERO, 0.05, 24, 48);
        let joint = |name: &str, parent, y| Joint {
            name: name.into(),
            parent,
            rest: DVec3::new(0.0, y, 0.0),
            limits: None,
            bend_axis: DVec3::X,
        };
        let sk = Skeleton::new(vec![joint("a", None, 0.0), joint("b", Some(0), 0.002)]).unwrap();
        let marker = MarkerDef {
            name: "m".into(),
            rest: DVec3::ZERO,
            joint: Some(0),
        };
        let m = std::slice::from_ref(&marker);
        let hand = default_cell_size(&v, &t, &sk, m, Figure::Hand, 0.1);
        let body = default_cell_size(&v, &t, &sk, m, Figure::Body, 0.1);
        // The bisection ends within 1e-9 of the ceiling's count; 0.5 is rounding room.
        assert!(
            (hand.estimated_control_vertices - 400.0).abs() < 0.5,
            "{hand:?}"
        );
        assert!(
            (body.estimated_control_vertices - 3000.0).abs() < 0.5,
            "{body:?}"
        );
        assert!(
            hand.cell_size_m > 1.5 * body.cell_size_m,
            "{hand:?} {body:?}"
        );
        assert!(hand.reason.contains("for a hand"), "{hand:?}");
    }
}
