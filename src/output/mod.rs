//! Sinks that read published frames: the vertex stream server.

pub mod stream;
