//! A solved take written to files: the full mesh's vertices, frame after frame, as a PC2
//! point cache ([`crate::protocol::pc2`]) that Blender's Mesh Cache modifier, 3ds Max
//! and Houdini play on the character's own mesh (same vertex order as its file); or the
//! fitted skeleton's motion as BVH ([`crate::replay::bvh::encode_header`]), which any
//! animation tool imports.

use super::skin_fit::SkinFit;
use crate::protocol::pc2::{encode_frame, encode_header, Pc2Header};
use crate::replay::bvh::BvhSkeleton;
use glam::{DQuat, DVec3};
use std::io::{Seek, Write};
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
        written: usize,
        samples: usize,
    },
    #[error("{path}: {count} {what} do not fit a PC2 file (at most {max})", max = i32::MAX)]
    TooMany {
        path: String,
        what: &'static str,
        count: usize,
    },
    #[error("{path}: it is not a regular file (a folder, a device, a pipe or a socket), and an export only replaces files")]
    NotAFile { path: String },
}

/// An export's file, written under a temporary name beside its final one and renamed
/// onto it only when complete (a rename within a folder is atomic, POSIX `rename(2)`):
/// an export that fails or is killed leaves whatever was at the final name as it was.
/// Dropped without [`StagedPath::commit`], it removes the temporary file it made (a
/// process killed outright leaves it, named `.NAME.PID-N.part`, beside the final name).
#[derive(Debug)]
pub struct StagedPath {
    /// Where the file goes: the path given, or the file a symbolic link there names.
    final_path: PathBuf,
    temp: PathBuf,
    committed: bool,
}

impl StagedPath {
    /// Stages `path`: an error when something other than a regular file is there (a
    /// folder, a device, a pipe: an export never replaces them); a link to a file stages
    /// the file it names.
    pub fn new(path: &Path) -> Result<Self, ExportError> {
        static STAGED: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let final_path = match std::fs::metadata(path) {
            Ok(meta) if meta.is_file() => {
                std::fs::canonicalize(path).map_err(|source| io_error(path, source))?
            }
            Ok(_) => {
                return Err(ExportError::NotAFile {
                    path: path.display().to_string(),
                })
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => path.to_owned(),
            Err(source) => return Err(io_error(path, source)),
        };
        let name = final_path
            .file_name()
            .ok_or_else(|| ExportError::NotAFile {
                path: path.display().to_string(),
            })?
            .to_string_lossy();
        let n = STAGED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let temp = final_path.with_file_name(format!(".{name}.{}-{n}.part", std::process::id()));
        Ok(Self {
            final_path,
            temp,
            committed: false,
        })
    }

    /// Where the export writes until it is complete.
    pub fn temp(&self) -> &Path {
        &self.temp
    }

    /// Renames the complete file onto the final name.
    pub fn commit(mut self) -> Result<(), ExportError> {
        std::fs::rename(&self.temp, &self.final_path)
            .map_err(|source| io_error(&self.final_path, source))?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for StagedPath {
    fn drop(&mut self) {
        if self.committed {
            return;
        }
        match std::fs::remove_file(&self.temp) {
            Ok(()) => {}
            // Never made: the export failed before its first byte.
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => tracing::warn!("could not remove {}: {e}", self.temp.display()),
        }
    }
}

/// A file of a header and a known number of frames, written frame by frame: what the
/// PC2 and BVH writers share.
struct FramedFile {
    out: std::io::BufWriter<std::fs::File>,
    path: PathBuf,
    frames: usize,
    written: usize,
}

impl FramedFile {
    /// Creates `path` (replacing it) and writes `header`.
    fn create(path: &Path, header: &[u8], frames: usize) -> Result<Self, ExportError> {
        let mut f = Self {
            out: std::io::BufWriter::new(
                std::fs::File::create(path).map_err(|source| io_error(path, source))?,
            ),
            path: path.to_owned(),
            frames,
            written: 0,
        };
        f.out
            .write_all(header)
            .map_err(|source| io_error(path, source))?;
        Ok(f)
    }

    /// Opens `path` (made by [`FramedFile::create`], not truncated) for `frames` frames
    /// starting `offset` bytes in: one part of a file whose parts are written at once.
    fn open_at(path: &Path, offset: u64, frames: usize) -> Result<Self, ExportError> {
        let mut file = std::fs::OpenOptions::new()
            .write(true)
            .open(path)
            .map_err(|source| io_error(path, source))?;
        file.seek(std::io::SeekFrom::Start(offset))
            .map_err(|source| io_error(path, source))?;
        Ok(Self {
            out: std::io::BufWriter::new(file),
            path: path.to_owned(),
            frames,
            written: 0,
        })
    }

    /// Writes one frame's bytes; an error past the promised count.
    fn write_frame(&mut self, bytes: &[u8]) -> Result<(), ExportError> {
        if self.written >= self.frames {
            return Err(self.frames_error(self.written + 1));
        }
        self.out
            .write_all(bytes)
            .map_err(|source| io_error(&self.path, source))?;
        self.written += 1;
        Ok(())
    }

    /// Flushes the file; an error unless every promised frame was written.
    fn finish(mut self) -> Result<(), ExportError> {
        if self.written != self.frames {
            return Err(self.frames_error(self.written));
        }
        self.out
            .flush()
            .map_err(|source| io_error(&self.path, source))
    }

    fn frames_error(&self, written: usize) -> ExportError {
        ExportError::Frames {
            path: self.path.display().to_string(),
            written,
            samples: self.frames,
        }
    }
}

fn io_error(path: &Path, source: std::io::Error) -> ExportError {
    ExportError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// Writes a PC2 file frame by frame (the frame count is known before the first).
pub struct Pc2Writer {
    file: FramedFile,
    points: usize,
    /// One frame's bytes, reused.
    buf: Vec<u8>,
}

impl Pc2Writer {
    /// A cache of `samples` frames of `points` points at `path` (replaced if it exists),
    /// its first frame at frame 0, a sample per frame.
    pub fn create(path: &Path, points: usize, samples: usize) -> Result<Self, ExportError> {
        let header = Self::header(path, points, samples)?;
        Ok(Self {
            file: FramedFile::create(path, &encode_header(&header), samples)?,
            points,
            buf: Vec::with_capacity(points * 12),
        })
    }

    /// [`Pc2Writer::create`]'s cache written in parts at once: one writer per range
    /// `bounds[i]..bounds[i + 1]` of samples, each positioned at its first frame (PC2
    /// frames have a fixed size, 12 bytes a point). `bounds` rises from 0 to `samples`;
    /// each writer's [`Pc2Writer::finish`] checks its own part.
    pub fn create_parts(
        path: &Path,
        points: usize,
        samples: usize,
        bounds: &[usize],
    ) -> Result<Vec<Self>, ExportError> {
        let head = encode_header(&Self::header(path, points, samples)?);
        let frame_bytes = points as u64 * 12;
        // Saturating: a size past the disk's fails at `set_len` with the OS's error.
        let whole = (head.len() as u64).saturating_add(frame_bytes.saturating_mul(samples as u64));
        std::fs::File::create(path)
            .and_then(|mut f| {
                f.write_all(&head)?;
                f.set_len(whole)
            })
            .map_err(|source| io_error(path, source))?;
        bounds
            .windows(2)
            .map(|w| {
                let at =
                    (head.len() as u64).saturating_add(frame_bytes.saturating_mul(w[0] as u64));
                Ok(Self {
                    file: FramedFile::open_at(path, at, w[1].saturating_sub(w[0]))?,
                    points,
                    buf: Vec::with_capacity(points * 12),
                })
            })
            .collect()
    }

    /// The header of a cache of `samples` frames of `points` points; an error when a
    /// count does not fit the format.
    fn header(path: &Path, points: usize, samples: usize) -> Result<Pc2Header, ExportError> {
        let fits = |what, count: usize| {
            u32::try_from(count)
                .ok()
                .filter(|&c| c <= i32::MAX as u32)
                .ok_or_else(|| ExportError::TooMany {
                    path: path.display().to_string(),
                    what,
                    count,
                })
        };
        Ok(Pc2Header {
            points: fits("points", points)?,
            start_frame: 0.0,
            sample_rate: 1.0,
            samples: fits("frames", samples)?,
        })
    }

    /// Appends a frame (metres, the character's frame: Y up).
    pub fn push(&mut self, vertices: &[DVec3]) -> Result<(), ExportError> {
        if vertices.len() != self.points {
            return Err(ExportError::Points {
                path: self.file.path.display().to_string(),
                got: vertices.len(),
                points: self.points,
            });
        }
        self.buf.clear();
        encode_frame(
            vertices.iter().map(|v| v.as_vec3().to_array()),
            &mut self.buf,
        );
        self.file.write_frame(&self.buf)
    }

    /// Flushes the file; an error unless every promised frame was written.
    pub fn finish(self) -> Result<(), ExportError> {
        self.file.finish()
    }
}

/// The formats a take exports to, by the file's extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    /// `.pc2`: the full mesh, a point cache.
    Pc2,
    /// `.bvh`: the fitted skeleton's motion.
    Bvh,
    /// `.glb`: the mesh skinned to the skeleton, with the fitted motion as an animation.
    Glb,
}

impl ExportFormat {
    /// The format of `path`'s extension (either case), if rigless writes it.
    pub fn of(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?;
        if ext.eq_ignore_ascii_case("pc2") {
            Some(Self::Pc2)
        } else if ext.eq_ignore_ascii_case("bvh") {
            Some(Self::Bvh)
        } else if ext.eq_ignore_ascii_case("glb") {
            Some(Self::Glb)
        } else {
            None
        }
    }
}

/// Writes a BVH file frame by frame (the frame count is known before the first): the
/// skeleton at rest as its hierarchy, each frame's posture as a motion line.
pub struct BvhWriter {
    file: FramedFile,
    names: Vec<String>,
    parents: Vec<Option<usize>>,
    rest: Vec<DVec3>,
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
        let header = crate::replay::bvh::encode_header(skeleton, frames, frame_time_s);
        Ok(Self {
            file: FramedFile::create(path, header.as_bytes(), frames)?,
            names: skeleton.names.to_vec(),
            parents: skeleton.parents.to_vec(),
            rest: skeleton.rest.to_vec(),
            line: String::new(),
        })
    }

    /// Appends a frame: every joint's world rotation from rest and world position.
    pub fn push(&mut self, world_rot: &[DQuat], world_pos: &[DVec3]) -> Result<(), ExportError> {
        self.line.clear();
        let sk = BvhSkeleton {
            names: &self.names,
            parents: &self.parents,
            rest: &self.rest,
        };
        crate::replay::bvh::encode_frame(&sk, world_rot, world_pos, &mut self.line);
        self.file.write_frame(self.line.as_bytes())
    }

    /// Flushes the file; an error unless every promised frame was written.
    pub fn finish(self) -> Result<(), ExportError> {
        self.file.finish()
    }
}

/// Collects a take's fitted postures and writes them, on [`GlbWriter::finish`], as a
/// binary glTF: the character's mesh at rest, skinned to its skeleton (up to four joints
/// a vertex, the weights fitted to the solved frames shown to [`GlbWriter::fit_skin`]
/// and [`GlbWriter::merge_skin`];
/// with none, each vertex wholly to the joint whose bone segment is nearest, as the bind
/// divides the mesh), and one animation of every joint's rotation and the roots'
/// translation, a key per frame. Any engine or DCC tool that reads glTF plays it.
pub struct GlbWriter {
    path: PathBuf,
    frame_time_s: f64,
    skeleton: crate::character::skeleton::Skeleton,
    vertices: Vec<DVec3>,
    triangles: Vec<[u32; 3]>,
    /// The skin weights' fit.
    skin: SkinFit,
    /// Per frame, every joint's rotation relative to its parent, then each root's
    /// position.
    rotations: Vec<Vec<DQuat>>,
    roots: Vec<Vec<DVec3>>,
}

impl GlbWriter {
    /// A writer for `skeleton` and the mesh `vertices`, `triangles` at rest (metres, Y
    /// up), frames `frame_time_s` apart; `path` is written on [`Self::finish`].
    pub fn new(
        path: &Path,
        skeleton: &crate::character::skeleton::Skeleton,
        vertices: &[DVec3],
        triangles: &[[u32; 3]],
        frame_time_s: f64,
    ) -> Self {
        Self {
            path: path.to_owned(),
            frame_time_s,
            skeleton: skeleton.clone(),
            vertices: vertices.to_vec(),
            triangles: triangles.to_vec(),
            skin: SkinFit::new(skeleton, vertices),
            rotations: Vec::new(),
            roots: Vec::new(),
        }
    }

    /// Shows the skin fit a solved frame: the posture (as [`Self::push`]) and the solved
    /// mesh in the rest mesh's vertex order, metres.
    pub fn fit_skin(&mut self, world_rot: &[DQuat], world_pos: &[DVec3], vertices: &[DVec3]) {
        self.skin.add(world_rot, world_pos, vertices);
    }

    /// Adds what another fit of the same mesh took in (a later part of the take).
    pub fn merge_skin(&mut self, fit: &SkinFit) {
        self.skin.merge(fit);
    }

    /// Adds a frame: every joint's world rotation from rest and world position.
    pub fn push(&mut self, world_rot: &[DQuat], world_pos: &[DVec3]) {
        let joints = &self.skeleton.joints;
        let at = |v: &[DQuat], j: usize| v.get(j).copied().unwrap_or(DQuat::IDENTITY);
        self.rotations.push(
            joints
                .iter()
                .enumerate()
                .map(|(j, jt)| match jt.parent {
                    Some(p) => (at(world_rot, p).inverse() * at(world_rot, j)).normalize(),
                    None => at(world_rot, j).normalize(),
                })
                .collect(),
        );
        self.roots.push(
            joints
                .iter()
                .enumerate()
                .filter(|(_, jt)| jt.parent.is_none())
                .map(|(j, jt)| world_pos.get(j).copied().unwrap_or(jt.rest))
                .collect(),
        );
    }

    /// Writes the file.
    pub fn finish(self) -> Result<(), ExportError> {
        let bytes = self.encode();
        std::fs::write(&self.path, bytes).map_err(|source| io_error(&self.path, source))
    }

    /// The GLB bytes (glTF 2.0: a JSON chunk, then a BIN chunk).
    fn encode(&self) -> Vec<u8> {
        use serde_json::json;
        let joints = &self.skeleton.joints;
        let mut b = GlbBuffers::default();
        let mesh = self.encode_mesh(&mut b);
        let ibm = b.add(
            joints
                .iter()
                .flat_map(|j| glam::Mat4::from_translation(-j.rest.as_vec3()).to_cols_array())
                .flat_map(f32::to_le_bytes)
                .collect(),
            json!({"componentType": FLOAT, "count": joints.len(), "type": "MAT4"}),
        );
        let (samplers, channels) = self.encode_animation(&mut b);
        // Nodes: the joints (at rest: translations from their parents), then the mesh.
        let mut nodes: Vec<serde_json::Value> = joints
            .iter()
            .map(|j| {
                let t = j.parent.map_or(j.rest, |p| j.rest - joints[p].rest);
                json!({"name": j.name, "translation": t.as_vec3().to_array()})
            })
            .collect();
        for (j, jt) in joints.iter().enumerate() {
            if let Some(p) = jt.parent {
                let children = nodes[p]
                    .as_object_mut()
                    .map(|o| o.entry("children").or_insert_with(|| json!([])));
                if let Some(serde_json::Value::Array(c)) = children {
                    c.push(json!(j));
                }
            }
        }
        nodes.push(json!({"name": "mesh", "mesh": 0, "skin": 0}));
        let mut scene: Vec<usize> = (0..joints.len())
            .filter(|&j| joints[j].parent.is_none())
            .collect();
        scene.push(joints.len());
        b.pad();
        let doc = json!({
            "asset": {"version": "2.0", "generator": concat!("rigless ", env!("CARGO_PKG_VERSION"))},
            "scene": 0,
            "scenes": [{"nodes": scene}],
            "nodes": nodes,
            "meshes": [{"primitives": [mesh]}],
            "skins": [{"joints": (0..joints.len()).collect::<Vec<_>>(), "inverseBindMatrices": ibm}],
            "animations": [{"name": "take", "samplers": samplers, "channels": channels}],
            "buffers": [{"byteLength": b.bin.len()}],
            "bufferViews": b.views,
            "accessors": b.accessors,
        });
        let mut json_bytes = doc.to_string().into_bytes();
        while !json_bytes.len().is_multiple_of(4) {
            json_bytes.push(b' ');
        }
        let total = 12 + 8 + json_bytes.len() + 8 + b.bin.len();
        let mut out = Vec::with_capacity(total);
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&(json_bytes.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend_from_slice(&json_bytes);
        out.extend_from_slice(&(b.bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&b.bin);
        out
    }

    /// The mesh at rest and its skin weights ([`SkinFit::weights`]); returns the
    /// primitive.
    fn encode_mesh(&self, b: &mut GlbBuffers) -> serde_json::Value {
        use serde_json::json;
        let n = self.vertices.len();
        let (mut lo, mut hi) = (glam::Vec3::ZERO, glam::Vec3::ZERO);
        for (k, v) in self.vertices.iter().enumerate() {
            let v = v.as_vec3();
            (lo, hi) = if k == 0 {
                (v, v)
            } else {
                (lo.min(v), hi.max(v))
            };
        }
        let position = b.add(
            self.vertices
                .iter()
                .flat_map(|v| v.as_vec3().to_array())
                .flat_map(f32::to_le_bytes)
                .collect(),
            json!({"componentType": FLOAT, "count": n, "type": "VEC3", "min": lo.to_array(), "max": hi.to_array()}),
        );
        let indices = b.add(
            self.triangles.iter().flatten().flat_map(|i| i.to_le_bytes()).collect(),
            json!({"componentType": UNSIGNED_INT, "count": self.triangles.len() * 3, "type": "SCALAR"}),
        );
        let skin = self.skin.weights();
        let joints_0 = b.add(
            skin.iter()
                .flat_map(|(j, _)| *j)
                .flat_map(u16::to_le_bytes)
                .collect(),
            json!({"componentType": UNSIGNED_SHORT, "count": n, "type": "VEC4"}),
        );
        let weights_0 = b.add(
            skin.iter()
                .flat_map(|(_, w)| *w)
                .flat_map(f32::to_le_bytes)
                .collect(),
            json!({"componentType": FLOAT, "count": n, "type": "VEC4"}),
        );
        json!({"attributes": {"POSITION": position, "JOINTS_0": joints_0, "WEIGHTS_0": weights_0}, "indices": indices})
    }

    /// A key per frame: every joint's rotation, each root's translation; returns the
    /// samplers and channels.
    fn encode_animation(
        &self,
        b: &mut GlbBuffers,
    ) -> (Vec<serde_json::Value>, Vec<serde_json::Value>) {
        use serde_json::json;
        let joints = &self.skeleton.joints;
        let frames = self.rotations.len();
        let last = (frames.saturating_sub(1) as f64 * self.frame_time_s) as f32;
        let times = b.add(
            (0..frames)
                .map(|f| (f as f64 * self.frame_time_s) as f32)
                .flat_map(f32::to_le_bytes)
                .collect(),
            json!({"componentType": FLOAT, "count": frames, "type": "SCALAR", "min": [0.0], "max": [last]}),
        );
        let (mut samplers, mut channels) = (Vec::new(), Vec::new());
        let mut channel =
            |b: &mut GlbBuffers, data: Vec<u8>, kind: &str, node: usize, path: &str| {
                let out = b.add(
                    data,
                    json!({"componentType": FLOAT, "count": frames, "type": kind}),
                );
                samplers.push(json!({"input": times, "output": out, "interpolation": "LINEAR"}));
                channels.push(
                    json!({"sampler": samplers.len() - 1, "target": {"node": node, "path": path}}),
                );
            };
        for j in 0..joints.len() {
            let data = self
                .rotations
                .iter()
                .flat_map(|f| f[j].as_quat().to_array())
                .flat_map(f32::to_le_bytes)
                .collect();
            channel(b, data, "VEC4", j, "rotation");
        }
        let roots = (0..joints.len()).filter(|&j| joints[j].parent.is_none());
        for (r, j) in roots.enumerate() {
            let data = self
                .roots
                .iter()
                .flat_map(|f| f[r].as_vec3().to_array())
                .flat_map(f32::to_le_bytes)
                .collect();
            channel(b, data, "VEC3", j, "translation");
        }
        (samplers, channels)
    }
}

/// glTF component types.
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const UNSIGNED_SHORT: u32 = 5123;

/// A GLB's binary chunk as it is built, with its buffer views and accessors.
#[derive(Default)]
struct GlbBuffers {
    bin: Vec<u8>,
    views: Vec<serde_json::Value>,
    accessors: Vec<serde_json::Value>,
}

impl GlbBuffers {
    /// Pads the chunk to four bytes.
    fn pad(&mut self) {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
    }

    /// Appends `data` (four-byte aligned) as a buffer view read by `accessor`; returns
    /// the accessor's index.
    fn add(&mut self, data: Vec<u8>, mut accessor: serde_json::Value) -> usize {
        self.pad();
        self.views.push(serde_json::json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": data.len()}));
        self.bin.extend_from_slice(&data);
        accessor["bufferView"] = serde_json::json!(self.views.len() - 1);
        self.accessors.push(accessor);
        self.accessors.len() - 1
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
