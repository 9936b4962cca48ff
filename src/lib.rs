//! rigless: animate a character mesh live from a handful of motion-capture markers, with
//! no rigging step.
//!
//! Method (Le Naour, Courty, Gibet, "Real-time mesh animation from low dimensional
//! positional constraints"): the character is embedded in a volumetric control mesh;
//! each frame, as-rigid-as-possible deformation with bone-length, straightness and
//! joint-limit constraints pulls the control mesh onto the markers, and the full mesh
//! follows through Green coordinates. A second method (de Aguiar et al.) spreads the
//! fitted joint rotations as harmonic fields and rebuilds the mesh with a Poisson solve.
//!
//! Data flow of a stage ([`daemon::stage::Stage`]):
//!
//! ```text
//!  inputs (a thread each)        solver thread, every 1/rate_hz          sinks
//!  OSC, VMC, NatNet, VRPN, ──▶  drain the bounded channel into the   ──▶ vertex stream
//!  glove, replay, synthetic     marker buffer; sample a gap-filled        (TCP, WebSocket),
//!  (MarkerSample, indices       frame; solve warm-started within its      Rerun, an
//!  resolved)                    deadline; full mesh; publish an           in-process reader
//!                               Arc<DeformedFrame> to each sink's slot
//! ```
//!
//! Units and frames: SI inside (metres, seconds, radians); the world frame is
//! right-handed, Y up. Input adapters convert once at the edge.
//!
//! Module map, top to bottom; a module imports only those below it:
//! - [`bench`]: the benchmark suites behind `rigless bench` (they run whole stages).
//! - [`daemon`]: the [`daemon::stage::Stage`] that builds and runs a stage from its
//!   config, and the fixed-rate loop.
//! - [`config`]: the stage config file: sections owned by their components, checks
//!   across sections, every problem reported at once with its line.
//! - [`output`]: the in-process frame and scene, the vertex stream server, the Rerun
//!   sink, and their config.
//! - [`input`]: input adapters (config section to socket, port or file, codec, names
//!   resolved, samples to a sink), and their config.
//! - [`replay`]: recording readers (C3D, TSV, BVH), the session format and recorder
//!   config, the replay sender, the bundled sessions.
//! - [`protocol`]: pure codecs and endpoint URLs: bytes in and out, no sockets, no
//!   solver or marker types.
//! - [`calibrate`]: fitting a take's marker layout onto a character (the marker-set
//!   tables that place each label on a humanoid part).
//! - [`solve`]: per-frame math (ARAP, posture fit, harmonic method, metrics) and the
//!   solver's config; no I/O.
//! - [`rig`]: offline binding (lattice, weights, Green coordinates, the precomputed
//!   systems the solver reads) and the bake cache.
//! - [`character`]: what the user brings (mesh, skeleton, limits, markers), the
//!   character's config, and the procedural characters and motions.
//! - [`markers`]: marker samples and frames, the marker index, the marker buffer and
//!   its gap filling.
//! - [`geom`], [`runtime`]: the ground floor: small geometry (rotations, the lattice);
//!   the clock, latest-value slots, socket waits, statistics.

pub mod bench;
pub mod calibrate;
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
