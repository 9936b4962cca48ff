//! The PC2 point cache (3ds Max's "Point Cache 2", read by Blender's Mesh Cache modifier,
//! 3ds Max and Houdini): a 32-byte header, then every frame's points as little-endian
//! `f32` triples, frame after frame. Pure: bytes in and out, no I/O. The format is in
//! `protocols/pc2.md`.
//!
//! Header (little-endian): `"POINTCACHE2\0"` (12 bytes), `i32` version (1), `i32`
//! points, `f32` start frame, `f32` sample rate (frames between samples: 1 for every
//! frame), `i32` samples (frames).

/// The signature the file starts with.
pub const MAGIC: &[u8; 12] = b"POINTCACHE2\0";
/// The only version there is.
pub const VERSION: i32 = 1;
/// Bytes of the header.
pub const HEADER_BYTES: usize = 32;

/// A PC2 header.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pc2Header {
    /// Points per frame (the mesh's vertices, in its order).
    pub points: u32,
    /// The first sample's frame on the reader's timeline.
    pub start_frame: f32,
    /// Frames between samples (1: a sample per frame).
    pub sample_rate: f32,
    /// Samples (frames) in the file.
    pub samples: u32,
}

impl Pc2Header {
    /// Bytes of the frames that follow the header (`points × samples × 12`), `None`
    /// when that overflows.
    pub fn body_bytes(&self) -> Option<usize> {
        (self.points as usize)
            .checked_mul(self.samples as usize)?
            .checked_mul(12)
    }
}

/// Why bytes are not a PC2 file.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum Pc2Error {
    #[error("{bytes} bytes: shorter than a PC2 header ({HEADER_BYTES})")]
    Short { bytes: usize },
    #[error("no PC2 signature (\"POINTCACHE2\\0\") at the start")]
    Magic,
    #[error("PC2 version {version}, only {VERSION} exists")]
    Version { version: i32 },
    #[error("PC2 header: {field} is negative ({value})")]
    Negative { field: &'static str, value: i32 },
    #[error("PC2 header: {points} points × {samples} samples need {expected:?} bytes of frames, the file has {actual}")]
    Length {
        points: u32,
        samples: u32,
        /// `None` when the product overflows.
        expected: Option<usize>,
        actual: usize,
    },
}

/// The header's 32 bytes.
pub fn encode_header(h: &Pc2Header) -> [u8; HEADER_BYTES] {
    let mut b = [0u8; HEADER_BYTES];
    b[..12].copy_from_slice(MAGIC);
    b[12..16].copy_from_slice(&VERSION.to_le_bytes());
    // Counts above i32::MAX are not representable; the writer never has that many.
    b[16..20].copy_from_slice(&(h.points.min(i32::MAX as u32) as i32).to_le_bytes());
    b[20..24].copy_from_slice(&h.start_frame.to_le_bytes());
    b[24..28].copy_from_slice(&h.sample_rate.to_le_bytes());
    b[28..32].copy_from_slice(&(h.samples.min(i32::MAX as u32) as i32).to_le_bytes());
    b
}

/// Appends one frame's points (`[x, y, z]` each) to `out`.
pub fn encode_frame(points: impl IntoIterator<Item = [f32; 3]>, out: &mut Vec<u8>) {
    for p in points {
        for c in p {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
}

/// A PC2 file read: its header and its frames' bytes (`points × samples` triples).
#[derive(Debug, PartialEq)]
pub struct Pc2<'a> {
    pub header: Pc2Header,
    body: &'a [u8],
}

impl Pc2<'_> {
    /// Point `p` of sample `s`; `None` out of range.
    pub fn point(&self, s: usize, p: usize) -> Option<[f32; 3]> {
        let n = self.header.points as usize;
        if p >= n || s >= self.header.samples as usize {
            return None;
        }
        let at = (s * n + p) * 12;
        let f = |k: usize| {
            let b = &self.body[at + 4 * k..at + 4 * k + 4];
            f32::from_le_bytes([b[0], b[1], b[2], b[3]])
        };
        Some([f(0), f(1), f(2)])
    }
}

/// Reads `bytes` as a PC2 file. The header's counts are checked against the bytes
/// present (exactly the frames they promise, nothing more): nothing is allocated.
pub fn decode(bytes: &[u8]) -> Result<Pc2<'_>, Pc2Error> {
    if bytes.len() < HEADER_BYTES {
        return Err(Pc2Error::Short { bytes: bytes.len() });
    }
    if &bytes[..12] != MAGIC {
        return Err(Pc2Error::Magic);
    }
    let word = |at: usize| [bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]];
    let version = i32::from_le_bytes(word(12));
    if version != VERSION {
        return Err(Pc2Error::Version { version });
    }
    let count = |field: &'static str, at: usize| {
        let value = i32::from_le_bytes(word(at));
        u32::try_from(value).map_err(|_| Pc2Error::Negative { field, value })
    };
    let header = Pc2Header {
        points: count("points", 16)?,
        start_frame: f32::from_le_bytes(word(20)),
        sample_rate: f32::from_le_bytes(word(24)),
        samples: count("samples", 28)?,
    };
    let body = &bytes[HEADER_BYTES..];
    let expected = header.body_bytes();
    if expected != Some(body.len()) {
        return Err(Pc2Error::Length {
            points: header.points,
            samples: header.samples,
            expected,
            actual: body.len(),
        });
    }
    Ok(Pc2 { header, body })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn file(h: &Pc2Header, frames: &[Vec<[f32; 3]>]) -> Vec<u8> {
        let mut b = encode_header(h).to_vec();
        for f in frames {
            encode_frame(f.iter().copied(), &mut b);
        }
        b
    }

    #[test]
    fn a_written_cache_reads_back() {
        let frames = vec![
            vec![[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]],
            vec![[-1.5, 0.25, 1e-7], [f32::MAX, f32::MIN_POSITIVE, -0.0]],
            vec![[7.0, 8.0, 9.0], [10.0, 11.0, 12.0]],
        ];
        let h = Pc2Header {
            points: 2,
            start_frame: 0.0,
            sample_rate: 1.0,
            samples: 3,
        };
        let bytes = file(&h, &frames);
        assert_eq!(bytes.len(), HEADER_BYTES + 3 * 2 * 12);
        // The header as 3ds Max writes it: the signature, then version 1.
        assert_eq!(&bytes[..16], b"POINTCACHE2\0\x01\0\0\0");
        let pc2 = decode(&bytes).expect("a valid cache");
        assert_eq!(pc2.header, h);
        for (s, f) in frames.iter().enumerate() {
            for (p, want) in f.iter().enumerate() {
                assert_eq!(
                    pc2.point(s, p).map(|v| v.map(f32::to_bits)),
                    Some(want.map(f32::to_bits))
                );
            }
        }
        assert_eq!(pc2.point(3, 0), None);
        assert_eq!(pc2.point(0, 2), None);
    }

    #[test]
    fn bad_files_say_why() {
        let h = Pc2Header {
            points: 2,
            start_frame: 0.0,
            sample_rate: 1.0,
            samples: 1,
        };
        let good = file(&h, &[vec![[0.0; 3]; 2]]);
        assert_eq!(decode(&good[..31]), Err(Pc2Error::Short { bytes: 31 }));
        let mut b = good.clone();
        b[0] = b'X';
        assert_eq!(decode(&b), Err(Pc2Error::Magic));
        let mut b = good.clone();
        b[12] = 2;
        assert_eq!(decode(&b), Err(Pc2Error::Version { version: 2 }));
        let mut b = good.clone();
        b[16..20].copy_from_slice(&(-5i32).to_le_bytes());
        assert_eq!(
            decode(&b),
            Err(Pc2Error::Negative {
                field: "points",
                value: -5
            })
        );
        // One byte short of the promised frames, and one over.
        assert!(matches!(
            decode(&good[..good.len() - 1]),
            Err(Pc2Error::Length { actual: 23, .. })
        ));
        let mut b = good.clone();
        b.push(0);
        assert!(matches!(
            decode(&b),
            Err(Pc2Error::Length { actual: 25, .. })
        ));
    }

    proptest! {
        /// Any bytes: an error or a cache whose every point reads, never a panic.
        #[test]
        fn any_bytes_decode_or_fail(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            if let Ok(pc2) = decode(&bytes) {
                let h = pc2.header;
                for s in 0..h.samples as usize {
                    for p in 0..h.points as usize {
                        prop_assert!(pc2.point(s, p).is_some());
                    }
                }
            }
        }

        /// Any header values before a short body: the counts are checked against the
        /// bytes, whatever they claim.
        #[test]
        fn any_header_values_are_checked(
            points in any::<i32>(),
            samples in any::<i32>(),
            start in any::<f32>(),
            rate in any::<f32>(),
            body in proptest::collection::vec(any::<u8>(), 0..200),
        ) {
            let mut b = MAGIC.to_vec();
            b.extend_from_slice(&VERSION.to_le_bytes());
            b.extend_from_slice(&points.to_le_bytes());
            b.extend_from_slice(&start.to_le_bytes());
            b.extend_from_slice(&rate.to_le_bytes());
            b.extend_from_slice(&samples.to_le_bytes());
            b.extend_from_slice(&body);
            match decode(&b) {
                Ok(pc2) => prop_assert_eq!(
                    pc2.header.points as usize * pc2.header.samples as usize * 12,
                    body.len()
                ),
                Err(Pc2Error::Negative { .. }) => prop_assert!(points < 0 || samples < 0),
                Err(Pc2Error::Length { .. }) => {}
                Err(e) => prop_assert!(false, "unexpected {e}"),
            }
        }
    }
}
