//! Session files (`.rlsession`, `protocols/session.md`): every marker sample the daemon
//! received, from every input, with its source and receive times; append-only, framed and
//! checksummed, so a file cut anywhere (a `kill -9`, a full disk) still reads up to its
//! last whole record, and a damaged record costs only itself: the reader scans forward to
//! the next record that frames and checksums correctly and warns of the bytes it skipped.
//!
//! Hostile files: the header's rate, marker names and inputs are range-checked
//! ([`MAX_MARKERS`], [`MAX_INPUTS`], the rates of `recording`), the scan for the next
//! record checksums at most [`RESYNC_CHECKSUM_BYTES_PER_BYTE`] bytes per byte of the
//! file, and at most [`MAX_WARNINGS`] warnings are kept.
//!
//! The codec is pure (bytes in, records out); [`SessionWriter`] adds the file and the
//! bounded flush interval, driven by times passed in.

use super::recording::{rate_in_range, MAX_RATE_HZ, MIN_RATE_HZ};
use crate::markers::MarkerSample;
use glam::DVec3;
use serde::de::{Deserializer, IgnoredAny, SeqAccess, Visitor};
use std::io::Write;

/// The 16 bytes a session file starts with.
pub const MAGIC: [u8; 16] = *b"RIGLESS-SESSION\0";
/// The format version this build writes and reads.
pub const VERSION: u32 = 1;
/// Longest record payload a reader accepts, bytes.
pub const MAX_RECORD_LEN: u32 = 16 << 20;
/// Bytes per sample in a samples record.
pub const SAMPLE_LEN: usize = 4 + 8 + 8 + 3 * 4 + 1;
/// Most marker names a session header may list (a character's markers: the body has 36).
pub const MAX_MARKERS: usize = 10_000;
/// Most input names a session header may list (a stage config's inputs).
pub const MAX_INPUTS: usize = 1024;
/// Most warnings a read keeps; one more counts those left out.
pub const MAX_WARNINGS: usize = 64;
/// Bytes the reader may checksum, per byte of the file (plus 1 MiB), while it looks for
/// the next whole record after a damaged one. Real damage costs about the next record's
/// length; this keeps a file crafted full of near-records linear.
pub const RESYNC_CHECKSUM_BYTES_PER_BYTE: usize = 4;
/// Bytes of framing around a payload: `u32 len`, `u8 kind`, `u32 crc`.
const FRAMING: usize = 4 + 1 + 4;

const KIND_HEADER: u8 = 1;
const KIND_SAMPLES: u8 = 2;

/// What a session file says about itself (record kind 1, JSON).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SessionHeader {
    /// The character's marker names (sample `marker` indexes this).
    pub marker_names: Vec<String>,
    /// The solver's rate when recorded, Hz (replay groups samples into frames at it).
    pub rate_hz: f64,
    /// When recording started, seconds since the Unix epoch.
    pub started_unix_s: f64,
    /// The inputs, as the stage config named them.
    pub inputs: Vec<String>,
}

/// CRC-32 (IEEE 802.3, reflected, as zlib's `crc32`).
pub fn crc32(data: &[u8]) -> u32 {
    const fn table() -> [u32; 256] {
        let mut t = [0u32; 256];
        let mut i = 0;
        while i < 256 {
            let mut c = i as u32;
            let mut k = 0;
            while k < 8 {
                c = if c & 1 != 0 {
                    0xEDB8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
                k += 1;
            }
            t[i] = c;
            i += 1;
        }
        t
    }
    const TABLE: [u32; 256] = table();
    let mut c = !0u32;
    for &b in data {
        c = TABLE[((c ^ b as u32) & 0xff) as usize] ^ (c >> 8);
    }
    !c
}

/// Appends one framed record: `u32 len`, `u8 kind`, payload, `u32 crc32(kind, payload)`.
fn put_record(out: &mut Vec<u8>, kind: u8, payload: &[u8]) {
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    let start = out.len();
    out.push(kind);
    out.extend_from_slice(payload);
    let crc = crc32(&out[start..]);
    out.extend_from_slice(&crc.to_le_bytes());
}

/// The file preamble and header record.
pub fn encode_start(h: &SessionHeader, out: &mut Vec<u8>) {
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    let json = serde_json::to_vec(h).expect("a header always serializes");
    put_record(out, KIND_HEADER, &json);
}

/// One samples record: `u32 count`, then per sample `u32 marker`, `f64 time_s` (receive,
/// daemon clock), `f64 source_time_s`, `f32 x y z` (metres, world frame), `u8 flags`
/// (bit 0 occluded).
pub fn encode_samples(samples: &[MarkerSample], out: &mut Vec<u8>) {
    let mut p = Vec::with_capacity(4 + samples.len() * SAMPLE_LEN);
    p.extend_from_slice(&(samples.len() as u32).to_le_bytes());
    for s in samples {
        p.extend_from_slice(&s.marker.to_le_bytes());
        p.extend_from_slice(&s.time_s.to_le_bytes());
        p.extend_from_slice(&s.source_time_s.to_le_bytes());
        for c in s.position_m.as_vec3().to_array() {
            p.extend_from_slice(&c.to_le_bytes());
        }
        p.push(s.occluded as u8);
    }
    put_record(out, KIND_SAMPLES, &p);
}

/// A session read back.
#[derive(Clone, Debug)]
pub struct Session {
    pub header: SessionHeader,
    pub samples: Vec<MarkerSample>,
    /// What was tolerated (a cut or damaged tail).
    pub warnings: Vec<String>,
}

/// Why bytes are not a session.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SessionError {
    #[error("not a rigless session file (bad magic)")]
    BadMagic,
    #[error("session format version {found} (this build reads {VERSION})")]
    Version { found: u32 },
    #[error("the header record is missing or damaged")]
    NoHeader,
    #[error("header record: {what}")]
    Header { what: String },
    #[error("header record: rate_hz {rate_hz:?} is outside {MIN_RATE_HZ}..={MAX_RATE_HZ} Hz")]
    Rate { rate_hz: f64 },
    #[error("header record: {count} marker_names (at most {MAX_MARKERS})")]
    Markers { count: usize },
    #[error("header record: {count} inputs (at most {MAX_INPUTS})")]
    Inputs { count: usize },
}

/// Names read from a header (at most `MAX` of them kept) and how many it lists: the
/// header is refused past `MAX` without storing the rest.
struct Counted<const MAX: usize> {
    names: Vec<String>,
    count: usize,
}

impl<'de, const MAX: usize> serde::Deserialize<'de> for Counted<MAX> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V<const MAX: usize>;
        impl<'de, const MAX: usize> Visitor<'de> for V<MAX> {
            type Value = Counted<MAX>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a list of strings")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut names = Vec::new();
                let mut count = 0usize;
                while count < MAX {
                    match seq.next_element::<String>()? {
                        Some(n) => names.push(n),
                        None => return Ok(Counted { names, count }),
                    }
                    count += 1;
                }
                while seq.next_element::<IgnoredAny>()?.is_some() {
                    count = count.saturating_add(1);
                }
                Ok(Counted { names, count })
            }
        }
        d.deserialize_seq(V::<MAX>)
    }
}

/// The header record as read, before its counts and rate are checked.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct RawHeader {
    marker_names: Counted<MAX_MARKERS>,
    rate_hz: f64,
    started_unix_s: f64,
    inputs: Counted<MAX_INPUTS>,
}

/// Parses and checks the header record's payload.
fn parse_header(payload: &[u8]) -> Result<SessionHeader, SessionError> {
    let h: RawHeader = serde_json::from_slice(payload).map_err(|e| SessionError::Header {
        what: e.to_string(),
    })?;
    if h.marker_names.count > MAX_MARKERS {
        return Err(SessionError::Markers {
            count: h.marker_names.count,
        });
    }
    if h.inputs.count > MAX_INPUTS {
        return Err(SessionError::Inputs {
            count: h.inputs.count,
        });
    }
    if !rate_in_range(h.rate_hz) {
        return Err(SessionError::Rate { rate_hz: h.rate_hz });
    }
    Ok(SessionHeader {
        marker_names: h.marker_names.names,
        rate_hz: h.rate_hz,
        started_unix_s: h.started_unix_s,
        inputs: h.inputs.names,
    })
}

/// A whole record: its kind, its payload and the offset just past it.
struct Record<'a> {
    kind: u8,
    payload: &'a [u8],
    end: usize,
}

/// Why the bytes at an offset are not a whole record.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Broken {
    /// Fewer than 4 bytes left.
    LengthCut,
    /// The length field is over [`MAX_RECORD_LEN`].
    TooLong {
        len: u32,
    },
    /// The record runs past the end of the file.
    Cut,
    Checksum,
}

impl Broken {
    /// What happened at byte `at`, for a warning.
    fn describe(self, at: usize) -> String {
        match self {
            Broken::LengthCut => format!("file ends inside a record length at byte {at}"),
            Broken::TooLong { len } => {
                format!("record at byte {at} claims {len} bytes (at most {MAX_RECORD_LEN})")
            }
            Broken::Cut => format!("file ends inside the record at byte {at}"),
            Broken::Checksum => format!("record at byte {at} fails its checksum"),
        }
    }
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    let c = b.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
}

/// Where the record at `at` ends, if its length is acceptable and it fits in the file.
fn frame_end(b: &[u8], at: usize) -> Result<usize, Broken> {
    let len = u32_at(b, at).ok_or(Broken::LengthCut)?;
    if len > MAX_RECORD_LEN {
        return Err(Broken::TooLong { len });
    }
    // `len` is at most 16 MiB, and `at` lies within the file: no overflow.
    let end = at + FRAMING + len as usize;
    if end > b.len() {
        return Err(Broken::Cut);
    }
    Ok(end)
}

/// The record at `at`, framed and checksummed.
fn record_at(b: &[u8], at: usize) -> Result<Record<'_>, Broken> {
    let end = frame_end(b, at)?;
    let body = &b[at + 4..end - 4];
    if u32_at(b, end - 4) != Some(crc32(body)) {
        return Err(Broken::Checksum);
    }
    Ok(Record {
        kind: body[0],
        payload: &body[1..],
        end,
    })
}

/// Whether the bytes at `at` could be a record of a known kind, short of its checksum: a
/// header's payload opens with `{`; a samples record's count matches its length.
fn plausible(b: &[u8], at: usize) -> Option<usize> {
    let end = frame_end(b, at).ok()?;
    let payload = &b[at + 5..end - 4];
    let fits = match b[at + 4] {
        KIND_HEADER => payload.first() == Some(&b'{'),
        KIND_SAMPLES => u32_at(payload, 0).is_some_and(|n| {
            (n as usize)
                .checked_mul(SAMPLE_LEN)
                .and_then(|x| x.checked_add(4))
                == Some(payload.len())
        }),
        _ => false,
    };
    fits.then_some(end)
}

/// How a scan for the next whole record ended.
enum Resync {
    Found(usize),
    NotFound,
    /// The checksum budget ran out at this offset.
    GaveUp(usize),
}

/// The offset of the next whole record of a known kind at or after `from`, checksumming
/// at most `budget` bytes (what is used is taken off it).
fn resync(b: &[u8], from: usize, budget: &mut usize) -> Resync {
    for at in from..b.len() {
        let Some(end) = plausible(b, at) else {
            continue;
        };
        let cost = end - at - 8;
        if cost > *budget {
            return Resync::GaveUp(at);
        }
        *budget -= cost;
        if record_at(b, at).is_ok() {
            return Resync::Found(at);
        }
    }
    Resync::NotFound
}

/// Warnings, at most [`MAX_WARNINGS`] of them, then a count of the rest.
#[derive(Default)]
struct Warnings {
    kept: Vec<String>,
    left_out: usize,
}

impl Warnings {
    fn push(&mut self, w: impl FnOnce() -> String) {
        if self.kept.len() < MAX_WARNINGS {
            self.kept.push(w());
        } else {
            self.left_out += 1;
        }
    }

    fn finish(mut self) -> Vec<String> {
        if self.left_out > 0 {
            self.kept
                .push(format!("{} more warnings left out", self.left_out));
        }
        self.kept
    }
}

/// Appends a samples record's samples; `false` when its count does not match its length.
fn read_samples(payload: &[u8], samples: &mut Vec<MarkerSample>) -> bool {
    let n = u32_at(payload, 0).map_or(0, |n| n as usize);
    if n.checked_mul(SAMPLE_LEN).and_then(|x| x.checked_add(4)) != Some(payload.len()) {
        return false;
    }
    samples.reserve(n);
    for c in payload[4..].chunks_exact(SAMPLE_LEN) {
        let f64_at = |i: usize| f64::from_le_bytes(std::array::from_fn(|k| c[i + k]));
        let f32_at = |i: usize| f32::from_le_bytes(std::array::from_fn(|k| c[i + k])) as f64;
        samples.push(MarkerSample {
            marker: u32::from_le_bytes([c[0], c[1], c[2], c[3]]),
            time_s: f64_at(4),
            source_time_s: f64_at(12),
            position_m: DVec3::new(f32_at(20), f32_at(24), f32_at(28)),
            occluded: c[32] & 1 != 0,
        });
    }
    true
}

/// Reads a session. A damaged record is skipped: the reader scans forward to the next
/// record that frames and checksums correctly, with a warning naming the offset and the
/// bytes skipped; a file cut short keeps every whole record before the cut.
pub fn read_session(b: &[u8]) -> Result<Session, SessionError> {
    if b.len() < 20 || b[..16] != MAGIC {
        return Err(SessionError::BadMagic);
    }
    let version = u32_at(b, 16).unwrap_or(0);
    if version != VERSION {
        return Err(SessionError::Version { found: version });
    }
    let mut budget = b
        .len()
        .saturating_mul(RESYNC_CHECKSUM_BYTES_PER_BYTE)
        .saturating_add(1 << 20);
    let mut at = 20;
    let mut header = None;
    let mut samples = Vec::new();
    let mut warnings = Warnings::default();
    while at < b.len() {
        let rec = match record_at(b, at) {
            Ok(rec) => rec,
            Err(broken) => match resync(b, at + 1, &mut budget) {
                Resync::Found(next) => {
                    warnings.push(|| {
                        format!(
                            "{}; skipped {} bytes to the next whole record at byte {next}",
                            broken.describe(at),
                            next - at
                        )
                    });
                    at = next;
                    continue;
                }
                Resync::NotFound => {
                    warnings.push(|| {
                        format!(
                            "{}; no whole record after it, kept what came before",
                            broken.describe(at)
                        )
                    });
                    break;
                }
                Resync::GaveUp(stop) => {
                    warnings.push(|| {
                        format!(
                            "{}; gave up looking for the next whole record at byte {stop} (checksum budget spent), kept what came before",
                            broken.describe(at)
                        )
                    });
                    break;
                }
            },
        };
        match rec.kind {
            KIND_HEADER => header = Some(parse_header(rec.payload)?),
            KIND_SAMPLES => {
                if !read_samples(rec.payload, &mut samples) {
                    warnings.push(|| {
                        format!("samples record at byte {at} has the wrong length; skipped")
                    });
                }
            }
            other => warnings.push(|| format!("unknown record kind {other} at byte {at}; skipped")),
        }
        at = rec.end;
    }
    let header = header.ok_or(SessionError::NoHeader)?;
    Ok(Session {
        header,
        samples,
        warnings: warnings.finish(),
    })
}

/// Writes a session file: samples are buffered and written out at most
/// `flush_interval_s` apart (by the times passed in), so a killed process loses at most
/// that much.
pub struct SessionWriter<W: Write> {
    out: W,
    pending: Vec<MarkerSample>,
    buf: Vec<u8>,
    flush_interval_s: f64,
    last_flush_s: f64,
    /// Samples written to the file so far.
    pub written: u64,
}

impl<W: Write> SessionWriter<W> {
    /// Starts a session (writes the preamble and header at once).
    pub fn new(
        mut out: W,
        header: &SessionHeader,
        flush_interval_s: f64,
        now_s: f64,
    ) -> std::io::Result<Self> {
        let mut buf = Vec::new();
        encode_start(header, &mut buf);
        out.write_all(&buf)?;
        out.flush()?;
        Ok(Self {
            out,
            pending: Vec::new(),
            buf,
            flush_interval_s,
            last_flush_s: now_s,
            written: 0,
        })
    }

    /// Queues samples; writes everything queued once the flush interval has passed.
    pub fn push(&mut self, samples: &[MarkerSample], now_s: f64) -> std::io::Result<()> {
        self.pending.extend_from_slice(samples);
        if now_s - self.last_flush_s >= self.flush_interval_s {
            self.flush(now_s)?;
        }
        Ok(())
    }

    /// Writes everything queued as one record and flushes it to the OS.
    pub fn flush(&mut self, now_s: f64) -> std::io::Result<()> {
        self.last_flush_s = now_s;
        if self.pending.is_empty() {
            return Ok(());
        }
        self.buf.clear();
        encode_samples(&self.pending, &mut self.buf);
        self.out.write_all(&self.buf)?;
        self.out.flush()?;
        self.written += self.pending.len() as u64;
        self.pending.clear();
        Ok(())
    }

    /// Writes what is queued and returns the sink.
    pub fn finish(mut self, now_s: f64) -> std::io::Result<W> {
        self.flush(now_s)?;
        Ok(self.out)
    }
}

/// What a recorder did.
#[derive(Debug)]
pub struct RecorderOutcome {
    /// Samples written to the file.
    pub written: u64,
    /// The write that failed (a full disk, say), when one did, and the samples that
    /// arrived after it and were not written.
    pub failed: Option<(std::io::Error, u64)>,
}

/// Writes the samples that arrive on `rx` to `w` until the channel closes, then finishes
/// the file. A write that fails is said once (naming `shown`, the file) and stops the
/// writing; the samples that arrive after it are counted and let go, so the loop
/// feeding `rx` goes on as before.
pub fn run_recorder<W: Write>(
    mut w: SessionWriter<W>,
    rx: &crossbeam_channel::Receiver<MarkerSample>,
    now_s: &dyn Fn() -> f64,
    shown: &str,
) -> RecorderOutcome {
    let tick = std::time::Duration::from_secs_f64((w.flush_interval_s / 4.0).clamp(0.001, 0.25));
    let mut batch = Vec::with_capacity(4096);
    let mut failed: Option<(std::io::Error, u64)> = None;
    loop {
        match rx.recv_timeout(tick) {
            Ok(s) => {
                batch.push(s);
                batch.extend(rx.try_iter().take(4095));
            }
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => {}
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
        }
        match &mut failed {
            Some((_, lost)) => *lost += batch.len() as u64,
            None => {
                if let Err(e) = w.push(&batch, now_s()) {
                    tracing::error!(
                        "recording to {shown} stopped after {} samples: {e}; the stage goes on without it",
                        w.written
                    );
                    // What was pending when the write failed (this batch with it) is
                    // lost with the rest.
                    failed = Some((e, w.pending.len() as u64));
                    w.pending.clear();
                }
            }
        }
        batch.clear();
    }
    if failed.is_none() {
        let pending = w.pending.len() as u64;
        if let Err(e) = w.flush(now_s()) {
            tracing::error!("recording to {shown}: its last {pending} samples not written: {e}");
            failed = Some((e, pending));
        }
    }
    RecorderOutcome {
        written: w.written,
        failed,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::sync::Arc;

    fn header() -> SessionHeader {
        SessionHeader {
            marker_names: vec!["a".into(), "b".into()],
            rate_hz: 120.0,
            started_unix_s: 1.7e9,
            inputs: vec!["replay:hand_finger_play".into()],
        }
    }

    fn samples(n: usize) -> Vec<MarkerSample> {
        (0..n)
            .map(|i| MarkerSample {
                marker: (i % 2) as u32,
                time_s: i as f64 * 0.01,
                source_time_s: 100.0 + i as f64 * 0.01,
                position_m: DVec3::new(i as f64 * 0.5, -0.25, 1.0),
                occluded: i % 5 == 0,
            })
            .collect()
    }

    /// A file on a disk with room for `room` bytes: a write past it fails as a full
    /// disk does (ENOSPC); `used` tells how many it took.
    struct Disk {
        room: usize,
        used: Arc<std::sync::atomic::AtomicUsize>,
    }

    impl Write for Disk {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            let used = self.used.load(std::sync::atomic::Ordering::SeqCst);
            if used + buf.len() > self.room {
                return Err(std::io::Error::from_raw_os_error(28));
            }
            self.used
                .fetch_add(buf.len(), std::sync::atomic::Ordering::SeqCst);
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    /// The disk fills part way: the failure is kept with the samples it cost, the
    /// samples that arrive after it are taken off the channel and counted (the loop
    /// feeding it never sees it closed or full), and the recorder returns when the
    /// channel closes; before, it returned the error at once and the stage printed no
    /// summary.
    #[test]
    fn a_full_disk_stops_the_recording_and_nothing_else() {
        let used = Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let mut header_bytes = Vec::new();
        encode_start(&header(), &mut header_bytes);
        let mut record = Vec::new();
        encode_samples(&samples(10), &mut record);
        let disk = Disk {
            // The header and one record of ten samples.
            room: header_bytes.len() + record.len(),
            used: Arc::clone(&used),
        };
        let w = SessionWriter::new(disk, &header(), 0.0, 0.0).unwrap();
        let (tx, rx) = crossbeam_channel::bounded(64);
        let recorder = std::thread::spawn(move || run_recorder(w, &rx, &|| 1.0, "full.rig"));
        for s in samples(10) {
            tx.send(s).unwrap();
        }
        let start = std::time::Instant::now();
        while used.load(std::sync::atomic::Ordering::SeqCst) < header_bytes.len() + record.len() {
            assert!(
                start.elapsed().as_secs() < 20,
                "the first record was not written"
            );
            std::thread::yield_now();
        }
        // Twice the channel's room: it is drained after the failure.
        for s in samples(128) {
            tx.send_timeout(s, std::time::Duration::from_secs(20))
                .expect("the channel is drained");
        }
        drop(tx);
        let out = recorder.join().unwrap();
        assert_eq!(out.written, 10);
        let (e, lost) = out.failed.expect("the disk filled");
        assert_eq!(e.raw_os_error(), Some(28));
        assert_eq!(lost, 128);
    }

    fn file(n_records: usize) -> Vec<u8> {
        let mut w = SessionWriter::new(Vec::new(), &header(), 0.0, 0.0).unwrap();
        for r in 0..n_records {
            w.push(&samples(3), r as f64).unwrap();
        }
        w.finish(99.0).unwrap()
    }

    #[test]
    fn samples_record_matches_the_documented_example() {
        // protocols/session.md, "Worked example" (CRC computed there with zlib).
        const HEX: &str = "25 00 00 00 02 01 00 00 00 01 00 00 00 00 00 00
            00 00 00 04 40 00 00 00 00 00 10 59 40 00 00 00
            3f 00 00 80 3f 00 00 80 be 00 35 47 4d 04";
        let expected: Vec<u8> = HEX
            .split_whitespace()
            .map(|h| u8::from_str_radix(h, 16).unwrap())
            .collect();
        let mut b = Vec::new();
        encode_samples(
            &[MarkerSample {
                marker: 1,
                time_s: 2.5,
                source_time_s: 100.25,
                position_m: DVec3::new(0.5, 1.0, -0.25),
                occluded: false,
            }],
            &mut b,
        );
        assert_eq!(b, expected);
        let mut start = Vec::new();
        encode_start(
            &SessionHeader {
                marker_names: vec!["a".into(), "b".into()],
                rate_hz: 120.0,
                started_unix_s: 1.7e9,
                inputs: vec!["replay:hand_finger_play".into()],
            },
            &mut start,
        );
        assert_eq!(start.len(), 138);
    }

    #[test]
    fn crc32_matches_zlib() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn samples_round_trip() {
        let s = read_session(&file(4)).unwrap();
        assert_eq!(s.header, header());
        assert!(s.warnings.is_empty());
        assert_eq!(s.samples.len(), 12);
        assert_eq!(&s.samples[..3], &samples(3)[..]);
    }

    #[test]
    fn flushes_only_at_the_interval() {
        let mut w = SessionWriter::new(Vec::new(), &header(), 0.5, 0.0).unwrap();
        w.push(&samples(2), 0.2).unwrap();
        assert_eq!(w.written, 0);
        w.push(&samples(2), 0.5).unwrap();
        assert_eq!(w.written, 4);
    }

    /// Bytes before the first samples record: magic, version and the header record.
    fn start_len() -> usize {
        let mut v = Vec::new();
        encode_start(&header(), &mut v);
        v.len()
    }

    #[test]
    fn a_file_cut_anywhere_keeps_its_whole_records() {
        let b = file(5);
        let start_len = start_len();
        let record_len = (b.len() - start_len) / 5;
        for cut in start_len..b.len() {
            let s = read_session(&b[..cut]).unwrap();
            let whole = (cut - start_len) / record_len;
            assert_eq!(s.samples.len(), 3 * whole, "cut at {cut}");
            assert_eq!(
                s.warnings.is_empty(),
                (cut - start_len).is_multiple_of(record_len)
            );
        }
    }

    #[test]
    fn a_damaged_record_costs_only_itself() {
        let b = file(5);
        let start_len = start_len();
        let record_len = (b.len() - start_len) / 5;
        let third = start_len + 2 * record_len;
        // A flipped byte in record 3's payload, then in its length field (which makes it
        // claim more than the file, or more than 16 MiB): records 1, 2, 4 and 5 stay.
        for (offset, flip) in [(10, 0x40), (0, 0x01), (2, 0x10), (3, 0x80)] {
            let mut d = b.clone();
            d[third + offset] ^= flip;
            let s = read_session(&d).unwrap();
            assert_eq!(s.samples.len(), 12, "byte {offset}");
            assert_eq!(&s.samples[6..9], &samples(3)[..]);
            assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
            let w = &s.warnings[0];
            assert!(w.contains(&format!("at byte {third}")), "{w}");
            assert!(w.contains(&format!("skipped {record_len} bytes")), "{w}");
            assert!(
                w.contains(&format!("record at byte {}", third + record_len)),
                "{w}"
            );
        }
        // Garbage between two records is skipped the same way.
        let mut d = b[..third].to_vec();
        d.extend_from_slice(&[0xAB; 100]);
        d.extend_from_slice(&b[third..]);
        let s = read_session(&d).unwrap();
        assert_eq!(s.samples.len(), 15);
        assert!(
            s.warnings[0].contains("skipped 100 bytes"),
            "{:?}",
            s.warnings
        );
    }

    #[test]
    fn the_scan_for_the_next_record_is_bounded() {
        // After a damaged record, a run of near-records: each 9-byte group claims a
        // samples record of 29,000 samples running to the end of the file, so that every
        // one of them is worth checksumming. The scan stops within its budget.
        let mut b = file(1);
        let n: u32 = 29_000;
        let len = 4 + n * SAMPLE_LEN as u32;
        b.extend_from_slice(&[0xFF; 8]);
        while b.len() < 2 * len as usize {
            b.extend_from_slice(&len.to_le_bytes());
            b.push(KIND_SAMPLES);
            b.extend_from_slice(&n.to_le_bytes());
        }
        let s = read_session(&b).unwrap();
        assert_eq!(s.samples.len(), 3);
        assert!(s.warnings[0].contains("gave up"), "{:?}", s.warnings);
    }

    #[test]
    fn warnings_are_bounded() {
        let mut b = file(1);
        for _ in 0..1000 {
            put_record(&mut b, 7, b"x");
        }
        let s = read_session(&b).unwrap();
        assert_eq!(s.warnings.len(), MAX_WARNINGS + 1);
        assert_eq!(
            s.warnings[MAX_WARNINGS],
            format!("{} more warnings left out", 1000 - MAX_WARNINGS)
        );
    }

    fn with_header_json(json: &str) -> Result<Session, SessionError> {
        let mut b = MAGIC.to_vec();
        b.extend_from_slice(&VERSION.to_le_bytes());
        put_record(&mut b, KIND_HEADER, json.as_bytes());
        read_session(&b)
    }

    #[test]
    fn header_values_out_of_range_are_named() {
        let json = |names: &str, rate: &str, inputs: &str| {
            format!(
                r#"{{"marker_names":[{names}],"rate_hz":{rate},"started_unix_s":0,"inputs":[{inputs}]}}"#
            )
        };
        for (rate, value) in [
            ("0", 0.0),
            ("-100", -100.0),
            ("1e9", 1e9),
            ("5e-324", 5e-324),
        ] {
            assert_eq!(
                with_header_json(&json(r#""a""#, rate, "")).unwrap_err(),
                SessionError::Rate { rate_hz: value }
            );
        }
        let many = vec![r#""m""#; MAX_MARKERS + 5].join(",");
        assert_eq!(
            with_header_json(&json(&many, "120", "")).unwrap_err(),
            SessionError::Markers {
                count: MAX_MARKERS + 5
            }
        );
        let many = vec![r#""i""#; MAX_INPUTS + 1].join(",");
        assert_eq!(
            with_header_json(&json(r#""a""#, "120", &many)).unwrap_err(),
            SessionError::Inputs {
                count: MAX_INPUTS + 1
            }
        );
        // At the limits: read.
        let names = vec![r#""m""#; MAX_MARKERS].join(",");
        let h = with_header_json(&json(&names, "100000", ""))
            .unwrap()
            .header;
        assert_eq!((h.marker_names.len(), h.rate_hz), (MAX_MARKERS, 100_000.0));
        assert!(matches!(
            with_header_json(&json(r#""a""#, "120", "").replace("inputs", "inputz")),
            Err(SessionError::Header { .. })
        ));
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(b in proptest::collection::vec(any::<u8>(), 0..600)) {
            let _ = read_session(&b);
        }

        #[test]
        fn arbitrary_tails_never_panic(tail in proptest::collection::vec(any::<u8>(), 0..300)) {
            let mut b = file(1);
            b.extend_from_slice(&tail);
            let s = read_session(&b).unwrap();
            prop_assert!(s.samples.len() >= 3);
        }
    }
}
