//! Recorded sessions: file readers (C3D with a writer, Qualisys TSV, BVH), recordings,
//! the session recording format and its `[recorder]` config, the sender that replays a
//! recording as network traffic, and the sessions bundled with rigless. (Playing a
//! recording into a stage is the replay input's, in `input/`.)

pub mod bundled;
pub mod bvh;
pub mod c3d;
pub mod config;
pub mod recording;
pub mod sender;
pub mod session;
pub mod tsv;
