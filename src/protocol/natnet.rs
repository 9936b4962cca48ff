//! NatNet (OptiTrack Motive) packets, as pure functions over bytes: frames of mocap data
//! (NatNet 3.x and 4.x; 4.1 puts a byte count before each section) and model definitions
//! (marker set names, rigid bodies). Every count is checked against the bytes left before
//! anything is allocated, so a packet costs at most its own size.
//!
//! Layout (little-endian): `u16 message id`, `u16 payload length`, payload. Frame of data
//! (id 7): frame number; marker sets (name, positions); legacy unlabelled markers; rigid
//! bodies (id, position, quaternion x y z w, mean error, params); skeletons; labelled
//! markers (id = asset << 16 | member, position, size, params: bit 0 occluded, bit 1
//! point-cloud solved, bit 2 model solved; residual); force plates; devices; timecode;
//! timestamp (f64 seconds); three camera clock stamps; params; end tag. Positions are
//! Motive's: metres, Y up, right-handed, as the world frame.

use glam::Vec3;

/// Message ids.
pub const NAT_CONNECT: u16 = 0;
pub const NAT_SERVERINFO: u16 = 1;
pub const NAT_REQUEST_MODELDEF: u16 = 4;
pub const NAT_KEEPALIVE: u16 = 10;
pub const NAT_MODELDEF: u16 = 5;
pub const NAT_FRAMEOFDATA: u16 = 7;

/// A NatNet protocol version (the server info says which).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct Version(pub u8, pub u8);

#[derive(Clone, Debug, PartialEq)]
pub struct RigidBody {
    pub id: i32,
    pub position_m: Vec3,
    /// Quaternion x, y, z, w.
    pub rotation: [f32; 4],
    pub mean_error_m: f32,
    pub tracking_valid: bool,
}

#[derive(Clone, Debug, PartialEq)]
pub struct LabeledMarker {
    /// Asset (model) id: the high 16 bits of the wire id.
    pub asset_id: u16,
    /// Member id within the asset (1-based): the low 16 bits.
    pub member_id: u16,
    pub position_m: Vec3,
    pub size_m: f32,
    pub occluded: bool,
    pub point_cloud_solved: bool,
    pub model_solved: bool,
    pub residual_m: f32,
}

/// A frame of mocap data.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MocapFrame {
    pub frame: i32,
    /// Marker sets by name, positions in the set's own marker order.
    pub marker_sets: Vec<(String, Vec<Vec3>)>,
    pub unlabeled: Vec<Vec3>,
    pub rigid_bodies: Vec<RigidBody>,
    pub labeled: Vec<LabeledMarker>,
    pub timecode: u32,
    pub timecode_sub: u32,
    /// Motive's timestamp, seconds.
    pub timestamp_s: f64,
    pub params: i16,
}

/// A model definition the decoder understands.
#[derive(Clone, Debug, PartialEq)]
pub enum Description {
    MarkerSet { name: String, markers: Vec<String> },
    RigidBody { name: String, id: i32, parent: i32 },
    Skeleton { name: String, id: i32 },
}

/// The server's answer to a connect request.
#[derive(Clone, Debug, PartialEq)]
pub struct ServerInfo {
    /// Application name ("Motive").
    pub app: String,
    pub app_version: [u8; 4],
    /// The NatNet version the server speaks (frames are decoded with it).
    pub natnet: Version,
    /// Connection info (NatNet 3 and later): the server's clock rate, data port and, when
    /// it streams multicast, the group.
    pub clock_hz: Option<u64>,
    pub data_port: Option<u16>,
    pub multicast_group: Option<std::net::Ipv4Addr>,
}

#[derive(Clone, Debug, PartialEq)]
pub enum Message {
    Frame(MocapFrame),
    /// Descriptions up to the first of a kind this decoder skips (force plates, devices,
    /// cameras), which ends the list.
    ModelDef(Vec<Description>),
    ServerInfo(ServerInfo),
    /// Any other message id (pings, responses, ...).
    Other {
        id: u16,
    },
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum NatNetError {
    #[error("packet shorter than its 4-byte header")]
    Short,
    #[error("a {bytes}-byte payload does not fit a NatNet packet (65,535 bytes at most)")]
    TooLarge { bytes: usize },
    #[error("message {id}: payload length {declared} but {have} bytes follow")]
    Length {
        id: u16,
        declared: usize,
        have: usize,
    },
    #[error("message {id} malformed at byte {offset}: {what}")]
    Malformed {
        id: u16,
        offset: usize,
        what: &'static str,
    },
}

struct Rd<'a> {
    b: &'a [u8],
    at: usize,
    id: u16,
}

impl<'a> Rd<'a> {
    fn err(&self, what: &'static str) -> NatNetError {
        NatNetError::Malformed {
            id: self.id,
            offset: self.at + 4,
            what,
        }
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], NatNetError> {
        if self.b.len() - self.at < n {
            return Err(self.err("truncated"));
        }
        let s = &self.b[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    fn i32(&mut self) -> Result<i32, NatNetError> {
        Ok(i32::from_le_bytes(self.take(4)?.try_into().expect("4")))
    }
    fn i16(&mut self) -> Result<i16, NatNetError> {
        Ok(i16::from_le_bytes(self.take(2)?.try_into().expect("2")))
    }
    fn u32(&mut self) -> Result<u32, NatNetError> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4")))
    }
    fn f32(&mut self) -> Result<f32, NatNetError> {
        Ok(f32::from_le_bytes(self.take(4)?.try_into().expect("4")))
    }
    fn f64(&mut self) -> Result<f64, NatNetError> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().expect("8")))
    }
    fn vec3(&mut self) -> Result<Vec3, NatNetError> {
        Ok(Vec3::new(self.f32()?, self.f32()?, self.f32()?))
    }
    /// A count of items of at least `item` bytes each, checked against what is left.
    fn count(&mut self, item: usize) -> Result<usize, NatNetError> {
        let n = self.i32()?;
        if n < 0 || (n as usize).saturating_mul(item) > self.b.len() - self.at {
            return Err(self.err("count larger than the packet"));
        }
        Ok(n as usize)
    }
    /// A NUL-terminated string.
    fn cstr(&mut self) -> Result<String, NatNetError> {
        let rest = &self.b[self.at..];
        let n = rest
            .iter()
            .position(|c| *c == 0)
            .ok_or_else(|| self.err("unterminated string"))?;
        let s = String::from_utf8_lossy(&rest[..n]).into_owned();
        self.at += n + 1;
        Ok(s)
    }
    /// NatNet 4.1+: the section's byte count (checked; the section must fit).
    fn section(&mut self, v: Version) -> Result<(), NatNetError> {
        if v >= Version(4, 1) {
            let n = self.i32()?;
            if n < 0 || n as usize > self.b.len() - self.at {
                return Err(self.err("section byte count larger than the packet"));
            }
        }
        Ok(())
    }
}

fn rigid_body(r: &mut Rd) -> Result<RigidBody, NatNetError> {
    let id = r.i32()?;
    let position_m = r.vec3()?;
    let rotation = [r.f32()?, r.f32()?, r.f32()?, r.f32()?];
    let mean_error_m = r.f32()?;
    let params = r.i16()?;
    Ok(RigidBody {
        id,
        position_m,
        rotation,
        mean_error_m,
        tracking_valid: params & 1 != 0,
    })
}

/// Bytes of one rigid body in a frame (3.0+).
const RIGID_BODY_LEN: usize = 4 + 12 + 16 + 4 + 2;
/// Bytes of one labelled marker in a frame (3.0+).
const LABELED_LEN: usize = 4 + 12 + 4 + 2 + 4;

fn frame(r: &mut Rd, v: Version) -> Result<MocapFrame, NatNetError> {
    let mut f = MocapFrame {
        frame: r.i32()?,
        ..MocapFrame::default()
    };
    r.section(v)?;
    let sets = r.count(5)?;
    for _ in 0..sets {
        let name = r.cstr()?;
        let n = r.count(12)?;
        let mut ps = Vec::with_capacity(n);
        for _ in 0..n {
            ps.push(r.vec3()?);
        }
        f.marker_sets.push((name, ps));
    }
    r.section(v)?;
    let n = r.count(12)?;
    for _ in 0..n {
        f.unlabeled.push(r.vec3()?);
    }
    r.section(v)?;
    let n = r.count(RIGID_BODY_LEN)?;
    for _ in 0..n {
        f.rigid_bodies.push(rigid_body(r)?);
    }
    r.section(v)?;
    let skeletons = r.count(8)?;
    for _ in 0..skeletons {
        let _id = r.i32()?;
        let n = r.count(RIGID_BODY_LEN)?;
        for _ in 0..n {
            f.rigid_bodies.push(rigid_body(r)?);
        }
    }
    r.section(v)?;
    let n = r.count(LABELED_LEN)?;
    for _ in 0..n {
        let id = r.i32()?;
        let position_m = r.vec3()?;
        let size_m = r.f32()?;
        let params = r.i16()?;
        let residual_m = r.f32()?;
        f.labeled.push(LabeledMarker {
            asset_id: (id as u32 >> 16) as u16,
            member_id: (id as u32 & 0xffff) as u16,
            position_m,
            size_m,
            occluded: params & 1 != 0,
            point_cloud_solved: params & 2 != 0,
            model_solved: params & 4 != 0,
            residual_m,
        });
    }
    // Force plates, then devices: id, channels, each channel a frame count and floats.
    for _ in 0..2 {
        r.section(v)?;
        let n = r.count(8)?;
        for _ in 0..n {
            let _id = r.i32()?;
            let channels = r.count(4)?;
            for _ in 0..channels {
                let frames = r.count(4)?;
                r.take(frames * 4)?;
            }
        }
    }
    f.timecode = r.u32()?;
    f.timecode_sub = r.u32()?;
    f.timestamp_s = r.f64()?;
    // Camera mid-exposure, data received and transmit stamps (3.0+).
    r.take(24)?;
    f.params = r.i16()?;
    // End-of-data tag.
    r.i32()?;
    Ok(f)
}

fn descriptions(r: &mut Rd, v: Version) -> Result<Vec<Description>, NatNetError> {
    let n = r.count(4)?;
    let mut out = Vec::new();
    for _ in 0..n {
        let kind = r.i32()?;
        if v >= Version(4, 1) {
            let _bytes = r.i32()?;
        }
        match kind {
            0 => {
                let name = r.cstr()?;
                let k = r.count(1)?;
                let mut markers = Vec::with_capacity(k);
                for _ in 0..k {
                    markers.push(r.cstr()?);
                }
                out.push(Description::MarkerSet { name, markers });
            }
            1 => out.push(rigid_body_description(r, v)?),
            2 => {
                let name = r.cstr()?;
                let id = r.i32()?;
                let n = r.count(4)?;
                for _ in 0..n {
                    rigid_body_description(r, v)?;
                }
                out.push(Description::Skeleton { name, id });
            }
            // Force plates, devices, cameras: not needed for markers; stop here.
            _ => break,
        }
    }
    Ok(out)
}

fn rigid_body_description(r: &mut Rd, v: Version) -> Result<Description, NatNetError> {
    let name = r.cstr()?;
    let id = r.i32()?;
    let parent = r.i32()?;
    let _offset = r.vec3()?;
    let n = r.count(16)?;
    r.take(n * 12)?;
    r.take(n * 4)?;
    if v >= Version(4, 0) {
        for _ in 0..n {
            r.cstr()?;
        }
    }
    Ok(Description::RigidBody { name, id, parent })
}

/// Wraps a payload in the packet header.
fn packet(id: u16, payload: Vec<u8>) -> Result<Vec<u8>, NatNetError> {
    let len = u16::try_from(payload.len()).map_err(|_| NatNetError::TooLarge {
        bytes: payload.len(),
    })?;
    let mut b = Vec::with_capacity(4 + payload.len());
    b.extend_from_slice(&id.to_le_bytes());
    b.extend_from_slice(&len.to_le_bytes());
    b.extend_from_slice(&payload);
    Ok(b)
}

fn put_vec3(p: &mut Vec<u8>, v: Vec3) {
    for c in v.to_array() {
        p.extend_from_slice(&c.to_le_bytes());
    }
}

fn put_cstr(p: &mut Vec<u8>, s: &str) {
    p.extend(s.bytes().filter(|&c| c != 0));
    p.push(0);
}

/// A frame of mocap data as a NatNet 3.0 server sends it (the inverse of [`decode`] for
/// that version; skeletons go out as top-level rigid bodies, force plates and devices
/// empty).
pub fn encode_frame(f: &MocapFrame) -> Result<Vec<u8>, NatNetError> {
    let mut p = Vec::new();
    let count = |p: &mut Vec<u8>, n: usize| p.extend_from_slice(&(n as i32).to_le_bytes());
    p.extend_from_slice(&f.frame.to_le_bytes());
    count(&mut p, f.marker_sets.len());
    for (name, ps) in &f.marker_sets {
        put_cstr(&mut p, name);
        count(&mut p, ps.len());
        for v in ps {
            put_vec3(&mut p, *v);
        }
    }
    count(&mut p, f.unlabeled.len());
    for v in &f.unlabeled {
        put_vec3(&mut p, *v);
    }
    count(&mut p, f.rigid_bodies.len());
    for rb in &f.rigid_bodies {
        p.extend_from_slice(&rb.id.to_le_bytes());
        put_vec3(&mut p, rb.position_m);
        for q in rb.rotation {
            p.extend_from_slice(&q.to_le_bytes());
        }
        p.extend_from_slice(&rb.mean_error_m.to_le_bytes());
        p.extend_from_slice(&i16::from(rb.tracking_valid).to_le_bytes());
    }
    count(&mut p, 0); // skeletons
    count(&mut p, f.labeled.len());
    for m in &f.labeled {
        let id = (u32::from(m.asset_id) << 16) | u32::from(m.member_id);
        p.extend_from_slice(&id.to_le_bytes());
        put_vec3(&mut p, m.position_m);
        p.extend_from_slice(&m.size_m.to_le_bytes());
        let params = i16::from(m.occluded)
            | (i16::from(m.point_cloud_solved) << 1)
            | (i16::from(m.model_solved) << 2);
        p.extend_from_slice(&params.to_le_bytes());
        p.extend_from_slice(&m.residual_m.to_le_bytes());
    }
    count(&mut p, 0); // force plates
    count(&mut p, 0); // devices
    p.extend_from_slice(&f.timecode.to_le_bytes());
    p.extend_from_slice(&f.timecode_sub.to_le_bytes());
    p.extend_from_slice(&f.timestamp_s.to_le_bytes());
    p.extend_from_slice(&[0; 24]); // camera mid-exposure, received, transmit stamps
    p.extend_from_slice(&f.params.to_le_bytes());
    count(&mut p, 0); // end tag
    packet(NAT_FRAMEOFDATA, p)
}

/// Model definitions as a NatNet 3.0 server sends them: marker sets, and rigid bodies
/// (without markers) and skeletons (without bones).
pub fn encode_model_def(d: &[Description]) -> Result<Vec<u8>, NatNetError> {
    let mut p = (d.len() as i32).to_le_bytes().to_vec();
    for x in d {
        match x {
            Description::MarkerSet { name, markers } => {
                p.extend_from_slice(&0i32.to_le_bytes());
                put_cstr(&mut p, name);
                p.extend_from_slice(&(markers.len() as i32).to_le_bytes());
                for m in markers {
                    put_cstr(&mut p, m);
                }
            }
            Description::RigidBody { name, id, parent } => {
                p.extend_from_slice(&1i32.to_le_bytes());
                put_cstr(&mut p, name);
                p.extend_from_slice(&id.to_le_bytes());
                p.extend_from_slice(&parent.to_le_bytes());
                put_vec3(&mut p, Vec3::ZERO);
                p.extend_from_slice(&0i32.to_le_bytes());
            }
            Description::Skeleton { name, id } => {
                p.extend_from_slice(&2i32.to_le_bytes());
                put_cstr(&mut p, name);
                p.extend_from_slice(&id.to_le_bytes());
                p.extend_from_slice(&0i32.to_le_bytes());
            }
        }
    }
    packet(NAT_MODELDEF, p)
}

/// A server's answer to a connect request (the layout [`decode`] reads).
pub fn encode_server_info(info: &ServerInfo) -> Vec<u8> {
    let mut p = vec![0u8; 256];
    let name = info.app.as_bytes();
    let n = name.len().min(255);
    p[..n].copy_from_slice(&name[..n]);
    p.extend_from_slice(&info.app_version);
    p.extend_from_slice(&[info.natnet.0, info.natnet.1, 0, 0]);
    p.extend_from_slice(&info.clock_hz.unwrap_or(0).to_le_bytes());
    p.extend_from_slice(&info.data_port.unwrap_or(0).to_le_bytes());
    p.push(u8::from(info.multicast_group.is_some()));
    p.extend_from_slice(
        &info
            .multicast_group
            .unwrap_or(std::net::Ipv4Addr::UNSPECIFIED)
            .octets(),
    );
    packet(NAT_SERVERINFO, p).expect("a 283-byte packet")
}

/// Name a client gives itself in its connect request (the NatNet SDK's own).
pub const CLIENT_NAME: &str = "NatNetLib";

/// A client's connect request to the command port, asking for NatNet `v`: the sender
/// block (name in 256 bytes, NUL-padded; application version; NatNet version).
pub fn encode_connect(v: Version) -> Vec<u8> {
    let mut b = Vec::with_capacity(268);
    b.extend_from_slice(&NAT_CONNECT.to_le_bytes());
    b.extend_from_slice(&264u16.to_le_bytes());
    let mut name = [0u8; 256];
    name[..CLIENT_NAME.len()].copy_from_slice(CLIENT_NAME.as_bytes());
    b.extend_from_slice(&name);
    b.extend_from_slice(&[v.0, v.1, 0, 0]);
    b.extend_from_slice(&[v.0, v.1, 0, 0]);
    b
}

/// A request for the model definitions (no payload).
pub fn encode_request_modeldef() -> [u8; 4] {
    let mut b = [0u8; 4];
    b[..2].copy_from_slice(&NAT_REQUEST_MODELDEF.to_le_bytes());
    b
}

/// A unicast client's keep-alive (no payload): the server keeps streaming to it.
pub fn encode_keepalive() -> [u8; 4] {
    let mut b = [0u8; 4];
    b[..2].copy_from_slice(&NAT_KEEPALIVE.to_le_bytes());
    b
}

/// Decodes one UDP datagram from a server speaking NatNet `v`.
pub fn decode(b: &[u8], v: Version) -> Result<Message, NatNetError> {
    if b.len() < 4 {
        return Err(NatNetError::Short);
    }
    let id = u16::from_le_bytes([b[0], b[1]]);
    let declared = u16::from_le_bytes([b[2], b[3]]) as usize;
    if declared > b.len() - 4 {
        return Err(NatNetError::Length {
            id,
            declared,
            have: b.len() - 4,
        });
    }
    let mut r = Rd {
        b: &b[4..4 + declared],
        at: 0,
        id,
    };
    Ok(match id {
        NAT_FRAMEOFDATA => Message::Frame(frame(&mut r, v)?),
        NAT_MODELDEF => Message::ModelDef(descriptions(&mut r, v)?),
        NAT_SERVERINFO => {
            let app_bytes = r.take(256)?;
            let end = app_bytes.iter().position(|c| *c == 0).unwrap_or(256);
            let app = String::from_utf8_lossy(&app_bytes[..end]).into_owned();
            let app_version: [u8; 4] = r.take(4)?.try_into().expect("4 bytes");
            let nv = r.take(4)?;
            // Connection info, when the payload carries it: u64 clock rate, u16 data
            // port, u8 multicast flag, 4 bytes of group address.
            let (mut clock_hz, mut data_port, mut multicast_group) = (None, None, None);
            if let Ok(c) = r.take(15) {
                clock_hz = Some(u64::from_le_bytes(c[..8].try_into().expect("8 bytes")));
                data_port = Some(u16::from_le_bytes([c[8], c[9]]));
                if c[10] != 0 {
                    multicast_group = Some(std::net::Ipv4Addr::new(c[11], c[12], c[13], c[14]));
                }
            }
            Message::ServerInfo(ServerInfo {
                app,
                app_version,
                natnet: Version(nv[0], nv[1]),
                clock_hz,
                data_port,
                multicast_group,
            })
        }
        other => Message::Other { id: other },
    })
}

/// An example NatNet 3.0 frame of data: one marker set `Body` and `n` labelled markers
/// (asset 1) at fixed positions, for tests and the codec benchmark.
pub fn example_frame(n: usize) -> Vec<u8> {
    use glam::Vec3;
    let p = |k: usize| {
        Vec3::new(
            k as f32 * 0.03,
            (k * 3 + 1) as f32 * 0.01,
            (k * 3 + 2) as f32 * 0.01,
        )
    };
    encode_frame(&MocapFrame {
        frame: 1234,
        marker_sets: vec![("Body".into(), (0..n).map(p).collect())],
        labeled: (0..n)
            .map(|k| LabeledMarker {
                asset_id: 1,
                member_id: k as u16 + 1,
                position_m: p(k),
                size_m: 0.014,
                occluded: false,
                point_cloud_solved: true,
                model_solved: false,
                residual_m: 0.0002,
            })
            .collect(),
        timestamp_s: 12.5,
        ..MocapFrame::default()
    })
    .expect("a small frame")
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn model_definitions_and_server_info_round_trip() {
        let d = vec![
            Description::MarkerSet {
                name: "take".into(),
                markers: vec!["LFHD".into(), "RFHD".into()],
            },
            Description::RigidBody {
                name: "Hand".into(),
                id: 3,
                parent: -1,
            },
            Description::Skeleton {
                name: "Actor".into(),
                id: 7,
            },
        ];
        let b = encode_model_def(&d).unwrap();
        assert_eq!(decode(&b, Version(3, 0)), Ok(Message::ModelDef(d)));
        let info = ServerInfo {
            app: "rigless".into(),
            app_version: [0, 1, 0, 0],
            natnet: Version(3, 0),
            clock_hz: Some(1_000_000),
            data_port: Some(1511),
            multicast_group: None,
        };
        let b = encode_server_info(&info);
        assert_eq!(b.len(), 283, "Motive's own length");
        assert_eq!(decode(&b, Version(3, 0)), Ok(Message::ServerInfo(info)));
        // 6,000 × 12 bytes of positions and 78 bytes of counts, stamps and tags.
        let huge = MocapFrame {
            unlabeled: vec![Vec3::ZERO; 6000],
            ..MocapFrame::default()
        };
        assert_eq!(
            encode_frame(&huge),
            Err(NatNetError::TooLarge { bytes: 72_078 })
        );
    }

    fn vec3() -> impl Strategy<Value = Vec3> {
        (-10.0f32..10.0, -10.0f32..10.0, -10.0f32..10.0).prop_map(|(x, y, z)| Vec3::new(x, y, z))
    }

    fn any_frame() -> impl Strategy<Value = MocapFrame> {
        let set = (
            "[A-Za-z][A-Za-z0-9_]{0,8}",
            proptest::collection::vec(vec3(), 0..6),
        );
        let rb = (
            any::<i32>(),
            vec3(),
            any::<[f32; 4]>(),
            any::<f32>(),
            any::<bool>(),
        )
            .prop_map(|(id, position_m, rotation, mean_error_m, tracking_valid)| {
                RigidBody {
                    id,
                    position_m,
                    rotation: rotation.map(|v| if v.is_nan() { 0.0 } else { v }),
                    mean_error_m: if mean_error_m.is_nan() {
                        0.0
                    } else {
                        mean_error_m
                    },
                    tracking_valid,
                }
            });
        let lm = (any::<u16>(), any::<u16>(), vec3(), any::<[bool; 3]>()).prop_map(
            |(asset_id, member_id, position_m, f)| LabeledMarker {
                asset_id,
                member_id,
                position_m,
                size_m: 0.014,
                occluded: f[0],
                point_cloud_solved: f[1],
                model_solved: f[2],
                residual_m: 0.0002,
            },
        );
        (
            any::<i32>(),
            proptest::collection::vec(set, 0..4),
            proptest::collection::vec(vec3(), 0..4),
            proptest::collection::vec(rb, 0..3),
            proptest::collection::vec(lm, 0..8),
            any::<(u32, u32, i16)>(),
            0.0f64..1e6,
        )
            .prop_map(
                |(frame, sets, unlabeled, rigid_bodies, labeled, (tc, tcs, params), t)| {
                    MocapFrame {
                        frame,
                        marker_sets: sets,
                        unlabeled,
                        rigid_bodies,
                        labeled,
                        timecode: tc,
                        timecode_sub: tcs,
                        timestamp_s: t,
                        params,
                    }
                },
            )
    }

    /// Names as servers write them; a NUL, which a C string cannot hold, is dropped.
    fn name() -> impl Strategy<Value = String> {
        "[A-Za-z0-9_:\\- \\x00]{0,16}"
    }

    fn any_description() -> impl Strategy<Value = Description> {
        prop_oneof![
            (name(), proptest::collection::vec(name(), 0..8))
                .prop_map(|(name, markers)| Description::MarkerSet { name, markers }),
            (name(), any::<i32>(), any::<i32>())
                .prop_map(|(name, id, parent)| Description::RigidBody { name, id, parent }),
            (name(), any::<i32>()).prop_map(|(name, id)| Description::Skeleton { name, id }),
        ]
    }

    /// What a description reads back as: its names without NULs.
    fn without_nuls(d: &Description) -> Description {
        let clean = |s: &String| s.replace('\0', "");
        match d {
            Description::MarkerSet { name, markers } => Description::MarkerSet {
                name: clean(name),
                markers: markers.iter().map(clean).collect(),
            },
            Description::RigidBody { name, id, parent } => Description::RigidBody {
                name: clean(name),
                id: *id,
                parent: *parent,
            },
            Description::Skeleton { name, id } => Description::Skeleton {
                name: clean(name),
                id: *id,
            },
        }
    }

    fn any_server_info() -> impl Strategy<Value = ServerInfo> {
        (
            "[A-Za-z0-9 ._-]{0,255}",
            any::<[u8; 4]>(),
            (3u8..=4, 0u8..=2),
            proptest::option::of(1u64..),
            proptest::option::of(1u16..),
            proptest::option::of(any::<[u8; 4]>()),
        )
            .prop_map(
                |(app, app_version, (major, minor), clock_hz, data_port, group)| ServerInfo {
                    app,
                    app_version,
                    natnet: Version(major, minor),
                    clock_hz,
                    data_port,
                    multicast_group: group.map(std::net::Ipv4Addr::from),
                },
            )
    }

    proptest! {
        /// The model definitions a replay server sends read back as themselves, names
        /// without NULs, whatever their names, counts and ids.
        #[test]
        fn encoded_model_definitions_decode_to_themselves(
            d in proptest::collection::vec(any_description(), 0..6),
        ) {
            let b = encode_model_def(&d).unwrap();
            let want: Vec<Description> = d.iter().map(without_nuls).collect();
            prop_assert_eq!(decode(&b, Version(3, 0)), Ok(Message::ModelDef(want)));
        }

        /// The server info reads back as itself, in Motive's 283 bytes, whatever its
        /// name (up to the field's 255 bytes), versions, clock, port and group. A NatNet
        /// 3 packet always carries the clock and the port: an absent one goes as 0.
        #[test]
        fn encoded_server_info_decodes_to_itself(info in any_server_info()) {
            let b = encode_server_info(&info);
            prop_assert_eq!(b.len(), 283);
            let want = ServerInfo {
                clock_hz: Some(info.clock_hz.unwrap_or(0)),
                data_port: Some(info.data_port.unwrap_or(0)),
                ..info
            };
            prop_assert_eq!(decode(&b, Version(3, 0)), Ok(Message::ServerInfo(want)));
        }

        #[test]
        fn encoded_frames_decode_to_themselves(f in any_frame()) {
            let b = encode_frame(&f).unwrap();
            prop_assert_eq!(decode(&b, Version(3, 0)), Ok(Message::Frame(f)));
        }

        #[test]
        fn arbitrary_bytes_never_panic(b in proptest::collection::vec(any::<u8>(), 0..600)) {
            for v in [Version(3, 0), Version(4, 0), Version(4, 1)] {
                let _ = decode(&b, v);
            }
        }

        #[test]
        fn arbitrary_frames_never_panic(body in proptest::collection::vec(any::<u8>(), 0..600)) {
            let mut b = vec![7u8, 0];
            b.extend_from_slice(&(body.len() as u16).to_le_bytes());
            b.extend_from_slice(&body);
            for v in [Version(3, 0), Version(4, 1)] {
                let _ = decode(&b, v);
            }
        }
    }
}
