//! A solved take written to files: the full mesh's vertices, frame after frame, as a PC2
//! point cache ([`crate::protocol::pc2`]) that Blender's Mesh Cache modifier, 3ds Max
//! and Houdini play on the character's own mesh (same vertex order as its file).

use crate::protocol::pc2::{encode_frame, encode_header, Pc2Header};
use glam::DVec3;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Why an export failed.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: a frame of {got} vertices, the cache holds {points}")]
    Points {
        path: String,
        got: usize,
        points: usize,
    },
    #[error("{path}: {written} frames written, the header promised {samples}")]
    Frames {
        path: String,
        written: u32,
        samples: u32,
    },
    #[error("{path}: {count} {what} do not fit a PC2 file (at most {max})", max = i32::MAX)]
    TooMany {
        path: String,
        what: &'static str,
        count: usize,
    },
}

/// Writes a PC2 file frame by frame (the frame count is known before the first).
pub struct Pc2Writer {
    out: std::io::BufWriter<std::fs::File>,
    path: PathBuf,
    points: usize,
    samples: u32,
    written: u32,
    /// One frame's bytes, reused.
    buf: Vec<u8>,
}

impl Pc2Writer {
    /// A cache of `samples` frames of `points` points at `path` (replaced if it exists),
    /// its first frame at frame 0, a sample per frame.
    pub fn create(path: &Path, points: usize, samples: usize) -> Result<Self, ExportError> {
        let shown = || path.display().to_string();
        let fits = |what, count: usize| {
            if count > i32::MAX as usize {
                Err(ExportError::TooMany {
                    path: shown(),
                    what,
                    count,
                })
            } else {
                Ok(count as u32)
            }
        };
        let header = Pc2Header {
            points: fits("points", points)?,
            start_frame: 0.0,
            sample_rate: 1.0,
            samples: fits("frames", samples)?,
        };
        let io = |source| ExportError::Io {
            path: shown(),
            source,
        };
        let file = std::fs::File::create(path).map_err(io)?;
        let mut out = std::io::BufWriter::new(file);
        out.write_all(&encode_header(&header)).map_err(io)?;
        Ok(Self {
            out,
            path: path.to_owned(),
            points,
            samples: header.samples,
            written: 0,
            buf: Vec::with_capacity(points * 12),
        })
    }

    /// Appends a frame (metres, the character's frame: Y up).
    pub fn push(&mut self, vertices: &[DVec3]) -> Result<(), ExportError> {
        if vertices.len() != self.points {
            return Err(ExportError::Points {
                path: self.path.display().to_string(),
                got: vertices.len(),
                points: self.points,
            });
        }
        if self.written >= self.samples {
            return Err(self.frames_error(self.written + 1));
        }
        self.buf.clear();
        encode_frame(
            vertices.iter().map(|v| v.as_vec3().to_array()),
            &mut self.buf,
        );
        self.out
            .write_all(&self.buf)
            .map_err(|source| ExportError::Io {
                path: self.path.display().to_string(),
                source,
            })?;
        self.written += 1;
        Ok(())
    }

    /// Flushes the file; an error unless every promised frame was written.
    pub fn finish(mut self) -> Result<(), ExportError> {
        if self.written != self.samples {
            return Err(self.frames_error(self.written));
        }
        self.out.flush().map_err(|source| ExportError::Io {
            path: self.path.display().to_string(),
            source,
        })
    }

    fn frames_error(&self, written: u32) -> ExportError {
        ExportError::Frames {
            path: self.path.display().to_string(),
            written,
            samples: self.samples,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::pc2::decode;

    #[test]
    fn frames_land_in_order_and_counts_are_held() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("take.pc2");
        let mut w = Pc2Writer::create(&path, 2, 2).unwrap();
        w.push(&[DVec3::new(0.1, 0.2, 0.3), DVec3::X]).unwrap();
        assert!(matches!(
            w.push(&[DVec3::ZERO]),
            Err(ExportError::Points {
                got: 1,
                points: 2,
                ..
            })
        ));
        w.push(&[DVec3::Y, DVec3::Z]).unwrap();
        assert!(matches!(
            w.push(&[DVec3::Y, DVec3::Z]),
            Err(ExportError::Frames {
                written: 3,
                samples: 2,
                ..
            })
        ));
        w.finish().unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let pc2 = decode(&bytes).unwrap();
        assert_eq!((pc2.header.points, pc2.header.samples), (2, 2));
        assert_eq!(pc2.point(0, 0), Some([0.1, 0.2, 0.3]));
        assert_eq!(pc2.point(1, 1), Some([0.0, 0.0, 1.0]));
        // A cache left short is an error, not a file that lies about its length.
        let short = Pc2Writer::create(&dir.path().join("short.pc2"), 1, 3).unwrap();
        assert!(matches!(
            short.finish(),
            Err(ExportError::Frames {
                written: 0,
                samples: 3,
                ..
            })
        ));
    }
}
