//! The vertex stream's wire format (version 4), as pure functions over bytes: encode a
//! [`Topology`], a frame (a [`FrameView`] of whatever holds it) or a goodbye into a
//! caller's buffer, and decode any of them back (a frame as a [`WireFrame`]). No I/O and
//! no solver or marker types here; `protocols/vertex-stream.md` is the specification and
//! `protocols/vertex_stream_client.py` the reference client.
//!
//! Every message is a 12-byte header followed by its payload, all little-endian:
//! `"RGLS"`, `u16` version, `u16` kind, `u32` payload length.

use glam::Vec3;

/// The four bytes every message starts with.
pub const MAGIC: [u8; 4] = *b"RGLS";
/// The format version this build writes; it reads this one and every earlier one
/// ([`OLDEST_VERSION`]..=`VERSION`).
pub const VERSION: u16 = 4;
/// The oldest version this build reads (version 1: no parts in the topology; versions 1
/// and 2: no arrival time and no joints in a frame; versions 1 to 3: one actor, named
/// after its character, and no actor index in a frame).
pub const OLDEST_VERSION: u16 = 1;
/// Header length, bytes.
pub const HEADER_LEN: usize = 12;
/// Largest payload a reader accepts, bytes (about 5.5 million vertices per frame); a
/// header announcing more is an error before anything is allocated.
pub const MAX_PAYLOAD_LEN: u32 = 64 << 20;

/// Most items a decoder reserves room for up front: a count read from the bytes is
/// checked against the payload's length, but an item in memory (a `String`, 24 bytes
/// and more) may be larger than its encoding (2 bytes), so larger lists grow as read.
const INITIAL_CAPACITY: usize = 4096;

/// Message kinds.
pub const KIND_TOPOLOGY: u16 = 1;
pub const KIND_FRAME: u16 = 2;
pub const KIND_GOODBYE: u16 = 3;

/// Marker state codes on the wire: 0 measured, 1 predicted, 2 rigid-filled, 3 held
/// (`protocols/vertex-stream.md`); a frame with a larger code is malformed.
pub const MAX_MARKER_STATE_CODE: u8 = 3;

/// What a client gets first: everything that does not change from frame to frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Topology {
    /// Character name.
    pub character: String,
    /// Solver rate, Hz.
    pub rate_hz: f32,
    /// Length unit of every position (always `"m"` in version 1).
    pub length_unit: String,
    /// Up axis of the world frame (always `"+Y"` in version 1).
    pub up_axis: String,
    /// Handedness of the world frame (always `"right"` in version 1).
    pub handedness: String,
    /// Vertex count of every frame (the character file's own vertex order and count).
    pub vertex_count: u32,
    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// Marker names, in the order of every frame's marker arrays.
    pub marker_names: Vec<String>,
    /// Joint names.
    pub joint_names: Vec<String>,
    /// Parent index of each joint, -1 for a root.
    pub joint_parents: Vec<i32>,
    /// The mesh file's parts (glTF primitives, OBJ groups) with their vertex and triangle
    /// ranges (version 2; empty from a version 1 server).
    pub parts: Vec<WirePart>,
    /// The actor this topology is for: its name on the stage (version 4; the character's
    /// name from an older server).
    pub actor: String,
    /// The actor's index, the one its frames carry (version 4; 0 from an older server).
    pub actor_index: u8,
    /// How many actors the stream carries, each with its own topology (version 4; 1
    /// from an older server). `actor_index < actor_count`.
    pub actor_count: u8,
}

/// A part of the mesh in the topology: its name and its vertex and triangle ranges.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WirePart {
    pub name: String,
    /// Vertices `first_vertex .. first_vertex + vertex_count` of every frame.
    pub first_vertex: u32,
    pub vertex_count: u32,
    /// Triangles `first_triangle .. first_triangle + triangle_count` of the topology.
    pub first_triangle: u32,
    pub triangle_count: u32,
}

/// Why a frame's iterations stopped (wire codes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
#[repr(u8)]
pub enum StopCode {
    Converged = 0,
    IterationCap = 1,
    Deadline = 2,
}

impl StopCode {
    pub fn from_code(c: u8) -> Option<Self> {
        [Self::Converged, Self::IterationCap, Self::Deadline]
            .get(c as usize)
            .copied()
    }
}

/// Solver status of one frame, as streamed.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct FrameStatus {
    pub iterations: u16,
    pub stop: StopCode,
    pub solve_ms: f32,
    pub gc_ms: f32,
    pub rrms: f32,
    pub bone_length_error: f32,
    pub joint_limit_violation_deg: f32,
    pub marker_residual_rms_mm: f32,
    pub marker_residual_max_mm: f32,
}

/// The parts of a solved frame that go on the wire, borrowed from whatever holds them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameView<'a> {
    /// Frame number, counting solver ticks from 0.
    pub frame: u64,
    /// The actor the frame is for (its topology's `actor_index`). Version 4.
    pub actor: u8,
    /// The markers' source time, seconds.
    pub source_time_s: f64,
    /// When the frame was published, seconds since the Unix epoch.
    pub publish_time_s: f64,
    pub status: FrameStatus,
    /// State code of each marker (up to [`MAX_MARKER_STATE_CODE`]).
    pub marker_states: &'a [u8],
    /// Each marker's position as the solver used it, metres.
    pub markers_m: &'a [Vec3],
    /// Full-resolution vertices, metres, world frame.
    pub vertices_m: &'a [Vec3],
    /// When the newest marker sample this frame used reached the daemon, seconds since
    /// the Unix epoch (0: none yet). Version 3.
    pub received_time_s: f64,
    /// The fitted skeleton's joint positions, metres, world frame, in the topology's
    /// joint order (empty: not sent). Version 3.
    pub joints_m: &'a [Vec3],
}

/// A decoded frame: what a client gets.
#[derive(Clone, Debug, PartialEq)]
pub struct WireFrame {
    /// Frame number, counting solver ticks from 0.
    pub frame: u64,
    /// The actor the frame is for (its topology's `actor_index`; 0 from a server older
    /// than version 4).
    pub actor: u8,
    /// The markers' source time, seconds.
    pub source_time_s: f64,
    /// When the frame was published, seconds since the Unix epoch.
    pub publish_time_s: f64,
    pub status: FrameStatus,
    /// State code of each marker (0 measured, 1 predicted, 2 rigid-filled, 3 held).
    pub marker_states: Vec<u8>,
    /// Each marker's position as the solver used it, metres.
    pub markers_m: Vec<Vec3>,
    /// Full-resolution vertices, metres, world frame.
    pub vertices_m: Vec<Vec3>,
    /// When the newest marker sample reached the daemon, seconds since the Unix epoch
    /// (0: none yet, or a version 1 or 2 server).
    pub received_time_s: f64,
    /// The fitted skeleton's joint positions, metres (empty from a version 1 or 2
    /// server).
    pub joints_m: Vec<Vec3>,
}

impl WireFrame {
    /// The frame as a view, to encode it again.
    pub fn view(&self) -> FrameView<'_> {
        FrameView {
            frame: self.frame,
            actor: self.actor,
            source_time_s: self.source_time_s,
            publish_time_s: self.publish_time_s,
            status: self.status,
            marker_states: &self.marker_states,
            markers_m: &self.markers_m,
            vertices_m: &self.vertices_m,
            received_time_s: self.received_time_s,
            joints_m: &self.joints_m,
        }
    }
}

impl FrameStatus {
    /// A status with every figure zero (converged after no iteration).
    pub const ZERO: FrameStatus = FrameStatus {
        iterations: 0,
        stop: StopCode::Converged,
        solve_ms: 0.0,
        gc_ms: 0.0,
        rrms: 0.0,
        bone_length_error: 0.0,
        joint_limit_violation_deg: 0.0,
        marker_residual_rms_mm: 0.0,
        marker_residual_max_mm: 0.0,
    };
}

/// A decoded message.
#[derive(Clone, Debug, PartialEq)]
pub enum Message {
    Topology(Topology),
    Frame(WireFrame),
    /// The server is closing the stream; the reason is for people.
    Goodbye(String),
}

/// Why bytes are not a message.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum DecodeError {
    #[error("need {needed} bytes, have {have}")]
    Incomplete { needed: usize, have: usize },
    #[error("bad magic {found:02x?} (expected \"RGLS\")")]
    BadMagic { found: [u8; 4] },
    #[error("unsupported version {found} (this build reads {OLDEST_VERSION} to {VERSION})")]
    Version { found: u16 },
    #[error("unknown message kind {kind}")]
    UnknownKind { kind: u16 },
    #[error("payload of {len} bytes exceeds the limit of {MAX_PAYLOAD_LEN}")]
    TooLong { len: u32 },
    #[error("{kind} payload malformed at byte {offset}: {what}")]
    Malformed {
        kind: &'static str,
        offset: usize,
        what: &'static str,
    },
}

fn header(out: &mut Vec<u8>, kind: u16) -> usize {
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&kind.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.len()
}

fn finish(out: &mut [u8], start: usize) {
    let len = (out.len() - start) as u32;
    out[start - 4..start].copy_from_slice(&len.to_le_bytes());
}

fn put_str(out: &mut Vec<u8>, s: &str) {
    let b = s.as_bytes();
    let n = b.len().min(u16::MAX as usize);
    out.extend_from_slice(&(n as u16).to_le_bytes());
    out.extend_from_slice(&b[..n]);
}

fn put_f32(out: &mut Vec<u8>, v: f32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

/// Appends a topology message to `out`.
pub fn encode_topology(t: &Topology, out: &mut Vec<u8>) {
    let start = header(out, KIND_TOPOLOGY);
    put_str(out, &t.character);
    put_f32(out, t.rate_hz);
    put_str(out, &t.length_unit);
    put_str(out, &t.up_axis);
    put_str(out, &t.handedness);
    put_u32(out, t.vertex_count);
    put_u32(out, t.triangles.len() as u32);
    for tri in &t.triangles {
        for &i in tri {
            put_u32(out, i);
        }
    }
    put_u32(out, t.marker_names.len() as u32);
    for n in &t.marker_names {
        put_str(out, n);
    }
    put_u32(out, t.joint_names.len() as u32);
    for (n, p) in t.joint_names.iter().zip(&t.joint_parents) {
        put_str(out, n);
        out.extend_from_slice(&p.to_le_bytes());
    }
    put_u32(out, t.parts.len() as u32);
    for p in &t.parts {
        put_str(out, &p.name);
        for v in [
            p.first_vertex,
            p.vertex_count,
            p.first_triangle,
            p.triangle_count,
        ] {
            put_u32(out, v);
        }
    }
    out.push(t.actor_index);
    out.push(t.actor_count);
    put_str(out, &t.actor);
    finish(out, start);
}

/// Appends a frame message to `out` (no allocation once `out` has grown to a frame). The
/// marker arrays must have the same length.
pub fn encode_frame(f: &FrameView<'_>, out: &mut Vec<u8>) {
    let start = header(out, KIND_FRAME);
    out.extend_from_slice(&f.frame.to_le_bytes());
    out.extend_from_slice(&f.source_time_s.to_le_bytes());
    out.extend_from_slice(&f.publish_time_s.to_le_bytes());
    let s = &f.status;
    out.extend_from_slice(&s.iterations.to_le_bytes());
    out.push(s.stop as u8);
    out.push(f.actor);
    for v in [
        s.solve_ms,
        s.gc_ms,
        s.rrms,
        s.bone_length_error,
        s.joint_limit_violation_deg,
        s.marker_residual_rms_mm,
        s.marker_residual_max_mm,
    ] {
        put_f32(out, v);
    }
    put_u32(out, f.marker_states.len() as u32);
    out.extend_from_slice(f.marker_states);
    let pad = (4 - f.marker_states.len() % 4) % 4;
    out.extend(std::iter::repeat_n(0u8, pad));
    for p in f.markers_m {
        for c in p.to_array() {
            put_f32(out, c);
        }
    }
    put_u32(out, f.vertices_m.len() as u32);
    for p in f.vertices_m {
        for c in p.to_array() {
            put_f32(out, c);
        }
    }
    out.extend_from_slice(&f.received_time_s.to_le_bytes());
    put_u32(out, f.joints_m.len() as u32);
    for p in f.joints_m {
        for c in p.to_array() {
            put_f32(out, c);
        }
    }
    finish(out, start);
}

/// Appends a goodbye message to `out`.
pub fn encode_goodbye(reason: &str, out: &mut Vec<u8>) {
    let start = header(out, KIND_GOODBYE);
    put_str(out, reason);
    finish(out, start);
}

/// Reads a header: the message kind and payload length. Checks magic, version, kind and
/// the length limit, so a reader can refuse before allocating.
pub fn decode_header(b: &[u8]) -> Result<(u16, u32), DecodeError> {
    if b.len() < HEADER_LEN {
        return Err(DecodeError::Incomplete {
            needed: HEADER_LEN,
            have: b.len(),
        });
    }
    let found = [b[0], b[1], b[2], b[3]];
    if found != MAGIC {
        return Err(DecodeError::BadMagic { found });
    }
    let version = u16::from_le_bytes([b[4], b[5]]);
    if !(OLDEST_VERSION..=VERSION).contains(&version) {
        return Err(DecodeError::Version { found: version });
    }
    let kind = u16::from_le_bytes([b[6], b[7]]);
    if !(KIND_TOPOLOGY..=KIND_GOODBYE).contains(&kind) {
        return Err(DecodeError::UnknownKind { kind });
    }
    let len = u32::from_le_bytes([b[8], b[9], b[10], b[11]]);
    if len > MAX_PAYLOAD_LEN {
        return Err(DecodeError::TooLong { len });
    }
    Ok((kind, len))
}

/// Decodes the first message in `b`; returns it and the bytes it used.
pub fn decode(b: &[u8]) -> Result<(Message, usize), DecodeError> {
    let (kind, len) = decode_header(b)?;
    let total = HEADER_LEN + len as usize;
    if b.len() < total {
        return Err(DecodeError::Incomplete {
            needed: total,
            have: b.len(),
        });
    }
    let payload = &b[HEADER_LEN..total];
    let version = u16::from_le_bytes([b[4], b[5]]);
    let msg = match kind {
        KIND_TOPOLOGY => Message::Topology(decode_topology(payload, version)?),
        KIND_FRAME => Message::Frame(decode_frame(payload, version)?),
        _ => {
            let mut r = Reader::new(payload, "goodbye");
            let s = r.string()?;
            r.end()?;
            Message::Goodbye(s)
        }
    };
    Ok((msg, total))
}

/// A bounds-checked cursor over a payload.
struct Reader<'a> {
    b: &'a [u8],
    at: usize,
    kind: &'static str,
}

impl<'a> Reader<'a> {
    fn new(b: &'a [u8], kind: &'static str) -> Self {
        Self { b, at: 0, kind }
    }

    fn err(&self, what: &'static str) -> DecodeError {
        DecodeError::Malformed {
            kind: self.kind,
            offset: self.at,
            what,
        }
    }

    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], DecodeError> {
        if self.b.len() - self.at < n {
            return Err(self.err(what));
        }
        let s = &self.b[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }

    fn u8(&mut self) -> Result<u8, DecodeError> {
        Ok(self.take(1, "truncated u8")?[0])
    }

    fn u16(&mut self) -> Result<u16, DecodeError> {
        let s = self.take(2, "truncated u16")?;
        Ok(u16::from_le_bytes([s[0], s[1]]))
    }

    fn u32(&mut self) -> Result<u32, DecodeError> {
        let s = self.take(4, "truncated u32")?;
        Ok(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
    }

    fn f32(&mut self) -> Result<f32, DecodeError> {
        Ok(f32::from_bits(self.u32()?))
    }

    fn u64(&mut self) -> Result<u64, DecodeError> {
        let s = self.take(8, "truncated u64")?;
        Ok(u64::from_le_bytes(s.try_into().expect("8 bytes")))
    }

    fn f64(&mut self) -> Result<f64, DecodeError> {
        Ok(f64::from_bits(self.u64()?))
    }

    fn string(&mut self) -> Result<String, DecodeError> {
        let n = self.u16()? as usize;
        let s = self.take(n, "truncated string")?;
        std::str::from_utf8(s)
            .map(str::to_owned)
            .map_err(|_| self.err("string is not UTF-8"))
    }

    /// A count of items of at least `min_item_len` bytes each, checked against the bytes
    /// left so that no allocation exceeds the payload.
    fn count(&mut self, min_item_len: usize) -> Result<usize, DecodeError> {
        let n = self.u32()? as usize;
        if n.saturating_mul(min_item_len) > self.b.len() - self.at {
            return Err(self.err("count larger than the payload"));
        }
        Ok(n)
    }

    fn vec3s(&mut self, n: usize) -> Result<Vec<Vec3>, DecodeError> {
        let s = self.take(n * 12, "truncated positions")?;
        Ok(s.chunks_exact(12)
            .map(|c| {
                let f = |i: usize| f32::from_le_bytes(c[i..i + 4].try_into().expect("4 bytes"));
                Vec3::new(f(0), f(4), f(8))
            })
            .collect())
    }

    fn end(&self) -> Result<(), DecodeError> {
        if self.at == self.b.len() {
            Ok(())
        } else {
            Err(self.err("trailing bytes"))
        }
    }
}

fn decode_topology(b: &[u8], version: u16) -> Result<Topology, DecodeError> {
    let mut r = Reader::new(b, "topology");
    let character = r.string()?;
    let rate_hz = r.f32()?;
    let length_unit = r.string()?;
    let up_axis = r.string()?;
    let handedness = r.string()?;
    let vertex_count = r.u32()?;
    let nt = r.count(12)?;
    let mut triangles = Vec::with_capacity(nt.min(INITIAL_CAPACITY));
    for _ in 0..nt {
        let tri = [r.u32()?, r.u32()?, r.u32()?];
        if tri.iter().any(|&i| i >= vertex_count) {
            return Err(r.err("triangle index out of range"));
        }
        triangles.push(tri);
    }
    let nm = r.count(2)?;
    let mut marker_names = Vec::with_capacity(nm.min(INITIAL_CAPACITY));
    for _ in 0..nm {
        marker_names.push(r.string()?);
    }
    let nj = r.count(6)?;
    let (mut joint_names, mut joint_parents) = (
        Vec::with_capacity(nj.min(INITIAL_CAPACITY)),
        Vec::with_capacity(nj.min(INITIAL_CAPACITY)),
    );
    for _ in 0..nj {
        joint_names.push(r.string()?);
        joint_parents.push(r.u32()? as i32);
    }
    let parts = if version >= 2 {
        decode_parts(&mut r, vertex_count, triangles.len())?
    } else {
        Vec::new()
    };
    let (actor_index, actor_count, actor) = if version >= 4 {
        let [index, count] = [r.u8()?, r.u8()?];
        if index >= count {
            return Err(r.err("actor index not below the actor count"));
        }
        (index, count, r.string()?)
    } else {
        (0, 1, character.clone())
    };
    r.end()?;
    Ok(Topology {
        character,
        rate_hz,
        length_unit,
        up_axis,
        handedness,
        vertex_count,
        triangles,
        marker_names,
        joint_names,
        joint_parents,
        parts,
        actor,
        actor_index,
        actor_count,
    })
}

/// The topology's parts (version 2), each range inside the mesh.
fn decode_parts(
    r: &mut Reader<'_>,
    vertex_count: u32,
    triangle_count: usize,
) -> Result<Vec<WirePart>, DecodeError> {
    let n = r.count(18)?;
    let mut parts = Vec::with_capacity(n.min(INITIAL_CAPACITY));
    for _ in 0..n {
        let name = r.string()?;
        let [first_vertex, vertex_count_p, first_triangle, triangle_count_p] =
            [r.u32()?, r.u32()?, r.u32()?, r.u32()?];
        let fits =
            |first: u32, count: u32, total: u64| u64::from(first) + u64::from(count) <= total;
        if !fits(first_vertex, vertex_count_p, vertex_count.into()) {
            return Err(r.err("part's vertex range outside the mesh"));
        }
        if !fits(first_triangle, triangle_count_p, triangle_count as u64) {
            return Err(r.err("part's triangle range outside the mesh"));
        }
        parts.push(WirePart {
            name,
            first_vertex,
            vertex_count: vertex_count_p,
            first_triangle,
            triangle_count: triangle_count_p,
        });
    }
    Ok(parts)
}

fn decode_frame(b: &[u8], version: u16) -> Result<WireFrame, DecodeError> {
    let mut r = Reader::new(b, "frame");
    let frame = r.u64()?;
    let source_time_s = r.f64()?;
    let publish_time_s = r.f64()?;
    let iterations = r.u16()?;
    let code = r.u8()?;
    let stop = StopCode::from_code(code).ok_or_else(|| r.err("unknown stop code"))?;
    // Reserved (zero) before version 4.
    let actor = r.u8()?;
    let actor = if version >= 4 { actor } else { 0 };
    let mut f = [0f32; 7];
    for v in &mut f {
        *v = r.f32()?;
    }
    let nm = r.count(13)?;
    let codes = r.take(nm, "truncated marker states")?;
    if codes.iter().any(|c| *c > MAX_MARKER_STATE_CODE) {
        return Err(r.err("unknown marker state"));
    }
    let marker_states = codes.to_vec();
    r.take((4 - nm % 4) % 4, "truncated padding")?;
    let markers_m = r.vec3s(nm)?;
    let nv = r.count(12)?;
    let vertices_m = r.vec3s(nv)?;
    let (received_time_s, joints_m) = if version >= 3 {
        let received = r.f64()?;
        let nj = r.count(12)?;
        (received, r.vec3s(nj)?)
    } else {
        (0.0, Vec::new())
    };
    r.end()?;
    Ok(WireFrame {
        frame,
        actor,
        source_time_s,
        publish_time_s,
        status: FrameStatus {
            iterations,
            stop,
            solve_ms: f[0],
            gc_ms: f[1],
            rrms: f[2],
            bone_length_error: f[3],
            joint_limit_violation_deg: f[4],
            marker_residual_rms_mm: f[5],
            marker_residual_max_mm: f[6],
        },
        marker_states,
        markers_m,
        vertices_m,
        received_time_s,
        joints_m,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn example_topology() -> Topology {
        Topology {
            character: "tri".into(),
            rate_hz: 120.0,
            length_unit: "m".into(),
            up_axis: "+Y".into(),
            handedness: "right".into(),
            vertex_count: 3,
            triangles: vec![[0, 1, 2]],
            marker_names: vec!["tip".into()],
            joint_names: vec!["root".into()],
            joint_parents: vec![-1],
            parts: vec![WirePart {
                name: "skin".into(),
                first_vertex: 0,
                vertex_count: 3,
                first_triangle: 0,
                triangle_count: 1,
            }],
            actor: "Bob".into(),
            actor_index: 1,
            actor_count: 2,
        }
    }

    fn example_frame() -> WireFrame {
        WireFrame {
            frame: 7,
            actor: 1,
            source_time_s: 0.5,
            publish_time_s: 1.0e9,
            status: FrameStatus {
                iterations: 3,
                stop: StopCode::Deadline,
                solve_ms: 0.75,
                ..FrameStatus::ZERO
            },
            // Predicted.
            marker_states: vec![1],
            markers_m: vec![Vec3::new(0.0, 1.0, 0.0)],
            vertices_m: vec![Vec3::X, Vec3::Y, Vec3::Z],
            received_time_s: 1.0e9 - 0.5,
            joints_m: vec![Vec3::new(0.0, 0.5, 0.0)],
        }
    }

    #[test]
    fn messages_round_trip() {
        let mut b = Vec::new();
        encode_topology(&example_topology(), &mut b);
        encode_frame(&example_frame().view(), &mut b);
        encode_goodbye("shutting down", &mut b);
        let (m1, n1) = decode(&b).unwrap();
        assert_eq!(m1, Message::Topology(example_topology()));
        let (m2, n2) = decode(&b[n1..]).unwrap();
        assert_eq!(m2, Message::Frame(example_frame()));
        let (m3, n3) = decode(&b[n1 + n2..]).unwrap();
        assert_eq!(m3, Message::Goodbye("shutting down".into()));
        assert_eq!(n1 + n2 + n3, b.len());
    }

    #[test]
    fn frame_bytes_match_the_documented_example() {
        // protocols/vertex-stream.md, "Worked example", byte for byte.
        const HEX: &str = "
            52 47 4c 53 04 00 02 00 8c 00 00 00 07 00 00 00
            00 00 00 00 00 00 00 00 00 00 e0 3f 00 00 00 00
            65 cd cd 41 03 00 02 01 00 00 40 3f 00 00 00 00
            00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00
            00 00 00 00 01 00 00 00 01 00 00 00 00 00 00 00
            00 00 80 3f 00 00 00 00 03 00 00 00 00 00 80 3f
            00 00 00 00 00 00 00 00 00 00 00 00 00 00 80 3f
            00 00 00 00 00 00 00 00 00 00 00 00 00 00 80 3f
            00 00 c0 ff 64 cd cd 41 01 00 00 00 00 00 00 00
            00 00 00 3f 00 00 00 00";
        let expected: Vec<u8> = HEX
            .split_whitespace()
            .map(|h| u8::from_str_radix(h, 16).unwrap())
            .collect();
        let mut b = Vec::new();
        encode_frame(&example_frame().view(), &mut b);
        assert_eq!(b, expected);
        // Bob's topology ends with his index, the count and his name.
        b.clear();
        encode_topology(&example_topology(), &mut b);
        assert_eq!(b[b.len() - 7..], [0x01, 0x02, 0x03, 0x00, b'B', b'o', b'b']);
    }

    /// The bytes of `b` (one message) without its last `cut` payload bytes, announced
    /// as `version`.
    fn older(b: &[u8], cut: usize, version: u8) -> Vec<u8> {
        let mut o = b[..b.len() - cut].to_vec();
        o[4] = version;
        let len = (o.len() - HEADER_LEN) as u32;
        o[8..12].copy_from_slice(&len.to_le_bytes());
        o
    }

    /// Versions 1 to 3 topologies (no parts before 2, no actor before 4) still read, as
    /// the one actor named after its character; a part outside the mesh, or an actor
    /// index not below the count, is malformed; version 5 is refused.
    #[test]
    fn older_topologies_read_and_parts_and_actors_are_checked() {
        let mut t = example_topology();
        t.parts.clear();
        let mut b = Vec::new();
        encode_topology(&t, &mut b);
        // Index, count, and the name "Bob" (2 + 3 bytes).
        let actor_len = 2 + 2 + t.actor.len();
        let alone = Topology {
            actor: t.character.clone(),
            actor_index: 0,
            actor_count: 1,
            ..t.clone()
        };
        // Version 3 is version 4 without the actor; version 1 also without the parts'
        // u32 count.
        assert_eq!(
            decode(&older(&b, actor_len, 3)).unwrap().0,
            Message::Topology(alone.clone())
        );
        assert_eq!(
            decode(&older(&b, actor_len + 4, 1)).unwrap().0,
            Message::Topology(alone)
        );
        for (vertex_count, triangle_count) in [(4, 1), (3, 2), (u32::MAX, 1)] {
            t.parts = vec![WirePart {
                name: "x".into(),
                first_vertex: 0,
                vertex_count,
                first_triangle: 0,
                triangle_count,
            }];
            b.clear();
            encode_topology(&t, &mut b);
            assert!(
                matches!(
                    decode(&b),
                    Err(DecodeError::Malformed {
                        kind: "topology",
                        ..
                    })
                ),
                "{vertex_count} {triangle_count}"
            );
        }
        for (index, count) in [(2, 2), (0, 0), (255, 1)] {
            b.clear();
            let t = Topology {
                actor_index: index,
                actor_count: count,
                ..example_topology()
            };
            encode_topology(&t, &mut b);
            assert_eq!(
                decode(&b),
                Err(DecodeError::Malformed {
                    kind: "topology",
                    offset: b.len() - HEADER_LEN - 3 - 2,
                    what: "actor index not below the actor count"
                }),
                "{index} of {count}"
            );
        }
        b.clear();
        encode_topology(&example_topology(), &mut b);
        b[4] = 5;
        assert_eq!(decode(&b), Err(DecodeError::Version { found: 5 }));
    }

    /// A version 2 frame (no arrival time, no joints) still reads, with neither, as
    /// actor 0's; the same bytes announced as version 3 are malformed (the new fields
    /// are missing).
    #[test]
    fn version_2_frames_read_without_arrival_time_or_joints() {
        let mut f = example_frame();
        let mut b = Vec::new();
        encode_frame(&f.view(), &mut b);
        let mut v2 = older(&b, 8 + 4 + 12, 2);
        // Byte 27 was reserved before version 4: an older server's frame is actor 0's.
        f.actor = 0;
        f.received_time_s = 0.0;
        f.joints_m.clear();
        assert_eq!(decode(&v2).unwrap().0, Message::Frame(f));
        v2[4] = 3;
        assert!(matches!(
            decode(&v2),
            Err(DecodeError::Malformed { kind: "frame", .. })
        ));
    }

    #[test]
    fn truncation_is_incomplete_not_an_error() {
        let mut b = Vec::new();
        encode_frame(&example_frame().view(), &mut b);
        for cut in 0..b.len() {
            assert!(
                matches!(decode(&b[..cut]), Err(DecodeError::Incomplete { .. })),
                "cut at {cut}"
            );
        }
    }

    #[test]
    fn oversized_header_is_refused_before_reading() {
        let mut b = b"RGLS\x04\x00\x02\x00".to_vec();
        b.extend_from_slice(&u32::MAX.to_le_bytes());
        assert_eq!(
            decode_header(&b),
            Err(DecodeError::TooLong { len: u32::MAX })
        );
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
            let _ = decode(&bytes);
        }

        #[test]
        fn corrupted_frames_never_panic(flip in 0usize..128, value in any::<u8>()) {
            let mut b = Vec::new();
            encode_frame(&example_frame().view(), &mut b);
            let i = flip % b.len();
            b[i] = value;
            let _ = decode(&b);
        }
    }
}
