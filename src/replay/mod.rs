//! Recorded sessions: file readers (C3D, with a writer, and Qualisys TSV), recordings
//! and their label mapping, the replayer that plays them as live input, and the sessions
//! bundled with rigless.

pub mod bundled;
pub mod bvh;
pub mod c3d;
pub mod player;
pub mod recording;
pub mod sender;
pub mod session;
pub mod tsv;
