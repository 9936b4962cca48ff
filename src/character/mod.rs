//! What the user brings: the character mesh, its skeleton with joint limits, and the
//! marker layout; plus the procedural characters and motions (with known truth) used by
//! the demo, the tests and the benchmarks.

pub mod animation;
pub mod bind_params;
pub mod body;
pub mod cell_size;
pub mod config;
pub mod demo;
pub mod file;
pub mod mesh;
pub mod procedural;
pub mod roles;
pub mod session;
pub mod skeleton;

use glam::DVec3;
use skeleton::Skeleton;

/// A marker of a character's layout.
#[derive(Clone, Debug)]
pub struct MarkerDef {
    pub name: String,
    /// Rest position, metres, world frame.
    pub rest: DVec3,
    /// The joint whose segments carry it; `None`: the owner of the nearest segment,
    /// decided at bind time.
    pub joint: Option<usize>,
}

/// Per-vertex skin: up to four (joint, weight) pairs, weights summing to one.
#[derive(Clone, Debug)]
pub struct Skin {
    pub influences: Vec<[(u32, f64); 4]>,
}

/// A character: full-resolution mesh (the file's vertex order and count, metres, world
/// frame), skeleton, markers, and (procedural only) its skin.
#[derive(Clone, Debug)]
pub struct Character {
    pub name: String,
    pub vertices: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
    pub skeleton: Skeleton,
    pub markers: Vec<MarkerDef>,
    /// Skin used to produce ground truth (procedural characters).
    pub skin: Option<Skin>,
    /// Correspondences for the harmonic method given by the character file (empty: all
    /// automatic).
    pub correspondences: Vec<Correspondence>,
    /// The mesh file's parts (glTF primitives, OBJ groups) with their vertex and triangle
    /// ranges; a procedural character is one part.
    pub parts: Vec<mesh::MeshPart>,
}

/// Triangles of the mesh that follow one joint's segment rigidly in the harmonic method
/// (de Aguiar et al.'s correspondences), as a character file gives them; they replace
/// the automatic ones of that joint.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Correspondence {
    /// The joint (skeleton index).
    pub joint: usize,
    /// Triangle indices into the character's triangles.
    pub triangles: Vec<u32>,
}
