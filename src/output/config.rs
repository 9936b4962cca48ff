//! The `[outputs]` tables of a stage config: the vertex stream and the Rerun recording,
//! each key documented, unknown keys refused, and each section's own checks.

use super::rerun_sink::RerunTarget;
use std::net::SocketAddr;

/// `[outputs]`.
#[derive(Clone, Debug, Default, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputsConfig {
    /// The vertex stream.
    pub stream: StreamOutputConfig,
    /// The Rerun recording.
    pub rerun: RerunOutputConfig,
}

/// `[outputs.rerun]`: the Rerun recording (`src/output/rerun_sink.rs`).
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RerunOutputConfig {
    /// `"off"`, `"spawn"` (start a viewer), `"connect=HOST:PORT"` (a running viewer's
    /// gRPC port) or `"save=PATH.rrd"` (relative to the stage config's folder).
    pub target: String,
    /// Log the mesh every this many frames (1: every frame).
    pub mesh_every: u64,
    /// Also log the control mesh as a wireframe, on the mesh's frames (ARAP only).
    pub control_mesh: bool,
    /// Also log the harmonic method's rotation field (the mesh coloured by each
    /// vertex's angle from the root segment) and its correspondences, on the mesh's
    /// frames (`solver.method = "harmonic"` only).
    pub harmonic_field: bool,
}

impl Default for RerunOutputConfig {
    fn default() -> Self {
        Self {
            target: "off".into(),
            mesh_every: 1,
            control_mesh: false,
            harmonic_field: false,
        }
    }
}

impl RerunOutputConfig {
    /// The target, with a relative save path taken from `base_dir` (off if the target
    /// does not parse; [`OutputsConfig::problems`] reports that).
    pub fn target(&self, base_dir: &std::path::Path) -> RerunTarget {
        match self.target.parse() {
            Ok(RerunTarget::Save(p)) => RerunTarget::Save(base_dir.join(p)),
            Ok(t) => t,
            Err(_) => RerunTarget::Off,
        }
    }
}

/// `[outputs.stream]`: the vertex stream (`protocols/vertex-stream.md`).
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StreamOutputConfig {
    /// TCP address to listen on (port 0: any free port); loopback by default.
    pub tcp: Option<SocketAddr>,
    /// WebSocket address to listen on (same messages, one binary WebSocket message
    /// each); off unless set (`rigless run`, `demo` and `replay --solve` open it at
    /// 127.0.0.1:7879 for the browser viewer unless told `--viewer off`).
    pub websocket: Option<SocketAddr>,
    /// Serve the browser viewer's page on the WebSocket port: a request there that is
    /// not a WebSocket upgrade gets the page (`src/output/viewer.rs`).
    pub viewer: bool,
    /// When the WebSocket address is taken, listen on a free port of the same host
    /// instead of failing. Not read from files: the command line's default viewer
    /// address sets it, so that two daemons on one machine both start.
    #[serde(skip)]
    pub websocket_any_port_if_taken: bool,
    /// Most clients served at once, over TCP and WebSocket together (a connection to the
    /// WebSocket port counts once its handshake is done; page requests never do); the
    /// next one is sent a goodbye saying the server is full, and closed.
    pub max_clients: usize,
}

/// The default of `[outputs.stream] max_clients`.
pub const DEFAULT_MAX_CLIENTS: usize = 64;

impl Default for StreamOutputConfig {
    fn default() -> Self {
        Self {
            tcp: Some(SocketAddr::from(([127, 0, 0, 1], 7878))),
            websocket: None,
            viewer: true,
            websocket_any_port_if_taken: false,
            max_clients: DEFAULT_MAX_CLIENTS,
        }
    }
}

impl OutputsConfig {
    /// What is wrong, as `(key, message)` with keys relative to `[outputs]`.
    pub fn problems(&self) -> Vec<(String, String)> {
        let mut out = Vec::new();
        if let Err(e) = self.rerun.target.parse::<RerunTarget>() {
            out.push(("rerun.target".into(), e));
        }
        if self.stream.max_clients == 0 {
            out.push(("stream.max_clients".into(), "must be at least 1".into()));
        }
        if self.rerun.mesh_every == 0 {
            out.push(("rerun.mesh_every".into(), "must be at least 1".into()));
        }
        if let (Some(t), Some(w)) = (self.stream.tcp, self.stream.websocket) {
            if t == w && t.port() != 0 {
                out.push((
                    "stream.websocket".into(),
                    format!("{w} is also the TCP address; give each its own port"),
                ));
            }
        }
        out
    }
}
