//! OSC marker packets (`protocols/osc.md`), as pure functions over bytes: the native
//! rigless schema, address patterns for existing senders (`/mocap/{name} f f f`), and the
//! VMC protocol. Parsing is rosc's, behind a nesting check (rosc recurses once per nested
//! bundle, so a hostile 64 KB packet could otherwise exhaust the stack).
//!
//! Output positions are in the world frame (metres, right-handed, Y up): native and
//! pattern senders are converted by their [`OscMapping`]'s scale and up axis; VMC's
//! left-handed Unity frame (Y up, metres) by negating Z.

use glam::DVec3;
use rosc::{OscBundle, OscMessage, OscPacket, OscType};

/// Deepest bundle nesting accepted.
pub const MAX_BUNDLE_DEPTH: usize = 8;
/// Largest packet accepted, bytes (a UDP datagram's limit).
pub const MAX_PACKET_LEN: usize = 65_507;

/// One marker observation from a packet.
#[derive(Clone, Debug, PartialEq)]
pub struct OscMarker {
    pub name: String,
    /// World frame, metres; NaN when the sender flagged it occluded or sent NaN.
    pub position_m: DVec3,
    pub occluded: bool,
}

/// What one packet carried.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OscFrame {
    /// The sender's frame number (native `/rigless/frame`), if any.
    pub frame: Option<i64>,
    /// The bundle's time tag as seconds since 1900 (NTP), unless it is "immediately".
    pub time_tag_s: Option<f64>,
    /// VMC's `/VMC/Ext/T` time, seconds.
    pub vmc_time_s: Option<f64>,
    pub markers: Vec<OscMarker>,
    /// Messages whose address nothing here uses (VMC's OK, unknown addresses).
    pub ignored_messages: usize,
}

/// How to read markers out of messages.
#[derive(Clone, Debug, PartialEq)]
pub struct OscMapping {
    /// Address patterns with a `{name}` part taking the marker name and three float
    /// arguments, e.g. `/mocap/{name}`. The native `/rigless/marker` always works.
    pub patterns: Vec<String>,
    /// Metres per sender unit (1 for metres, 0.001 for millimetres).
    pub scale: f64,
    /// The sender's up axis: `Y` (as the world) or `Z` (`(x, y, z)` becomes `(x, z, -y)`).
    pub z_up: bool,
    /// Read VMC addresses (`/VMC/Ext/...`): trackers and bones become markers named by
    /// their serial or bone name, the root `root`.
    pub vmc: bool,
}

impl Default for OscMapping {
    fn default() -> Self {
        Self {
            patterns: vec!["/marker/{name}".into(), "/mocap/{name}".into()],
            scale: 1.0,
            z_up: false,
            vmc: true,
        }
    }
}

/// Why a packet was dropped.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum OscDecodeError {
    #[error("packet of {len} bytes exceeds {MAX_PACKET_LEN}")]
    TooLong { len: usize },
    #[error("bundles nested deeper than {MAX_BUNDLE_DEPTH}")]
    TooDeep,
    #[error("not OSC: {0}")]
    Osc(String),
}

/// Nesting depth of bundles in `b` without recursing more than `MAX_BUNDLE_DEPTH` deep;
/// `None` when deeper. Malformed sizes end the walk (rosc reports them).
fn bundle_depth(b: &[u8], depth: usize) -> Option<usize> {
    if !b.starts_with(b"#bundle\0") {
        return Some(depth);
    }
    if depth >= MAX_BUNDLE_DEPTH {
        return None;
    }
    let mut at = 16;
    let mut deepest = depth + 1;
    while at + 4 <= b.len() {
        let n = u32::from_be_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]) as usize;
        let end = at.saturating_add(4).saturating_add(n);
        let Some(elem) = b.get(at + 4..end) else {
            break;
        };
        deepest = deepest.max(bundle_depth(elem, depth + 1)?);
        at = end;
    }
    Some(deepest)
}

fn float(a: &OscType) -> Option<f64> {
    match a {
        OscType::Float(f) => Some(*f as f64),
        OscType::Double(d) => Some(*d),
        OscType::Int(i) => Some(*i as f64),
        OscType::Long(l) => Some(*l as f64),
        _ => None,
    }
}

fn seconds_1900(t: rosc::OscTime) -> Option<f64> {
    // (0, 1) means "immediately".
    (!(t.seconds == 0 && t.fractional <= 1))
        .then(|| t.seconds as f64 + t.fractional as f64 / 4_294_967_296.0)
}

/// Matches `addr` against `pattern` with one `{name}` part; returns the name.
fn match_pattern<'a>(pattern: &str, addr: &'a str) -> Option<&'a str> {
    let (pre, post) = pattern.split_once("{name}")?;
    let rest = addr.strip_prefix(pre)?;
    let name = rest.strip_suffix(post)?;
    (!name.is_empty() && !name.contains('/')).then_some(name)
}

/// Seconds between the NTP epoch (1900) and the Unix epoch (1970).
pub const NTP_UNIX_OFFSET_S: f64 = 2_208_988_800.0;

impl OscFrame {
    /// The sender's time of this packet, seconds: the bundle time tag as Unix time, else
    /// VMC's `/VMC/Ext/T`; `None` when the packet carries no time.
    pub fn source_time_s(&self) -> Option<f64> {
        self.time_tag_s
            .map(|t| t - NTP_UNIX_OFFSET_S)
            .or(self.vmc_time_s)
    }
}

impl OscMapping {
    fn to_world(&self, p: DVec3) -> DVec3 {
        let p = p * self.scale;
        if self.z_up {
            DVec3::new(p.x, p.z, -p.y)
        } else {
            p
        }
    }

    fn message(&self, m: &OscMessage, out: &mut OscFrame) {
        let xyz = |args: &[OscType]| -> Option<DVec3> {
            Some(DVec3::new(
                float(args.first()?)?,
                float(args.get(1)?)?,
                float(args.get(2)?)?,
            ))
        };
        let addr = m.addr.as_str();
        if addr == "/rigless/frame" {
            out.frame = m.args.first().and_then(float).map(|f| f as i64);
            return;
        }
        if addr == "/rigless/marker" {
            if let Some(OscType::String(name)) = m.args.first() {
                let p = xyz(&m.args[1..]);
                let occluded = p.is_none_or(|p| !p.is_finite());
                out.markers.push(OscMarker {
                    name: name.clone(),
                    position_m: p
                        .filter(|p| p.is_finite())
                        .map_or(DVec3::NAN, |p| self.to_world(p)),
                    occluded,
                });
                return;
            }
        }
        if self.vmc && addr.starts_with("/VMC/Ext/") {
            match addr {
                "/VMC/Ext/Root/Pos" | "/VMC/Ext/Bone/Pos" | "/VMC/Ext/Tra/Pos" => {
                    if let (Some(OscType::String(name)), Some(p)) =
                        (m.args.first(), xyz(&m.args[1..]))
                    {
                        // Unity: left-handed, Y up, metres.
                        out.markers.push(OscMarker {
                            name: name.clone(),
                            position_m: DVec3::new(p.x, p.y, -p.z),
                            occluded: !p.is_finite(),
                        });
                        return;
                    }
                }
                "/VMC/Ext/T" => {
                    out.vmc_time_s = m.args.first().and_then(float);
                    return;
                }
                _ => {}
            }
            out.ignored_messages += 1;
            return;
        }
        for pat in &self.patterns {
            if let Some(name) = match_pattern(pat, addr) {
                if let Some(p) = xyz(&m.args) {
                    out.markers.push(OscMarker {
                        name: name.to_owned(),
                        position_m: if p.is_finite() {
                            self.to_world(p)
                        } else {
                            DVec3::NAN
                        },
                        occluded: !p.is_finite(),
                    });
                    return;
                }
            }
        }
        out.ignored_messages += 1;
    }

    fn bundle(&self, b: &OscBundle, out: &mut OscFrame) {
        if out.time_tag_s.is_none() {
            out.time_tag_s = seconds_1900(b.timetag);
        }
        for p in &b.content {
            match p {
                OscPacket::Message(m) => self.message(m, out),
                OscPacket::Bundle(inner) => self.bundle(inner, out),
            }
        }
    }

    /// Decodes one UDP datagram.
    pub fn decode(&self, b: &[u8]) -> Result<OscFrame, OscDecodeError> {
        if b.len() > MAX_PACKET_LEN {
            return Err(OscDecodeError::TooLong { len: b.len() });
        }
        bundle_depth(b, 0).ok_or(OscDecodeError::TooDeep)?;
        let (_, packet) =
            rosc::decoder::decode_udp(b).map_err(|e| OscDecodeError::Osc(format!("{e:?}")))?;
        let mut out = OscFrame::default();
        match &packet {
            OscPacket::Message(m) => self.message(m, &mut out),
            OscPacket::Bundle(bd) => self.bundle(bd, &mut out),
        }
        Ok(out)
    }
}

/// Encodes a frame of markers in the native schema: one bundle (time tag `time_tag`,
/// NTP seconds and fraction) holding `/rigless/frame i` and one `/rigless/marker s f f f`
/// per marker (NaN positions are sent as NaN: occluded).
pub fn encode_native(frame: i64, time_tag: (u32, u32), markers: &[(&str, DVec3)]) -> Vec<u8> {
    let mut content = vec![OscPacket::Message(OscMessage {
        addr: "/rigless/frame".into(),
        args: vec![OscType::Long(frame)],
    })];
    for (name, p) in markers {
        content.push(OscPacket::Message(OscMessage {
            addr: "/rigless/marker".into(),
            args: vec![
                OscType::String((*name).to_owned()),
                OscType::Float(p.x as f32),
                OscType::Float(p.y as f32),
                OscType::Float(p.z as f32),
            ],
        }));
    }
    rosc::encoder::encode(&OscPacket::Bundle(OscBundle {
        timetag: rosc::OscTime {
            seconds: time_tag.0,
            fractional: time_tag.1,
        },
        content,
    }))
    .expect("a bundle of messages always encodes")
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn native_bytes_match_the_documented_example() {
        // protocols/osc.md, "Native schema" example.
        const HEX: &str = "23 62 75 6e 64 6c 65 00 e8 75 47 00 80 00 00 00
            00 00 00 1c 2f 72 69 67 6c 65 73 73 2f 66 72 61
            6d 65 00 00 2c 68 00 00 00 00 00 00 00 00 00 07
            00 00 00 2c 2f 72 69 67 6c 65 73 73 2f 6d 61 72
            6b 65 72 00 2c 73 66 66 66 00 00 00 4c 46 48 44
            00 00 00 00 3e 80 00 00 3f c0 00 00 be 00 00 00";
        let expected: Vec<u8> = HEX
            .split_whitespace()
            .map(|h| u8::from_str_radix(h, 16).unwrap())
            .collect();
        let b = encode_native(
            7,
            (3_900_000_000, 1 << 31),
            &[("LFHD", DVec3::new(0.25, 1.5, -0.125))],
        );
        assert_eq!(b, expected);
    }

    #[test]
    fn native_round_trip() {
        let b = encode_native(
            42,
            (3_900_000_000, 1 << 31),
            &[("LFHD", DVec3::new(1.0, 2.0, 3.0)), ("RFHD", DVec3::NAN)],
        );
        let f = OscMapping::default().decode(&b).unwrap();
        assert_eq!(f.frame, Some(42));
        assert_eq!(f.time_tag_s, Some(3_900_000_000.5));
        assert_eq!(f.markers.len(), 2);
        assert_eq!(f.markers[0].position_m, DVec3::new(1.0, 2.0, 3.0));
        assert!(f.markers[1].occluded && !f.markers[1].position_m.is_finite());
    }

    #[test]
    fn patterns_scale_and_z_up() {
        let m = OscMapping {
            patterns: vec!["/subject/{name}/pos".into()],
            scale: 0.001,
            z_up: true,
            vmc: false,
        };
        let b = rosc::encoder::encode(&OscPacket::Message(OscMessage {
            addr: "/subject/C7/pos".into(),
            args: vec![
                OscType::Float(100.0),
                OscType::Float(200.0),
                OscType::Float(1500.0),
            ],
        }))
        .unwrap();
        let f = m.decode(&b).unwrap();
        assert_eq!(f.markers[0].name, "C7");
        assert!((f.markers[0].position_m - DVec3::new(0.1, 1.5, -0.2)).length() < 1e-9);
        assert_eq!(match_pattern("/a/{name}", "/a/b/c"), None);
    }

    #[test]
    fn deep_nesting_is_refused_without_recursing() {
        // 3,000 nested bundles: rosc alone would recurse 3,000 times.
        let mut b: Vec<u8> = Vec::new();
        for _ in 0..3000 {
            let mut outer = b"#bundle\0\0\0\0\0\0\0\0\x01".to_vec();
            outer.extend_from_slice(&(b.len() as u32).to_be_bytes());
            outer.extend_from_slice(&b);
            b = outer;
            if b.len() > 60_000 {
                break;
            }
        }
        assert_eq!(
            OscMapping::default().decode(&b),
            Err(OscDecodeError::TooDeep)
        );
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(b in proptest::collection::vec(any::<u8>(), 0..512)) {
            let _ = OscMapping::default().decode(&b);
        }

        #[test]
        fn arbitrary_bytes_after_a_bundle_header_never_panic(tail in proptest::collection::vec(any::<u8>(), 0..512)) {
            let mut b = b"#bundle\0\0\0\0\0\0\0\0\x01".to_vec();
            b.extend_from_slice(&tail);
            let _ = OscMapping::default().decode(&b);
        }
    }
}
