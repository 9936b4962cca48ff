//! VRPN 07.x wire format (the connection and tracker messages), as pure functions over
//! bytes: the 24-byte cookie, framed messages, sender and type descriptions (each side
//! numbers its own senders and types and describes them by name), and the tracker's
//! position reports. The network client built on it comes with the VRPN input.
//!
//! Layout (big-endian): cookie `"vrpn: ver. 07.38  0"` NUL-padded to 24 bytes; then
//! messages: `u32 length` (header and payload, unpadded), `u32 seconds`, `u32
//! microseconds`, `i32 sender`, `i32 type`, 4 bytes of padding, payload padded to a
//! multiple of 8. A description (type -1 sender, -2 type) carries `u32 name length`
//! (NUL included) and the name; its `sender` field is the id being named. A tracker
//! position (`vrpn_Tracker Pos_Quat`) is `i32 sensor`, 4 bytes of padding, `f64`
//! position x y z, `f64` quaternion x y z w.

use glam::DVec3;
use std::collections::HashMap;

/// Length of the cookie each side sends first.
pub const COOKIE_LEN: usize = 24;
/// Length of a message header.
pub const HEADER_LEN: usize = 24;
/// Longest message accepted, bytes.
pub const MAX_MESSAGE_LEN: u32 = 1 << 20;

/// Message types below zero are the connection's own.
pub const SENDER_DESCRIPTION: i32 = -1;
pub const TYPE_DESCRIPTION: i32 = -2;
pub const UDP_DESCRIPTION: i32 = -3;
pub const DISCONNECT: i32 = -5;

pub const POS_QUAT: &str = "vrpn_Tracker Pos_Quat";
pub const PING: &str = "vrpn_Base ping_message";
pub const PONG: &str = "vrpn_Base pong_message";

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum VrpnError {
    #[error("not a VRPN cookie: {found:?}")]
    BadCookie { found: String },
    #[error("VRPN major version {major} (this client speaks 7)")]
    Version { major: u32 },
    #[error("message length {len} outside 24..={MAX_MESSAGE_LEN}")]
    Length { len: u32 },
    #[error("description payload malformed")]
    Description,
    #[error("a description names something with {len} bytes (at most {MAX_NAME_LEN})")]
    NameTooLong { len: usize },
    #[error("connection request {text:?} is not \"IP PORT\" with a numeric IP")]
    Request { text: String },
    #[error("UDP description {text:?} (port {port}) is not a numeric IP and a port")]
    UdpDescription { text: String, port: i32 },
}

/// The peer's VRPN version from its cookie.
pub fn parse_cookie(b: &[u8; COOKIE_LEN]) -> Result<(u32, u32), VrpnError> {
    let text: String = b
        .iter()
        .take_while(|c| **c != 0)
        .map(|c| *c as char)
        .collect();
    let bad = || VrpnError::BadCookie {
        found: text.clone(),
    };
    let rest = text.strip_prefix("vrpn: ver. ").ok_or_else(bad)?;
    let ver = rest.split_whitespace().next().ok_or_else(bad)?;
    let (major, minor) = ver.split_once('.').ok_or_else(bad)?;
    let (major, minor) = (
        major.parse::<u32>().map_err(|_| bad())?,
        minor.parse::<u32>().map_err(|_| bad())?,
    );
    if major != 7 {
        return Err(VrpnError::Version { major });
    }
    Ok((major, minor))
}

/// This side's cookie (version 07.38, no remote logging).
pub fn cookie() -> [u8; COOKIE_LEN] {
    let mut c = [0u8; COOKIE_LEN];
    let t = b"vrpn: ver. 07.38  0";
    c[..t.len()].copy_from_slice(t);
    c
}

/// One message, borrowing its payload.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Message<'a> {
    pub seconds: u32,
    pub microseconds: u32,
    pub sender: i32,
    pub kind: i32,
    pub payload: &'a [u8],
}

fn be_u32(b: &[u8]) -> u32 {
    u32::from_be_bytes([b[0], b[1], b[2], b[3]])
}

/// The bytes of one VRPN TCP connection as they arrive: the peer's cookie, then
/// messages. Pure (bytes in, messages out, no I/O). Between calls it keeps at most one
/// partial message, which [`decode_message`] bounds by [`MAX_MESSAGE_LEN`].
#[derive(Debug, Default)]
pub struct StreamReader {
    buf: Vec<u8>,
    /// The peer's version, once its cookie is whole.
    version: Option<(u32, u32)>,
}

impl StreamReader {
    /// Takes `bytes`: checks the cookie once it is whole, passes every whole message
    /// to `on_message`, and keeps the rest. A bad cookie or message, or an error from
    /// `on_message`, is returned: the stream cannot be trusted after it.
    pub fn feed<E: From<VrpnError>>(
        &mut self,
        bytes: &[u8],
        on_message: &mut dyn FnMut(&Message<'_>) -> Result<(), E>,
    ) -> Result<(), E> {
        self.buf.extend_from_slice(bytes);
        let mut at = 0;
        if self.version.is_none() {
            let Some(c) = self.buf.first_chunk::<COOKIE_LEN>() else {
                return Ok(());
            };
            self.version = Some(parse_cookie(c)?);
            at = COOKIE_LEN;
        }
        let result = loop {
            match decode_message(&self.buf[at..]) {
                Ok(Some((m, used))) => {
                    at += used;
                    if let Err(e) = on_message(&m) {
                        break Err(e);
                    }
                }
                Ok(None) => break Ok(()),
                Err(e) => break Err(e.into()),
            }
        };
        self.buf.drain(..at);
        result
    }

    /// The peer's VRPN version, once its cookie has arrived.
    pub fn version(&self) -> Option<(u32, u32)> {
        self.version
    }
}

/// The first message of `b` and the bytes it takes (padding included), or `None` when
/// `b` holds only part of it.
pub fn decode_message(b: &[u8]) -> Result<Option<(Message<'_>, usize)>, VrpnError> {
    if b.len() < HEADER_LEN {
        return Ok(None);
    }
    let len = be_u32(b);
    if !(HEADER_LEN as u32..=MAX_MESSAGE_LEN).contains(&len) {
        return Err(VrpnError::Length { len });
    }
    let payload_len = len as usize - HEADER_LEN;
    let used = HEADER_LEN + payload_len.div_ceil(8) * 8;
    if b.len() < used {
        return Ok(None);
    }
    Ok(Some((
        Message {
            seconds: be_u32(&b[4..]),
            microseconds: be_u32(&b[8..]),
            sender: be_u32(&b[12..]) as i32,
            kind: be_u32(&b[16..]) as i32,
            payload: &b[HEADER_LEN..HEADER_LEN + payload_len],
        },
        used,
    )))
}

/// Appends a message.
pub fn encode_message(
    out: &mut Vec<u8>,
    seconds: u32,
    microseconds: u32,
    sender: i32,
    kind: i32,
    payload: &[u8],
) {
    let len = (HEADER_LEN + payload.len()) as u32;
    for v in [len, seconds, microseconds, sender as u32, kind as u32, 0] {
        out.extend_from_slice(&v.to_be_bytes());
    }
    out.extend_from_slice(payload);
    let pad = payload.len().div_ceil(8) * 8 - payload.len();
    out.extend(std::iter::repeat_n(0u8, pad));
}

/// The payload of a sender or type description.
pub fn description_payload(name: &str) -> Vec<u8> {
    let mut p = ((name.len() + 1) as u32).to_be_bytes().to_vec();
    p.extend_from_slice(name.as_bytes());
    p.push(0);
    p
}

/// The name a description carries.
pub fn parse_description(payload: &[u8]) -> Result<String, VrpnError> {
    let n = payload.get(..4).map(be_u32).ok_or(VrpnError::Description)? as usize;
    // VRPN's own names are `char[100]`; a longer one would let a peer pin up to a
    // message's length (1 MiB) per name, times MAX_NAMES, in the tables.
    if n > MAX_NAME_LEN + 1 {
        return Err(VrpnError::NameTooLong { len: n });
    }
    let name = payload.get(4..4 + n).ok_or(VrpnError::Description)?;
    let name = name.strip_suffix(&[0]).unwrap_or(name);
    if name.len() > MAX_NAME_LEN {
        return Err(VrpnError::NameTooLong { len: name.len() });
    }
    Ok(String::from_utf8_lossy(name).into_owned())
}

/// Longest connection request accepted, bytes (VRPN's own buffer is 150).
pub const MAX_REQUEST_LEN: usize = 150;

/// The datagram a client in the UDP connection mode (`DEVICE@HOST[:PORT]`) sends to the
/// server's port, asking to be called back over TCP: `"IP PORT"` and a NUL.
pub fn encode_connection_request(callback: std::net::SocketAddr) -> Vec<u8> {
    let mut b = format!("{} {}", callback.ip(), callback.port()).into_bytes();
    b.push(0);
    b
}

/// The TCP address a connection request asks the server to call back.
pub fn parse_connection_request(b: &[u8]) -> Result<std::net::SocketAddr, VrpnError> {
    let b = &b[..b.len().min(MAX_REQUEST_LEN)];
    let text = b.split(|&c| c == 0).next().unwrap_or_default();
    let text = String::from_utf8_lossy(text).into_owned();
    let bad = || VrpnError::Request { text: text.clone() };
    let (ip, port) = text.trim().split_once(' ').ok_or_else(bad)?;
    let ip: std::net::IpAddr = ip.parse().map_err(|_| bad())?;
    let port: u16 = port.trim().parse().map_err(|_| bad())?;
    if port == 0 {
        return Err(bad());
    }
    Ok(std::net::SocketAddr::new(ip, port))
}

/// The UDP description each side sends after its cookie (type [`UDP_DESCRIPTION`]): the
/// header's `sender` field is the UDP port its low-latency messages should go to, the
/// payload the IP as text with a NUL. Returns `(sender field, payload)`.
pub fn udp_description(inbound: std::net::SocketAddr) -> (i32, Vec<u8>) {
    let mut p = inbound.ip().to_string().into_bytes();
    p.push(0);
    (i32::from(inbound.port()), p)
}

/// Where a UDP description asks for low-latency messages to go.
pub fn parse_udp_description(m: &Message) -> Result<std::net::SocketAddr, VrpnError> {
    let text = m.payload.split(|&c| c == 0).next().unwrap_or_default();
    let text = String::from_utf8_lossy(&text[..text.len().min(MAX_REQUEST_LEN)]).into_owned();
    let bad = || VrpnError::UdpDescription {
        text: text.clone(),
        port: m.sender,
    };
    let ip: std::net::IpAddr = text.trim().parse().map_err(|_| bad())?;
    let port = u16::try_from(m.sender)
        .ok()
        .filter(|&p| p != 0)
        .ok_or_else(bad)?;
    Ok(std::net::SocketAddr::new(ip, port))
}

/// Splits a run of whole messages into datagrams of at most `max_bytes` each (a message
/// longer than that goes alone), as VRPN packs its low-latency messages: returns the
/// byte ranges.
pub fn datagrams(messages: &[u8], max_bytes: usize) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let (mut start, mut at) = (0, 0);
    while let Ok(Some((_, used))) = decode_message(&messages[at..]) {
        if at > start && at + used - start > max_bytes {
            out.push(start..at);
            start = at;
        }
        at += used;
    }
    if at > start {
        out.push(start..at);
    }
    out
}

/// A tracker position report.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PosQuat {
    pub sensor: i32,
    /// As the server sends it (VRPN: metres; the server's own axes).
    pub position: DVec3,
    /// Quaternion x, y, z, w.
    pub rotation: [f64; 4],
}

pub fn parse_pos_quat(p: &[u8]) -> Option<PosQuat> {
    if p.len() < 64 {
        return None;
    }
    let f = |i: usize| f64::from_be_bytes(p[i..i + 8].try_into().expect("8 bytes"));
    Some(PosQuat {
        sensor: be_u32(p) as i32,
        position: DVec3::new(f(8), f(16), f(24)),
        rotation: [f(32), f(40), f(48), f(56)],
    })
}

pub fn encode_pos_quat(r: &PosQuat) -> Vec<u8> {
    let mut p = (r.sensor as u32).to_be_bytes().to_vec();
    p.extend_from_slice(&[0; 4]);
    for v in r.position.to_array().into_iter().chain(r.rotation) {
        p.extend_from_slice(&v.to_be_bytes());
    }
    p
}

/// The names one side gave its senders and types (each direction has its own).
#[derive(Clone, Debug, Default)]
pub struct Names {
    pub senders: HashMap<i32, String>,
    pub types: HashMap<i32, String>,
}

/// Cap on descriptions kept per direction (a hostile peer cannot grow the tables).
pub const MAX_NAMES: usize = 4096;
/// Longest sender or type name accepted, bytes without the NUL (VRPN's `cName` holds
/// 99): the tables hold at most `2 × MAX_NAMES × 3 × MAX_NAME_LEN` bytes of names, 6 MiB
/// (a byte that is not UTF-8 becomes a 3-byte replacement character).
pub const MAX_NAME_LEN: usize = 255;

impl Names {
    /// Takes in a description; true when `m` was one.
    pub fn observe(&mut self, m: &Message) -> Result<bool, VrpnError> {
        let table = match m.kind {
            SENDER_DESCRIPTION => &mut self.senders,
            TYPE_DESCRIPTION => &mut self.types,
            _ => return Ok(false),
        };
        let name = parse_description(m.payload)?;
        if table.len() < MAX_NAMES || table.contains_key(&m.sender) {
            table.insert(m.sender, name);
        }
        Ok(true)
    }

    pub fn sender(&self, id: i32) -> Option<&str> {
        self.senders.get(&id).map(String::as_str)
    }

    pub fn kind(&self, id: i32) -> Option<&str> {
        self.types.get(&id).map(String::as_str)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn connection_requests_and_udp_descriptions_round_trip() {
        let a: std::net::SocketAddr = "127.0.0.1:40123".parse().unwrap();
        let req = encode_connection_request(a);
        assert_eq!(req, b"127.0.0.1 40123\0");
        assert_eq!(parse_connection_request(&req), Ok(a));
        for bad in [
            &b"127.0.0.1\0"[..],
            b"host 1\0",
            b"1.2.3.4 0\0",
            b"1.2.3.4 x",
            b"",
        ] {
            assert!(parse_connection_request(bad).is_err(), "{bad:?}");
        }
        let (port, payload) = udp_description(a);
        let mut b = Vec::new();
        encode_message(&mut b, 0, 0, port, UDP_DESCRIPTION, &payload);
        let (m, _) = decode_message(&b).unwrap().unwrap();
        assert_eq!(parse_udp_description(&m), Ok(a));
    }

    #[test]
    fn names_are_bounded_so_the_tables_are() {
        // 4,096 senders of names of almost a message's 1 MiB each used to be kept: 4 GiB
        // a table.
        let mut names = Names::default();
        let long = "x".repeat((1 << 20) - 64);
        let mut out = Vec::new();
        encode_message(
            &mut out,
            0,
            0,
            5,
            SENDER_DESCRIPTION,
            &description_payload(&long),
        );
        let (m, _) = decode_message(&out).unwrap().unwrap();
        assert_eq!(
            names.observe(&m),
            Err(VrpnError::NameTooLong {
                len: (1 << 20) - 63
            })
        );
        assert!(names.senders.is_empty());
        let longest = "y".repeat(MAX_NAME_LEN);
        out.clear();
        encode_message(
            &mut out,
            0,
            0,
            5,
            SENDER_DESCRIPTION,
            &description_payload(&longest),
        );
        let (m, _) = decode_message(&out).unwrap().unwrap();
        assert_eq!(names.observe(&m), Ok(true));
        assert_eq!(names.sender(5), Some(longest.as_str()));
        // One byte more and no NUL (the length field counts 256 bytes): refused too.
        let mut payload = 256u32.to_be_bytes().to_vec();
        payload.extend(std::iter::repeat_n(b'z', 256));
        assert_eq!(
            parse_description(&payload),
            Err(VrpnError::NameTooLong { len: 256 })
        );
    }

    #[test]
    fn datagrams_hold_whole_messages_up_to_the_limit() {
        let mut b = Vec::new();
        for k in 0..40 {
            encode_message(&mut b, 0, 0, 0, 0, &[k as u8; 72]);
        }
        let parts = datagrams(&b, 1472);
        // 96 bytes a message: 15 fit in 1,472.
        assert_eq!(
            parts.iter().map(|r| r.len()).collect::<Vec<_>>(),
            [1440, 1440, 960]
        );
        assert_eq!(parts.last().unwrap().end, b.len());
    }

    #[test]
    fn messages_round_trip_with_padding() {
        let mut b = cookie().to_vec();
        encode_message(
            &mut b,
            1,
            2,
            3,
            SENDER_DESCRIPTION,
            &description_payload("Tracker0"),
        );
        let pq = PosQuat {
            sensor: 1,
            position: DVec3::new(0.5, -1.0, 2.0),
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        encode_message(&mut b, 5, 6, 3, 4, &encode_pos_quat(&pq));
        assert_eq!(parse_cookie(b[..24].try_into().unwrap()), Ok((7, 38)));
        let (m1, n1) = decode_message(&b[24..]).unwrap().unwrap();
        assert_eq!(n1 % 8, 0);
        let mut names = Names::default();
        assert!(names.observe(&m1).unwrap());
        assert_eq!(names.sender(3), Some("Tracker0"));
        let (m2, n2) = decode_message(&b[24 + n1..]).unwrap().unwrap();
        assert_eq!((m2.seconds, m2.microseconds, m2.kind), (5, 6, 4));
        assert_eq!(parse_pos_quat(m2.payload), Some(pq));
        assert_eq!(24 + n1 + n2, b.len());
        // Any prefix of a message is "need more", not an error.
        for cut in 0..n2 {
            assert_eq!(decode_message(&b[24 + n1..24 + n1 + cut]), Ok(None));
        }
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(b in proptest::collection::vec(any::<u8>(), 0..300)) {
            let mut names = Names::default();
            let mut at = 0;
            while let Ok(Some((m, n))) = decode_message(&b[at..]) {
                let _ = names.observe(&m);
                let _ = parse_udp_description(&m);
                let _ = parse_pos_quat(m.payload);
                at += n;
            }
            let _ = parse_connection_request(&b);
            let _ = datagrams(&b, 1472);
            if b.len() >= 24 {
                let _ = parse_cookie(b[..24].try_into().unwrap());
            }
            // A stream reader over hostile bytes, in two pieces: no panic, and what it
            // keeps stays below one message.
            let mut r = StreamReader::default();
            let cut = b.len() / 3;
            let _ = r.feed::<VrpnError>(&b[..cut], &mut |_| Ok(()));
            let _ = r.feed::<VrpnError>(&b[cut..], &mut |_| Ok(()));
            prop_assert!(r.buf.len() <= MAX_MESSAGE_LEN as usize + b.len());
        }

        /// A valid stream fed in any two pieces gives the same messages as in one.
        #[test]
        fn a_stream_split_anywhere_reads_the_same(cut in 0usize..400, n in 1usize..6) {
            let mut b = cookie().to_vec();
            for k in 0..n {
                encode_message(&mut b, k as u32, 0, 3, 4, &[k as u8; 37]);
            }
            let cut = cut.min(b.len());
            let mut r = StreamReader::default();
            let mut seen = Vec::new();
            for part in [&b[..cut], &b[cut..]] {
                r.feed::<VrpnError>(part, &mut |m| {
                    seen.push((m.seconds, m.payload.to_vec()));
                    Ok(())
                })
                .unwrap();
            }
            prop_assert_eq!(r.version(), Some((7, 38)));
            prop_assert_eq!(seen.len(), n);
            for (k, (s, p)) in seen.iter().enumerate() {
                prop_assert_eq!((*s, p.clone()), (k as u32, vec![k as u8; 37]));
            }
            prop_assert!(r.buf.is_empty());
        }
    }
}
