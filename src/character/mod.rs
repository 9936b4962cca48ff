//! What the user brings: the character mesh, its skeleton with joint limits, and the
//! marker layout; plus the procedural characters and motions (with known truth) used by
//! the demo, the tests and the benchmarks.

pub mod procedural;
pub mod skeleton;
