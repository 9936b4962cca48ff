//! Serial data gloves: the port (opened, read, reopened after an unplug) and the mapping
//! from a glove's readings to the hand skeleton's joint angles (per-finger calibration,
//! curls to flexion, splay to abduction). The solver gets the angles as pinned posture
//! parameters, and forward kinematics from the wrist turns them into the skeleton joint
//! positions that constrain the control mesh (Le Naour et al.: "positions of the skeleton
//! joints as control inputs"). The wrist itself comes from optical markers when the stage
//! has them, otherwise it stays where it is.

use super::config::{endpoint_of, GloveInputConfig, GLOVE_SCHEMES};
use super::{InputError, InputSink, PacketStats};
use crate::character::skeleton::{compose, Skeleton, SwingTwist};
use crate::protocol::glove::{decode_line, GloveReading, LineFramer, FINGERS};
use crate::protocol::url::{Endpoint, GlovePort};
use crate::runtime::clock::unix_now;
use crate::runtime::net::is_wait;
use glam::{DQuat, DVec3};
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

/// Joints per finger a glove drives (base, middle, distal).
pub const JOINTS_PER_FINGER: usize = 3;

/// How long a blocked read waits before checking the stop flag.
const READ_POLL: Duration = Duration::from_millis(100);

/// Wait between attempts to open a port that is absent or failing.
pub const REOPEN_INTERVAL: Duration = Duration::from_millis(250);

/// Per-finger calibration: the raw readings of the open and the closed hand.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FingerCalibration {
    /// Reading with the finger straight.
    pub open: u32,
    /// Reading with the finger fully curled.
    pub closed: u32,
}

impl FingerCalibration {
    /// Curl fraction of a raw reading: 0 open, 1 closed, clamped (a reversed range, where
    /// `closed < open`, is a sensor mounted the other way round).
    pub fn fraction(&self, raw: u32) -> f64 {
        if self.open == self.closed {
            return 0.0;
        }
        ((f64::from(raw) - f64::from(self.open)) / (f64::from(self.closed) - f64::from(self.open)))
            .clamp(0.0, 1.0)
    }
}

/// Names of the joints each finger drives, thumb to pinky, base to distal (the procedural
/// hand's by default).
pub fn default_finger_joints() -> [[String; JOINTS_PER_FINGER]; 5] {
    FINGERS.map(|f| [1, 2, 3].map(|k| format!("{f}_{k}")))
}

/// Why a glove cannot drive a skeleton.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GloveMapError {
    #[error("glove joint {name:?} ({finger}) is not in the skeleton")]
    UnknownJoint { finger: &'static str, name: String },
    #[error("glove joint {name:?} ({finger}) is a root or a leaf: it has no angles to drive")]
    NotDrivable { finger: &'static str, name: String },
}

/// One driven joint: its index, its rest frame, and its flexion and abduction ranges.
#[derive(Clone, Copy, Debug)]
struct Driven {
    joint: usize,
    twist_axis: DVec3,
    bend_axis: DVec3,
    /// Flexion of the closed finger (the limit's upper end; 90° without limits).
    closed_bend_rad: f64,
    bend_rad: (f64, f64),
    side_rad: (f64, f64),
}

/// The mapping from glove readings to the joint angles of one skeleton.
#[derive(Clone, Debug)]
pub struct HandMap {
    driven: [[Driven; JOINTS_PER_FINGER]; 5],
    calibration: [FingerCalibration; 5],
    max_value: u32,
}

impl HandMap {
    /// Resolves `finger_joints` (thumb to pinky, base to distal) in `sk`; `calibration`
    /// per finger in raw readings; `max_value` the full scale (splay and joystick centre).
    pub fn new(
        sk: &Skeleton,
        finger_joints: &[[String; JOINTS_PER_FINGER]; 5],
        calibration: [FingerCalibration; 5],
        max_value: u32,
    ) -> Result<Self, Vec<GloveMapError>> {
        let mut errors = Vec::new();
        let mut driven = [[None; JOINTS_PER_FINGER]; 5];
        for (f, names) in finger_joints.iter().enumerate() {
            for (k, name) in names.iter().enumerate() {
                let finger = FINGERS[f];
                let Some(j) = sk.joints.iter().position(|jt| jt.name == *name) else {
                    errors.push(GloveMapError::UnknownJoint {
                        finger,
                        name: name.clone(),
                    });
                    continue;
                };
                let joint = &sk.joints[j];
                if joint.parent.is_none() || sk.children(j).next().is_none() {
                    errors.push(GloveMapError::NotDrivable {
                        finger,
                        name: name.clone(),
                    });
                    continue;
                }
                let full = (-std::f64::consts::PI, std::f64::consts::PI);
                let (bend, side) = joint.limits.map_or((full, full), |l| (l.bend, l.side));
                driven[f][k] = Some(Driven {
                    joint: j,
                    twist_axis: sk.twist_axis(j),
                    bend_axis: joint.bend_axis,
                    closed_bend_rad: if joint.limits.is_some() {
                        bend.1
                    } else {
                        std::f64::consts::FRAC_PI_2
                    },
                    bend_rad: bend,
                    side_rad: side,
                });
            }
        }
        if !errors.is_empty() {
            return Err(errors);
        }
        Ok(Self {
            driven: driven.map(|d| d.map(|x| x.expect("every joint resolved"))),
            calibration,
            max_value,
        })
    }

    /// The glove's full-scale reading.
    pub fn max_value(&self) -> u32 {
        self.max_value
    }

    /// The skeleton joints driven, thumb to pinky, base to distal.
    pub fn joints(&self) -> [[usize; JOINTS_PER_FINGER]; 5] {
        self.driven.map(|d| d.map(|x| x.joint))
    }

    /// Joint angles for a reading, per finger and joint: flexion = calibrated curl ×
    /// the closed flexion (per-joint readings where sent, else the finger's), abduction of
    /// the base joint = splay (−1..1 about the centre reading) × its limit on that side,
    /// no twist. `None` where the reading has no value for the joint.
    pub fn angles(&self, r: &GloveReading) -> [[Option<SwingTwist>; JOINTS_PER_FINGER]; 5] {
        let mut out = [[None; JOINTS_PER_FINGER]; 5];
        for (f, joints) in self.driven.iter().enumerate() {
            let splay = r.splay[f].map_or(0.0, |v| {
                (2.0 * f64::from(v) / f64::from(self.max_value.max(1)) - 1.0).clamp(-1.0, 1.0)
            });
            for (k, d) in joints.iter().enumerate() {
                let Some(raw) = r.joint_raw(f, k) else {
                    continue;
                };
                let curl = self.calibration[f].fraction(raw);
                let bend = (curl * d.closed_bend_rad).clamp(d.bend_rad.0, d.bend_rad.1);
                let side = if k > 0 {
                    0.0
                } else if splay >= 0.0 {
                    splay * d.side_rad.1.max(0.0)
                } else {
                    -splay * d.side_rad.0.min(0.0)
                };
                out[f][k] = Some(SwingTwist {
                    twist: 0.0,
                    bend,
                    side,
                });
            }
        }
        out
    }

    /// Writes a reading's angles as posture pins (`first` gives each joint's first
    /// parameter, as [`crate::rig::ik_model::IkModel::angle_params`]); joints without a value
    /// keep their pins.
    pub fn write_pins(
        &self,
        r: &GloveReading,
        first: &dyn Fn(usize) -> Option<usize>,
        pins: &mut [f64],
    ) {
        let angles = self.angles(r);
        for (f, joints) in self.driven.iter().enumerate() {
            for (k, d) in joints.iter().enumerate() {
                if let (Some(a), Some(i)) = (angles[f][k], first(d.joint)) {
                    if i + 3 <= pins.len() {
                        pins[i..i + 3].copy_from_slice(&[a.twist, a.bend, a.side]);
                    }
                }
            }
        }
    }

    /// Local rotations (relative to rest, one per joint of `sk`) for a reading; joints the
    /// glove does not drive stay at rest.
    pub fn local_rotations(&self, r: &GloveReading, local: &mut [DQuat]) {
        local.fill(DQuat::IDENTITY);
        let angles = self.angles(r);
        for (f, joints) in self.driven.iter().enumerate() {
            for (k, d) in joints.iter().enumerate() {
                if let Some(a) = angles[f][k] {
                    local[d.joint] = compose(a, d.twist_axis, d.bend_axis);
                }
            }
        }
    }
}

/// What a glove input has done: lines as packets, plus how often the port was opened.
#[derive(Debug, Default)]
pub struct GloveStats {
    pub lines: PacketStats,
    /// Successful opens of the port (1 + replugs).
    pub connections: AtomicU64,
    /// Times an open port failed (unplugged, or the device went away).
    pub disconnects: AtomicU64,
}

impl std::fmt::Display for GloveStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} (lines), {} connections, {} disconnects",
            self.lines,
            self.connections.load(Ordering::Relaxed),
            self.disconnects.load(Ordering::Relaxed)
        )
    }
}

/// Reads the glove on `port` until `stop` is set, calling `on_reading(receive_unix_s,
/// reading)` for each line that decodes. An absent or failing port is retried every
/// [`REOPEN_INTERVAL`] (a replugged glove is picked up by itself); a partial line cut by
/// an unplug is dropped. Bad lines are counted and skipped. The first failure to open
/// after a working period is logged once.
pub fn run(
    port: &GlovePort,
    stop: &AtomicBool,
    stats: &GloveStats,
    on_reading: &mut dyn FnMut(f64, &GloveReading),
) {
    let mut framer = LineFramer::default();
    let mut reading = GloveReading::default();
    let mut buf = [0u8; 1024];
    // The last failure to open that was logged (each different one is, once).
    let mut logged: Option<String> = None;
    while !stop.load(Ordering::Relaxed) {
        let mut serial = match open(&port.path, port.baud) {
            Ok(s) => s,
            Err(e) => {
                let text = e.to_string();
                if logged.as_deref() != Some(text.as_str()) {
                    tracing::warn!(
                        "glove port {}: {text}; retrying every {} ms",
                        port.path.display(),
                        REOPEN_INTERVAL.as_millis()
                    );
                    logged = Some(text);
                }
                std::thread::sleep(REOPEN_INTERVAL);
                continue;
            }
        };
        logged = None;
        stats.connections.fetch_add(1, Ordering::Relaxed);
        tracing::info!("glove port {} open", port.path.display());
        framer.reset();
        while !stop.load(Ordering::Relaxed) {
            match serial.read(&mut buf) {
                Ok(0) => {
                    // End of file: the device is gone.
                    stats.disconnects.fetch_add(1, Ordering::Relaxed);
                    break;
                }
                Ok(n) => {
                    let now = unix_now();
                    framer.push(&buf[..n], &mut |line| match line.and_then(|l| {
                        decode_line(l, port.format, port.max_value, &mut reading).map(|_| l.len())
                    }) {
                        Ok(len) => {
                            stats.lines.received(len + 1, now);
                            on_reading(now, &reading);
                        }
                        Err(_) => stats.lines.error(),
                    });
                }
                Err(e) if is_wait(&e) => {}
                Err(e) => {
                    tracing::warn!("glove port {}: {e}; reopening", port.path.display());
                    stats.disconnects.fetch_add(1, Ordering::Relaxed);
                    break;
                }
            }
        }
    }
}

/// An opened glove input: its port and its map onto the character's joints.
pub struct GloveInput {
    port: GlovePort,
    map: HandMap,
}

impl GloveInput {
    /// Reads `cfg.url` and maps the glove onto `skeleton` (the port itself is opened
    /// when it runs, and again after an unplug).
    pub fn open(cfg: &GloveInputConfig, skeleton: Option<&Skeleton>) -> Result<Self, InputError> {
        let endpoint = endpoint_of(&cfg.url, GLOVE_SCHEMES).map_err(|source| InputError::Url {
            url: cfg.url.clone(),
            source,
        })?;
        let Endpoint::Glove(port) = endpoint else {
            unreachable!("endpoint_of checked the scheme")
        };
        let skeleton = skeleton.ok_or_else(|| InputError::NeedsSkeleton {
            url: cfg.url.clone(),
        })?;
        let map = HandMap::new(
            skeleton,
            &cfg.joints(),
            cfg.calibration(port.max_value),
            port.max_value,
        )
        .map_err(|problems| InputError::GloveMap {
            url: cfg.url.clone(),
            problems,
        })?;
        Ok(Self { port, map })
    }

    /// The port's settings.
    pub fn port(&self) -> &GlovePort {
        &self.port
    }

    /// `glove input reading PORT (BAUD baud, FORMAT, full scale MAX)`.
    pub fn opened(&self) -> String {
        let p = &self.port;
        format!(
            "glove input reading {} ({} baud, {:?}, full scale {}; reopens by itself)",
            p.path.display(),
            p.baud,
            p.format,
            p.max_value
        )
    }

    /// Reads lines until `stop` is set; returns what it read.
    pub fn run(self, stop: &AtomicBool, sink: &mut dyn InputSink) -> String {
        let stats = GloveStats::default();
        run(&self.port, stop, &stats, &mut |recv, r| {
            if !sink.glove(recv, r, &self.map) {
                stop.store(true, Ordering::Relaxed);
            }
        });
        stats.to_string()
    }
}

fn open(path: &Path, baud: u32) -> Result<Box<dyn serialport::SerialPort>, serialport::Error> {
    serialport::new(path.to_string_lossy(), baud)
        .data_bits(serialport::DataBits::Eight)
        .parity(serialport::Parity::None)
        .stop_bits(serialport::StopBits::One)
        .flow_control(serialport::FlowControl::None)
        .timeout(READ_POLL)
        .open()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::character::demo::demo_hand;
    use crate::protocol::glove::DEFAULT_MAX_VALUE;

    fn full_scale() -> [FingerCalibration; 5] {
        [FingerCalibration {
            open: 0,
            closed: DEFAULT_MAX_VALUE,
        }; 5]
    }

    #[test]
    fn calibration_maps_open_and_closed_readings_to_0_and_1() {
        let c = FingerCalibration {
            open: 400,
            closed: 3600,
        };
        assert_eq!(c.fraction(400), 0.0);
        assert_eq!(c.fraction(3600), 1.0);
        assert_eq!(c.fraction(2000), 0.5);
        assert_eq!((c.fraction(0), c.fraction(4095)), (0.0, 1.0));
        let reversed = FingerCalibration {
            open: 3600,
            closed: 400,
        };
        assert_eq!(reversed.fraction(2000), 0.5);
        assert_eq!(reversed.fraction(400), 1.0);
    }

    #[test]
    fn closed_fist_bends_every_joint_to_its_limit_and_open_hand_is_rest() {
        let hand = demo_hand();
        let sk = &hand.skeleton;
        let map = HandMap::new(
            sk,
            &default_finger_joints(),
            full_scale(),
            DEFAULT_MAX_VALUE,
        )
        .unwrap();
        let fist = GloveReading {
            curl: [Some(DEFAULT_MAX_VALUE); 5],
            ..Default::default()
        };
        let a = map.angles(&fist);
        for (f, joints) in map.joints().iter().enumerate() {
            for (k, &j) in joints.iter().enumerate() {
                let lim = sk.joints[j].limits.unwrap();
                let st = a[f][k].unwrap();
                assert_eq!(st.bend, lim.bend.1, "{}", sk.joints[j].name);
                assert_eq!((st.twist, st.side), (0.0, 0.0));
            }
        }
        let open = GloveReading {
            curl: [Some(0); 5],
            ..Default::default()
        };
        let mut local = vec![DQuat::IDENTITY; sk.len()];
        map.local_rotations(&open, &mut local);
        assert!(local
            .iter()
            .all(|q| q.angle_between(DQuat::IDENTITY) < 1e-12));
        // Per-joint readings override the finger's; splay reaches the side limits.
        let r = GloveReading {
            curl: [Some(0); 5],
            joint_curl: [[None, Some(DEFAULT_MAX_VALUE), None, None]; 5],
            splay: [Some(0), Some(DEFAULT_MAX_VALUE), None, None, None],
            ..Default::default()
        };
        let a = map.angles(&r);
        let j_index = map.joints()[1];
        let lim = |j: usize| sk.joints[j].limits.unwrap();
        assert_eq!(a[1][1].unwrap().bend, lim(j_index[1]).bend.1);
        assert_eq!(a[1][0].unwrap().bend, 0.0);
        assert_eq!(a[1][0].unwrap().side, lim(j_index[0]).side.1);
        assert_eq!(a[0][0].unwrap().side, lim(map.joints()[0][0]).side.0);
        assert_eq!(a[2][0].unwrap().side, 0.0);
    }

    #[test]
    fn unknown_and_undrivable_joints_are_all_reported() {
        let hand = demo_hand();
        let mut names = default_finger_joints();
        names[1][0] = "knuckle".into();
        names[4][2] = "wrist".into();
        let errs =
            HandMap::new(&hand.skeleton, &names, full_scale(), DEFAULT_MAX_VALUE).unwrap_err();
        assert_eq!(errs.len(), 2);
        assert!(errs[0]
            .to_string()
            .contains("\"knuckle\" (index) is not in the skeleton"));
        assert!(errs[1]
            .to_string()
            .contains("\"wrist\" (pinky) is a root or a leaf"));
    }
}
