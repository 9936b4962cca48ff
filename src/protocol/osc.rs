//! OSC marker packets (`protocols/osc.md`), as pure functions over bytes: the native
//! rigless schema, address patterns for existing senders (`/mocap/{name} f f f`), and the
//! VMC protocol. Decoding is our own zero-copy reader (rosc's took 17-21 µs for a
//! 50-marker bundle, against a 5 µs budget, and recurses without limit on nested
//! bundles); encoding, for senders and tests, is rosc's.
//!
//! Output positions are in the world frame (metres, right-handed, Y up): native and
//! pattern senders are converted by their [`OscMapping`]'s scale and up axis; VMC's
//! left-handed Unity frame (Y up, metres) by negating Z.

use crate::geom::axes::y_up_from_z_up;
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
    markers: Vec<OscMarker>,
    /// Messages whose address nothing here uses (VMC's OK, unknown addresses).
    pub ignored_messages: usize,
    /// Markers written by the packet being decoded.
    used: usize,
    /// Markers of the last decoded packet.
    visible: usize,
}

impl OscFrame {
    /// The markers of the last decoded packet.
    pub fn markers(&self) -> &[OscMarker] {
        &self.markers[..self.visible]
    }
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

/// One OSC argument, borrowed from the packet.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Arg<'a> {
    Num(f64),
    Str(&'a str),
    Other,
}

impl Arg<'_> {
    fn num(self) -> Option<f64> {
        match self {
            Arg::Num(v) => Some(v),
            _ => None,
        }
    }
}

/// Most arguments read from one message (a marker needs a name and three numbers; VMC
/// sends eight).
const MAX_ARGS: usize = 16;

/// A message's arguments, decoded into a fixed array (no allocation).
struct Args<'a> {
    vals: [Arg<'a>; MAX_ARGS],
    len: usize,
}

impl<'a> Args<'a> {
    fn get(&self, i: usize) -> Option<Arg<'a>> {
        (i < self.len).then(|| self.vals[i])
    }

    fn xyz(&self, from: usize) -> Option<DVec3> {
        Some(DVec3::new(
            self.get(from)?.num()?,
            self.get(from + 1)?.num()?,
            self.get(from + 2)?.num()?,
        ))
    }
}

/// An OSC string at the start of `b` (NUL-terminated, padded to 4): the text and the
/// bytes it takes.
fn osc_str(b: &[u8]) -> Option<(&str, usize)> {
    let n = b.iter().position(|c| *c == 0)?;
    let s = std::str::from_utf8(&b[..n]).ok()?;
    let used = (n + 4) & !3;
    (used <= b.len()).then_some((s, used))
}

fn be4(b: &[u8]) -> Option<[u8; 4]> {
    b.get(..4)?.try_into().ok()
}

fn be8(b: &[u8]) -> Option<[u8; 8]> {
    b.get(..8)?.try_into().ok()
}

/// Decodes a message's type tags and arguments (OSC 1.0 types plus the common
/// extensions); `None` when malformed.
fn parse_args<'a>(tags: &str, mut b: &'a [u8]) -> Option<Args<'a>> {
    let mut out = Args {
        vals: [Arg::Other; MAX_ARGS],
        len: 0,
    };
    for t in tags.bytes().skip(1) {
        let (arg, used) = match t {
            b'f' => (Arg::Num(f32::from_be_bytes(be4(b)?) as f64), 4),
            b'i' => (Arg::Num(i32::from_be_bytes(be4(b)?) as f64), 4),
            b'd' => (Arg::Num(f64::from_be_bytes(be8(b)?)), 8),
            b'h' => (Arg::Num(i64::from_be_bytes(be8(b)?) as f64), 8),
            b's' | b'S' => {
                let (s, used) = osc_str(b)?;
                (Arg::Str(s), used)
            }
            b'b' => {
                let n = u32::from_be_bytes(be4(b)?) as usize;
                let used = 4usize.checked_add((n + 3) & !3)?;
                (Arg::Other, used)
            }
            b't' => (Arg::Other, 8),
            b'c' | b'r' | b'm' => (Arg::Other, 4),
            b'T' | b'F' | b'N' | b'I' => (Arg::Other, 0),
            _ => return None,
        };
        if used > b.len() {
            return None;
        }
        b = &b[used..];
        if out.len < MAX_ARGS {
            out.vals[out.len] = arg;
            out.len += 1;
        }
    }
    Some(out)
}

/// Seconds since 1900 of an NTP time tag, unless it is "immediately" (0, 1).
fn seconds_1900(t: [u8; 8]) -> Option<f64> {
    let secs = u32::from_be_bytes([t[0], t[1], t[2], t[3]]);
    let frac = u32::from_be_bytes([t[4], t[5], t[6], t[7]]);
    (!(secs == 0 && frac <= 1)).then(|| secs as f64 + frac as f64 / 4_294_967_296.0)
}

/// Matches `addr` against `pattern` with one `{name}` part and at most one `{subject}`
/// part (each one address segment or part of one, never empty); returns the subject, if
/// the pattern has one, and the name.
fn match_pattern<'a>(pattern: &str, addr: &'a str) -> Option<(Option<&'a str>, &'a str)> {
    let part = |p: &'a str| (!p.is_empty() && !p.contains('/')).then_some(p);
    let Some((pre, post)) = pattern.split_once("{subject}") else {
        let (pre, post) = pattern.split_once("{name}")?;
        let name = addr.strip_prefix(pre)?.strip_suffix(post)?;
        return Some((None, part(name)?));
    };
    // `{subject}` first, then `{name}`, or the other way round; literal text between.
    let (first_is_subject, pre, mid, post) = match post.split_once("{name}") {
        Some((mid, post)) => (true, pre, mid, post),
        None => {
            let (pre, mid) = pre.split_once("{name}")?;
            (false, pre, mid, post)
        }
    };
    let rest = addr.strip_prefix(pre)?.strip_suffix(post)?;
    if mid.is_empty() {
        return None;
    }
    let (a, b) = rest.split_once(mid)?;
    let (subject, name) = if first_is_subject { (a, b) } else { (b, a) };
    Some((Some(part(subject)?), part(name)?))
}

/// Seconds between the NTP epoch (1900) and the Unix epoch (1970).
pub const NTP_UNIX_OFFSET_S: f64 = 2_208_988_800.0;

/// The NTP time tag `(seconds since 1900, 2^-32 fractions)` of a Unix time (the inverse
/// of [`OscFrame::source_time_s`]'s conversion, to 2^-32 s).
pub fn time_tag_of_unix(unix_s: f64) -> (u32, u32) {
    let secs = unix_s.floor();
    (
        (secs + NTP_UNIX_OFFSET_S) as u64 as u32,
        ((unix_s - secs) * 4_294_967_296.0) as u32,
    )
}

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
            y_up_from_z_up(p)
        } else {
            p
        }
    }

    /// Appends a marker, reusing the slot (and its name's memory) of an earlier packet.
    fn push(
        &self,
        out: &mut OscFrame,
        name: &str,
        p: Option<DVec3>,
        world: impl Fn(DVec3) -> DVec3,
    ) {
        self.push_of(out, None, name, p, world);
    }

    /// [`Self::push`] of a subject's marker, named `subject:name`.
    fn push_of(
        &self,
        out: &mut OscFrame,
        subject: Option<&str>,
        name: &str,
        p: Option<DVec3>,
        world: impl Fn(DVec3) -> DVec3,
    ) {
        let ok = p.filter(|p| p.is_finite());
        let position_m = ok.map_or(DVec3::NAN, world);
        let occluded = ok.is_none();
        if out.used == out.markers.len() {
            out.markers.push(OscMarker {
                name: String::new(),
                position_m,
                occluded,
            });
        }
        let m = &mut out.markers[out.used];
        m.name.clear();
        if let Some(s) = subject {
            m.name.push_str(s);
            m.name.push(':');
        }
        m.name.push_str(name);
        m.position_m = position_m;
        m.occluded = occluded;
        out.used += 1;
    }

    /// One message; false when it is malformed.
    fn message(&self, b: &[u8], out: &mut OscFrame) -> bool {
        let Some((addr, used)) = osc_str(b) else {
            return false;
        };
        let rest = &b[used..];
        // A message without type tags has no arguments.
        let (tags, used) = if rest.is_empty() {
            (",", 0)
        } else {
            match osc_str(rest) {
                Some((t, u)) if t.starts_with(',') => (t, u),
                _ => return false,
            }
        };
        let Some(args) = parse_args(tags, &rest[used..]) else {
            return false;
        };
        if addr == "/rigless/frame" {
            out.frame = args.get(0).and_then(Arg::num).map(|f| f as i64);
            return true;
        }
        if addr == "/rigless/marker" {
            if let Some(Arg::Str(name)) = args.get(0) {
                self.push(out, name, args.xyz(1), |p| self.to_world(p));
                return true;
            }
        }
        if self.vmc && addr.starts_with("/VMC/Ext/") {
            match addr {
                "/VMC/Ext/Root/Pos" | "/VMC/Ext/Bone/Pos" | "/VMC/Ext/Tra/Pos" => {
                    if let (Some(Arg::Str(name)), Some(p)) = (args.get(0), args.xyz(1)) {
                        // Unity: left-handed, Y up, metres.
                        self.push(out, name, Some(p), |p| DVec3::new(p.x, p.y, -p.z));
                        return true;
                    }
                }
                "/VMC/Ext/T" => {
                    out.vmc_time_s = args.get(0).and_then(Arg::num);
                    return true;
                }
                _ => {}
            }
            out.ignored_messages += 1;
            return true;
        }
        for pat in &self.patterns {
            if let Some((subject, name)) = match_pattern(pat, addr) {
                if let Some(p) = args.xyz(0) {
                    self.push_of(out, subject, name, Some(p), |p| self.to_world(p));
                    return true;
                }
            }
        }
        out.ignored_messages += 1;
        true
    }

    /// A packet (message or bundle) at nesting `depth`; false when malformed.
    fn packet(&self, b: &[u8], depth: usize, out: &mut OscFrame) -> Result<(), OscDecodeError> {
        if !b.starts_with(b"#bundle\0") {
            return if b.first() == Some(&b'/') && self.message(b, out) {
                Ok(())
            } else {
                Err(OscDecodeError::Osc("malformed message".into()))
            };
        }
        if depth >= MAX_BUNDLE_DEPTH {
            return Err(OscDecodeError::TooDeep);
        }
        let tag =
            be8(&b[8..]).ok_or_else(|| OscDecodeError::Osc("bundle without a time tag".into()))?;
        if out.time_tag_s.is_none() {
            out.time_tag_s = seconds_1900(tag);
        }
        let mut at = 16;
        while at < b.len() {
            let n = be4(&b[at..])
                .map(|s| u32::from_be_bytes(s) as usize)
                .ok_or_else(|| OscDecodeError::Osc("bundle element size cut short".into()))?;
            let elem = at
                .checked_add(4)
                .and_then(|s| b.get(s..s.checked_add(n)?))
                .ok_or_else(|| {
                    OscDecodeError::Osc("bundle element longer than the bundle".into())
                })?;
            self.packet(elem, depth + 1, out)?;
            at += 4 + n;
        }
        Ok(())
    }

    /// Decodes one UDP datagram.
    pub fn decode(&self, b: &[u8]) -> Result<OscFrame, OscDecodeError> {
        let mut out = OscFrame::default();
        self.decode_into(b, &mut out)?;
        Ok(out)
    }

    /// Decodes one UDP datagram into `out`, reusing its memory: once `out` has held a
    /// packet as large, decoding allocates nothing. On error `out` is left empty.
    pub fn decode_into(&self, b: &[u8], out: &mut OscFrame) -> Result<(), OscDecodeError> {
        out.frame = None;
        out.time_tag_s = None;
        out.vmc_time_s = None;
        out.ignored_messages = 0;
        out.used = 0;
        let r = if b.len() > MAX_PACKET_LEN {
            Err(OscDecodeError::TooLong { len: b.len() })
        } else {
            self.packet(b, 0, out)
        };
        if r.is_err() {
            out.used = 0;
        }
        // Markers past this packet's count are kept (with their memory) for the next.
        out.visible = out.used;
        r
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
    fn a_reused_frame_shows_only_the_latest_packet() {
        let m = OscMapping::default();
        let mut f = OscFrame::default();
        let two = encode_native(1, (0, 1), &[("A", DVec3::X), ("B", DVec3::Y)]);
        let one = encode_native(2, (0, 1), &[("C", DVec3::Z)]);
        m.decode_into(&two, &mut f).unwrap();
        assert_eq!(f.markers().len(), 2);
        m.decode_into(&one, &mut f).unwrap();
        assert_eq!(f.frame, Some(2));
        assert_eq!(f.markers().len(), 1);
        assert_eq!(
            (f.markers()[0].name.as_str(), f.markers()[0].position_m),
            ("C", DVec3::Z)
        );
        assert!(m.decode_into(b"junk", &mut f).is_err());
        assert!(f.markers().is_empty());
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
        assert_eq!(f.markers().len(), 2);
        assert_eq!(f.markers()[0].position_m, DVec3::new(1.0, 2.0, 3.0));
        assert!(f.markers()[1].occluded && !f.markers()[1].position_m.is_finite());
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
        assert_eq!(f.markers()[0].name, "C7");
        assert!((f.markers()[0].position_m - DVec3::new(0.1, 1.5, -0.2)).length() < 1e-9);
        assert_eq!(match_pattern("/a/{name}", "/a/b/c"), None);
        assert_eq!(
            match_pattern("/mocap/{subject}/{name}", "/mocap/Ann/LFHD"),
            Some((Some("Ann"), "LFHD"))
        );
        assert_eq!(
            match_pattern("/m/{name}@{subject}", "/m/LFHD@Bob"),
            Some((Some("Bob"), "LFHD"))
        );
        assert_eq!(match_pattern("/mocap/{subject}/{name}", "/mocap/Ann"), None);
        assert_eq!(
            match_pattern("/mocap/{subject}/{name}", "/mocap//LFHD"),
            None
        );
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
