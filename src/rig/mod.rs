//! Offline binding: control mesh (lattice tetrahedralization and the benchmark tet
//! format), weights, Green coordinates, and the bound rig.

pub mod arap_system;
pub mod bind;
pub mod cache;
pub mod factor;
pub mod green;
pub mod lattice;
pub mod tetmesh;
