//! A solved take written to files: the full mesh's vertices, frame after frame, as a PC2
//! point cache ([`crate::protocol::pc2`]) that Blender's Mesh Cache modifier, 3ds Max
//! and Houdini play on the character's own mesh (same vertex order as its file); or the
//! fitted skeleton's motion as BVH ([`crate::replay::bvh::encode_header`]), which any
//! animation tool imports.

use crate::protocol::pc2::{encode_frame, encode_header, Pc2Header};
use crate::replay::bvh::BvhSkeleton;
use glam::{DQuat, DVec3};
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

/// The formats a take exports to, by the file's extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    /// `.pc2`: the full mesh, a point cache.
    Pc2,
    /// `.bvh`: the fitted skeleton's motion.
    Bvh,
}

impl ExportFormat {
    /// The format of `path`'s extension (either case), if rigless writes it.
    pub fn of(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?;
        if ext.eq_ignore_ascii_case("pc2") {
            Some(Self::Pc2)
        } else if ext.eq_ignore_ascii_case("bvh") {
            Some(Self::Bvh)
        } else {
            None
        }
    }
}

/// Writes a BVH file frame by frame (the frame count is known before the first): the
/// skeleton at rest as its hierarchy, each frame's posture as a motion line.
pub struct BvhWriter {
    out: std::io::BufWriter<std::fs::File>,
    path: PathBuf,
    names: Vec<String>,
    parents: Vec<Option<usize>>,
    rest: Vec<DVec3>,
    frames: usize,
    written: usize,
    /// One motion line, reused.
    line: String,
}

impl BvhWriter {
    /// A file of `frames` frames `frame_time_s` apart for the skeleton `names`,
    /// `parents`, `rest` (world, metres) at `path` (replaced if it exists).
    pub fn create(
        path: &Path,
        skeleton: &BvhSkeleton<'_>,
        frames: usize,
        frame_time_s: f64,
    ) -> Result<Self, ExportError> {
        let io = |source| ExportError::Io {
            path: path.display().to_string(),
            source,
        };
        let file = std::fs::File::create(path).map_err(io)?;
        let mut out = std::io::BufWriter::new(file);
        let header = crate::replay::bvh::encode_header(skeleton, frames, frame_time_s);
        out.write_all(header.as_bytes()).map_err(io)?;
        Ok(Self {
            out,
            path: path.to_owned(),
            names: skeleton.names.to_vec(),
            parents: skeleton.parents.to_vec(),
            rest: skeleton.rest.to_vec(),
            frames,
            written: 0,
            line: String::new(),
        })
    }

    /// Appends a frame: every joint's world rotation from rest and world position.
    pub fn push(&mut self, world_rot: &[DQuat], world_pos: &[DVec3]) -> Result<(), ExportError> {
        if self.written >= self.frames {
            return Err(ExportError::Frames {
                path: self.path.display().to_string(),
                written: (self.written + 1) as u32,
                samples: self.frames as u32,
            });
        }
        self.line.clear();
        let sk = BvhSkeleton {
            names: &self.names,
            parents: &self.parents,
            rest: &self.rest,
        };
        crate::replay::bvh::encode_frame(&sk, world_rot, world_pos, &mut self.line);
        self.out
            .write_all(self.line.as_bytes())
            .map_err(|source| ExportError::Io {
                path: self.path.display().to_string(),
                source,
            })?;
        self.written += 1;
        Ok(())
    }

    /// Flushes the file; an error unless every promised frame was written.
    pub fn finish(mut self) -> Result<(), ExportError> {
        if self.written != self.frames {
            return Err(ExportError::Frames {
                path: self.path.display().to_string(),
                written: self.written as u32,
                samples: self.frames as u32,
            });
        }
        self.out.flush().map_err(|source| ExportError::Io {
            path: self.path.display().to_string(),
            source,
        })
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
