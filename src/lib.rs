//! rigless: animate a character mesh live from a handful of motion-capture markers, with
//! no rigging step.
//!
//! Method (Le Naour, Courty, Gibet, "Real-time mesh animation from low dimensional
//! positional constraints"): the character is embedded in a volumetric control mesh;
//! each frame, as-rigid-as-possible deformation with bone-length, straightness and
//! joint-limit constraints pulls the control mesh onto the markers, and the full mesh
//! follows through Green coordinates.
//!
//! Units and frames: SI inside (metres, seconds, radians); the world frame is
//! right-handed, Y up. Adapters convert once at the edge.
//!
//! Module map (data flows top to bottom; a module only imports those above it):
//! - [`config`]: the stage config of `rigless run`.
//! - [`rig`]: control mesh construction and binding (offline).
//! - [`solve`]: per-frame math, no I/O.
//! - [`markers`]: marker samples and frames, the marker buffer and its gap filling.
//! - [`protocol`]: pure wire codecs (the vertex stream).
//! - [`replay`]: recorded sessions from files (Qualisys TSV).
//! - [`input`]: sources feeding marker samples into the daemon's channel.
//! - [`output`]: sinks reading published frames (the vertex stream server).
//! - [`daemon`]: the clock, latest-value slots and the fixed-rate loop.
//! - [`bench`]: the benchmark suites behind `rigless bench`.

pub mod bench;
pub mod character;
pub mod config;
pub mod daemon;
pub mod geom;
pub mod input;
pub mod markers;
pub mod output;
pub mod protocol;
pub mod replay;
pub mod rig;
pub mod runtime;
pub mod solve;
