//! Ground floor: small geometry used by every layer (rotations, the lattice, ...).

pub mod axes;
pub mod lattice;
pub mod polar;
