//! C3D files (the motion-capture interchange format, c3d.org): a reader for 3D point data
//! and a writer whose output the reader reads back exactly.
//!
//! The reader takes the parameter section as the truth (POINT:USED, POINT:RATE,
//! POINT:SCALE, POINT:DATA_START, POINT:FRAMES or TRIAL:ACTUAL_START/END_FIELD, POINT:UNITS,
//! POINT:LABELS and LABELS2..., ANALOG:USED and ANALOG:RATE) with the header as fallback,
//! and warns where they disagree. Integer and floating-point storage; Intel, DEC and MIPS
//! processor types. A sample with a negative residual or a non-finite coordinate is
//! missing (NaN). Analog data is skipped. Positions come out in metres, in the world frame
//! (right-handed, Y up): C3D's usual Z up (`POINT:Y_SCREEN = +Z`, the default) becomes
//! `(x, z, -y)`. A file cut short keeps its whole frames, with a warning.
//!
//! Layout: 512-byte blocks; block 1 the header, then the parameter section (4-byte
//! preamble with the block count and the processor type, then groups and parameters),
//! then the data: per frame, per point `x y z residual` (f32, or i16 scaled by
//! POINT:SCALE), then the analog samples.

use crate::geom::axes::{y_up_from_z_up, z_up_from_y_up};
use glam::DVec3;

const BLOCK: usize = 512;
/// Processor type codes (parameter preamble byte 4).
const PROC_INTEL: u8 = 84;
const PROC_DEC: u8 = 85;
const PROC_MIPS: u8 = 86;
/// Most points a file may declare (bounds allocation before reading data).
pub const MAX_POINTS: usize = 100_000;

/// Byte order and float format of a file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Processor {
    Intel,
    Dec,
    Mips,
}

impl Processor {
    fn code(self) -> u8 {
        match self {
            Processor::Intel => PROC_INTEL,
            Processor::Dec => PROC_DEC,
            Processor::Mips => PROC_MIPS,
        }
    }

    fn u16(self, b: [u8; 2]) -> u16 {
        match self {
            Processor::Mips => u16::from_be_bytes(b),
            _ => u16::from_le_bytes(b),
        }
    }

    fn i16(self, b: [u8; 2]) -> i16 {
        self.u16(b) as i16
    }

    fn f32(self, b: [u8; 4]) -> f32 {
        match self {
            Processor::Intel => f32::from_le_bytes(b),
            Processor::Mips => f32::from_be_bytes(b),
            // VAX F_floating: the 16-bit halves swapped, exponent bias one higher.
            Processor::Dec => {
                if b[1] & 0x7f == 0 && b[0] & 0x80 == 0 {
                    0.0
                } else {
                    f32::from_le_bytes([b[2], b[3], b[0], b[1]]) / 4.0
                }
            }
        }
    }

    fn put_u16(self, v: u16) -> [u8; 2] {
        match self {
            Processor::Mips => v.to_be_bytes(),
            _ => v.to_le_bytes(),
        }
    }

    fn put_f32(self, v: f32) -> [u8; 4] {
        match self {
            Processor::Intel => v.to_le_bytes(),
            Processor::Mips => v.to_be_bytes(),
            Processor::Dec => {
                if v == 0.0 {
                    [0; 4]
                } else {
                    let c = (v * 4.0).to_le_bytes();
                    [c[2], c[3], c[0], c[1]]
                }
            }
        }
    }
}

/// A C3D file's 3D point data.
#[derive(Clone, Debug)]
pub struct C3d {
    pub rate_hz: f64,
    pub labels: Vec<String>,
    /// First frame number in the file's own numbering.
    pub first_frame: u32,
    /// `frames[f][k]`: metres, world frame (Y up); NaN where missing.
    pub frames: Vec<Vec<DVec3>>,
    /// POINT:UNITS as written in the file (`mm` when absent).
    pub units: String,
    pub processor: Processor,
    /// Things the reader tolerated (header and parameters disagreeing, a cut file).
    pub warnings: Vec<String>,
}

/// Why a file is not C3D data the reader can use.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum C3dError {
    #[error("file too short for a C3D header ({len} bytes)")]
    TooShort { len: usize },
    #[error("not a C3D file: header byte 2 is {found:#04x}, expected 0x50")]
    BadKey { found: u8 },
    #[error("parameter section at block {block} lies outside the file")]
    NoParameters { block: usize },
    #[error("unknown processor type {code} (expected 84 Intel, 85 DEC or 86 MIPS)")]
    Processor { code: u8 },
    #[error("parameter section malformed at byte {offset}: {what}")]
    Parameters { offset: usize, what: &'static str },
    #[error("{what}")]
    Invalid { what: String },
}

/// A parameter's raw value.
#[derive(Clone, Debug)]
struct Param {
    group: String,
    name: String,
    /// -1 char, 1 byte, 2 int16, 4 float.
    kind: i8,
    dims: Vec<usize>,
    data: Vec<u8>,
}

impl Param {
    fn count(&self) -> usize {
        self.dims.iter().product::<usize>().max(1)
    }

    fn ints(&self, p: Processor) -> Vec<i64> {
        match self.kind {
            1 => self.data.iter().map(|b| *b as i64).collect(),
            2 => self
                .data
                .chunks_exact(2)
                .map(|c| p.i16([c[0], c[1]]) as i64)
                .collect(),
            4 => self.floats(p).iter().map(|f| *f as i64).collect(),
            _ => Vec::new(),
        }
    }

    fn floats(&self, p: Processor) -> Vec<f64> {
        match self.kind {
            4 => self
                .data
                .chunks_exact(4)
                .map(|c| p.f32([c[0], c[1], c[2], c[3]]) as f64)
                .collect(),
            1 | 2 => self.ints(p).iter().map(|i| *i as f64).collect(),
            _ => Vec::new(),
        }
    }

    /// Char data as strings: `dims[0]` characters each, trailing blanks trimmed.
    fn strings(&self) -> Vec<String> {
        if self.kind != -1 {
            return Vec::new();
        }
        let w = self.dims.first().copied().unwrap_or(self.data.len()).max(1);
        if self.dims.len() <= 1 {
            return vec![String::from_utf8_lossy(&self.data).trim().to_owned()];
        }
        self.data
            .chunks(w)
            .map(|c| {
                String::from_utf8_lossy(c)
                    .trim_matches(|ch: char| ch.is_whitespace() || ch == '\0')
                    .to_owned()
            })
            .collect()
    }
}

struct Params {
    list: Vec<Param>,
    proc: Processor,
}

impl Params {
    fn get(&self, group: &str, name: &str) -> Option<&Param> {
        self.list
            .iter()
            .find(|p| p.group.eq_ignore_ascii_case(group) && p.name.eq_ignore_ascii_case(name))
    }

    fn int(&self, group: &str, name: &str) -> Option<i64> {
        self.get(group, name)
            .and_then(|p| p.ints(self.proc).first().copied())
    }

    fn float(&self, group: &str, name: &str) -> Option<f64> {
        self.get(group, name)
            .and_then(|p| p.floats(self.proc).first().copied())
    }

    fn string(&self, group: &str, name: &str) -> Option<String> {
        self.get(group, name)
            .and_then(|p| p.strings().into_iter().next())
    }
}

fn parse_params(b: &[u8], start: usize, proc: Processor) -> Result<Params, C3dError> {
    let err = |offset: usize, what: &'static str| C3dError::Parameters { offset, what };
    let mut groups: Vec<(i8, String)> = Vec::new();
    let mut raw: Vec<(i8, Param)> = Vec::new();
    let mut at = start + 4;
    while at + 2 <= b.len() {
        let name_len = (b[at] as i8).unsigned_abs() as usize;
        let id = b[at + 1] as i8;
        if name_len == 0 || id == 0 {
            break;
        }
        let name_at = at + 2;
        let name = b
            .get(name_at..name_at + name_len)
            .ok_or(err(at, "name runs past the end"))?;
        let name = String::from_utf8_lossy(name).trim().to_owned();
        let off_at = name_at + name_len;
        let next = b
            .get(off_at..off_at + 2)
            .map(|c| proc.i16([c[0], c[1]]))
            .ok_or(err(off_at, "offset runs past the end"))?;
        let body = off_at + 2;
        if id < 0 {
            groups.push((-id, name));
        } else {
            let kind = *b.get(body).ok_or(err(body, "type runs past the end"))? as i8;
            if ![-1, 1, 2, 4].contains(&kind) {
                return Err(err(body, "unknown parameter type"));
            }
            let nd = *b
                .get(body + 1)
                .ok_or(err(body, "dimensions run past the end"))? as usize;
            let dims: Vec<usize> = b
                .get(body + 2..body + 2 + nd)
                .ok_or(err(body, "dimensions run past the end"))?
                .iter()
                .map(|d| *d as usize)
                .collect();
            let p = Param {
                group: String::new(),
                name,
                kind,
                dims,
                data: Vec::new(),
            };
            let n = p.count() * kind.unsigned_abs() as usize;
            let d0 = body + 2 + nd;
            let data = b
                .get(d0..d0 + n)
                .ok_or(err(d0, "data runs past the end"))?
                .to_vec();
            raw.push((id, Param { data, ..p }));
        }
        if next <= 0 {
            break;
        }
        at = off_at + next as usize;
    }
    let list = raw
        .into_iter()
        .map(|(id, mut p)| {
            p.group = groups
                .iter()
                .find(|(g, _)| *g == id)
                .map(|(_, n)| n.clone())
                .unwrap_or_default();
            p
        })
        .collect();
    Ok(Params { list, proc })
}

/// What the header (block 1) says, the fallback for the parameter section, and where
/// that section starts and what processor type it names.
struct Header {
    /// Byte offset of the parameter section.
    pstart: usize,
    proc: Processor,
    h_points: u16,
    h_analog: u16,
    h_first: u16,
    h_last: u16,
    h_scale: f64,
    h_data_start: u16,
    h_rate: f64,
}

/// How the points are stored, from the parameters (header as fallback).
struct PointFormat {
    points: usize,
    rate_hz: f64,
    /// POINT:SCALE: negative for float storage, else the file's units per integer step.
    scale: f64,
    /// First block of the data.
    data_block: usize,
}

/// The header block: the key, the parameter section's place and its processor type, and
/// the header's own values.
fn read_header(b: &[u8]) -> Result<Header, C3dError> {
    if b.len() < BLOCK {
        return Err(C3dError::TooShort { len: b.len() });
    }
    if b[1] != 0x50 {
        return Err(C3dError::BadKey { found: b[1] });
    }
    let pblock = (b[0] as usize).max(1);
    let pstart = (pblock - 1) * BLOCK;
    if pstart + 4 > b.len() {
        return Err(C3dError::NoParameters { block: pblock });
    }
    let code = b[pstart + 3];
    let proc = match code {
        PROC_INTEL => Processor::Intel,
        PROC_DEC => Processor::Dec,
        PROC_MIPS => Processor::Mips,
        _ => return Err(C3dError::Processor { code }),
    };
    let word = |i: usize| proc.u16([b[2 * i], b[2 * i + 1]]);
    let hfloat = |i: usize| proc.f32([b[2 * i], b[2 * i + 1], b[2 * i + 2], b[2 * i + 3]]) as f64;
    let (h_points, h_analog, h_first, h_last) = (word(1), word(2), word(3), word(4));
    let (h_scale, h_data_start, h_rate) = (hfloat(6), word(8), hfloat(10));
    Ok(Header {
        pstart,
        proc,
        h_points,
        h_analog,
        h_first,
        h_last,
        h_scale,
        h_data_start,
        h_rate,
    })
}

/// Point count (POINT:USED), frame rate (POINT:RATE), scale (POINT:SCALE) and data start
/// (POINT:DATA_START), each from the parameters with the header as fallback.
fn point_format(
    params: &Params,
    h: &Header,
    warnings: &mut Vec<String>,
) -> Result<PointFormat, C3dError> {
    let Header {
        h_points,
        h_scale,
        h_data_start,
        h_rate,
        ..
    } = *h;
    let points = match params.int("POINT", "USED") {
        Some(n) => (n as u16) as usize,
        None => h_points as usize,
    };
    if points != h_points as usize {
        warnings.push(format!(
            "header says {h_points} points, POINT:USED says {points} (using the parameter)"
        ));
    }
    if points > MAX_POINTS {
        return Err(C3dError::Invalid {
            what: format!("{points} points (at most {MAX_POINTS})"),
        });
    }
    let rate_hz = params
        .float("POINT", "RATE")
        .filter(|r| r.is_finite() && *r > 0.0)
        .unwrap_or(h_rate);
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(C3dError::Invalid {
            what: format!("no usable frame rate (header {h_rate}, POINT:RATE absent)"),
        });
    }
    let scale = params
        .float("POINT", "SCALE")
        .filter(|s| s.is_finite() && *s != 0.0)
        .unwrap_or(h_scale);
    let data_block = params
        .int("POINT", "DATA_START")
        .map(|d| (d as u16) as usize)
        .filter(|d| *d > 0)
        .unwrap_or(h_data_start as usize);
    if data_block != h_data_start as usize {
        warnings.push(format!(
            "header says data starts at block {h_data_start}, POINT:DATA_START says {data_block} (using the parameter)"
        ));
    }
    Ok(PointFormat {
        points,
        rate_hz,
        scale,
        data_block,
    })
}

/// The first frame number and the frame count: TRIAL:ACTUAL_START/END_FIELD, else the
/// header's range, and POINT:FRAMES where it disagrees with a 16-bit range.
fn frame_range(params: &Params, h: &Header, warnings: &mut Vec<String>) -> (u32, usize) {
    let proc = h.proc;
    // Frame range: TRIAL fields (32-bit, for long trials), else header.
    let field = |name: &str| {
        params.get("TRIAL", name).and_then(|p| {
            let v = p.ints(proc);
            (v.len() >= 2).then(|| (v[0] as u16 as u32) | ((v[1] as u16 as u32) << 16))
        })
    };
    let (first_frame, last_frame) = match (field("ACTUAL_START_FIELD"), field("ACTUAL_END_FIELD")) {
        (Some(s), Some(e)) if e >= s => (s, e),
        _ => (h.h_first as u32, h.h_last as u32),
    };
    let mut n_frames = (last_frame as usize + 1).saturating_sub(first_frame as usize);
    if let Some(pf) = params.int("POINT", "FRAMES") {
        let pf = (pf as u16) as usize;
        if pf != n_frames && n_frames <= u16::MAX as usize {
            warnings.push(format!(
                "header frame range gives {n_frames} frames, POINT:FRAMES says {pf} (using the parameter)"
            ));
            n_frames = pf;
        }
    }
    (first_frame, n_frames)
}

/// Analog samples per frame (ANALOG:USED × ANALOG:RATE / POINT:RATE, else the header's).
fn analog_samples_per_frame(
    params: &Params,
    h: &Header,
    rate_hz: f64,
    warnings: &mut Vec<String>,
) -> usize {
    let h_analog = h.h_analog;
    let analog_used = params.int("ANALOG", "USED").map(|n| (n as u16) as usize);
    let analog_rate = params.float("ANALOG", "RATE");
    match (analog_used, analog_rate) {
        (Some(u), Some(r)) if r.is_finite() && r > 0.0 => {
            let per = (r / rate_hz).round() as usize;
            let n = u * per;
            if n != h_analog as usize {
                warnings.push(format!(
                    "header says {h_analog} analog values per frame, ANALOG:USED × ANALOG:RATE / POINT:RATE gives {n} (using the parameters)"
                ));
            }
            n
        }
        (Some(0), _) => 0,
        _ => h_analog as usize,
    }
}

/// One label per point: POINT:LABELS, LABELS2..., then `pointN` for the rest.
fn point_labels(params: &Params, points: usize) -> Vec<String> {
    let mut labels: Vec<String> = params
        .get("POINT", "LABELS")
        .map(|p| p.strings())
        .unwrap_or_default();
    for i in 2..100 {
        match params.get("POINT", &format!("LABELS{i}")) {
            Some(p) => labels.extend(p.strings()),
            None => break,
        }
    }
    labels.truncate(points);
    while labels.len() < points {
        labels.push(format!("point{}", labels.len() + 1));
    }
    labels
}

/// POINT:UNITS (`mm` when absent) and metres per unit.
fn point_units(params: &Params, warnings: &mut Vec<String>) -> (String, f64) {
    let units = params
        .string("POINT", "UNITS")
        .filter(|u| !u.is_empty())
        .unwrap_or_else(|| "mm".to_owned());
    let metres_per_unit = match units.to_ascii_lowercase().as_str() {
        "mm" => 1e-3,
        "cm" => 1e-2,
        "dm" => 1e-1,
        "m" => 1.0,
        "in" => 0.0254,
        other => {
            warnings.push(format!("unknown POINT:UNITS {other:?}, assuming mm"));
            1e-3
        }
    };
    (units, metres_per_unit)
}

/// How to turn a stored point into a world position.
struct PointDecoding {
    proc: Processor,
    is_float: bool,
    /// Units per integer step (integer storage).
    int_scale: f64,
    metres_per_unit: f64,
    /// POINT:Y_SCREEN is `+Y` (already Y up).
    y_up: bool,
}

/// The point stored at byte `at`: metres, world frame; NaN when its residual is negative
/// or a coordinate is not finite.
fn read_point(b: &[u8], at: usize, d: &PointDecoding) -> DVec3 {
    let proc = d.proc;
    let (c, residual_ok) = if d.is_float {
        let v = |i: usize| {
            let o = at + 4 * i;
            proc.f32([b[o], b[o + 1], b[o + 2], b[o + 3]]) as f64
        };
        ([v(0), v(1), v(2)], v(3) >= 0.0)
    } else {
        let v = |i: usize| {
            let o = at + 2 * i;
            proc.i16([b[o], b[o + 1]])
        };
        (
            [
                v(0) as f64 * d.int_scale,
                v(1) as f64 * d.int_scale,
                v(2) as f64 * d.int_scale,
            ],
            v(3) >= 0,
        )
    };
    if residual_ok && c.iter().all(|x| x.is_finite()) {
        let p = DVec3::new(c[0], c[1], c[2]) * d.metres_per_unit;
        if d.y_up {
            p
        } else {
            y_up_from_z_up(p)
        }
    } else {
        DVec3::NAN
    }
}

/// The data section: the whole frames the file holds (at most `n_frames`, with a warning
/// when it is cut short), each frame's points read and its analog samples skipped.
fn read_frames(
    b: &[u8],
    data_block: usize,
    points: usize,
    analog_per_frame: usize,
    mut n_frames: usize,
    d: &PointDecoding,
    warnings: &mut Vec<String>,
) -> Vec<Vec<DVec3>> {
    let value_len = if d.is_float { 4 } else { 2 };
    let frame_len = (4 * points + analog_per_frame) * value_len;
    let data_at = (data_block.max(1) - 1) * BLOCK;
    let available = b.len().saturating_sub(data_at);
    let whole = available.checked_div(frame_len).unwrap_or(0);
    if whole < n_frames {
        warnings.push(format!(
            "file holds {whole} of {n_frames} frames (cut short); keeping those"
        ));
        n_frames = whole;
    }
    let mut frames = Vec::with_capacity(n_frames);
    for f in 0..n_frames {
        let base = data_at + f * frame_len;
        let mut row = Vec::with_capacity(points);
        for k in 0..points {
            let at = base + k * 4 * value_len;
            row.push(read_point(b, at, d));
        }
        frames.push(row);
    }
    frames
}

/// Reads a C3D file's 3D points from its bytes.
pub fn read_c3d(b: &[u8]) -> Result<C3d, C3dError> {
    let h = read_header(b)?;
    let proc = h.proc;
    let params = parse_params(b, h.pstart, proc)?;
    let mut warnings = Vec::new();

    let PointFormat {
        points,
        rate_hz,
        scale,
        data_block,
    } = point_format(&params, &h, &mut warnings)?;
    let is_float = scale < 0.0;
    let (first_frame, n_frames) = frame_range(&params, &h, &mut warnings);
    let analog_per_frame = analog_samples_per_frame(&params, &h, rate_hz, &mut warnings);
    let labels = point_labels(&params, points);
    let (units, metres_per_unit) = point_units(&params, &mut warnings);
    let y_up = params
        .string("POINT", "Y_SCREEN")
        .is_some_and(|s| s.trim().eq_ignore_ascii_case("+Y"));

    let decoding = PointDecoding {
        proc,
        is_float,
        int_scale: scale.abs(),
        metres_per_unit,
        y_up,
    };
    let frames = read_frames(
        b,
        data_block,
        points,
        analog_per_frame,
        n_frames,
        &decoding,
        &mut warnings,
    );
    Ok(C3d {
        rate_hz,
        labels,
        first_frame,
        frames,
        units,
        processor: proc,
        warnings,
    })
}

/// Writes frames (metres, world frame, NaN for missing) as a float C3D file in
/// millimetres, Z up, with POINT:LABELS (and LABELS2... past 255 markers), no analog data.
pub fn write_c3d(
    labels: &[String],
    rate_hz: f64,
    frames: &[Vec<DVec3>],
    proc: Processor,
) -> Result<Vec<u8>, C3dError> {
    let points = labels.len();
    if points > u16::MAX as usize || frames.len() > u16::MAX as usize {
        return Err(C3dError::Invalid {
            what: format!(
                "{points} points and {} frames: this writer stores at most 65535 of each",
                frames.len()
            ),
        });
    }
    if frames.iter().any(|f| f.len() != points) {
        return Err(C3dError::Invalid {
            what: "every frame needs one position per label".into(),
        });
    }
    let u16b = |v: u16| proc.put_u16(v);
    // Parameters.
    let mut params = Vec::new();
    let group = |params: &mut Vec<u8>, id: i8, name: &str| {
        params.push(name.len() as u8);
        params.push((-id) as u8);
        params.extend_from_slice(name.as_bytes());
        params.extend_from_slice(&u16b(3));
        params.push(0);
    };
    let param =
        |params: &mut Vec<u8>, id: i8, name: &str, kind: i8, dims: &[usize], data: &[u8]| {
            params.push(name.len() as u8);
            params.push(id as u8);
            params.extend_from_slice(name.as_bytes());
            let len = 2 + 1 + 1 + dims.len() + data.len() + 1;
            params.extend_from_slice(&u16b(len as u16));
            params.push(kind as u8);
            params.push(dims.len() as u8);
            params.extend(dims.iter().map(|d| *d as u8));
            params.extend_from_slice(data);
            params.push(0);
        };
    group(&mut params, 1, "POINT");
    group(&mut params, 2, "ANALOG");
    param(&mut params, 1, "USED", 2, &[], &u16b(points as u16));
    param(&mut params, 1, "FRAMES", 2, &[], &u16b(frames.len() as u16));
    param(&mut params, 1, "SCALE", 4, &[], &proc.put_f32(-1.0));
    param(
        &mut params,
        1,
        "RATE",
        4,
        &[],
        &proc.put_f32(rate_hz as f32),
    );
    param(&mut params, 1, "UNITS", -1, &[2], b"mm");
    param(&mut params, 1, "Y_SCREEN", -1, &[2], b"+Z");
    let width = labels
        .iter()
        .map(|l| l.len())
        .max()
        .unwrap_or(1)
        .clamp(1, 255);
    for (i, chunk) in labels.chunks(255).enumerate() {
        let mut data = Vec::with_capacity(width * chunk.len());
        for l in chunk {
            let mut bytes = l.as_bytes().to_vec();
            bytes.resize(width, b' ');
            data.extend_from_slice(&bytes[..width]);
        }
        let name = if i == 0 {
            "LABELS".to_owned()
        } else {
            format!("LABELS{}", i + 1)
        };
        param(&mut params, 1, &name, -1, &[width, chunk.len()], &data);
    }
    param(&mut params, 2, "USED", 2, &[], &u16b(0));
    param(
        &mut params,
        2,
        "RATE",
        4,
        &[],
        &proc.put_f32(rate_hz as f32),
    );
    // A zero name length ends the section.
    params.extend_from_slice(&[0; 4]);
    let pblocks = (4 + params.len()).div_ceil(BLOCK);
    let data_block = 2 + pblocks;
    let mut out = vec![0u8; BLOCK];
    out[0] = 2;
    out[1] = 0x50;
    let mut put = |i: usize, v: [u8; 2]| out[2 * i..2 * i + 2].copy_from_slice(&v);
    put(1, u16b(points as u16));
    put(2, u16b(0));
    put(3, u16b(1));
    put(4, u16b(frames.len().max(1) as u16));
    put(5, u16b(0));
    put(8, u16b(data_block as u16));
    put(9, u16b(0));
    let s = proc.put_f32(-1.0);
    out[12..16].copy_from_slice(&s);
    let r = proc.put_f32(rate_hz as f32);
    out[20..24].copy_from_slice(&r);
    let mut psec = vec![1u8, 0x50, pblocks as u8, proc.code()];
    psec.extend_from_slice(&params);
    psec.resize(pblocks * BLOCK, 0);
    out.extend_from_slice(&psec);
    for f in frames {
        for p in f {
            let (vals, residual) = if p.is_finite() {
                let c = z_up_from_y_up(*p) * 1e3;
                ([c.x as f32, c.y as f32, c.z as f32], 0.0f32)
            } else {
                ([0.0f32; 3], -1.0f32)
            };
            for v in vals.into_iter().chain([residual]) {
                out.extend_from_slice(&proc.put_f32(v));
            }
        }
    }
    let padded = out.len().div_ceil(BLOCK) * BLOCK;
    out.resize(padded, 0);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn example() -> (Vec<String>, Vec<Vec<DVec3>>) {
        let labels: Vec<String> = (0..300).map(|i| format!("M{i}")).collect();
        let frames = (0..5)
            .map(|f| {
                (0..300)
                    .map(|k| {
                        if (k + f) % 7 == 0 {
                            DVec3::NAN
                        } else {
                            DVec3::new(k as f64 * 0.01, f as f64 * 0.125, -0.5 + k as f64 * 1e-3)
                        }
                    })
                    .collect()
            })
            .collect();
        (labels, frames)
    }

    #[test]
    fn round_trip_on_every_processor_type() {
        let (labels, frames) = example();
        for proc in [Processor::Intel, Processor::Dec, Processor::Mips] {
            let bytes = write_c3d(&labels, 120.0, &frames, proc).unwrap();
            let c = read_c3d(&bytes).unwrap();
            assert_eq!(c.processor, proc);
            assert!(c.warnings.is_empty(), "{:?}", c.warnings);
            assert_eq!(c.labels, labels);
            assert_eq!(c.rate_hz, 120.0);
            assert_eq!(c.frames.len(), 5);
            for (a, b) in c.frames.iter().flatten().zip(frames.iter().flatten()) {
                if b.is_finite() {
                    // f32 millimetres: 1e-7 relative.
                    assert!((*a - *b).length() < 1e-6, "{proc:?}: {a} vs {b}");
                } else {
                    assert!(!a.is_finite());
                }
            }
            // What the reader returns, written again, is the same file byte for byte.
            let again = write_c3d(&c.labels, c.rate_hz, &c.frames, proc).unwrap();
            assert_eq!(again, bytes, "{proc:?}");
        }
    }

    #[test]
    fn a_cut_file_keeps_its_whole_frames_with_a_warning() {
        let (labels, frames) = example();
        let bytes = write_c3d(&labels, 100.0, &frames, Processor::Intel).unwrap();
        let frame_len = 300 * 16;
        let data_at = (u16::from_le_bytes([bytes[16], bytes[17]]) as usize - 1) * BLOCK;
        let c = read_c3d(&bytes[..data_at + 3 * frame_len + frame_len / 2]).unwrap();
        assert_eq!(c.frames.len(), 3);
        assert!(
            c.warnings.iter().any(|w| w.contains("cut short")),
            "{:?}",
            c.warnings
        );
        assert_eq!(c.frames[2][1], read_c3d(&bytes).unwrap().frames[2][1]);
    }

    #[test]
    fn not_c3d_is_a_clear_error() {
        assert!(matches!(
            read_c3d(&[0u8; 100]),
            Err(C3dError::TooShort { len: 100 })
        ));
        let mut b = vec![0u8; 1024];
        b[0] = 2;
        b[1] = 0x51;
        assert!(matches!(
            read_c3d(&b),
            Err(C3dError::BadKey { found: 0x51 })
        ));
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(b in proptest::collection::vec(any::<u8>(), 0..3000)) {
            let _ = read_c3d(&b);
        }

        #[test]
        fn corrupted_files_never_panic(i in 0usize..4096, v in any::<u8>()) {
            let (labels, frames) = example();
            let mut bytes = write_c3d(&labels[..20], 100.0, &frames.iter().map(|f| f[..20].to_vec()).collect::<Vec<_>>(), Processor::Intel).unwrap();
            let n = bytes.len();
            bytes[i % n] = v;
            let _ = read_c3d(&bytes);
        }
    }
}
