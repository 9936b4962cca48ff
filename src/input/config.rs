//! The `[[inputs]]` tables of a stage config: one struct per kind of input, each key
//! documented, unknown keys refused, and each kind's own checks ([`InputConfig::problems`]).
//! The runtime side of each kind is its adapter in this folder.

use crate::protocol::url::{self, Endpoint, UrlError};
use std::collections::BTreeMap;
use std::path::PathBuf;

/// One `[[inputs]]` entry, chosen by `type`.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum InputConfig {
    /// The in-process test source: the procedural character playing a motion, with
    /// noise and occlusion gaps (needs `character.procedural`).
    Synthetic(SyntheticInputConfig),
    /// A recording played as live input with its own timing: a bundled session or a
    /// C3D / TSV / BVH / session file. Labels map to the character's markers by name.
    Replay(ReplayInputConfig),
    /// OSC over UDP (`protocols/osc.md`): `url = "osc://127.0.0.1:9000"` for the native
    /// schema and address patterns, `"vmc://127.0.0.1:39539"` for VMC. Marker names map
    /// to the character's markers by name.
    Osc(OscInputConfig),
    /// NatNet (OptiTrack Motive) frames of data (`protocols/natnet.md`):
    /// `url = "natnet://239.255.42.99:1511"` (a multicast group is joined) or a unicast
    /// data port; `?version=4.1` for newer servers, `?server=IP` for the command port
    /// (marker names). Markers are named `SET:NAME`, or `SET_1`, `SET_2`... without it.
    /// `type = "natnet"` (`"nat_net"` is read too).
    #[serde(rename = "natnet", alias = "nat_net")]
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
    pub calibration: BTreeMap<String, super::glove::FingerCalibration>,
    /// The character's joints each finger drives, base to distal, e.g.
    /// `index = ["index_1", "index_2", "index_3"]` (default: those names, the procedural
    /// hand's).
    #[serde(default)]
    pub joints: BTreeMap<String, [String; 3]>,
}

impl GloveInputConfig {
    /// Per-finger calibration, thumb to pinky, defaults filled in for `max_value`.
    pub fn calibration(&self, max_value: u32) -> [super::glove::FingerCalibration; 5] {
        crate::protocol::glove::FINGERS.map(|f| {
            self.calibration
                .get(f)
                .copied()
                .unwrap_or(super::glove::FingerCalibration {
                    open: 0,
                    closed: max_value,
                })
        })
    }

    /// Driven joint names, thumb to pinky, defaults filled in.
    pub fn joints(&self) -> [[String; 3]; 5] {
        let mut names = super::glove::default_finger_joints();
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
    pub sensors: BTreeMap<String, String>,
}

/// `type = "natnet"`.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NatNetInputConfig {
    /// `natnet://HOST:PORT[?version=M.m&server=IP[:PORT]]`: the data port to bind.
    pub url: String,
    /// With a server in the URL: drop frames from any sender but the stream's (the first
    /// to send frames from the server's host). Off by default: they are taken, counted
    /// and said once (a server with several interfaces may send from more than one).
    #[serde(default)]
    pub strict_source: bool,
}

/// `type = "osc"`.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OscInputConfig {
    /// `osc://HOST:PORT` or `vmc://HOST:PORT`: the address to bind.
    pub url: String,
    /// Address patterns with a `{name}` part and three float arguments; a `{subject}`
    /// part names the performer (`/mocap/{subject}/{name}` makes `Ann:LFHD` of
    /// `/mocap/Ann/LFHD`).
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
    /// Whose take it is: its labels without a subject prefix are read as this subject's
    /// (`LFHD` as `Ann:LFHD`), so that a stage of several actors plays one file per
    /// actor (default: as written).
    pub subject: Option<String>,
}

impl Default for ReplayInputConfig {
    fn default() -> Self {
        Self {
            session: None,
            path: None,
            bvh_scale: crate::replay::recording::DEFAULT_BVH_METRES_PER_UNIT,
            speed: 1.0,
            looping: false,
            subject: None,
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
    /// Length of the session, seconds (at most 3600, and a million frames).
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

/// Why an input URL cannot serve as the input of a given `type`.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum InputUrlError {
    #[error(transparent)]
    Url(#[from] UrlError),
    #[error("{url:?} is not a {expected} URL")]
    WrongScheme { url: String, expected: &'static str },
}

/// Parses `url` and checks that it is one of `schemes`.
pub fn endpoint_of(url: &str, schemes: &[&'static str]) -> Result<Endpoint, InputUrlError> {
    let e = url::parse(url)?;
    if schemes.contains(&e.scheme()) {
        Ok(e)
    } else {
        Err(InputUrlError::WrongScheme {
            url: url.to_owned(),
            expected: match schemes {
                ["osc", "vmc"] => "osc:// or vmc://",
                ["natnet"] => "natnet://",
                ["vrpn"] => "vrpn://",
                _ => "glove://",
            },
        })
    }
}

/// The URL schemes each kind of network input takes.
pub const OSC_SCHEMES: &[&str] = &["osc", "vmc"];
pub const NATNET_SCHEMES: &[&str] = &["natnet"];
pub const VRPN_SCHEMES: &[&str] = &["vrpn"];
pub const GLOVE_SCHEMES: &[&str] = &["glove"];

impl InputConfig {
    /// The input a URL names, every other key at its default: what `rigless listen`
    /// opens.
    pub fn from_url(url: &str) -> Result<Self, UrlError> {
        Ok(match url::parse(url)? {
            Endpoint::Osc(_) | Endpoint::Vmc(_) => InputConfig::Osc(OscInputConfig {
                url: url.to_owned(),
                ..OscInputConfig::default()
            }),
            Endpoint::NatNet { .. } => InputConfig::NatNet(NatNetInputConfig {
                url: url.to_owned(),
                strict_source: false,
            }),
            Endpoint::Vrpn { .. } => InputConfig::Vrpn(VrpnInputConfig {
                url: url.to_owned(),
                sensors: BTreeMap::new(),
            }),
            Endpoint::Glove(_) => InputConfig::Glove(GloveInputConfig {
                url: url.to_owned(),
                calibration: BTreeMap::new(),
                joints: BTreeMap::new(),
            }),
        })
    }

    /// The same input with the sender's units and up axis set (`rigless listen --scale
    /// --z-up`): they apply to an `osc://` input, whose senders use their own; the other
    /// kinds' units are fixed by their protocol.
    pub fn with_sender_units(mut self, metres_per_unit: f64, z_up: bool) -> Self {
        if let InputConfig::Osc(o) = &mut self {
            if o.url.starts_with("osc://") {
                o.scale = metres_per_unit;
                o.up = if z_up { "Z" } else { "Y" }.into();
            }
        }
        self
    }

    /// Whether the input poses joints directly (a data glove) rather than sending
    /// markers: the stage then gives the loop a pin slot.
    pub fn poses_joints(&self) -> bool {
        matches!(self, InputConfig::Glove(_))
    }

    /// The input's kind, as `type` names it and as its Rerun series are named.
    pub fn kind(&self) -> &'static str {
        match self {
            InputConfig::Osc(_) => "osc",
            InputConfig::NatNet(_) => "natnet",
            InputConfig::Vrpn(_) => "vrpn",
            InputConfig::Glove(_) => "glove",
            InputConfig::Synthetic(_) => "synthetic",
            InputConfig::Replay(_) => "replay",
        }
    }

    /// How a session file's header names the input: its URL, `replay:NAME` or
    /// `synthetic:MOTION`.
    pub fn describe(&self) -> String {
        match self {
            InputConfig::Osc(o) => o.url.clone(),
            InputConfig::NatNet(n) => n.url.clone(),
            InputConfig::Vrpn(v) => v.url.clone(),
            InputConfig::Glove(g) => g.url.clone(),
            InputConfig::Synthetic(s) => {
                format!("synthetic:{}", s.motion.as_deref().unwrap_or("default"))
            }
            InputConfig::Replay(r) => match (&r.session, &r.path) {
                (Some(n), _) => format!("replay:{n}"),
                (None, Some(p)) => format!("replay:{}", p.display()),
                (None, None) => "replay".into(),
            },
        }
    }

    /// What is wrong with this entry on its own, as `(key, message)` with keys relative
    /// to the entry (`""` for the entry itself). Rules that involve other sections (a
    /// synthetic input needs a procedural character) are the stage config's.
    pub fn problems(&self) -> Vec<(String, String)> {
        let mut out = Vec::new();
        let mut push = |key: &str, msg: String| out.push((key.to_owned(), msg));
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let mut url_problem = |url: &str, schemes: &[&'static str]| {
            if let Err(e) = endpoint_of(url, schemes) {
                push("url", e.to_string());
            }
        };
        match self {
            InputConfig::Vrpn(v) => url_problem(&v.url, VRPN_SCHEMES),
            InputConfig::Glove(g) => url_problem(&g.url, GLOVE_SCHEMES),
            InputConfig::NatNet(n) => url_problem(&n.url, NATNET_SCHEMES),
            InputConfig::Osc(o) => url_problem(&o.url, OSC_SCHEMES),
            InputConfig::Replay(_) | InputConfig::Synthetic(_) => {}
        }
        match self {
            InputConfig::Vrpn(v) => {
                for k in v.sensors.keys().filter(|k| k.parse::<i32>().is_err()) {
                    push("sensors", format!("{k:?} is not a sensor number"));
                }
            }
            InputConfig::Glove(g) => {
                let fingers = crate::protocol::glove::FINGERS;
                for (key, names) in [
                    ("calibration", g.calibration.keys().collect::<Vec<_>>()),
                    ("joints", g.joints.keys().collect()),
                ] {
                    for k in names.into_iter().filter(|k| !fingers.contains(&k.as_str())) {
                        push(
                            key,
                            format!("{k:?} is not a finger (expected one of {fingers:?})"),
                        );
                    }
                }
            }
            InputConfig::NatNet(_) => {}
            InputConfig::Osc(o) => {
                if !(positive(o.scale) && o.scale <= 1e3) {
                    push(
                        "scale",
                        format!("must be in (0, 1000] metres per unit, got {:?}", o.scale),
                    );
                }
                if !["Y", "Z", "y", "z"].contains(&o.up.as_str()) {
                    push("up", format!("must be \"Y\" or \"Z\", got {:?}", o.up));
                }
                for p in &o.patterns {
                    let subjects = p.matches("{subject}").count();
                    let apart = subjects == 0
                        || !(p.contains("{subject}{name}") || p.contains("{name}{subject}"));
                    if p.matches("{name}").count() != 1
                        || !p.starts_with('/')
                        || subjects > 1
                        || !apart
                    {
                        push(
                            "patterns",
                            format!("{p:?} needs to start with / and hold {{name}} once, and {{subject}} at most once, apart from {{name}}"),
                        );
                    }
                }
            }
            InputConfig::Replay(r) => {
                match (&r.session, &r.path) {
                    (Some(_), Some(_)) => push("", "give either session or path, not both".into()),
                    (None, None) => push(
                        "",
                        "a replay input needs session = \"NAME\" (bundled) or path = \"FILE.c3d\""
                            .into(),
                    ),
                    (Some(n), None) if crate::replay::bundled::bundled(n).is_none() => {
                        let names: Vec<&str> = crate::replay::bundled::names().collect();
                        push(
                            "session",
                            format!("no bundled session {n:?} (there are {names:?})"),
                        );
                    }
                    _ => {}
                }
                if let Some(m) = r.subject.as_deref().and_then(|s| {
                    crate::character::config::name_problem(
                        s,
                        "a subject's name as it prefixes labels (`Ann` for `Ann:LFHD`)",
                    )
                }) {
                    push("subject", m);
                }
                if !(positive(r.bvh_scale) && r.bvh_scale <= 10.0) {
                    push(
                        "bvh_scale",
                        format!("must be in (0, 10] metres per unit, got {:?}", r.bvh_scale),
                    );
                }
                if !(positive(r.speed) && r.speed <= 100.0) {
                    push("speed", format!("must be in (0, 100], got {:?}", r.speed));
                }
            }
            InputConfig::Synthetic(s) => {
                // The session is made whole before it plays: an hour at most, and at
                // most a million frames.
                if !(positive(s.session_secs) && s.session_secs <= 3600.0) {
                    push(
                        "session_secs",
                        format!("must be in (0, 3600] s, got {:?}", s.session_secs),
                    );
                } else if s.session_secs * s.rate_hz > 1e6 {
                    push(
                        "session_secs",
                        format!(
                            "{} s at {} Hz is more than a million frames",
                            s.session_secs, s.rate_hz
                        ),
                    );
                }
                if !(positive(s.rate_hz) && s.rate_hz <= 10_000.0) {
                    push(
                        "rate_hz",
                        format!("must be in (0, 10000] Hz, got {:?}", s.rate_hz),
                    );
                }
                if !(s.noise_mm.is_finite() && s.noise_mm >= 0.0) {
                    push(
                        "noise_mm",
                        format!("must be zero or more, got {:?}", s.noise_mm),
                    );
                }
                if !(s.gap_percent.is_finite() && (0.0..=90.0).contains(&s.gap_percent)) {
                    push(
                        "gap_percent",
                        format!("must be 0 to 90, got {:?}", s.gap_percent),
                    );
                }
            }
        }
        out
    }
}
