//! Ground floor: small geometry used by every layer (rotations, the lattice, the
//! generalized winding number, ...).

pub mod axes;
pub mod lattice;
pub mod polar;
pub mod ray;
pub mod shapes;
pub mod winding;
