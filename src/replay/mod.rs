//! Recorded sessions from files: C3D (reader and writer) and Qualisys TSV.

pub mod c3d;
pub mod tsv;
