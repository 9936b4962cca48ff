//! The stage config (`rigless run --config stage.toml`): which character, which inputs,
//! how the solver runs, where the outputs go. Every key is documented here, unknown keys
//! are rejected, and every problem in a file is reported at once with its line.
//!
//! ```toml
//! [character]
//! procedural = "hand"            # or: path = "hand/hand.toml" (a character file)
//!
//! [solver]
//! rate_hz = 120
//!
//! [[inputs]]
//! type = "synthetic"             # the in-process test source
//! motion = "finger_play"
//!
//! [outputs.stream]
//! tcp = "127.0.0.1:7878"
//! ```

use crate::markers::buffer::BufferConfig;
use std::net::SocketAddr;
use std::path::PathBuf;

/// A whole stage config.
#[derive(Clone, Debug, PartialEq)]
pub struct StageConfig {
    pub character: CharacterConfig,
    pub solver: SolverConfig,
    pub buffer: BufferConfig,
    pub inputs: Vec<InputConfig>,
    pub outputs: OutputsConfig,
    pub recorder: RecorderConfig,
}

/// `[recorder]`: record every incoming sample to a session file (off unless `path` is
/// set).
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecorderConfig {
    /// Session file to write (`.rlsession`), relative to the stage config's folder;
    /// `{time}` is replaced by the start time (UTC, `YYYYmmdd-HHMMSS`).
    pub path: Option<PathBuf>,
    /// Longest time between writes to the file, seconds: a killed daemon loses at most
    /// this much.
    pub flush_interval_secs: f64,
}

impl Default for RecorderConfig {
    fn default() -> Self {
        Self {
            path: None,
            flush_interval_secs: 0.5,
        }
    }
}

/// `[character]`: exactly one of `procedural` or `path`.
#[derive(Clone, Debug, Default, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CharacterConfig {
    /// A procedural character: `"hand"` or `"body"`.
    pub procedural: Option<String>,
    /// A character file (TOML, see README), relative to the stage config's folder. It is
    /// baked on first use and its bake cache reused afterwards.
    pub path: Option<PathBuf>,
}

/// `[solver]`: the fixed-rate loop and the frame solver.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SolverConfig {
    /// Deformation method: `"arap"` (volumetric ARAP and Green coordinates, the default)
    /// or `"harmonic"` (harmonic rotation fields and a Poisson rebuild, de Aguiar et al.).
    pub method: SolverMethod,
    /// Harmonic method: share of each bone's length, at each end, left free of
    /// correspondences (larger: softer bends).
    pub harmonic_margin: f64,
    /// Frames per second of the solver thread, Hz.
    pub rate_hz: f64,
    /// ARAP iteration cap per frame.
    pub max_iterations: usize,
    /// Relative change of `0.5·rrms + 0.5·bone_length_error` that ends a frame.
    pub tolerance: f64,
    /// Share of the frame period a solve may use before it stops at its deadline.
    pub deadline_fraction: f64,
    /// Capacity of the input channel, samples (inputs drop and count samples beyond it).
    pub channel_capacity: usize,
    /// Posture fit weight towards the rest pose: metres of marker misfit per metre of
    /// height that one radian away from rest is worth (higher: stiffer, less noise).
    pub rest_prior: f64,
    /// The same towards the previous frame's posture (higher: smoother, more lag).
    pub prev_prior: f64,
    /// ARAP: gain of the volume restoration (0: off; 1: the default, which gives
    /// compressed flesh at creases back its volume within a few frames; above 2 it may
    /// oscillate).
    pub volume_gain: f64,
}

/// `solver.method`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SolverMethod {
    #[default]
    Arap,
    Harmonic,
}

impl SolverConfig {
    /// The solver's method with its settings.
    pub fn method(&self) -> crate::solve::frame::Method {
        match self.method {
            SolverMethod::Arap => crate::solve::frame::Method::Arap,
            SolverMethod::Harmonic => {
                crate::solve::frame::Method::Harmonic(crate::solve::harmonic::HarmonicParams {
                    margin: self.harmonic_margin,
                })
            }
        }
    }
}

impl Default for SolverConfig {
    fn default() -> Self {
        Self {
            method: SolverMethod::Arap,
            harmonic_margin: crate::solve::harmonic::HarmonicParams::default().margin,
            rate_hz: 120.0,
            max_iterations: 30,
            tolerance: 1e-3,
            deadline_fraction: 0.8,
            channel_capacity: 4096,
            rest_prior: crate::solve::ik::IkParams::default().rest_prior,
            prev_prior: crate::solve::ik::IkParams::default().prev_prior,
            volume_gain: crate::solve::frame::SolverParams::default().volume_gain,
        }
    }
}

/// One `[[inputs]]` entry, chosen by `type`.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum InputConfig {
    /// The in-process test source: the procedural character playing a motion, with
    /// noise and occlusion gaps (needs `character.procedural`).
    Synthetic(SyntheticInputConfig),
    /// A recording played as live input with its own timing: a bundled session or a
    /// C3D / TSV file. Labels map to the character's markers by name.
    Replay(ReplayInputConfig),
    /// OSC over UDP (`protocols/osc.md`): `url = "osc://127.0.0.1:9000"` for the native
    /// schema and address patterns, `"vmc://127.0.0.1:39539"` for VMC. Marker names map
    /// to the character's markers by name.
    Osc(OscInputConfig),
    /// NatNet (OptiTrack Motive) frames of data (`protocols/natnet.md`):
    /// `url = "natnet://239.255.42.99:1511"` (a multicast group is joined) or a unicast
    /// data port; `?version=4.1` for newer servers. Markers are named `SET_1`, `SET_2`...
    NatNet(NatNetInputConfig),
    /// A VRPN tracker (`url = "vrpn://Tracker0@127.0.0.1"` for the UDP connection mode,
    /// `"vrpn://Tracker0@tcp://127.0.0.1:3883"` for TCP only). Each sensor is a marker
    /// named `DEVICE_SENSOR`, or as `sensors` maps it.
    Vrpn(VrpnInputConfig),
    /// A serial data glove (`protocols/glove.md`):
    /// `url = "glove:///dev/ttyUSB0?baud=115200&format=alpha"`. Its curls pose the hand's
    /// finger joints; the wrist follows the optical markers, if any.
    Glove(GloveInputConfig),
}

/// `type = "glove"`.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GloveInputConfig {
    /// `glove:///PORT[?baud=115200&format=alpha|legacy&max=4095]`.
    pub url: String,
    /// Raw readings of the straight and the fully curled finger, per finger, e.g.
    /// `index = { open = 350, closed = 3700 }` (default: 0 and the full scale).
    #[serde(default)]
    pub calibration: std::collections::BTreeMap<String, crate::input::glove::FingerCalibration>,
    /// The character's joints each finger drives, base to distal, e.g.
    /// `index = ["index_1", "index_2", "index_3"]` (default: those names, the procedural
    /// hand's).
    #[serde(default)]
    pub joints: std::collections::BTreeMap<String, [String; 3]>,
}

impl GloveInputConfig {
    /// Per-finger calibration, thumb to pinky, defaults filled in for `max_value`.
    pub fn calibration(&self, max_value: u32) -> [crate::input::glove::FingerCalibration; 5] {
        crate::protocol::glove::FINGERS.map(|f| {
            self.calibration
                .get(f)
                .copied()
                .unwrap_or(crate::input::glove::FingerCalibration {
                    open: 0,
                    closed: max_value,
                })
        })
    }

    /// Driven joint names, thumb to pinky, defaults filled in.
    pub fn joints(&self) -> [[String; 3]; 5] {
        let mut names = crate::input::glove::default_finger_joints();
        for (f, n) in crate::protocol::glove::FINGERS.iter().zip(names.iter_mut()) {
            if let Some(given) = self.joints.get(*f) {
                *n = given.clone();
            }
        }
        names
    }
}

/// `type = "vrpn"`.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VrpnInputConfig {
    /// `vrpn://DEVICE@HOST[:PORT]` or `vrpn://DEVICE@tcp://HOST:PORT`.
    pub url: String,
    /// Marker name per sensor number, e.g. `{ "0" = "LFHD", "1" = "RFHD" }`.
    #[serde(default)]
    pub sensors: std::collections::BTreeMap<String, String>,
}

/// `type = "natnet"`.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NatNetInputConfig {
    /// `natnet://HOST:PORT[?version=M.m]`: the data port to bind.
    pub url: String,
}

/// `type = "osc"`.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OscInputConfig {
    /// `osc://HOST:PORT` or `vmc://HOST:PORT`: the address to bind.
    pub url: String,
    /// Address patterns with a `{name}` part and three float arguments.
    pub patterns: Vec<String>,
    /// Metres per sender unit (0.001 for millimetres).
    pub scale: f64,
    /// The sender's up axis: `"Y"` or `"Z"`.
    pub up: String,
}

impl Default for OscInputConfig {
    fn default() -> Self {
        Self {
            url: "osc://127.0.0.1:9000".into(),
            patterns: crate::protocol::osc::OscMapping::default().patterns,
            scale: 1.0,
            up: "Y".into(),
        }
    }
}

/// `type = "replay"`: exactly one of `session` or `path`.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayInputConfig {
    /// A bundled session: `"hand_finger_play"`, `"body_walk"` or `"body_reach"`.
    pub session: Option<String>,
    /// A recording file (`.c3d`, `.tsv`, `.bvh` or `.rlsession`), relative to the stage
    /// config's folder. A BVH's joints are its labels.
    pub path: Option<PathBuf>,
    /// Metres per BVH unit (BVH files have no units).
    pub bvh_scale: f64,
    /// Playback speed (1 = the recording's own timing).
    pub speed: f64,
    /// Play the recording again and again.
    #[serde(rename = "loop")]
    pub looping: bool,
}

impl Default for ReplayInputConfig {
    fn default() -> Self {
        Self {
            session: None,
            path: None,
            bvh_scale: crate::replay::recording::DEFAULT_BVH_METRES_PER_UNIT,
            speed: 1.0,
            looping: false,
        }
    }
}

/// `type = "synthetic"`.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SyntheticInputConfig {
    /// `"finger_play"` (the hand), `"walk"` or `"reach"` (the body); default: the
    /// character's first.
    pub motion: Option<String>,
    /// Length of the session, seconds.
    pub session_secs: f64,
    /// Capture rate, Hz.
    pub rate_hz: f64,
    /// Uniform marker noise amplitude per axis, millimetres.
    pub noise_mm: f64,
    /// Share of samples lost in occlusion gaps, percent.
    pub gap_percent: f64,
    /// Seed of the noise and the gaps.
    pub seed: u64,
    /// Play the session again and again.
    #[serde(rename = "loop")]
    pub looping: bool,
}

impl Default for SyntheticInputConfig {
    fn default() -> Self {
        Self {
            motion: None,
            session_secs: 20.0,
            rate_hz: 120.0,
            noise_mm: 0.5,
            gap_percent: 5.0,
            seed: 1,
            looping: false,
        }
    }
}

/// `[outputs]`.
#[derive(Clone, Debug, Default, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputsConfig {
    pub stream: StreamOutputConfig,
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

/// `[outputs.stream]`: the vertex stream (protocols/vertex-stream.md).
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StreamOutputConfig {
    /// TCP address to listen on (port 0: any free port); binds loopback by default.
    pub tcp: Option<SocketAddr>,
    /// WebSocket address to listen on (same messages, one binary WebSocket message
    /// each); off unless set.
    pub websocket: Option<SocketAddr>,
}

impl Default for StreamOutputConfig {
    fn default() -> Self {
        Self {
            tcp: Some(SocketAddr::from(([127, 0, 0, 1], 7878))),
            websocket: None,
        }
    }
}

impl RerunOutputConfig {
    /// The target, with a relative save path taken from `base_dir`.
    pub fn target(&self, base_dir: &std::path::Path) -> crate::output::rerun_sink::RerunTarget {
        use crate::output::rerun_sink::RerunTarget;
        match self.target.parse() {
            Ok(RerunTarget::Save(p)) => RerunTarget::Save(base_dir.join(p)),
            Ok(t) => t,
            Err(_) => RerunTarget::Off,
        }
    }
}

/// Why a stage config was refused: every problem, each with its line when known.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: {} problem{}:\n  - {}", .problems.len(), if .problems.len() == 1 { "" } else { "s" }, .problems.join("\n  - "))]
    Invalid { path: String, problems: Vec<String> },
}

/// The motions each procedural character plays.
pub fn motions_of(procedural: &str) -> &'static [&'static str] {
    match procedural {
        "hand" => &["finger_play"],
        "body" => &["walk", "reach"],
        _ => &[],
    }
}

/// Where keys are in the text: `(table path, key) -> line`, with table paths such as
/// `solver`, `inputs[1]`, `outputs.stream` (dotted keys are joined onto the table).
struct Lines {
    keys: Vec<(String, usize)>,
}

impl Lines {
    fn scan(text: &str) -> Self {
        let mut keys = Vec::new();
        let mut table = String::new();
        let mut arrays: Vec<(String, usize)> = Vec::new();
        for (i, raw) in text.lines().enumerate() {
            let line = raw.trim();
            let n = i + 1;
            if let Some(name) = line.strip_prefix("[[").and_then(|l| l.split("]]").next()) {
                let name = name.trim().to_owned();
                let idx = match arrays.iter_mut().find(|(a, _)| *a == name) {
                    Some((_, c)) => {
                        *c += 1;
                        *c
                    }
                    None => {
                        arrays.push((name.clone(), 0));
                        0
                    }
                };
                table = format!("{name}[{idx}]");
                keys.push((table.clone(), n));
            } else if let Some(name) = line.strip_prefix('[').and_then(|l| l.split(']').next()) {
                table = name.trim().to_owned();
                keys.push((table.clone(), n));
            } else if let Some((k, _)) = line.split_once('=') {
                let k = k.trim().trim_matches('"');
                if !k.is_empty() && !k.starts_with('#') {
                    let full = if table.is_empty() {
                        k.to_owned()
                    } else {
                        format!("{table}.{k}")
                    };
                    keys.push((full, n));
                }
            }
        }
        Self { keys }
    }

    /// The line of `path` (a key or table), or of its nearest enclosing table.
    fn of(&self, path: &str) -> Option<usize> {
        let mut p = path;
        loop {
            if let Some((_, n)) = self.keys.iter().find(|(k, _)| k == p) {
                return Some(*n);
            }
            p = &p[..p.rfind('.')?];
        }
    }

    fn at(&self, path: &str, what: impl std::fmt::Display) -> String {
        match self.of(path) {
            Some(n) => format!("line {n}: {path}: {what}"),
            None => format!("{path}: {what}"),
        }
    }
}

/// The field a serde error names (`unknown field `x`` or `missing field `x``), if any.
fn named_field(message: &str) -> Option<&str> {
    let rest = message.split("field `").nth(1)?;
    rest.split('`').next()
}

/// Deserializes `value` (found at `at`) into `T`. An unknown key is reported and left
/// out, and the rest tried again, so one stray key does not hide the other problems.
fn typed<T: serde::de::DeserializeOwned>(
    value: &toml::Value,
    at: &str,
    lines: &Lines,
    problems: &mut Vec<String>,
) -> Option<T> {
    let mut v = value.clone();
    for _ in 0..64 {
        match v.clone().try_into::<T>() {
            Ok(t) => return Some(t),
            Err(e) => {
                let msg = e.message().trim().to_owned();
                match named_field(&msg) {
                    Some(f) if msg.starts_with("unknown field") => {
                        problems.push(lines.at(&format!("{at}.{f}"), &msg));
                        v.as_table_mut().and_then(|t| t.remove(f))?;
                    }
                    _ => {
                        problems.push(lines.at(at, msg));
                        return None;
                    }
                }
            }
        }
    }
    None
}

fn section<T: serde::de::DeserializeOwned + Default>(
    table: &toml::Table,
    key: &str,
    lines: &Lines,
    problems: &mut Vec<String>,
) -> T {
    table
        .get(key)
        .and_then(|v| typed(v, key, lines, problems))
        .unwrap_or_default()
}

/// Parses and validates a stage config's text; `path` names it in errors. Relative
/// character paths are kept as written (resolve them against the file's folder).
pub fn parse_stage(text: &str, path: &str) -> Result<StageConfig, ConfigError> {
    let invalid = |problems: Vec<String>| ConfigError::Invalid {
        path: path.to_owned(),
        problems,
    };
    let table: toml::Table = toml::from_str(text).map_err(|e| {
        let line = e
            .span()
            .map(|s| text[..s.start.min(text.len())].lines().count().max(1));
        let msg = e.message().trim().to_owned();
        invalid(vec![match line {
            Some(n) => format!("line {n}: {msg}"),
            None => msg,
        }])
    })?;
    let lines = Lines::scan(text);
    let mut problems = Vec::new();
    let positive = |v: f64| v.is_finite() && v > 0.0;
    for k in table.keys() {
        if ![
            "character",
            "solver",
            "buffer",
            "inputs",
            "outputs",
            "recorder",
        ]
        .contains(&k.as_str())
        {
            problems.push(lines.at(
                k,
                "unknown section (expected character, solver, buffer, inputs, outputs, recorder)",
            ));
        }
    }
    let character: CharacterConfig = section(&table, "character", &lines, &mut problems);
    let solver: SolverConfig = section(&table, "solver", &lines, &mut problems);
    let buffer: BufferConfig = section(&table, "buffer", &lines, &mut problems);
    let outputs: OutputsConfig = section(&table, "outputs", &lines, &mut problems);
    let recorder: RecorderConfig = section(&table, "recorder", &lines, &mut problems);
    if !(positive(recorder.flush_interval_secs) && recorder.flush_interval_secs <= 60.0) {
        problems.push(lines.at(
            "recorder.flush_interval_secs",
            format!(
                "must be in (0, 60] seconds, got {}",
                recorder.flush_interval_secs
            ),
        ));
    }
    let mut inputs = Vec::new();
    let lines_ref = &lines;
    match table.get("inputs") {
        None => {}
        Some(toml::Value::Array(a)) => {
            for (i, v) in a.iter().enumerate() {
                if let Some(c) =
                    typed::<InputConfig>(v, &format!("inputs[{i}]"), lines_ref, &mut problems)
                {
                    inputs.push(c);
                }
            }
        }
        Some(_) => problems.push(lines.at("inputs", "must be an array of tables ([[inputs]])")),
    }
    // Semantics.
    match (&character.procedural, &character.path) {
        (Some(_), Some(_)) => {
            problems.push(lines.at("character", "give either procedural or path, not both"))
        }
        (None, None) => problems.push(lines.at(
            "character",
            "missing: set procedural = \"hand\" or \"body\", or path = \"CHARACTER.toml\"",
        )),
        (Some(p), None) if motions_of(p).is_empty() => problems.push(lines.at(
            "character.procedural",
            format!("unknown procedural character {p:?} (expected \"hand\" or \"body\")"),
        )),
        _ => {}
    }
    if !(positive(solver.rate_hz) && solver.rate_hz <= 2000.0) {
        problems.push(lines.at(
            "solver.rate_hz",
            format!("must be in (0, 2000] Hz, got {}", solver.rate_hz),
        ));
    }
    if solver.max_iterations == 0 || solver.max_iterations > 10_000 {
        problems.push(lines.at(
            "solver.max_iterations",
            format!("must be 1 to 10000, got {}", solver.max_iterations),
        ));
    }
    if !positive(solver.tolerance) {
        problems.push(lines.at(
            "solver.tolerance",
            format!("must be positive, got {}", solver.tolerance),
        ));
    }
    if !(positive(solver.deadline_fraction) && solver.deadline_fraction <= 1.0) {
        problems.push(lines.at(
            "solver.deadline_fraction",
            format!("must be in (0, 1], got {}", solver.deadline_fraction),
        ));
    }
    for (key, v) in [
        ("rest_prior", solver.rest_prior),
        ("prev_prior", solver.prev_prior),
    ] {
        if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
            problems.push(lines.at(
                &format!("solver.{key}"),
                format!("must be in [0, 1], got {v}"),
            ));
        }
    }
    if !(solver.volume_gain.is_finite() && (0.0..=2.0).contains(&solver.volume_gain)) {
        problems.push(lines.at(
            "solver.volume_gain",
            format!("must be in [0, 2], got {}", solver.volume_gain),
        ));
    }
    if !(solver.harmonic_margin.is_finite() && (0.0..0.5).contains(&solver.harmonic_margin)) {
        problems.push(lines.at(
            "solver.harmonic_margin",
            format!("must be in [0, 0.5), got {}", solver.harmonic_margin),
        ));
    }
    if !(16..=1 << 24).contains(&solver.channel_capacity) {
        problems.push(lines.at(
            "solver.channel_capacity",
            format!(
                "must be 16 to 16777216 samples, got {}",
                solver.channel_capacity
            ),
        ));
    }
    if let Err(e) = outputs
        .rerun
        .target
        .parse::<crate::output::rerun_sink::RerunTarget>()
    {
        problems.push(lines.at("outputs.rerun.target", e));
    }
    if outputs.rerun.mesh_every == 0 {
        problems.push(lines.at("outputs.rerun.mesh_every", "must be at least 1"));
    }
    for p in buffer.problems() {
        let key = p.split(' ').next().unwrap_or("buffer").to_owned();
        problems.push(lines.at(&key, p.trim_start_matches(&key).trim_start()));
    }
    for (i, input) in inputs.iter().enumerate() {
        let at = format!("inputs[{i}]");
        match input {
            InputConfig::Vrpn(v) => {
                match crate::input::parse_url(&v.url) {
                    Ok(crate::input::InputUrl::Vrpn { .. }) => {}
                    Ok(_) => problems.push(lines.at(
                        &format!("{at}.url"),
                        format!("{:?} is not a vrpn:// URL", v.url),
                    )),
                    Err(e) => problems.push(lines.at(&format!("{at}.url"), e)),
                }
                for k in v.sensors.keys() {
                    if k.parse::<i32>().is_err() {
                        problems.push(lines.at(
                            &format!("{at}.sensors"),
                            format!("{k:?} is not a sensor number"),
                        ));
                    }
                }
            }
            InputConfig::Glove(g) => {
                match crate::input::parse_url(&g.url) {
                    Ok(crate::input::InputUrl::Glove(_)) => {}
                    Ok(_) => problems.push(lines.at(
                        &format!("{at}.url"),
                        format!("{:?} is not a glove:// URL", g.url),
                    )),
                    Err(e) => problems.push(lines.at(&format!("{at}.url"), e)),
                }
                let fingers = crate::protocol::glove::FINGERS;
                for (key, names) in [
                    ("calibration", g.calibration.keys().collect::<Vec<_>>()),
                    ("joints", g.joints.keys().collect()),
                ] {
                    for k in names {
                        if !fingers.contains(&k.as_str()) {
                            problems.push(lines.at(
                                &format!("{at}.{key}"),
                                format!("{k:?} is not a finger (expected one of {fingers:?})"),
                            ));
                        }
                    }
                }
            }
            InputConfig::NatNet(n) => match crate::input::parse_url(&n.url) {
                Ok(crate::input::InputUrl::NatNet(..)) => {}
                Ok(_) => problems.push(lines.at(
                    &format!("{at}.url"),
                    format!("{:?} is not a natnet:// URL", n.url),
                )),
                Err(e) => problems.push(lines.at(&format!("{at}.url"), e)),
            },
            InputConfig::Osc(o) => {
                if let Err(e) = crate::input::parse_url(&o.url).and_then(|u| match u {
                    crate::input::InputUrl::NatNet(..) => {
                        Err(format!("{:?}: a natnet URL needs type = \"natnet\"", o.url))
                    }
                    _ => Ok(()),
                }) {
                    problems.push(lines.at(&format!("{at}.url"), e));
                }
                if !(positive(o.scale) && o.scale <= 1e3) {
                    problems.push(lines.at(
                        &format!("{at}.scale"),
                        format!("must be in (0, 1000] metres per unit, got {}", o.scale),
                    ));
                }
                if !["Y", "Z", "y", "z"].contains(&o.up.as_str()) {
                    problems.push(lines.at(
                        &format!("{at}.up"),
                        format!("must be \"Y\" or \"Z\", got {:?}", o.up),
                    ));
                }
                for p in &o.patterns {
                    if p.matches("{name}").count() != 1 || !p.starts_with('/') {
                        problems.push(lines.at(
                            &format!("{at}.patterns"),
                            format!("{p:?} needs to start with / and hold {{name}} once"),
                        ));
                    }
                }
            }
            InputConfig::Replay(r) => {
                match (&r.session, &r.path) {
                    (Some(_), Some(_)) => {
                        problems.push(lines.at(&at, "give either session or path, not both"))
                    }
                    (None, None) => problems.push(lines.at(
                        &at,
                        "a replay input needs session = \"NAME\" (bundled) or path = \"FILE.c3d\"",
                    )),
                    (Some(n), None) if crate::replay::bundled::bundled(n).is_none() => {
                        let names: Vec<&str> = crate::replay::bundled::names().collect();
                        problems.push(lines.at(
                            &format!("{at}.session"),
                            format!("no bundled session {n:?} (there are {names:?})"),
                        ));
                    }
                    _ => {}
                }
                if !(positive(r.bvh_scale) && r.bvh_scale <= 10.0) {
                    problems.push(lines.at(
                        &format!("{at}.bvh_scale"),
                        format!("must be in (0, 10] metres per unit, got {}", r.bvh_scale),
                    ));
                }
                if !(positive(r.speed) && r.speed <= 100.0) {
                    problems.push(lines.at(
                        &format!("{at}.speed"),
                        format!("must be in (0, 100], got {}", r.speed),
                    ));
                }
            }
            InputConfig::Synthetic(s) => {
                match &character.procedural {
                    None => problems.push(lines.at(
                        &at,
                        "a synthetic input needs a procedural character (character.procedural)",
                    )),
                    Some(ch) => {
                        if let Some(m) = &s.motion {
                            let ok = motions_of(ch);
                            if !ok.is_empty() && !ok.contains(&m.as_str()) {
                                problems.push(lines.at(
                                    &format!("{at}.motion"),
                                    format!("the {ch} has no motion {m:?} (it has {ok:?})"),
                                ));
                            }
                        }
                    }
                }
                if !positive(s.session_secs) {
                    problems.push(lines.at(
                        &format!("{at}.session_secs"),
                        format!("must be positive, got {}", s.session_secs),
                    ));
                }
                if !(positive(s.rate_hz) && s.rate_hz <= 10_000.0) {
                    problems.push(lines.at(
                        &format!("{at}.rate_hz"),
                        format!("must be in (0, 10000] Hz, got {}", s.rate_hz),
                    ));
                }
                if !(s.noise_mm.is_finite() && s.noise_mm >= 0.0) {
                    problems.push(lines.at(
                        &format!("{at}.noise_mm"),
                        format!("must be zero or more, got {}", s.noise_mm),
                    ));
                }
                if !(s.gap_percent.is_finite() && (0.0..=90.0).contains(&s.gap_percent)) {
                    problems.push(lines.at(
                        &format!("{at}.gap_percent"),
                        format!("must be 0 to 90, got {}", s.gap_percent),
                    ));
                }
            }
        }
    }
    if let (Some(t), Some(w)) = (outputs.stream.tcp, outputs.stream.websocket) {
        if t == w && t.port() != 0 {
            problems.push(lines.at(
                "outputs.stream.websocket",
                format!("{w} is also the TCP address; give each its own port"),
            ));
        }
    }
    if inputs.is_empty() {
        problems.push(lines.at("inputs", "no inputs: add at least one [[inputs]] table"));
    }
    if !problems.is_empty() {
        // In file order; problems without a line last.
        let line_of = |p: &String| {
            p.strip_prefix("line ")
                .and_then(|r| r.split(':').next())
                .and_then(|n| n.parse::<usize>().ok())
                .unwrap_or(usize::MAX)
        };
        problems.sort_by_key(line_of);
        return Err(invalid(problems));
    }
    Ok(StageConfig {
        character,
        solver,
        buffer,
        inputs,
        outputs,
        recorder,
    })
}

/// Reads and parses a stage config file.
pub fn load_stage(path: &std::path::Path) -> Result<StageConfig, ConfigError> {
    let shown = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
        path: shown.clone(),
        source,
    })?;
    parse_stage(&text, &shown)
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
[character]
procedural = "body"

[solver]
rate_hz = 90

[buffer]
predict_max_gap_secs = 0.2

[[inputs]]
type = "synthetic"
motion = "reach"
loop = true

[outputs.stream]
tcp = "127.0.0.1:0"
"#;

    #[test]
    fn a_good_config_reads_with_defaults_filled_in() {
        let c = parse_stage(GOOD, "stage.toml").unwrap();
        assert_eq!(c.character.procedural.as_deref(), Some("body"));
        assert_eq!(c.solver.rate_hz, 90.0);
        assert_eq!(c.solver.max_iterations, 30);
        assert_eq!(c.buffer.predict_max_gap_secs, 0.2);
        assert_eq!(c.buffer.history_len, BufferConfig::default().history_len);
        let InputConfig::Synthetic(s) = &c.inputs[0] else {
            panic!("{:?}", c.inputs[0])
        };
        assert_eq!(s.motion.as_deref(), Some("reach"));
        assert!(s.looping);
        assert_eq!(c.outputs.stream.tcp, Some("127.0.0.1:0".parse().unwrap()));
    }

    #[test]
    fn every_problem_is_reported_at_once_with_its_line() {
        let bad = r#"
[character]
procedural = "body"

[solver]
rate_hz = -5
max_iterations = 0
colour = "red"

[buffer]
bogus = 1

[[inputs]]
type = "synthetic"
motion = "finger_play"
gap_percent = 95

[lights]
on = true
"#;
        let err = parse_stage(bad, "stage.toml").unwrap_err();
        let ConfigError::Invalid { problems, .. } = &err else {
            panic!("{err}")
        };
        let text = problems.join("\n");
        assert_eq!(problems.len(), 7, "{text}");
        for want in [
            "line 6: solver.rate_hz",
            "line 7: solver.max_iterations",
            "line 8: solver.colour: unknown field",
            "line 11: buffer.bogus: unknown field",
            "line 15: inputs[0].motion",
            "line 16: inputs[0].gap_percent",
            "line 18: lights: unknown section",
        ] {
            assert!(text.contains(want), "missing {want:?} in:\n{text}");
        }
    }

    #[test]
    fn replay_inputs_name_a_bundled_session_or_a_file() {
        let ok = "[character]\nprocedural = \"hand\"\n[[inputs]]\ntype = \"replay\"\nsession = \"hand_finger_play\"\nspeed = 2\n";
        let c = parse_stage(ok, "s.toml").unwrap();
        let InputConfig::Replay(r) = &c.inputs[0] else {
            panic!("{:?}", c.inputs[0])
        };
        assert_eq!(
            (r.session.as_deref(), r.speed, r.looping),
            (Some("hand_finger_play"), 2.0, false)
        );
        let bad = "[character]\npath = \"x.toml\"\n[[inputs]]\ntype = \"replay\"\nsession = \"nope\"\n[[inputs]]\ntype = \"replay\"\nspeed = 0\n";
        let text = parse_stage(bad, "s.toml").unwrap_err().to_string();
        for want in [
            "line 5: inputs[0].session: no bundled session \"nope\"",
            "line 6: inputs[1]: a replay input needs session",
            "line 8: inputs[1].speed: must be in (0, 100]",
        ] {
            assert!(text.contains(want), "missing {want:?} in {text}");
        }
    }

    #[test]
    fn the_shipped_stage_files_are_valid_and_show_the_defaults() {
        let hand = parse_stage(include_str!("../stages/hand.toml"), "stages/hand.toml").unwrap();
        // stages/hand.toml spells out every default (except its looping input).
        assert_eq!(hand.solver, SolverConfig::default());
        assert_eq!(hand.buffer, BufferConfig::default());
        parse_stage(
            include_str!("../stages/body-walk.toml"),
            "stages/body-walk.toml",
        )
        .unwrap();
        let glove = parse_stage(
            include_str!("../stages/hand-glove.toml"),
            "stages/hand-glove.toml",
        )
        .unwrap();
        let InputConfig::Glove(g) = &glove.inputs[0] else {
            panic!("{:?}", glove.inputs[0]);
        };
        let cal = g.calibration(4095);
        assert_eq!((cal[1].open, cal[1].closed), (250, 3800));
        assert_eq!(g.joints()[4], ["pinky_1", "pinky_2", "pinky_3"]);
    }

    #[test]
    fn glove_inputs_name_fingers_and_take_glove_urls() {
        let err = parse_stage(
            "[character]\nprocedural = \"hand\"\n[[inputs]]\ntype = \"glove\"\nurl = \"osc://127.0.0.1:9\"\ncalibration.thumbs = { open = 0, closed = 9 }\n",
            "s.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("is not a glove:// URL"), "{err}");
        assert!(err.contains("\"thumbs\" is not a finger"), "{err}");
    }

    #[test]
    fn the_solver_method_is_chosen_in_the_stage() {
        let stage = "[character]\nprocedural = \"hand\"\n[solver]\nmethod = \"harmonic\"\nharmonic_margin = 0.1\n[[inputs]]\ntype = \"synthetic\"\n";
        let cfg = parse_stage(stage, "s.toml").unwrap();
        assert_eq!(
            cfg.solver.method(),
            crate::solve::frame::Method::Harmonic(crate::solve::harmonic::HarmonicParams {
                margin: 0.1
            })
        );
        let bad = stage.replace("0.1", "0.7");
        let err = parse_stage(&bad, "s.toml").unwrap_err().to_string();
        assert!(
            err.contains("line 5: solver.harmonic_margin: must be in [0, 0.5)"),
            "{err}"
        );
        let err = parse_stage(&stage.replace("harmonic\"", "laplace\""), "s.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("laplace"), "{err}");
    }

    #[test]
    fn syntax_errors_name_their_line() {
        let err = parse_stage("[solver]\nrate_hz = = 3\n", "s.toml").unwrap_err();
        assert!(err.to_string().contains("line 2"), "{err}");
    }

    #[test]
    fn character_must_be_one_of_procedural_or_path() {
        let err = parse_stage("[[inputs]]\ntype = \"synthetic\"\n", "s.toml").unwrap_err();
        let s = err.to_string();
        assert!(s.contains("character: missing"), "{s}");
        assert!(s.contains("needs a procedural character"), "{s}");
    }
}
