//! Sinks that read published frames: the vertex stream server and the Rerun recording.

pub mod rerun_sink;
pub mod stream;
