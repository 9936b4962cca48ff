//! What every sink knows of the character before the first frame: its name, the solver's
//! rate, the mesh's triangles, the marker and joint names, the skeleton's tree, the rest
//! volume, the control mesh's edges and the harmonic method's correspondences. Built once
//! per stage from the bound rig; the vertex stream sends it as its topology message and
//! the Rerun sink logs it as static data.

use crate::protocol::vertex_stream::{Topology, WirePart};
use crate::rig::bind::Rig;

/// The parts of a character that do not change per frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// Character name.
    pub character: String,
    /// Frames per second of the solver thread, Hz.
    pub rate_hz: f64,
    /// Full-resolution vertex count (the character file's own order and count).
    pub vertex_count: usize,
    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// Marker names, in the order of every frame's marker arrays.
    pub marker_names: Vec<String>,
    /// Joint names.
    pub joint_names: Vec<String>,
    /// Parent of each joint (`None`: root).
    pub joint_parents: Vec<Option<usize>>,
    /// Volume enclosed by the mesh at rest, m³ (0: not known).
    pub rest_volume_m3: f64,
    /// The control mesh's edges (vertex pairs, each once), for its wireframe.
    pub control_edges: Vec<[u32; 2]>,
    /// The harmonic method's correspondences, `(vertex, joint)` (empty with ARAP).
    pub tied: Vec<(u32, u32)>,
    /// The mesh file's parts and their vertex and triangle ranges.
    pub parts: Vec<WirePart>,
    /// The actor this scene is for: its name on the stage, its index in the stage's
    /// config, and how many actors the stage has (the character's name, 0 and 1 on a
    /// stage of one).
    pub actor: String,
    pub actor_index: u8,
    pub actor_count: u8,
}

impl Scene {
    /// The scene of a bound character solved at `rate_hz`.
    pub fn of_rig(rig: &Rig, character: &str, rate_hz: f64) -> Self {
        Self {
            character: character.to_owned(),
            rate_hz,
            vertex_count: rig.mesh_rest.len(),
            triangles: rig.triangles.clone(),
            marker_names: rig.marker_names.clone(),
            joint_names: rig.skeleton.joints.iter().map(|j| j.name.clone()).collect(),
            joint_parents: rig.skeleton.joints.iter().map(|j| j.parent).collect(),
            rest_volume_m3: crate::character::procedural::mesh_volume(
                &rig.mesh_rest,
                &rig.triangles,
            ),
            control_edges: tet_edges(&rig.control.tets),
            tied: Vec::new(),
            parts: rig
                .parts
                .iter()
                .map(|p| WirePart {
                    name: p.name.clone(),
                    first_vertex: p.first_vertex,
                    vertex_count: p.vertex_count,
                    first_triangle: p.first_triangle,
                    triangle_count: p.triangle_count,
                })
                .collect(),
            actor: character.to_owned(),
            actor_index: 0,
            actor_count: 1,
        }
    }

    /// The same, for actor `name`, `index` of `count` on the stage.
    pub fn for_actor(mut self, name: &str, index: u8, count: u8) -> Self {
        self.actor = name.to_owned();
        self.actor_index = index;
        self.actor_count = count;
        self
    }

    /// The same, with the harmonic method's correspondences (`Solver::harmonic_tied`).
    pub fn with_tied(mut self, tied: &[(u32, u32)]) -> Self {
        self.tied = tied.to_vec();
        self
    }

    /// The vertex stream's topology message (world frame: metres, +Y up, right-handed).
    pub fn topology(&self) -> Topology {
        Topology {
            character: self.character.clone(),
            rate_hz: self.rate_hz as f32,
            length_unit: "m".into(),
            up_axis: "+Y".into(),
            handedness: "right".into(),
            vertex_count: self.vertex_count as u32,
            triangles: self.triangles.clone(),
            marker_names: self.marker_names.clone(),
            joint_names: self.joint_names.clone(),
            joint_parents: self
                .joint_parents
                .iter()
                .map(|p| p.map_or(-1, |p| p as i32))
                .collect(),
            parts: self.parts.clone(),
            actor: self.actor.clone(),
            actor_index: self.actor_index,
            actor_count: self.actor_count,
        }
    }
}

/// The edges of tets, each once, as sorted vertex pairs in ascending order.
pub fn tet_edges(tets: &[[u32; 4]]) -> Vec<[u32; 2]> {
    let mut edges: Vec<[u32; 2]> = tets
        .iter()
        .flat_map(|t| {
            [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)].map(|(i, j)| {
                let (a, b) = (t[i], t[j]);
                [a.min(b), a.max(b)]
            })
        })
        .collect();
    edges.sort_unstable();
    edges.dedup();
    edges
}
