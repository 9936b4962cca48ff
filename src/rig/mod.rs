//! Offline binding: control mesh (lattice tetrahedralization and the benchmark tet
//! format), weights, Green coordinates, and the bound rig, with what `solve` reads every
//! frame: the factored ARAP system (and its sparse Cholesky) and the posture problem.

pub mod arap_system;
pub mod bind;
pub mod cache;
pub mod factor;
pub mod green;
pub mod ik_model;
pub mod lattice;
pub mod tetmesh;
