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
//!
//! Hostile files: POINT:RATE is held to `recording`'s rate limits, ANALOG:RATE to
//! [`MAX_ANALOG_RATE_HZ`], POINT:USED to [`MAX_POINTS`], POINT:SCALE to a finite non-zero
//! number; the frame layout is computed with checked arithmetic and every frame is read
//! from a slice of the file, so the frames kept are those the file holds (a frame needs
//! at least 8 bytes a point, for 24 bytes of position).

use super::recording::{rate_in_range, MAX_RATE_HZ, MIN_RATE_HZ};
use crate::geom::axes::{y_up_from_z_up, z_up_from_y_up};
use glam::DVec3;

const BLOCK: usize = 512;
/// Processor type codes (parameter preamble byte 4).
const PROC_INTEL: u8 = 84;
const PROC_DEC: u8 = 85;
const PROC_MIPS: u8 = 86;
/// Most points a file may declare (bounds allocation before reading data).
pub const MAX_POINTS: usize = 100_000;
/// Highest ANALOG:RATE a file may declare, Hz (analog boards sample at up to ~100 kHz).
pub const MAX_ANALOG_RATE_HZ: f64 = 1_000_000.0;

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
    /// For each label, the POINT parameter that lists it as a model output rather than a
    /// marker (`ANGLES`, `FORCES`, `MOMENTS`, `POWERS`, `SCALARS`, `REACTIONS`,
    /// `MODELED_MARKERS`, or any group POINT:TYPE_GROUPS names); `None` for the rest.
    pub point_groups: Vec<Option<String>>,
}

/// POINT parameters that list model outputs stored as points (Vicon's Plug-in Gait and
/// Nexus write them; POINT:TYPE_GROUPS may name more).
pub const MODEL_OUTPUT_GROUPS: [&str; 7] = [
    "ANGLES",
    "FORCES",
    "MOMENTS",
    "POWERS",
    "SCALARS",
    "REACTIONS",
    "MODELED_MARKERS",
];

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
    #[error("POINT:USED {points}: at most {MAX_POINTS} points")]
    TooManyPoints { points: usize },
    #[error("{field} {value:?} Hz is outside {MIN_RATE_HZ}..={MAX_RATE_HZ} Hz")]
    Rate { field: &'static str, value: f64 },
    #[error("ANALOG:RATE {value:?} Hz is above {MAX_ANALOG_RATE_HZ} Hz")]
    AnalogRate { value: f64 },
    #[error("{field} {value:?} is not a scale (a finite number other than 0)")]
    Scale { field: &'static str, value: f64 },
    #[error(
        "a frame of {points} points and {analog_per_frame} analog values \
         (ANALOG:USED {analog_used} × ANALOG:RATE {analog_rate:?} Hz / POINT:RATE {rate_hz:?} Hz) \
         is too long to address"
    )]
    FrameLength {
        points: usize,
        analog_per_frame: u64,
        analog_used: usize,
        analog_rate: f64,
        rate_hz: f64,
    },
    /// The writer's refusal (more than it can store, frames of the wrong width).
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

    /// Char data as strings (at most `most` of them): `dims[0]` characters each,
    /// trailing blanks trimmed.
    fn strings(&self, most: usize) -> Vec<String> {
        if self.kind != -1 || most == 0 {
            return Vec::new();
        }
        let w = self.dims.first().copied().unwrap_or(self.data.len()).max(1);
        if self.dims.len() <= 1 {
            return vec![String::from_utf8_lossy(&self.data).trim().to_owned()];
        }
        self.data
            .chunks(w)
            .take(most)
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
            .and_then(|p| p.strings(1).into_iter().next())
    }
}

fn parse_params(b: &[u8], start: usize, proc: Processor) -> Result<Params, C3dError> {
    let err = |offset: usize, what: &'static str| C3dError::Parameters { offset, what };
    // Group names by id (1..=128); the first group of an id names it.
    let mut groups: Vec<Option<String>> = vec![None; 129];
    let mut raw: Vec<(u8, Param)> = Vec::new();
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
            let slot = &mut groups[id.unsigned_abs() as usize];
            if slot.is_none() {
                *slot = Some(name);
            }
        } else {
            raw.push((id.unsigned_abs(), read_param(b, body, name)?));
        }
        if next <= 0 {
            break;
        }
        at = off_at + next as usize;
    }
    let list = raw
        .into_iter()
        .map(|(id, mut p)| {
            p.group = groups[id as usize].clone().unwrap_or_default();
            p
        })
        .collect();
    Ok(Params { list, proc })
}

/// A parameter's type, dimensions and data, from its body at `body` (its group set later).
fn read_param(b: &[u8], body: usize, name: String) -> Result<Param, C3dError> {
    let err = |offset: usize, what: &'static str| C3dError::Parameters { offset, what };
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
    // Up to 255 dimensions of up to 255: the product can overflow.
    let n = dims
        .iter()
        .try_fold(1usize, |acc, d| acc.checked_mul(*d))
        .map(|count| count.max(1))
        .and_then(|count| count.checked_mul(kind.unsigned_abs() as usize))
        .ok_or(err(body + 1, "dimensions overflow"))?;
    let d0 = body + 2 + nd;
    let data = d0
        .checked_add(n)
        .and_then(|end| b.get(d0..end))
        .ok_or(err(d0, "data runs past the end"))?
        .to_vec();
    Ok(Param {
        group: String::new(),
        name,
        kind,
        dims,
        data,
    })
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
        return Err(C3dError::TooManyPoints { points });
    }
    // A missing, zero or non-finite parameter falls back to the header.
    let (field, rate_hz) = match params
        .float("POINT", "RATE")
        .filter(|r| r.is_finite() && *r > 0.0)
    {
        Some(r) => ("POINT:RATE", r),
        None => ("header frame rate", h_rate),
    };
    if !rate_in_range(rate_hz) {
        return Err(C3dError::Rate {
            field,
            value: rate_hz,
        });
    }
    let (field, scale) = match params
        .float("POINT", "SCALE")
        .filter(|s| s.is_finite() && *s != 0.0)
    {
        Some(s) => ("POINT:SCALE", s),
        None => ("header scale", h_scale),
    };
    if !(scale.is_finite() && scale != 0.0) {
        return Err(C3dError::Scale {
            field,
            value: scale,
        });
    }
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
) -> Result<AnalogLayout, C3dError> {
    let h_analog = h.h_analog;
    let analog_used = params.int("ANALOG", "USED").map(|n| (n as u16) as usize);
    let analog_rate = params.float("ANALOG", "RATE");
    let per_frame = match (analog_used, analog_rate) {
        (Some(0), _) => {
            if h_analog != 0 {
                warnings.push(format!(
                    "header says {h_analog} analog values per frame, ANALOG:USED says 0 (using the parameter)"
                ));
            }
            0
        }
        (Some(u), Some(r)) if r.is_finite() && r > 0.0 => {
            if r > MAX_ANALOG_RATE_HZ {
                return Err(C3dError::AnalogRate { value: r });
            }
            // At most 1e6 / MIN_RATE_HZ: the cast is exact.
            let per = (r / rate_hz).round() as u64;
            let n = per * u as u64;
            if n != h_analog as u64 {
                warnings.push(format!(
                    "header says {h_analog} analog values per frame, ANALOG:USED × ANALOG:RATE / POINT:RATE gives {n} (using the parameters)"
                ));
            }
            return Ok(AnalogLayout {
                per_frame: n,
                used: u,
                rate_hz: r,
            });
        }
        _ => h_analog as u64,
    };
    Ok(AnalogLayout {
        per_frame,
        used: analog_used.unwrap_or(0),
        rate_hz: analog_rate.unwrap_or(0.0),
    })
}

/// The analog values stored in each frame, and the parameters they come from.
struct AnalogLayout {
    per_frame: u64,
    used: usize,
    rate_hz: f64,
}

/// One label per point: POINT:LABELS, LABELS2..., then `pointN` for the rest.
fn point_labels(params: &Params, points: usize) -> Vec<String> {
    let mut labels: Vec<String> = params
        .get("POINT", "LABELS")
        .map(|p| p.strings(points))
        .unwrap_or_default();
    for i in 2..100 {
        match params.get("POINT", &format!("LABELS{i}")) {
            Some(p) => labels.extend(p.strings(points.saturating_sub(labels.len()))),
            None => break,
        }
    }
    labels.truncate(points);
    while labels.len() < points {
        labels.push(format!("point{}", labels.len() + 1));
    }
    labels
}

/// For each label, the model-output group that lists it ([`C3d::point_groups`]): the
/// groups of [`MODEL_OUTPUT_GROUPS`] and those POINT:TYPE_GROUPS names (pairs of a
/// parameter and its kind, `ANGLES`, `ANGLE`, ...: every name that is a POINT parameter
/// listing labels counts). A label matches as written or without its `Subject:` prefix.
fn point_type_groups(params: &Params, labels: &[String]) -> Vec<Option<String>> {
    let mut groups: Vec<String> = MODEL_OUTPUT_GROUPS.iter().map(|g| g.to_string()).collect();
    if let Some(p) = params.get("POINT", "TYPE_GROUPS") {
        for g in p.strings(64) {
            let g = g.to_ascii_uppercase();
            if !g.is_empty() && !groups.contains(&g) && !is_point_setting(&g) {
                groups.push(g);
            }
        }
    }
    let bare = |l: &str| l.rsplit(':').next().unwrap_or(l).trim().to_owned();
    let mut out: Vec<Option<String>> = vec![None; labels.len()];
    for g in &groups {
        let Some(p) = params.get("POINT", g) else {
            continue;
        };
        let listed: Vec<String> = p.strings(labels.len()).iter().map(|l| bare(l)).collect();
        for (k, l) in labels.iter().enumerate() {
            if out[k].is_none() && listed.iter().any(|x| !x.is_empty() && *x == bare(l)) {
                out[k] = Some(g.clone());
            }
        }
    }
    out
}

/// POINT parameters that are settings, never lists of labels.
fn is_point_setting(name: &str) -> bool {
    matches!(
        name,
        "USED" | "FRAMES" | "SCALE" | "RATE" | "DATA_START" | "UNITS" | "LABELS" | "DESCRIPTIONS"
    ) || name.starts_with("LABELS")
        || name.ends_with("_UNITS")
        || name.ends_with("_SCREEN")
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
    /// POINT:RATE, for errors.
    rate_hz: f64,
}

/// The point stored in `v` (16 bytes for float storage, 8 for integer): metres, world
/// frame; NaN when its residual is negative or a coordinate is not finite.
fn read_point(v: &[u8], d: &PointDecoding) -> DVec3 {
    let proc = d.proc;
    let (c, residual_ok) = if d.is_float {
        let Some(v) = v.first_chunk::<16>() else {
            return DVec3::NAN;
        };
        let f = |i: usize| proc.f32([v[4 * i], v[4 * i + 1], v[4 * i + 2], v[4 * i + 3]]) as f64;
        ([f(0), f(1), f(2)], f(3) >= 0.0)
    } else {
        let Some(v) = v.first_chunk::<8>() else {
            return DVec3::NAN;
        };
        let i = |k: usize| proc.i16([v[2 * k], v[2 * k + 1]]);
        (
            [
                i(0) as f64 * d.int_scale,
                i(1) as f64 * d.int_scale,
                i(2) as f64 * d.int_scale,
            ],
            i(3) >= 0,
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
    analog: &AnalogLayout,
    mut n_frames: usize,
    d: &PointDecoding,
    warnings: &mut Vec<String>,
) -> Result<Vec<Vec<DVec3>>, C3dError> {
    let value_len: usize = if d.is_float { 4 } else { 2 };
    let point_len = 4 * value_len;
    // Checked: ANALOG:USED × ANALOG:RATE / POINT:RATE reaches 6.6e11 values a frame.
    let frame_len = usize::try_from(analog.per_frame)
        .ok()
        .and_then(|a| a.checked_add(4 * points))
        .and_then(|v| v.checked_mul(value_len))
        .ok_or(C3dError::FrameLength {
            points,
            analog_per_frame: analog.per_frame,
            analog_used: analog.used,
            analog_rate: analog.rate_hz,
            rate_hz: d.rate_hz,
        })?;
    let data_at = (data_block.max(1) - 1) * BLOCK;
    let data = b.get(data_at..).unwrap_or_default();
    let whole = data.len().checked_div(frame_len).unwrap_or(0);
    if whole < n_frames {
        warnings.push(format!(
            "file holds {whole} of {n_frames} frames (cut short); keeping those"
        ));
        n_frames = whole;
    }
    // A frame of `frame_len` bytes holds the points' `points * point_len` bytes first.
    let mut zeros = 0usize;
    let frames = data
        .chunks_exact(frame_len.max(1))
        .take(n_frames)
        .map(|frame| {
            frame
                .chunks_exact(point_len)
                .take(points)
                .map(|v| {
                    let p = read_point(v, d);
                    // Some writers (Qualisys, Motion Analysis, older Vicon) store a gap as
                    // the origin with a residual of zero; a marker never sits on the
                    // origin to the last bit in all three coordinates.
                    if p == DVec3::ZERO {
                        zeros += 1;
                        DVec3::NAN
                    } else {
                        p
                    }
                })
                .collect()
        })
        .collect();
    if zeros > 0 {
        warnings.push(format!(
            "{zeros} samples at exactly (0, 0, 0) read as gaps (a writer's way of storing one)"
        ));
    }
    Ok(frames)
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
    let analog = analog_samples_per_frame(&params, &h, rate_hz, &mut warnings)?;
    let labels = point_labels(&params, points);
    let point_groups = point_type_groups(&params, &labels);
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
        rate_hz,
    };
    let frames = read_frames(
        b,
        data_block,
        points,
        &analog,
        n_frames,
        &decoding,
        &mut warnings,
    )?;
    Ok(C3d {
        rate_hz,
        labels,
        first_frame,
        frames,
        units,
        processor: proc,
        warnings,
        point_groups,
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

    /// A parameter for [`crafted`]: group id, name, type, dimensions, data.
    type RawParam<'a> = (i8, &'a str, i8, &'a [u8], Vec<u8>);

    /// An Intel file built byte by byte: header words 1-4 (points, analog values per
    /// frame, first and last frame), the header scale and rate, groups POINT (1) and
    /// ANALOG (2) with `params`, data from block 3: `frames` frames of one point (x=1, y=2,
    /// z=3 in the storage's units) and no analog values.
    fn crafted(
        words: [u16; 4],
        scale: f32,
        rate_bits: u32,
        params: &[RawParam],
        frames: usize,
    ) -> Vec<u8> {
        let mut h = vec![0u8; BLOCK];
        h[0] = 2;
        h[1] = 0x50;
        for (i, w) in words.iter().enumerate() {
            h[2 + 2 * i..4 + 2 * i].copy_from_slice(&w.to_le_bytes());
        }
        h[12..16].copy_from_slice(&scale.to_le_bytes());
        h[16..18].copy_from_slice(&3u16.to_le_bytes());
        h[20..24].copy_from_slice(&rate_bits.to_le_bytes());
        let mut p = vec![1u8, 0x50, 1, PROC_INTEL];
        for (id, name) in [(1i8, "POINT"), (2, "ANALOG")] {
            p.extend([name.len() as u8, (-id) as u8]);
            p.extend(name.bytes());
            p.extend(3i16.to_le_bytes());
            p.push(0);
        }
        for (id, name, kind, dims, data) in params {
            p.extend([name.len() as u8, *id as u8]);
            p.extend(name.bytes());
            p.extend((5 + dims.len() as i16 + data.len() as i16).to_le_bytes());
            p.extend([*kind as u8, dims.len() as u8]);
            p.extend(*dims);
            p.extend(data);
            p.push(0);
        }
        p.extend([0; 4]);
        p.resize(BLOCK, 0);
        h.extend(p);
        for _ in 0..frames {
            if scale < 0.0 {
                [1.0f32, 2.0, 3.0, 0.0]
                    .iter()
                    .for_each(|v| h.extend(v.to_le_bytes()));
            } else {
                [1i16, 2, 3, 0]
                    .iter()
                    .for_each(|v| h.extend(v.to_le_bytes()));
            }
        }
        h
    }

    fn int(v: i16) -> Vec<u8> {
        v.to_le_bytes().to_vec()
    }

    fn float(v: f32) -> Vec<u8> {
        v.to_le_bytes().to_vec()
    }

    #[test]
    fn a_sane_crafted_file_reads() {
        for scale in [-1.0f32, 0.1] {
            let params = [
                (1, "USED", 2, &[][..], int(1)),
                (1, "SCALE", 4, &[], float(scale)),
                (1, "RATE", 4, &[], float(100.0)),
                (2, "USED", 2, &[], int(2)),
                (2, "RATE", 4, &[], float(100.0)),
            ];
            // Each frame: one point and two analog values, 4 + 2 values of the storage.
            let mut b = crafted([1, 2, 1, 3], scale, 100f32.to_bits(), &params, 0);
            let v = if scale < 0.0 { 4 } else { 2 };
            for f in 0..3 {
                let vals = [1.0 + f as f32, 2.0, 3.0, 0.0, 9.0, 9.0];
                for x in vals {
                    if v == 4 {
                        b.extend(x.to_le_bytes());
                    } else {
                        b.extend((x as i16).to_le_bytes());
                    }
                }
            }
            let c = read_c3d(&b).unwrap();
            assert!(c.warnings.is_empty(), "{:?}", c.warnings);
            assert_eq!(c.frames.len(), 3);
            // Metres per stored unit: millimetres, times the scale in integer storage.
            let mm = if scale < 0.0 { 1e-3 } else { 1e-4 };
            // (x, y, z) Z up becomes (x, z, -y); f32 and the scale: 1e-12 relative.
            let want = DVec3::new(3.0, 3.0, -2.0) * mm;
            // POINT:SCALE is an f32: 0.1 is off by 1.5e-8 relative.
            assert!(
                (c.frames[2][0] - want).length() < 1e-7 * want.length(),
                "{}",
                c.frames[2][0]
            );
        }
    }

    #[test]
    fn a_subnormal_point_rate_is_refused_not_a_panic() {
        // The file: POINT:RATE the smallest subnormal, ANALOG:USED 3, ANALOG:RATE
        // 1. The analog count per frame used to saturate and wrap, leaving a 4-byte frame
        // (2 bytes in integer storage) and reading past the end.
        for scale in [-1.0f32, 0.1] {
            let params = [
                (1, "USED", 2, &[][..], int(1)),
                (1, "SCALE", 4, &[], float(scale)),
                (1, "RATE", 4, &[], 1u32.to_le_bytes().to_vec()),
                (2, "USED", 2, &[], int(3)),
                (2, "RATE", 4, &[], float(1.0)),
            ];
            let b = crafted([1, 0, 1, 40], scale, 1, &params, 10);
            assert_eq!(
                read_c3d(&b).unwrap_err(),
                C3dError::Rate {
                    field: "POINT:RATE",
                    value: f32::from_bits(1) as f64
                }
            );
            // Without the parameter, the header's rate is the one named.
            let b = crafted([1, 0, 1, 40], scale, 1, &params[..2], 10);
            assert_eq!(
                read_c3d(&b).unwrap_err(),
                C3dError::Rate {
                    field: "header frame rate",
                    value: f32::from_bits(1) as f64
                }
            );
        }
    }

    #[test]
    fn header_values_out_of_range_are_named() {
        let base = |extra: Vec<RawParam<'static>>| {
            let mut p: Vec<RawParam> = vec![
                (1, "USED", 2, &[], int(1)),
                (1, "SCALE", 4, &[], float(-1.0)),
                (1, "RATE", 4, &[], float(100.0)),
            ];
            p.extend(extra);
            read_c3d(&crafted([1, 0, 1, 10], -1.0, 100f32.to_bits(), &p, 10))
        };
        assert_eq!(base(vec![]).unwrap().frames.len(), 10);
        // A huge ANALOG:RATE used to saturate the same way as a tiny POINT:RATE.
        assert_eq!(
            base(vec![
                (2, "USED", 2, &[], int(3)),
                (2, "RATE", 4, &[], float(3e38))
            ])
            .unwrap_err(),
            C3dError::AnalogRate {
                value: 3e38f32 as f64
            }
        );
        // A large one still in range makes frames longer than the file: none kept.
        let c = base(vec![
            (2, "USED", 2, &[], int(-1)),
            (2, "RATE", 4, &[], float(1e6)),
        ])
        .unwrap();
        assert!(c.frames.is_empty());
        assert!(
            c.warnings.iter().any(|w| w.contains("gives 655350000")),
            "{:?}",
            c.warnings
        );
        for rate in [1e9f32, 0.05, f32::MAX] {
            let p = [
                (1, "USED", 2, &[][..], int(1)),
                (1, "RATE", 4, &[], float(rate)),
            ];
            assert_eq!(
                read_c3d(&crafted([1, 0, 1, 10], -1.0, 100f32.to_bits(), &p, 10)).unwrap_err(),
                C3dError::Rate {
                    field: "POINT:RATE",
                    value: rate as f64
                }
            );
        }
        // A zero POINT:SCALE falls back to the header's, which must be usable.
        let p = vec![
            (1, "USED", 2, &[][..], int(1)),
            (1, "SCALE", 4, &[], float(0.0)),
            (1, "RATE", 4, &[], float(100.0)),
        ];
        assert_eq!(
            read_c3d(&crafted([1, 0, 1, 10], f32::NAN, 100f32.to_bits(), &p, 10))
                .unwrap_err()
                .to_string(),
            "header scale NaN is not a scale (a finite number other than 0)"
        );
    }

    #[test]
    fn parameter_dimensions_that_overflow_are_an_error() {
        // 200 dimensions of 255: 255^200 elements.
        let dims = [255u8; 200];
        let p = [(1, "LABELS", -1, &dims[..], vec![b'a'; 10])];
        let b = crafted([1, 0, 1, 10], -1.0, 100f32.to_bits(), &p, 10);
        assert!(matches!(
            read_c3d(&b),
            Err(C3dError::Parameters {
                what: "dimensions overflow",
                ..
            })
        ));
    }

    #[test]
    fn parameters_are_read_in_linear_time() {
        // Group id -128 (its negation overflows an i8), then 100,000 groups of id 1 and
        // 100,000 parameters of group 2, which none names: looking each parameter's group
        // up among every group took 1e10 steps.
        let mut b = crafted([1, 0, 1, 1], -1.0, 100f32.to_bits(), &[], 0);
        b.truncate(BLOCK + 4);
        b.extend([1u8, 0x80, b'X']);
        b.extend(3i16.to_le_bytes());
        b.push(0);
        for _ in 0..100_000 {
            b.extend([1u8, 0xFF, b'G']);
            b.extend(3i16.to_le_bytes());
            b.push(0);
        }
        for _ in 0..100_000 {
            b.extend([1u8, 2, b'P']);
            b.extend(6i16.to_le_bytes());
            b.extend([1u8, 0, 7, 0]);
        }
        b.extend([0; 4]);
        let t = std::time::Instant::now();
        let c = read_c3d(&b).unwrap();
        assert_eq!((c.labels.len(), c.rate_hz), (1, 100.0));
        // Linear, this takes milliseconds; the bound leaves room for a loaded machine.
        assert!(t.elapsed().as_secs_f64() < 5.0, "{:?}", t.elapsed());
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
