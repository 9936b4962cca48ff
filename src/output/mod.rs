//! Sinks that read published frames: the in-process frame itself ([`frame`]), what
//! every sink knows of the character ([`scene`]), the vertex stream server and the Rerun
//! recording, the browser viewer served on the stream's WebSocket port ([`viewer`]),
//! files of a solved take ([`export`]) with the glTF skin fitted to it ([`skin_fit`]), and their config sections ([`config`]).

pub mod config;
pub mod export;
pub mod frame;
pub mod rerun_sink;
pub mod scene;
pub mod skin_fit;
pub mod stream;
pub mod viewer;
