//! Session files (`.rlsession`, `protocols/session.md`): every marker sample the daemon
//! received, from every input, with its source and receive times; append-only, framed and
//! checksummed, so a file cut anywhere (a `kill -9`, a full disk) still reads up to its
//! last whole record.
//!
//! The codec is pure (bytes in, records out); [`SessionWriter`] adds the file and the
//! bounded flush interval, driven by times passed in.

use crate::markers::MarkerSample;
use glam::DVec3;
use std::io::Write;

/// The 16 bytes a session file starts with.
pub const MAGIC: [u8; 16] = *b"RIGLESS-SESSION\0";
/// The format version this build writes and reads.
pub const VERSION: u32 = 1;
/// Longest record payload a reader accepts, bytes.
pub const MAX_RECORD_LEN: u32 = 16 << 20;
/// Bytes per sample in a samples record.
pub const SAMPLE_LEN: usize = 4 + 8 + 8 + 3 * 4 + 1;

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
}

/// Reads a session; a cut or damaged record ends the reading with a warning, keeping every
/// sample before it.
pub fn read_session(b: &[u8]) -> Result<Session, SessionError> {
    if b.len() < 20 || b[..16] != MAGIC {
        return Err(SessionError::BadMagic);
    }
    let version = u32::from_le_bytes(b[16..20].try_into().expect("4 bytes"));
    if version != VERSION {
        return Err(SessionError::Version { found: version });
    }
    let mut at = 20;
    let mut header = None;
    let mut samples = Vec::new();
    let mut warnings = Vec::new();
    while at < b.len() {
        let Some(len) = b
            .get(at..at + 4)
            .map(|c| u32::from_le_bytes(c.try_into().expect("4 bytes")))
        else {
            warnings.push(format!(
                "file ends inside a record length at byte {at}; kept what came before"
            ));
            break;
        };
        if len > MAX_RECORD_LEN {
            warnings.push(format!(
                "record at byte {at} claims {len} bytes; stopped there"
            ));
            break;
        }
        let body = at + 4;
        let end = body + 1 + len as usize + 4;
        if end > b.len() {
            warnings.push(format!(
                "file ends inside the record at byte {at} (cut short, e.g. by a kill); kept what came before"
            ));
            break;
        }
        let crc = u32::from_le_bytes(b[end - 4..end].try_into().expect("4 bytes"));
        if crc32(&b[body..end - 4]) != crc {
            warnings.push(format!(
                "record at byte {at} fails its checksum; stopped there"
            ));
            break;
        }
        let kind = b[body];
        let payload = &b[body + 1..end - 4];
        match kind {
            KIND_HEADER => {
                let h: SessionHeader =
                    serde_json::from_slice(payload).map_err(|e| SessionError::Header {
                        what: e.to_string(),
                    })?;
                header = Some(h);
            }
            KIND_SAMPLES => {
                let n = payload.get(..4).map_or(0, |c| {
                    u32::from_le_bytes(c.try_into().expect("4 bytes")) as usize
                });
                if payload.len() != 4 + n * SAMPLE_LEN {
                    warnings.push(format!(
                        "samples record at byte {at} has the wrong length; skipped"
                    ));
                } else {
                    for c in payload[4..].chunks_exact(SAMPLE_LEN) {
                        let f32_at =
                            |i: usize| f32::from_le_bytes(c[i..i + 4].try_into().expect("4 bytes"));
                        samples.push(MarkerSample {
                            marker: u32::from_le_bytes(c[0..4].try_into().expect("4 bytes")),
                            time_s: f64::from_le_bytes(c[4..12].try_into().expect("8 bytes")),
                            source_time_s: f64::from_le_bytes(
                                c[12..20].try_into().expect("8 bytes"),
                            ),
                            position_m: DVec3::new(
                                f32_at(20) as f64,
                                f32_at(24) as f64,
                                f32_at(28) as f64,
                            ),
                            occluded: c[32] & 1 != 0,
                        });
                    }
                }
            }
            other => warnings.push(format!("unknown record kind {other} at byte {at}; skipped")),
        }
        at = end;
    }
    let header = header.ok_or(SessionError::NoHeader)?;
    Ok(Session {
        header,
        samples,
        warnings,
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

/// Runs a recorder on the calling thread: takes samples from `rx` and writes them with
/// `w` until the channel closes, flushing at `w`'s interval by `now_s()`. Returns the
/// samples written.
pub fn run_recorder<W: Write>(
    mut w: SessionWriter<W>,
    rx: &crossbeam_channel::Receiver<MarkerSample>,
    now_s: &dyn Fn() -> f64,
) -> std::io::Result<u64> {
    let tick = std::time::Duration::from_secs_f64((w.flush_interval_s / 4.0).clamp(0.001, 0.25));
    let mut batch = Vec::with_capacity(4096);
    loop {
        match rx.recv_timeout(tick) {
            Ok(s) => {
                batch.push(s);
                batch.extend(rx.try_iter().take(4095));
            }
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => {}
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
        }
        w.push(&batch, now_s())?;
        batch.clear();
    }
    let written = w.written + w.pending.len() as u64;
    w.finish(now_s())?;
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

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

    #[test]
    fn a_file_cut_anywhere_keeps_its_whole_records() {
        let b = file(5);
        let start_len = {
            let mut v = Vec::new();
            encode_start(&header(), &mut v);
            v.len()
        };
        let record_len = (b.len() - start_len) / 5;
        for cut in start_len..b.len() {
            let s = read_session(&b[..cut]).unwrap();
            let whole = (cut - start_len) / record_len;
            assert_eq!(s.samples.len(), 3 * whole, "cut at {cut}");
            assert_eq!(s.warnings.is_empty(), (cut - start_len) % record_len == 0);
        }
        // A flipped byte in record 3 keeps records 1 and 2.
        let mut d = b.clone();
        d[start_len + 2 * record_len + 10] ^= 0x40;
        let s = read_session(&d).unwrap();
        assert_eq!(s.samples.len(), 6);
        assert!(s.warnings[0].contains("checksum"));
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
