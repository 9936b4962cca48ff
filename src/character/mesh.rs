//! Character meshes from files: Wavefront OBJ (our own reader: `v`, `f`, `g`/`o`, so the
//! output keeps the file's vertex order) and glTF 2.0 (our own reader over the `gltf`
//! crate's JSON types: triangle primitives, node transforms, the first skin's joints);
//! unit and up-axis conversion; welding of coincident positions; the closed-manifold check
//! the solver needs.
//!
//! The parsers take bytes and return typed data or an error naming the line (OBJ) or the
//! glTF object at fault (primitive, accessor, buffer view, buffer, node or skin) and the
//! value; they never panic on hostile input and never allocate more than a small multiple
//! of the input's size. For glTF this holds because the document is checked here before
//! anything is sized by it, the buffers are loaded and read here, and the calls left into
//! the `gltf` crate run under `catch_unwind` ([`parse_gltf`] lists the checks and limits).

use crate::geom::winding::orient_parts;
use crate::runtime::files::{read_bounded, MAX_DATA_BYTES};
use glam::{DMat4, DVec3};
use std::collections::HashMap;
use std::path::Path;

/// A triangle mesh in the file's own vertex order, plus the skin's joints when the file
/// has one.
#[derive(Clone, Debug, Default)]
pub struct MeshData {
    pub positions: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
    /// Every vertex the file defines, in file order (OBJ: every `v` line, also those of
    /// groups that were not kept; glTF: the same as `positions`). Character files name
    /// joint positions by these indices.
    pub source_positions: Vec<DVec3>,
    /// Joints of the first skin (glTF), parents before children.
    pub skin_joints: Vec<SkinJoint>,
    /// The transform the skinned vertices and the joints were taken through from the
    /// file's bind space to its world (an armature's unit scale or axis turn above the
    /// joints); `None` when the bind space is the world.
    pub rest_from_bind: Option<DMat4>,
    /// The file's parts, in output order: every glTF triangle primitive, or every run of
    /// an OBJ file's faces under one group.
    pub parts: Vec<MeshPart>,
    /// glTF: the node each of `parts` hangs from (its world transform placed it); empty
    /// for OBJ.
    pub part_nodes: Vec<usize>,
    /// OBJ: the line (from 1) of each of `positions`' `v` lines; empty for glTF.
    pub source_lines: Vec<u32>,
}

/// Where a mesh file gives a vertex, as errors name it.
#[derive(Clone, Debug, PartialEq)]
pub enum VertexAt {
    /// An OBJ file's `v` line (from 1).
    ObjLine(usize),
    /// A glTF triangle primitive (its part's name) and the node it hangs from.
    Node { node: usize, part: String },
    /// Neither is known (a mesh made in memory).
    InMemory,
}

impl std::fmt::Display for VertexAt {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            VertexAt::ObjLine(line) => write!(f, "OBJ line {line}"),
            VertexAt::Node { node, part } => write!(f, "glTF nodes[{node}], part {part:?}"),
            VertexAt::InMemory => write!(f, "a mesh made in memory"),
        }
    }
}

impl MeshData {
    /// Where the file gives vertex `v` of `positions`.
    pub fn vertex_at(&self, v: usize) -> VertexAt {
        if let Some(&line) = self.source_lines.get(v) {
            return VertexAt::ObjLine(line as usize);
        }
        let holds = |p: &MeshPart| {
            (p.first_vertex as usize..(p.first_vertex + p.vertex_count) as usize).contains(&v)
        };
        match (
            self.parts.iter().position(holds),
            self.part_nodes.is_empty(),
        ) {
            (Some(k), false) => VertexAt::Node {
                node: self.part_nodes.get(k).copied().unwrap_or(0),
                part: self.parts[k].name.clone(),
            },
            _ => VertexAt::InMemory,
        }
    }
}

/// A part of a mesh as its file has it: a glTF triangle primitive, or a run of an OBJ
/// file's kept faces under one `g` / `o` line.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MeshPart {
    /// glTF: the node's name (else its mesh's, else `nodes[N]`), with `/K` for the
    /// mesh's K-th primitive when it has several; OBJ: the group's names as the line
    /// gives them (empty before any).
    pub name: String,
    /// Its triangles: `first_triangle .. first_triangle + triangle_count`.
    pub first_triangle: u32,
    pub triangle_count: u32,
    /// Its vertices: `first_vertex .. first_vertex + vertex_count`. A glTF primitive's
    /// own vertices, disjoint from the other parts'; an OBJ run's lowest to highest
    /// vertex, which holds other groups' vertices too when groups share or interleave
    /// their `v` lines.
    pub first_vertex: u32,
    pub vertex_count: u32,
}

impl MeshPart {
    /// One part holding a whole mesh of `vertices` vertices and `triangles` triangles.
    pub fn whole(name: &str, vertices: usize, triangles: usize) -> Self {
        Self {
            name: name.to_string(),
            first_triangle: 0,
            triangle_count: triangles as u32,
            first_vertex: 0,
            vertex_count: vertices as u32,
        }
    }
}

/// A joint of a glTF skin at its bind pose.
#[derive(Clone, Debug)]
pub struct SkinJoint {
    pub name: String,
    /// Index into `skin_joints` of the nearest ancestor that is also a joint.
    pub parent: Option<usize>,
    /// Bind-pose world matrix (inverse of the inverse bind matrix), mesh space.
    pub world_from_joint: DMat4,
    /// Whether some vertex the skin deforms has weight on it (`JOINTS_0` and
    /// `WEIGHTS_0` of the primitives it skins) or an unskinned mesh node hangs from it;
    /// every joint counts as weighted when no primitive gives weights.
    pub weighted: bool,
}

/// Errors reading a mesh file. The glTF variants name the object at fault as the JSON
/// does (`accessors[3]`, `meshes[0] "body" primitives[1]`, `buffers[0]`) and the value.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("line {line}: {message}")]
    Obj { line: usize, message: String },
    #[error("the file has no triangles{}", if .groups.is_empty() { String::new() } else { format!(" in groups {:?}", .groups) })]
    NoTriangles { groups: Vec<String> },
    #[error("OBJ groups not found: {missing:?} (the file has {found:?})")]
    MissingGroups {
        missing: Vec<String>,
        found: Vec<String>,
    },
    /// A GLB container whose header or chunks do not fit the file.
    #[error("GLB: {problem}")]
    Glb { problem: GlbProblem },
    /// The JSON does not parse into glTF's types (serde's message, with line and column).
    #[error("glTF JSON: {message}")]
    Json { message: String },
    /// The JSON's top-level arrays would take more memory than [`GLTF_JSON_ALLOWANCE`]
    /// plus [`GLTF_JSON_BYTES_PER_BYTE`] per byte of JSON.
    #[error("glTF JSON: {objects} top-level objects would take {bytes} bytes in memory, more than the {limit} allowed for {json_len} bytes of JSON")]
    TooManyObjects {
        objects: u64,
        bytes: u64,
        json_len: usize,
        limit: u64,
    },
    /// An index past the end of the array it points into.
    #[error("glTF {field} is {index}, but the document has {count} {array}")]
    Reference {
        field: String,
        index: usize,
        array: &'static str,
        count: usize,
    },
    /// The first problem the `gltf` crate's validation found: where (a JSON path) and
    /// what.
    #[error("glTF {path}: {problem}")]
    Invalid { path: String, problem: String },
    /// A buffer view that does not fit in its buffer (as declared).
    #[error("glTF bufferViews[{view}]: {length} bytes from byte {offset} run past the end of buffers[{buffer}] ({buffer_length} bytes)")]
    ViewOutsideBuffer {
        view: usize,
        buffer: usize,
        offset: u64,
        length: u64,
        buffer_length: u64,
    },
    #[error("glTF accessors[{accessor}]: {problem}")]
    Accessor {
        accessor: usize,
        problem: AccessorProblem,
    },
    #[error("glTF buffers[{buffer}]: {problem}")]
    Buffer {
        buffer: usize,
        problem: BufferProblem,
    },
    #[error("glTF nodes[{node}]: {problem}")]
    Node { node: usize, problem: NodeProblem },
    #[error("glTF skins[{skin}]: {problem}")]
    Skin { skin: usize, problem: SkinProblem },
    #[error("glTF {at}: {problem}")]
    Primitive {
        at: PrimitiveAt,
        problem: PrimitiveProblem,
    },
    /// The `gltf` crate panicked on this file (a bug of the crate that the checks before
    /// it did not foresee); `stage` says what it was doing.
    #[error("{file}: the gltf crate panicked while {stage}: {message}")]
    Panicked {
        file: String,
        stage: &'static str,
        message: String,
    },
}

/// What is wrong with a GLB container.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum GlbProblem {
    #[error("{length} bytes are too few for a GLB header (12)")]
    TooShort { length: usize },
    #[error("version {version} (only 2 is read)")]
    Version { version: u32 },
    #[error("the header's length {declared} does not fit the file's {actual} bytes")]
    Length { declared: u32, actual: usize },
    #[error("the chunk at byte {offset} declares {length} bytes, but {remaining} remain")]
    Chunk {
        offset: usize,
        length: u64,
        remaining: usize,
    },
    #[error("the first chunk has type 0x{chunk_type:08x}, not JSON")]
    FirstChunk { chunk_type: u32 },
    #[error("no JSON chunk")]
    NoJson,
}

/// What is wrong with an accessor (any accessor of the document, used or not).
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum AccessorProblem {
    #[error("it has neither a bufferView nor sparse values")]
    NoData,
    #[error("bufferViews[{view}].byteStride {stride} is smaller than its {element}-byte elements")]
    StrideTooSmall {
        view: usize,
        stride: u64,
        element: u64,
    },
    #[error("{count} elements of {element} bytes, {stride} bytes apart from byte {offset}, run past the end of bufferViews[{view}] ({view_length} bytes)")]
    OutsideView {
        view: usize,
        offset: u64,
        stride: u64,
        count: u64,
        element: u64,
        view_length: u64,
    },
    #[error("count {count} of {element}-byte elements without a bufferView is more than the {limit} bytes of all buffers")]
    TooLarge {
        count: u64,
        element: u64,
        limit: u64,
    },
    #[error("sparse.count {sparse} is more than its count {count}")]
    SparseCount { sparse: u64, count: u64 },
    #[error("sparse.{part}: {count} of {size} bytes from byte {offset} run past the end of bufferViews[{view}] ({view_length} bytes)")]
    SparseOutsideView {
        part: &'static str,
        view: usize,
        offset: u64,
        count: u64,
        size: u64,
        view_length: u64,
    },
    #[error("sparse index {index} (entry {entry}) is outside its {count} elements")]
    SparseIndex {
        entry: usize,
        index: u32,
        count: u64,
    },
    #[error("{field} is not an array of {expected} numbers")]
    MinMax {
        field: &'static str,
        expected: usize,
    },
    #[error("its bytes lie outside its buffer's data")]
    Unreadable,
}

/// What is wrong with a buffer or its data.
#[derive(Debug, thiserror::Error)]
pub enum BufferProblem {
    #[error("it has no uri and there is no GLB BIN chunk for it")]
    NoData,
    #[error("it holds {actual} bytes, fewer than its byteLength {declared}")]
    Short { declared: u64, actual: u64 },
    #[error("uri {uri:?}: only base64 data: URIs and relative file paths are read")]
    Scheme { uri: String },
    #[error("uri {uri:?}: it is not a relative path")]
    Absolute { uri: String },
    #[error("uri {uri:?}: a bad percent-escape, or the path is not UTF-8")]
    PercentEncoding { uri: String },
    /// The decoded path holds a NUL byte (no file name can).
    #[error("uri {uri:?}: the path holds a NUL byte")]
    NulByte { uri: String },
    /// The decoded path's `..` components climb above the mesh's folder.
    #[error("uri {uri:?}: it climbs out of the mesh's folder (a `..` above it); buffers are read only from the folder and below")]
    OutsideFolder { uri: String },
    /// The path stays in the mesh's folder by its text, but a symbolic link on it leads
    /// out (the folder and the file compared after resolving links).
    #[error("uri {uri:?}: a symbolic link on the path leads out of the mesh's folder; buffers are read only from the folder and below")]
    LinkOutsideFolder { uri: String },
    #[error("uri: bad base64 at character {offset} of the data")]
    Base64 { offset: usize },
    #[error("uri {uri:?} names a file, but the document was given without its folder")]
    NoFolder { uri: String },
    #[error("{path}: not a regular file")]
    NotAFile { path: String },
    #[error("{path} has {actual} bytes, but byteLength is {declared} (the file must hold exactly that, or up to 3 bytes of padding more)")]
    FileLength {
        path: String,
        declared: u64,
        actual: u64,
    },
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
}

/// What is wrong with the node hierarchy.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum NodeProblem {
    #[error("it is a child of nodes[{first}] and again of nodes[{second}]")]
    TwoParents { first: usize, second: usize },
    #[error("it is its own ancestor (the children make a cycle)")]
    Cycle,
}

/// What is wrong with a skin.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum SkinProblem {
    #[error("{joints} joints, more than the {max} read")]
    TooManyJoints { joints: usize, max: usize },
    #[error("nodes[{node}] is one of its joints twice")]
    DuplicateJoint { node: usize },
    #[error("inverseBindMatrices accessors[{accessor}] is {accessor_type} of componentType {component_type}; it must be MAT4 of 5126 (float)")]
    MatrixFormat {
        accessor: usize,
        accessor_type: &'static str,
        component_type: u32,
    },
    #[error("{joints} joints but {matrices} inverse bind matrices")]
    MatrixCount { joints: usize, matrices: usize },
    /// A skinned primitive's `JOINTS_0` or `WEIGHTS_0`.
    #[error("{at}: {detail}")]
    Weights { at: PrimitiveAt, detail: String },
}

/// A primitive of a mesh, as errors name it.
#[derive(Clone, Debug, PartialEq)]
pub struct PrimitiveAt {
    pub mesh: usize,
    pub name: Option<String>,
    pub primitive: usize,
}

impl std::fmt::Display for PrimitiveAt {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.name {
            Some(n) => write!(
                f,
                "meshes[{}] {n:?} primitives[{}]",
                self.mesh, self.primitive
            ),
            None => write!(f, "meshes[{}] primitives[{}]", self.mesh, self.primitive),
        }
    }
}

/// What is wrong with a triangle primitive.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum PrimitiveProblem {
    #[error("it has no POSITION attribute")]
    NoPositions,
    #[error("POSITION accessors[{accessor}] is {accessor_type} of componentType {component_type}; it must be VEC3 of 5126 (float)")]
    PositionFormat {
        accessor: usize,
        accessor_type: &'static str,
        component_type: u32,
    },
    #[error("indices accessors[{accessor}] is {accessor_type} of componentType {component_type}; indices must be SCALAR of 5121, 5123 or 5125 (unsigned 8, 16 or 32 bits)")]
    IndexFormat {
        accessor: usize,
        accessor_type: &'static str,
        component_type: u32,
    },
    #[error("{count} {}, not a multiple of 3 (a triangle list)", if *.indexed { "indices" } else { "vertices without indices" })]
    NotTriangles { count: usize, indexed: bool },
    #[error("index {index} is outside its {vertices} vertices")]
    IndexOutOfRange { index: u32, vertices: u32 },
    #[error("it takes the file's {what} to {total}, over the budget of {budget} for {input_len} bytes of input")]
    OverBudget {
        what: &'static str,
        total: u64,
        budget: u64,
        input_len: u64,
    },
}

/// Most vertices a polygon may have (a longer `f` line is an error, not an allocation).
pub const MAX_POLYGON_VERTICES: usize = 256;

/// Parses an OBJ file. `groups`: keep only faces under these `g`/`o` names (all when
/// empty). The result has one vertex per `v` line referenced by a kept face, in file
/// order; polygons are split into fans.
pub fn parse_obj(bytes: &[u8], groups: &[String]) -> Result<MeshData, MeshError> {
    let text = String::from_utf8_lossy(bytes);
    let mut positions: Vec<DVec3> = Vec::new();
    let mut lines: Vec<u32> = Vec::new();
    let mut faces: Vec<[u32; 3]> = Vec::new();
    let mut found: Vec<String> = Vec::new();
    let mut keep = groups.is_empty();
    let mut poly: Vec<u32> = Vec::new();
    // Runs of kept faces under one group line: (names, first face).
    let mut runs: Vec<(String, usize)> = Vec::new();
    let mut group = String::new();
    for (ln, raw) in text.lines().enumerate() {
        let line = ln + 1;
        let err = |message: String| MeshError::Obj { line, message };
        let body = raw.split('#').next().unwrap_or("").trim();
        let mut it = body.split_whitespace();
        match it.next() {
            Some("v") => {
                let mut c = [0.0; 3];
                for (k, v) in c.iter_mut().enumerate() {
                    let s = it
                        .next()
                        .ok_or_else(|| err(format!("vertex has {k} coordinates, needs 3")))?;
                    *v = s
                        .parse::<f64>()
                        .map_err(|_| err(format!("vertex coordinate {s:?} is not a number")))?;
                    if !v.is_finite() {
                        return Err(err(format!("vertex coordinate {s:?} is not finite")));
                    }
                }
                positions.push(DVec3::from_array(c));
                lines.push(u32::try_from(line).unwrap_or(u32::MAX));
            }
            Some("g") | Some("o") => {
                let names: Vec<&str> = it.collect();
                for n in &names {
                    if !found.iter().any(|f| f == n) {
                        found.push(n.to_string());
                    }
                }
                keep = groups.is_empty() || names.iter().any(|n| groups.iter().any(|g| g == n));
                group = names.join(" ");
            }
            Some("f") => {
                poly.clear();
                for tok in it {
                    if poly.len() == MAX_POLYGON_VERTICES {
                        return Err(err(format!(
                            "face has more than {MAX_POLYGON_VERTICES} vertices"
                        )));
                    }
                    let first = tok.split('/').next().unwrap_or("");
                    let idx: i64 = first
                        .parse()
                        .map_err(|_| err(format!("face index {tok:?} is not an integer")))?;
                    let n = positions.len() as i64;
                    let abs = if idx > 0 { idx - 1 } else { n + idx };
                    if idx == 0 || abs < 0 || abs >= n {
                        return Err(err(format!(
                            "face index {idx} is outside the {n} vertices defined so far"
                        )));
                    }
                    poly.push(abs as u32);
                }
                if poly.len() < 3 {
                    return Err(err(format!("face has {} vertices, needs 3", poly.len())));
                }
                if keep {
                    if runs.last().is_none_or(|(g, _)| *g != group) {
                        runs.push((group.clone(), faces.len()));
                    }
                    for k in 1..poly.len() - 1 {
                        faces.push([poly[0], poly[k], poly[k + 1]]);
                    }
                }
            }
            _ => {}
        }
    }
    let missing: Vec<String> = groups
        .iter()
        .filter(|g| !found.contains(g))
        .cloned()
        .collect();
    if !missing.is_empty() {
        return Err(MeshError::MissingGroups { missing, found });
    }
    if faces.is_empty() {
        return Err(MeshError::NoTriangles {
            groups: groups.to_vec(),
        });
    }
    // Compact to referenced vertices, keeping file order.
    let mut used = vec![false; positions.len()];
    for f in &faces {
        for &i in f {
            used[i as usize] = true;
        }
    }
    let mut remap = vec![u32::MAX; positions.len()];
    let mut out = Vec::new();
    let mut source_lines = Vec::new();
    for (i, p) in positions.iter().enumerate() {
        if used[i] {
            remap[i] = out.len() as u32;
            out.push(*p);
            source_lines.push(lines[i]);
        }
    }
    let triangles: Vec<[u32; 3]> = faces.iter().map(|f| f.map(|i| remap[i as usize])).collect();
    let parts = runs
        .iter()
        .enumerate()
        .map(|(k, (name, first))| {
            let end = runs.get(k + 1).map_or(triangles.len(), |r| r.1);
            let used = triangles[*first..end].iter().flatten();
            let (lo, hi) = used.fold((u32::MAX, 0), |(lo, hi), &v| (lo.min(v), hi.max(v)));
            MeshPart {
                name: name.clone(),
                first_triangle: *first as u32,
                triangle_count: (end - first) as u32,
                first_vertex: lo,
                vertex_count: hi + 1 - lo,
            }
        })
        .collect();
    Ok(MeshData {
        positions: out,
        triangles,
        source_positions: positions,
        skin_joints: Vec::new(),
        rest_from_bind: None,
        parts,
        part_nodes: Vec::new(),
        source_lines,
    })
}

/// Most joints a glTF skin may have (a hand has about 25, a body with fingers and a face a
/// few hundred); a skin with more is an error naming its count.
pub const MAX_SKIN_JOINTS: usize = 1024;

/// Vertices a glTF file may give in all: this many plus one per four bytes of input (the
/// file and the external buffers it reads). A vertex takes 12 bytes of a buffer, so every
/// vertex may be drawn three times (instanced meshes), and 65,536 more.
pub const GLTF_VERTEX_ALLOWANCE: u64 = 1 << 16;

/// Indices (three a triangle) a glTF file may give in all: this many plus one per byte of
/// input.
pub const GLTF_INDEX_ALLOWANCE: u64 = 1 << 16;

/// Bytes the JSON's top-level objects (nodes, accessors, materials, ...) may take in
/// memory before they are built: this many plus [`GLTF_JSON_BYTES_PER_BYTE`] per byte of
/// JSON. A node takes 224 bytes, so 3 MB of empty nodes `{}` are refused, while a real
/// file (dozens of bytes of JSON an object) is far below.
pub const GLTF_JSON_ALLOWANCE: u64 = 1 << 20;

/// See [`GLTF_JSON_ALLOWANCE`].
pub const GLTF_JSON_BYTES_PER_BYTE: u64 = 16;

/// Reads a glTF 2.0 file (`.glb`, or `.gltf` with its buffers next to it): every triangle
/// primitive of every mesh node, in document order (scenes are not consulted); unskinned
/// nodes are placed by their world transform, skinned ones stay in bind space (as the
/// glTF specification says). Images are not decoded.
pub fn read_gltf(path: &Path) -> Result<MeshData, MeshError> {
    let bytes = read_bounded(path, MAX_DATA_BYTES).map_err(|source| MeshError::Io {
        path: path.display().to_string(),
        source,
    })?;
    parse_gltf_file(&bytes, path)
}

/// [`parse_gltf`] of the bytes already read from the file at `path` (relative buffers
/// are found beside it; errors name it).
pub fn parse_gltf_file(bytes: &[u8], path: &Path) -> Result<MeshData, MeshError> {
    parse_glb_or_gltf(bytes, path.parent(), &path.display().to_string())
}

/// [`read_gltf`] on bytes; `base` is the folder external buffers are relative to (none:
/// only embedded or GLB buffers).
///
/// The `gltf` crate only parses the JSON into its types and validates them; everything
/// it would do with numbers from the file is done here, checked first:
///
/// 1. The GLB container is split here: chunk lengths within the header's length, which is
///    within the file; the first chunk JSON, the first `BIN` chunk kept, others skipped.
/// 2. A census of the JSON's top-level arrays, which allocates nothing, refuses a
///    document whose objects would take more than [`GLTF_JSON_ALLOWANCE`] plus
///    [`GLTF_JSON_BYTES_PER_BYTE`] per byte of JSON; then the crate parses it.
/// 3. Every index of an accessor, buffer view, buffer, mesh, node or skin is in range
///    (the crate's validation indexes with some of them unchecked), then the crate's
///    validation runs (its first problem is the error).
/// 4. Every buffer view lies within its buffer; every accessor within its view, its
///    stride no smaller than its element; a sparse accessor's indices and values within
///    their views and its count within the accessor's, and one without a view no larger
///    than all the buffers; `min` and `max` hold one number per component. All with
///    checked arithmetic: a sum or product that overflows is out of bounds.
/// 5. The nodes make a forest (one parent each, no cycle); a skin has at most
///    [`MAX_SKIN_JOINTS`] joints, each once.
/// 6. Buffers are loaded here: the GLB `BIN` chunk (borrowed), base64 `data:` URIs, and
///    relative paths (percent-decoded here, to UTF-8 or an error) to regular files whose
///    length is the declared `byteLength` (plus up to 3 bytes of padding), checked before
///    reading. A path must stay inside `base`: `/` and `\` separate, a `..` above the
///    folder, a NUL byte, or a symbolic link leading out of the folder (both resolved
///    before comparing) is refused before anything is read, and the error names the URI,
///    never what the file holds. Other schemes and absolute paths are refused.
/// 7. Triangle primitives: POSITION is VEC3 float, indices SCALAR unsigned 8, 16 or 32
///    bits, their count a multiple of three; all of them together within
///    [`GLTF_VERTEX_ALLOWANCE`] plus one vertex per four bytes of input and
///    [`GLTF_INDEX_ALLOWANCE`] plus one index per byte, so the output is allocated once,
///    at its final size. Then the data is read, every index checked.
///
/// Every allocation is bounded by the input's length or these limits. The calls into the
/// crate (parsing, validation, node transforms) run under `catch_unwind`, so a panic the
/// checks did not foresee becomes [`MeshError::Panicked`] naming the file instead of
/// taking the daemon down (the release profile unwinds).
pub fn parse_gltf(bytes: &[u8], base: Option<&Path>) -> Result<MeshData, MeshError> {
    parse_glb_or_gltf(bytes, base, "glTF bytes")
}

/// [`parse_gltf`], naming the file as `file` in a [`MeshError::Panicked`].
fn parse_glb_or_gltf(bytes: &[u8], base: Option<&Path>, file: &str) -> Result<MeshData, MeshError> {
    parse_document(bytes, base, file).map(|(_, _, mesh)| mesh)
}

/// A glTF file opened for its scene graph, skins and animations
/// ([`crate::character::animation`] plays them): the `gltf` crate's document and each
/// buffer's bytes, after every check of [`parse_gltf`], and the mesh as [`read_gltf`]
/// reads it.
pub struct GltfSource {
    /// Validated, its indices in range (checked here before the crate's types are used).
    pub document: gltf::Document,
    /// Distinct buffer sources, and which one each buffer uses.
    data: Vec<Vec<u8>>,
    source: Vec<usize>,
    pub mesh: MeshData,
}

impl GltfSource {
    /// Buffer `b`'s bytes.
    pub fn buffer(&self, b: usize) -> Option<&[u8]> {
        self.data.get(*self.source.get(b)?).map(Vec::as_slice)
    }
}

/// Opens the glTF file at `path` as [`read_gltf`] reads it, keeping its document and
/// buffers.
pub fn open_gltf(path: &Path) -> Result<GltfSource, MeshError> {
    let bytes = read_bounded(path, MAX_DATA_BYTES).map_err(|source| MeshError::Io {
        path: path.display().to_string(),
        source,
    })?;
    let file = path.display().to_string();
    let (root, buffers, mesh) = parse_document(&bytes, path.parent(), &file)?;
    let Buffers { data, source, .. } = buffers;
    Ok(GltfSource {
        document: gltf::Document::from_json_without_validation(root),
        data: data.into_iter().map(std::borrow::Cow::into_owned).collect(),
        source,
        mesh,
    })
}

/// The checked document, its buffers and its mesh ([`parse_gltf`]'s steps).
fn parse_document<'a>(
    bytes: &'a [u8],
    base: Option<&Path>,
    file: &str,
) -> Result<(gltf::json::Root, Buffers<'a>, MeshData), MeshError> {
    let (json, bin) = if bytes.starts_with(b"glTF") {
        split_glb(bytes).map_err(|problem| MeshError::Glb { problem })?
    } else {
        (bytes, None)
    };
    let root = read_json(json, file)?;
    check_references(&root)?;
    crate_validation(&root, file)?;
    let layouts = accessor_layouts(&root)?;
    let forest = node_forest(&root)?;
    check_skins(&root)?;
    let buffers = load_buffers(&root, bin, base)?;
    let input_len = (bytes.len() as u64).saturating_add(buffers.external_bytes);
    let totals = check_primitives(&root, &layouts, input_len)?;
    let world = world_matrices(&root, &forest, file)?;
    let mut out = read_meshes(&root, &layouts, &buffers, &world, &totals)?;
    if out.triangles.is_empty() {
        return Err(MeshError::NoTriangles { groups: Vec::new() });
    }
    out.source_positions = out.positions.clone();
    let first_skin = root
        .nodes
        .iter()
        .filter(|n| n.mesh.is_some())
        .find_map(|n| n.skin);
    let rest = rest_transform(&root, &layouts, &buffers, &world, &out.positions)?;
    if let Some(c) = rest {
        let skinned: Vec<bool> = skinned_vertices(&root, &out);
        for (p, _) in out.positions.iter_mut().zip(&skinned).filter(|(_, s)| **s) {
            *p = c.transform_point3(*p);
        }
        out.source_positions = out.positions.clone();
        out.rest_from_bind = Some(c);
    }
    if let Some(skin) = first_skin {
        let world = rest.is_some().then_some(world.as_slice());
        let influences = read_influences_all(&root, &layouts, &buffers, &out)?;
        let at = (&layouts[..], &buffers, &forest);
        out.skin_joints = read_skin(&root, skin.value(), at, world, &influences)?;
        add_end_joints(&mut out, &influences.dominant, &root);
    }
    Ok((root, buffers, out))
}

/// What the skinned primitives' `JOINTS_0` and `WEIGHTS_0` say, read once through every
/// skin (a character's head mesh may have a skin of its own over the same joints).
struct Influences {
    /// Each vertex's most weighted joint node (`None`: unskinned, or a primitive
    /// without joints and weights), in the reader's vertex order.
    dominant: Vec<Option<usize>>,
    /// Per node: whether some vertex has weight on it.
    weighted_node: Vec<bool>,
    /// Whether any primitive gave joints and weights (without, no joint can be told
    /// unused).
    read_any: bool,
}

/// Reads [`Influences`] over the parts of `out` in the reader's order.
fn read_influences_all(
    root: &gltf::json::Root,
    layouts: &[Layout],
    buffers: &Buffers,
    out: &MeshData,
) -> Result<Influences, MeshError> {
    use gltf::json::mesh::Semantic;
    use gltf::json::validation::Checked;
    let mut dominant = vec![None; out.positions.len()];
    let mut weighted_node = vec![false; root.nodes.len()];
    let mut read_any = false;
    let (mut joints, mut weights) = (Vec::new(), Vec::new());
    for (part, (_, node, m, mesh, p, prim)) in triangle_primitives(root).enumerate() {
        let range = out.parts.get(part).map(|q| {
            let first = q.first_vertex as usize;
            first..first + q.vertex_count as usize
        });
        let skin = node
            .skin
            .and_then(|s| Some((s.value(), root.skins.get(s.value())?)));
        let has = |sem| prim.attributes.contains_key(&Checked::Valid(sem));
        let (Some(range), Some((t, skin)), true) = (
            range,
            skin,
            has(Semantic::Joints(0)) && has(Semantic::Weights(0)),
        ) else {
            continue;
        };
        read_influences(prim, layouts, buffers, &mut joints, &mut weights).map_err(|detail| {
            MeshError::Skin {
                skin: t,
                problem: SkinProblem::Weights {
                    at: PrimitiveAt {
                        mesh: m,
                        name: mesh.name.clone(),
                        primitive: p,
                    },
                    detail,
                },
            }
        })?;
        read_any = true;
        let node_of = |k: u16| skin.joints.get(usize::from(k)).map(|n| n.value());
        for ((v, j), w) in range.zip(&joints).zip(&weights) {
            for c in (0..4).filter(|&c| w[c] > 0.0) {
                if let Some(x) = node_of(j[c]).and_then(|n| weighted_node.get_mut(n)) {
                    *x = true;
                }
            }
            let c = (0..4).fold(0, |b, c| if w[c] > w[b] { c } else { b });
            if w[c] > 0.0 {
                dominant[v] = node_of(j[c]);
            }
        }
    }
    Ok(Influences {
        dominant,
        weighted_node,
        read_any,
    })
}

/// Shortest skin past a leaf joint, as a share of the mesh's extent, that makes an end
/// joint for it (shorter: a fingertip's nail).
const END_JOINT_SHARE: f64 = 0.02;

/// An end joint for every leaf joint of the skin whose own skin (the vertices it weighs
/// most) reaches past it: a limb of one joint (Kenney's `leg-left`, from the hips down
/// to the foot) or a head without a top joint has a bone only from its parent to it,
/// and its skin hangs beyond; the end joint (`NAME_end`, no role, no weight) sits where
/// that skin ends in the direction of its middle.
fn add_end_joints(out: &mut MeshData, dominant: &[Option<usize>], root: &gltf::json::Root) {
    let (lo, hi) = crate::geom::shapes::bounds(&out.positions);
    let extent = (hi - lo).max_element();
    let n = out.skin_joints.len();
    let mut has_child = vec![false; n];
    for j in &out.skin_joints {
        if let Some(p) = j.parent.filter(|&p| p < n) {
            has_child[p] = true;
        }
    }
    let node_name = |i: usize| &out.skin_joints[i].name;
    let nodes: Vec<Option<usize>> = (0..n)
        .map(|i| {
            let mut skin_nodes = root
                .skins
                .iter()
                .flat_map(|s| s.joints.iter().map(|j| j.value()));
            skin_nodes.find(|&k| root.nodes[k].name.as_deref() == Some(node_name(i).as_str()))
        })
        .collect();
    let mut ends = Vec::new();
    for i in (0..n).filter(|&i| !has_child[i]) {
        let (Some(p), Some(node)) = (out.skin_joints[i].parent, nodes[i]) else {
            continue;
        };
        if p >= n {
            continue;
        }
        // Toward the middle of its own skin (a bone from the parent may point the other
        // way: a root on the floor under a leg joint at the hips), as far as it reaches.
        let at = out.skin_joints[i].world_from_joint.w_axis.truncate();
        let own: Vec<DVec3> = out
            .positions
            .iter()
            .zip(dominant)
            .filter(|(_, &k)| k == Some(node))
            .map(|(v, _)| *v)
            .collect();
        let middle = own.iter().sum::<DVec3>() / own.len().max(1) as f64;
        let d = (middle - at).normalize_or_zero();
        let reach = own.iter().map(|v| (*v - at).dot(d)).fold(0.0, f64::max);
        if d != DVec3::ZERO && reach > END_JOINT_SHARE * extent {
            let mut m = out.skin_joints[i].world_from_joint;
            m.w_axis = (at + d * reach).extend(1.0);
            ends.push(SkinJoint {
                name: format!("{}_end", node_name(i)),
                parent: Some(i),
                world_from_joint: m,
                weighted: false,
            });
        }
    }
    let taken: std::collections::HashSet<String> =
        out.skin_joints.iter().map(|j| j.name.clone()).collect();
    out.skin_joints
        .extend(ends.into_iter().filter(|e| !taken.contains(&e.name)));
}

/// Runs a call into the `gltf` crate, turning a panic into [`MeshError::Panicked`]. The
/// crate's code is not ours to fix, and a panic on a crafted file must not take the
/// daemon down; `AssertUnwindSafe` holds because nothing the call touches outlives a
/// panic (the document is only read, and the results are dropped).
pub(crate) fn guarded<T>(
    file: &str,
    stage: &'static str,
    f: impl FnOnce() -> T,
) -> Result<T, MeshError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).map_err(|payload| {
        let message = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "(no message)".to_string());
        MeshError::Panicked {
            file: file.to_string(),
            stage,
            message,
        }
    })
}

/// The JSON and `BIN` chunks of a GLB container.
fn split_glb(bytes: &[u8]) -> Result<(&[u8], Option<&[u8]>), GlbProblem> {
    let word = |bytes: &[u8], at: usize| {
        bytes
            .get(at..at.checked_add(4)?)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let (Some(version), Some(declared)) = (word(bytes, 4), word(bytes, 8)) else {
        return Err(GlbProblem::TooShort {
            length: bytes.len(),
        });
    };
    if version != 2 {
        return Err(GlbProblem::Version { version });
    }
    let total = declared as usize;
    if total < 12 || total > bytes.len() {
        return Err(GlbProblem::Length {
            declared,
            actual: bytes.len(),
        });
    }
    let bytes = bytes.get(..total).unwrap_or_default();
    let (mut json, mut bin) = (None, None);
    let mut at = 12;
    while at < total {
        let remaining = total - at;
        let (Some(length), Some(kind)) = (word(bytes, at), word(bytes, at + 4)) else {
            return Err(GlbProblem::Chunk {
                offset: at,
                length: 0,
                remaining,
            });
        };
        let end = (at + 8)
            .checked_add(length as usize)
            .filter(|&e| e <= total)
            .ok_or(GlbProblem::Chunk {
                offset: at,
                length: length.into(),
                remaining: remaining.saturating_sub(8),
            })?;
        let data = bytes.get(at + 8..end).unwrap_or_default();
        match (json.is_none(), &kind.to_le_bytes()) {
            (true, b"JSON") => json = Some(data),
            (true, _) => return Err(GlbProblem::FirstChunk { chunk_type: kind }),
            (false, b"BIN\0") if bin.is_none() => bin = Some(data),
            _ => {}
        }
        at = end;
    }
    Ok((json.ok_or(GlbProblem::NoJson)?, bin))
}

/// The lengths of a glTF JSON's top-level arrays, counted without building anything
/// (`IgnoredAny` takes no memory, nor a vector of it).
#[derive(serde::Deserialize)]
struct Census {
    #[serde(default)]
    accessors: Vec<serde::de::IgnoredAny>,
    #[serde(default)]
    animations: Vec<serde::de::IgnoredAny>,
    #[serde(default)]
    buffers: Vec<serde::de::IgnoredAny>,
    #[serde(default, rename = "bufferViews")]
    buffer_views: Vec<serde::de::IgnoredAny>,
    #[serde(default)]
    cameras: Vec<serde::de::IgnoredAny>,
    #[serde(default)]
    images: Vec<serde::de::IgnoredAny>,
    #[serde(default)]
    materials: Vec<serde::de::IgnoredAny>,
    #[serde(default)]
    meshes: Vec<serde::de::IgnoredAny>,
    #[serde(default)]
    nodes: Vec<serde::de::IgnoredAny>,
    #[serde(default)]
    samplers: Vec<serde::de::IgnoredAny>,
    #[serde(default)]
    scenes: Vec<serde::de::IgnoredAny>,
    #[serde(default)]
    skins: Vec<serde::de::IgnoredAny>,
    #[serde(default)]
    textures: Vec<serde::de::IgnoredAny>,
    #[serde(default, rename = "extensionsUsed")]
    extensions_used: Vec<serde::de::IgnoredAny>,
    #[serde(default, rename = "extensionsRequired")]
    extensions_required: Vec<serde::de::IgnoredAny>,
}

impl Census {
    /// The objects counted, and the bytes the crate's types for them take.
    fn memory(&self) -> (u64, u64) {
        use gltf::json as j;
        use std::mem::size_of;
        [
            (self.accessors.len(), size_of::<j::Accessor>()),
            (self.animations.len(), size_of::<j::Animation>()),
            (self.buffers.len(), size_of::<j::Buffer>()),
            (self.buffer_views.len(), size_of::<j::buffer::View>()),
            (self.cameras.len(), size_of::<j::Camera>()),
            (self.images.len(), size_of::<j::Image>()),
            (self.materials.len(), size_of::<j::Material>()),
            (self.meshes.len(), size_of::<j::Mesh>()),
            (self.nodes.len(), size_of::<j::Node>()),
            (self.samplers.len(), size_of::<j::texture::Sampler>()),
            (self.scenes.len(), size_of::<j::Scene>()),
            (self.skins.len(), size_of::<j::Skin>()),
            (self.textures.len(), size_of::<j::Texture>()),
            (self.extensions_used.len(), size_of::<String>()),
            (self.extensions_required.len(), size_of::<String>()),
        ]
        .iter()
        .fold((0u64, 0u64), |(n, b), &(count, size)| {
            (
                n.saturating_add(count as u64),
                b.saturating_add((count as u64).saturating_mul(size as u64)),
            )
        })
    }
}

/// The document's JSON in the crate's types, after the census allowed it.
fn read_json(json: &[u8], file: &str) -> Result<gltf::json::Root, MeshError> {
    let census: Census = serde_json::from_slice(json).map_err(|e| MeshError::Json {
        message: e.to_string(),
    })?;
    let (objects, bytes) = census.memory();
    let limit = GLTF_JSON_ALLOWANCE
        .saturating_add(GLTF_JSON_BYTES_PER_BYTE.saturating_mul(json.len() as u64));
    if bytes > limit {
        return Err(MeshError::TooManyObjects {
            objects,
            bytes,
            json_len: json.len(),
            limit,
        });
    }
    guarded(file, "parsing the JSON", || {
        gltf::json::deserialize::from_slice::<gltf::json::Root>(json)
    })?
    .map_err(|e| MeshError::Json {
        message: e.to_string(),
    })
}

/// `Ok` when `index` is within an array of `count` (`array`, as the JSON calls it);
/// `field` names the reference.
fn in_range(
    index: usize,
    count: usize,
    array: &'static str,
    field: impl FnOnce() -> String,
) -> Result<(), MeshError> {
    if index < count {
        return Ok(());
    }
    Err(MeshError::Reference {
        field: field(),
        index,
        array,
        count,
    })
}

/// Checks every reference to an accessor, buffer view, buffer, mesh, node or skin.
fn check_references(root: &gltf::json::Root) -> Result<(), MeshError> {
    let (n_acc, n_views) = (root.accessors.len(), root.buffer_views.len());
    let acc = |i: usize, field: &dyn Fn() -> String| in_range(i, n_acc, "accessors", field);
    let view = |i: usize, field: &dyn Fn() -> String| in_range(i, n_views, "bufferViews", field);
    for (a, x) in root.accessors.iter().enumerate() {
        if let Some(v) = x.buffer_view {
            view(v.value(), &|| format!("accessors[{a}].bufferView"))?;
        }
        if let Some(s) = &x.sparse {
            let v = s.indices.buffer_view.value();
            view(v, &|| format!("accessors[{a}].sparse.indices.bufferView"))?;
            let v = s.values.buffer_view.value();
            view(v, &|| format!("accessors[{a}].sparse.values.bufferView"))?;
        }
    }
    for (v, x) in root.buffer_views.iter().enumerate() {
        let b = x.buffer.value();
        in_range(b, root.buffers.len(), "buffers", || {
            format!("bufferViews[{v}].buffer")
        })?;
    }
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let at = format!("meshes[{m}].primitives[{p}]");
            for (name, a) in &prim.attributes {
                acc(a.value(), &|| {
                    format!("{at}.attributes.{}", name.to_string())
                })?;
            }
            if let Some(a) = prim.indices {
                acc(a.value(), &|| format!("{at}.indices"))?;
            }
            for (t, target) in prim.targets.iter().flatten().enumerate() {
                for a in [target.positions, target.normals, target.tangents]
                    .into_iter()
                    .flatten()
                {
                    acc(a.value(), &|| format!("{at}.targets[{t}]"))?;
                }
            }
        }
    }
    for (k, anim) in root.animations.iter().enumerate() {
        for (s, sampler) in anim.samplers.iter().enumerate() {
            for (a, what) in [(sampler.input, "input"), (sampler.output, "output")] {
                acc(a.value(), &|| {
                    format!("animations[{k}].samplers[{s}].{what}")
                })?;
            }
        }
    }
    check_node_references(root)
}

/// Checks every reference of the nodes and skins to a node, mesh, skin or accessor.
fn check_node_references(root: &gltf::json::Root) -> Result<(), MeshError> {
    let n_nodes = root.nodes.len();
    for (n, node) in root.nodes.iter().enumerate() {
        for (k, c) in node.children.iter().flatten().enumerate() {
            in_range(c.value(), n_nodes, "nodes", || {
                format!("nodes[{n}].children[{k}]")
            })?;
        }
        if let Some(m) = node.mesh {
            in_range(m.value(), root.meshes.len(), "meshes", || {
                format!("nodes[{n}].mesh")
            })?;
        }
        if let Some(s) = node.skin {
            in_range(s.value(), root.skins.len(), "skins", || {
                format!("nodes[{n}].skin")
            })?;
        }
    }
    for (s, skin) in root.skins.iter().enumerate() {
        for (k, j) in skin.joints.iter().enumerate() {
            in_range(j.value(), n_nodes, "nodes", || {
                format!("skins[{s}].joints[{k}]")
            })?;
        }
        if let Some(j) = skin.skeleton {
            in_range(j.value(), n_nodes, "nodes", || {
                format!("skins[{s}].skeleton")
            })?;
        }
        if let Some(a) = skin.inverse_bind_matrices {
            in_range(a.value(), root.accessors.len(), "accessors", || {
                format!("skins[{s}].inverseBindMatrices")
            })?;
        }
    }
    Ok(())
}

/// The `gltf` crate's validation of the document (its first problem is the error).
fn crate_validation(root: &gltf::json::Root, file: &str) -> Result<(), MeshError> {
    use gltf::json::validation::Validate;
    let first = guarded(file, "validating the document", || {
        let mut first: Option<(String, String)> = None;
        root.validate(root, gltf::json::Path::new, &mut |path, error| {
            if first.is_none() {
                first = Some((path().as_str().to_string(), error.to_string()));
            }
        });
        first
    })?;
    match first {
        Some((path, problem)) => Err(MeshError::Invalid { path, problem }),
        None => Ok(()),
    }
}

/// Where an accessor's elements are and what they are, checked against the declared
/// lengths of its views and buffers.
#[derive(Clone, Copy, Debug)]
struct Layout {
    kind: gltf::json::accessor::Type,
    component: gltf::json::accessor::ComponentType,
    count: usize,
    /// Bytes of one element (matrix columns padded to four bytes, as glTF lays them out).
    element: usize,
    /// Buffer, first byte and stride of the elements; none: zeros (sparse accessors).
    dense: Option<(usize, usize, usize)>,
    sparse: Option<SparseLayout>,
}

/// Where a sparse accessor's substitutions are.
#[derive(Clone, Copy, Debug)]
struct SparseLayout {
    count: usize,
    /// Bytes of one index (1, 2 or 4).
    index_size: usize,
    /// Buffer and first byte of the indices, and of the values.
    indices: (usize, usize),
    values: (usize, usize),
}

/// The glTF name of an accessor type.
fn type_name(kind: gltf::json::accessor::Type) -> &'static str {
    use gltf::json::accessor::Type::*;
    match kind {
        Scalar => "SCALAR",
        Vec2 => "VEC2",
        Vec3 => "VEC3",
        Vec4 => "VEC4",
        Mat2 => "MAT2",
        Mat3 => "MAT3",
        Mat4 => "MAT4",
    }
}

/// Bytes of one element: components times their size, matrix columns padded to a
/// multiple of four bytes.
fn element_size(
    kind: gltf::json::accessor::Type,
    component: gltf::json::accessor::ComponentType,
) -> usize {
    use gltf::json::accessor::Type::*;
    let size = component.size();
    match kind {
        Mat2 if size == 1 => 8,
        Mat3 if size == 1 => 12,
        Mat3 if size == 2 => 24,
        _ => kind.multiplicity() * size,
    }
}

/// A number from the file as an index or length here, once checked against a declared
/// length (only a 32-bit machine can fail it).
fn to_usize(
    value: Option<u64>,
    accessor: usize,
    count: u64,
    element: u64,
) -> Result<usize, MeshError> {
    value
        .and_then(|v| usize::try_from(v).ok())
        .ok_or(MeshError::Accessor {
            accessor,
            problem: AccessorProblem::TooLarge {
                count,
                element,
                limit: usize::MAX as u64,
            },
        })
}

/// The layout of every accessor, after checking that every buffer view lies in its
/// buffer.
fn accessor_layouts(root: &gltf::json::Root) -> Result<Vec<Layout>, MeshError> {
    let mut views = Vec::with_capacity(root.buffer_views.len());
    for (v, view) in root.buffer_views.iter().enumerate() {
        let buffer = view.buffer.value();
        let buffer_length = root.buffers.get(buffer).map_or(0, |b| b.byte_length.0);
        let offset = view.byte_offset.map_or(0, |o| o.0);
        let length = view.byte_length.0;
        if offset
            .checked_add(length)
            .is_none_or(|end| end > buffer_length)
        {
            return Err(MeshError::ViewOutsideBuffer {
                view: v,
                buffer,
                offset,
                length,
                buffer_length,
            });
        }
        views.push((buffer, offset, length));
    }
    let all_buffers = root
        .buffers
        .iter()
        .fold(0u64, |sum, b| sum.saturating_add(b.byte_length.0));
    root.accessors
        .iter()
        .enumerate()
        .map(|(a, accessor)| accessor_layout(root, &views, a, accessor, all_buffers))
        .collect()
}

/// One accessor's layout; `views` holds each buffer view's buffer, offset and length.
fn accessor_layout(
    root: &gltf::json::Root,
    views: &[(usize, u64, u64)],
    a: usize,
    accessor: &gltf::json::Accessor,
    all_buffers: u64,
) -> Result<Layout, MeshError> {
    use gltf::json::validation::Checked;
    let err = |problem| MeshError::Accessor {
        accessor: a,
        problem,
    };
    let (Checked::Valid(kind), Checked::Valid(component)) =
        (accessor.type_, accessor.component_type)
    else {
        return Err(MeshError::Invalid {
            path: format!("accessors[{a}]"),
            problem: "type or componentType is not valid".into(),
        });
    };
    let component = component.0;
    let element = element_size(kind, component);
    let (count, el) = (accessor.count.0, element as u64);
    for (field, value) in [("min", &accessor.min), ("max", &accessor.max)] {
        let expected = kind.multiplicity();
        let fits = |v: &serde_json::Value| {
            v.as_array()
                .is_some_and(|x| x.len() == expected && x.iter().all(|n| n.is_number()))
        };
        if value.as_ref().is_some_and(|v| !fits(v)) {
            return Err(err(AccessorProblem::MinMax { field, expected }));
        }
    }
    let dense = match accessor.buffer_view {
        Some(v) => {
            let v = v.value();
            let (buffer, view_offset, view_length) = views.get(v).copied().unwrap_or_default();
            let stride = root
                .buffer_views
                .get(v)
                .and_then(|x| x.byte_stride)
                .map_or(el, |s| s.0 as u64);
            if stride < el {
                return Err(err(AccessorProblem::StrideTooSmall {
                    view: v,
                    stride,
                    element: el,
                }));
            }
            let offset = accessor.byte_offset.map_or(0, |o| o.0);
            let needed = match count {
                0 => Some(offset),
                _ => stride
                    .checked_mul(count - 1)
                    .and_then(|b| b.checked_add(el))
                    .and_then(|b| b.checked_add(offset)),
            };
            if needed.is_none_or(|n| n > view_length) {
                return Err(err(AccessorProblem::OutsideView {
                    view: v,
                    offset,
                    stride,
                    count,
                    element: el,
                    view_length,
                }));
            }
            let first = to_usize(view_offset.checked_add(offset), a, count, el)?;
            Some((buffer, first, to_usize(Some(stride), a, count, el)?))
        }
        None if accessor.sparse.is_none() => return Err(err(AccessorProblem::NoData)),
        None => {
            if count.checked_mul(el).is_none_or(|b| b > all_buffers) {
                return Err(err(AccessorProblem::TooLarge {
                    count,
                    element: el,
                    limit: all_buffers,
                }));
            }
            None
        }
    };
    let sparse = match &accessor.sparse {
        Some(s) => Some(sparse_layout(views, a, s, count, el)?),
        None => None,
    };
    Ok(Layout {
        kind,
        component,
        count: to_usize(Some(count), a, count, el)?,
        element,
        dense,
        sparse,
    })
}

/// A sparse accessor's substitutions: at most its `count` elements of `element` bytes,
/// indices and values within their views.
fn sparse_layout(
    views: &[(usize, u64, u64)],
    a: usize,
    s: &gltf::json::accessor::sparse::Sparse,
    count: u64,
    element: u64,
) -> Result<SparseLayout, MeshError> {
    use gltf::json::validation::Checked;
    let err = |problem| MeshError::Accessor {
        accessor: a,
        problem,
    };
    let n = s.count.0;
    if n > count {
        return Err(err(AccessorProblem::SparseCount { sparse: n, count }));
    }
    let Checked::Valid(index_type) = s.indices.component_type else {
        return Err(MeshError::Invalid {
            path: format!("accessors[{a}].sparse.indices.componentType"),
            problem: "not an unsigned integer type".into(),
        });
    };
    let index_size = index_type.0.size() as u64;
    let place = |part: &'static str, view: usize, offset: u64, size: u64| {
        let (buffer, view_offset, view_length) = views.get(view).copied().unwrap_or_default();
        let end = n.checked_mul(size).and_then(|b| b.checked_add(offset));
        if end.is_none_or(|e| e > view_length) {
            return Err(err(AccessorProblem::SparseOutsideView {
                part,
                view,
                offset,
                count: n,
                size,
                view_length,
            }));
        }
        let first = to_usize(view_offset.checked_add(offset), a, count, element)?;
        Ok((buffer, first))
    };
    let indices = place(
        "indices",
        s.indices.buffer_view.value(),
        s.indices.byte_offset.0,
        index_size,
    )?;
    let values = place(
        "values",
        s.values.buffer_view.value(),
        s.values.byte_offset.0,
        element,
    )?;
    Ok(SparseLayout {
        count: to_usize(Some(n), a, count, element)?,
        index_size: index_size as usize,
        indices,
        values,
    })
}

/// The node hierarchy: each node's parent, and every node with parents before children.
struct Forest {
    parent: Vec<Option<usize>>,
    order: Vec<usize>,
}

/// Checks that the nodes make a forest (one parent each, no cycle) and orders them.
fn node_forest(root: &gltf::json::Root) -> Result<Forest, MeshError> {
    let n = root.nodes.len();
    let mut parent: Vec<Option<usize>> = vec![None; n];
    for (p, node) in root.nodes.iter().enumerate() {
        for c in node.children.iter().flatten() {
            let Some(slot) = parent.get_mut(c.value()) else {
                continue;
            };
            if let Some(first) = *slot {
                return Err(MeshError::Node {
                    node: c.value(),
                    problem: NodeProblem::TwoParents { first, second: p },
                });
            }
            *slot = Some(p);
        }
    }
    // Breadth first from the roots: each node has one parent, so it is pushed once.
    let mut order: Vec<usize> = (0..n).filter(|&i| parent[i].is_none()).collect();
    let mut next = 0;
    while let Some(&p) = order.get(next) {
        next += 1;
        for c in root.nodes[p].children.iter().flatten() {
            if c.value() < n {
                order.push(c.value());
            }
        }
    }
    if order.len() < n {
        // The nodes not reached all have a parent not reached: walking up from one
        // comes back to a node on the cycle.
        let mut seen = vec![false; n];
        for &i in &order {
            seen[i] = true;
        }
        let mut i = (0..n).find(|&i| !seen[i]).unwrap_or(0);
        let mut walked = vec![false; n];
        while !walked[i] {
            walked[i] = true;
            i = parent[i].unwrap_or(i);
        }
        return Err(MeshError::Node {
            node: i,
            problem: NodeProblem::Cycle,
        });
    }
    Ok(Forest { parent, order })
}

/// Checks every skin: at most [`MAX_SKIN_JOINTS`] joints, each once.
fn check_skins(root: &gltf::json::Root) -> Result<(), MeshError> {
    for (s, skin) in root.skins.iter().enumerate() {
        let err = |problem| MeshError::Skin { skin: s, problem };
        if skin.joints.len() > MAX_SKIN_JOINTS {
            return Err(err(SkinProblem::TooManyJoints {
                joints: skin.joints.len(),
                max: MAX_SKIN_JOINTS,
            }));
        }
        let mut seen = std::collections::HashSet::with_capacity(skin.joints.len());
        if let Some(j) = skin.joints.iter().find(|j| !seen.insert(j.value())) {
            return Err(err(SkinProblem::DuplicateJoint { node: j.value() }));
        }
    }
    Ok(())
}

/// The buffers' bytes: distinct sources (the GLB `BIN` chunk is borrowed, a file read
/// once however many buffers name it), and which one each buffer uses.
#[derive(Default)]
struct Buffers<'a> {
    data: Vec<std::borrow::Cow<'a, [u8]>>,
    source: Vec<usize>,
    /// Bytes read from external files.
    external_bytes: u64,
}

impl Buffers<'_> {
    /// `len` bytes from byte `first` of a buffer, if its data holds them.
    fn span(&self, buffer: usize, first: usize, len: usize) -> Option<&[u8]> {
        let data = self.data.get(*self.source.get(buffer)?)?;
        data.get(first..first.checked_add(len)?)
    }
}

/// Whether a file of `actual` bytes can hold a buffer of `declared` bytes: that many, or
/// up to 3 more (padding to four bytes, as a GLB chunk may have).
fn file_length_fits(declared: u64, actual: u64) -> bool {
    actual >= declared && actual - declared <= 3
}

/// Loads every buffer's data: the GLB `BIN` chunk for the first buffer without a URI,
/// base64 `data:` URIs, and regular files named by relative paths inside `base`
/// ([`relative_path`], [`confined_file`]).
fn load_buffers<'a>(
    root: &gltf::json::Root,
    mut bin: Option<&'a [u8]>,
    base: Option<&Path>,
) -> Result<Buffers<'a>, MeshError> {
    use std::borrow::Cow;
    let mut out = Buffers::default();
    let mut files: HashMap<std::path::PathBuf, usize> = HashMap::new();
    for (b, buffer) in root.buffers.iter().enumerate() {
        let err = |problem| MeshError::Buffer { buffer: b, problem };
        let declared = buffer.byte_length.0;
        let source = match buffer.uri.as_deref() {
            None => {
                let data = bin.take().ok_or(err(BufferProblem::NoData))?;
                out.data.push(Cow::Borrowed(data));
                out.data.len() - 1
            }
            Some(uri) if uri.starts_with("data:") => {
                out.data
                    .push(Cow::Owned(decode_data_uri(uri).map_err(err)?));
                out.data.len() - 1
            }
            Some(uri) => {
                let relative = relative_path(uri).map_err(err)?;
                let base = base.ok_or_else(|| {
                    err(BufferProblem::NoFolder {
                        uri: shown_uri(uri),
                    })
                })?;
                let path = confined_file(base, &relative, uri).map_err(err)?;
                let source = match files.get(&path) {
                    Some(&s) => s,
                    None => {
                        let data = read_buffer_file(&path, declared).map_err(err)?;
                        out.external_bytes = out.external_bytes.saturating_add(data.len() as u64);
                        out.data.push(Cow::Owned(data));
                        files.insert(path.clone(), out.data.len() - 1);
                        out.data.len() - 1
                    }
                };
                let actual = out.data[source].len() as u64;
                if !file_length_fits(declared, actual) {
                    return Err(err(BufferProblem::FileLength {
                        path: path.display().to_string(),
                        declared,
                        actual,
                    }));
                }
                source
            }
        };
        let actual = out.data[source].len() as u64;
        if actual < declared {
            return Err(err(BufferProblem::Short { declared, actual }));
        }
        out.source.push(source);
    }
    Ok(out)
}

/// A URI as errors show it: its first 64 characters.
fn shown_uri(uri: &str) -> String {
    match uri.char_indices().nth(64) {
        Some((cut, _)) => format!("{}...", &uri[..cut]),
        None => uri.to_string(),
    }
}

/// The bytes of a `data:[<media type>];base64,<data>` URI.
fn decode_data_uri(uri: &str) -> Result<Vec<u8>, BufferProblem> {
    let Some(at) = uri.find(";base64,") else {
        return Err(BufferProblem::Scheme {
            uri: shown_uri(uri),
        });
    };
    decode_base64(&uri.as_bytes()[at + 8..]).map_err(|offset| BufferProblem::Base64 { offset })
}

/// Standard base64 (`A-Z a-z 0-9 + /`, `=` padding optional); the error is the offset of
/// the first character that is not base64, or of a lone last character.
fn decode_base64(text: &[u8]) -> Result<Vec<u8>, usize> {
    let end = text.len()
        - text
            .iter()
            .rev()
            .take(2)
            .take_while(|&&c| c == b'=')
            .count();
    let text = &text[..end];
    let mut out = Vec::with_capacity(text.len() / 4 * 3 + 2);
    let (mut acc, mut bits) = (0u32, 0u32);
    for (i, &c) in text.iter().enumerate() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            _ => return Err(i),
        };
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    if bits == 6 {
        return Err(text.len() - 1);
    }
    Ok(out)
}

/// The relative path a URI without a scheme names, percent-decoded (to UTF-8, or an
/// error) and resolved by its text inside the folder: `/` and `\` both separate
/// components (whether written or percent-encoded), `.` and empty components are
/// dropped, a `..` takes back the component before it. The result holds only plain
/// names. Refused: URIs with a scheme (`file:`, `http:`, a Windows drive `C:`), absolute
/// paths, a NUL byte, and a `..` with no component left to take back (above the
/// folder). Symbolic links are [`confined_file`]'s to check.
fn relative_path(uri: &str) -> Result<std::path::PathBuf, BufferProblem> {
    if uri.contains(':') {
        return Err(BufferProblem::Scheme {
            uri: shown_uri(uri),
        });
    }
    let bad = || BufferProblem::PercentEncoding {
        uri: shown_uri(uri),
    };
    let bytes = uri.as_bytes();
    let mut decoded = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while let Some(&c) = bytes.get(i) {
        if c == b'%' {
            let hex = bytes.get(i + 1..i + 3).ok_or_else(bad)?;
            let hex = std::str::from_utf8(hex).map_err(|_| bad())?;
            decoded.push(u8::from_str_radix(hex, 16).map_err(|_| bad())?);
            i += 3;
        } else {
            decoded.push(c);
            i += 1;
        }
    }
    let path = String::from_utf8(decoded).map_err(|_| bad())?;
    // `%3A` decodes to a drive's colon.
    if path.contains(':') {
        return Err(BufferProblem::Scheme {
            uri: shown_uri(uri),
        });
    }
    if path.contains('\0') {
        return Err(BufferProblem::NulByte {
            uri: shown_uri(uri),
        });
    }
    if path.starts_with('/') || path.starts_with('\\') {
        return Err(BufferProblem::Absolute {
            uri: shown_uri(uri),
        });
    }
    let mut names: Vec<&str> = Vec::new();
    for name in path.split(['/', '\\']) {
        match name {
            "" | "." => {}
            ".." => {
                if names.pop().is_none() {
                    return Err(BufferProblem::OutsideFolder {
                        uri: shown_uri(uri),
                    });
                }
            }
            _ => names.push(name),
        }
    }
    Ok(names.iter().collect())
}

/// The file `relative` (from [`relative_path`]) names under `folder`, with every
/// symbolic link on the way resolved, if it lies in the folder (itself resolved): a link
/// inside the folder to a file inside it is followed, one that leads out is refused
/// before anything is read. The path to read is the resolved one, so what was checked
/// is what is opened (a link swapped in between by someone writing the folder at the
/// same moment is not guarded against).
fn confined_file(
    folder: &Path,
    relative: &Path,
    uri: &str,
) -> Result<std::path::PathBuf, BufferProblem> {
    // A file named without a folder (`mesh.gltf`) has the empty path as its parent.
    let folder = if folder.as_os_str().is_empty() {
        Path::new(".")
    } else {
        folder
    };
    let resolve = |p: &Path| {
        std::fs::canonicalize(p).map_err(|source| BufferProblem::Io {
            path: p.display().to_string(),
            source,
        })
    };
    let inside = resolve(folder)?;
    let target = resolve(&folder.join(relative))?;
    if !target.starts_with(&inside) {
        return Err(BufferProblem::LinkOutsideFolder {
            uri: shown_uri(uri),
        });
    }
    Ok(target)
}

/// A buffer's file: a regular file (not a device or a pipe, which could be endless) of
/// `declared` bytes or up to 3 more, its length checked before reading.
fn read_buffer_file(path: &Path, declared: u64) -> Result<Vec<u8>, BufferProblem> {
    use std::io::Read;
    let shown = || path.display().to_string();
    let io = |source| BufferProblem::Io {
        path: shown(),
        source,
    };
    let check = |meta: &std::fs::Metadata| {
        if !meta.is_file() {
            return Err(BufferProblem::NotAFile { path: shown() });
        }
        if !file_length_fits(declared, meta.len()) {
            return Err(BufferProblem::FileLength {
                path: shown(),
                declared,
                actual: meta.len(),
            });
        }
        Ok(meta.len())
    };
    // Before opening (opening a pipe would wait for a writer), and again on the handle.
    check(&std::fs::metadata(path).map_err(io)?)?;
    let file = std::fs::File::open(path).map_err(io)?;
    let len = check(&file.metadata().map_err(io)?)?;
    let mut data = Vec::with_capacity(usize::try_from(len).unwrap_or(0));
    file.take(len).read_to_end(&mut data).map_err(io)?;
    if data.len() as u64 != len {
        return Err(BufferProblem::FileLength {
            path: shown(),
            declared,
            actual: data.len() as u64,
        });
    }
    Ok(data)
}

/// The sizes of the output, once every triangle primitive is checked.
struct Totals {
    vertices: usize,
    indices: usize,
    /// The most indices of one primitive.
    largest: usize,
}

/// Where a primitive's positions are: its POSITION accessor, a VEC3 of floats.
fn position_accessor(
    prim: &gltf::json::mesh::Primitive,
    layouts: &[Layout],
) -> Result<usize, PrimitiveProblem> {
    use gltf::json::accessor::{ComponentType, Type};
    use gltf::json::validation::Checked;
    let a = prim
        .attributes
        .get(&Checked::Valid(gltf::json::mesh::Semantic::Positions))
        .ok_or(PrimitiveProblem::NoPositions)?
        .value();
    let layout = layouts.get(a).ok_or(PrimitiveProblem::NoPositions)?;
    if layout.kind != Type::Vec3 || layout.component != ComponentType::F32 {
        return Err(PrimitiveProblem::PositionFormat {
            accessor: a,
            accessor_type: type_name(layout.kind),
            component_type: layout.component.as_gl_enum(),
        });
    }
    Ok(a)
}

/// The number of a primitive's indices, from an accessor of unsigned integers.
fn index_count(a: usize, layouts: &[Layout]) -> Result<usize, PrimitiveProblem> {
    use gltf::json::accessor::{ComponentType::*, Type};
    let Some(layout) = layouts.get(a) else {
        return Ok(0);
    };
    if layout.kind != Type::Scalar || !matches!(layout.component, U8 | U16 | U32) {
        return Err(PrimitiveProblem::IndexFormat {
            accessor: a,
            accessor_type: type_name(layout.kind),
            component_type: layout.component.as_gl_enum(),
        });
    }
    Ok(layout.count)
}

/// Every triangle primitive of every mesh node in the reader's order (mesh nodes in
/// document order, their triangle primitives in order), as the node, its mesh's index,
/// the mesh, the primitive's index in the mesh, and the primitive.
fn triangle_primitives(
    root: &gltf::json::Root,
) -> impl Iterator<
    Item = (
        usize,
        &gltf::json::Node,
        usize,
        &gltf::json::Mesh,
        usize,
        &gltf::json::mesh::Primitive,
    ),
> {
    root.nodes
        .iter()
        .enumerate()
        .filter_map(|(n, node)| {
            let m = node.mesh?.value();
            Some((n, node, m, root.meshes.get(m)?))
        })
        .flat_map(|(n, node, m, mesh)| {
            mesh.primitives
                .iter()
                .enumerate()
                .filter(|(_, prim)| is_triangles(prim))
                .map(move |(p, prim)| (n, node, m, mesh, p, prim))
        })
}

/// The error of primitive `p` of mesh `m` (`mesh`) for a problem with it.
fn primitive_error(
    m: usize,
    mesh: &gltf::json::Mesh,
    p: usize,
) -> impl Fn(PrimitiveProblem) -> MeshError + Copy + '_ {
    move |problem| MeshError::Primitive {
        at: PrimitiveAt {
            mesh: m,
            name: mesh.name.clone(),
            primitive: p,
        },
        problem,
    }
}

/// Whether a primitive is read (a triangle list).
fn is_triangles(prim: &gltf::json::mesh::Primitive) -> bool {
    prim.mode == gltf::json::validation::Checked::Valid(gltf::json::mesh::Mode::Triangles)
}

/// Checks every triangle primitive of every mesh node (formats, counts) and the output's
/// size against the budgets for `input_len` bytes of input.
fn check_primitives(
    root: &gltf::json::Root,
    layouts: &[Layout],
    input_len: u64,
) -> Result<Totals, MeshError> {
    let vertex_budget = (GLTF_VERTEX_ALLOWANCE + input_len / 4).min(u32::MAX.into());
    let index_budget = GLTF_INDEX_ALLOWANCE.saturating_add(input_len);
    let (mut vertices, mut indices, mut largest) = (0u64, 0u64, 0usize);
    for (_, _, m, mesh, p, prim) in triangle_primitives(root) {
        let err = primitive_error(m, mesh, p);
        let a = position_accessor(prim, layouts).map_err(err)?;
        let count = layouts[a].count;
        let (n, indexed) = match prim.indices {
            Some(ix) => (index_count(ix.value(), layouts).map_err(err)?, true),
            None => (count, false),
        };
        if n % 3 != 0 {
            return Err(err(PrimitiveProblem::NotTriangles { count: n, indexed }));
        }
        vertices = vertices.saturating_add(count as u64);
        indices = indices.saturating_add(n as u64);
        if indexed {
            largest = largest.max(n);
        }
        for (what, total, budget) in [
            ("vertices", vertices, vertex_budget),
            ("indices", indices, index_budget),
        ] {
            if total > budget {
                return Err(err(PrimitiveProblem::OverBudget {
                    what,
                    total,
                    budget,
                    input_len,
                }));
            }
        }
    }
    Ok(Totals {
        vertices: vertices as usize,
        indices: indices as usize,
        largest,
    })
}

/// Each node's world matrix (the crate's TRS arithmetic, under `catch_unwind`, then
/// products down the forest).
fn world_matrices(
    root: &gltf::json::Root,
    forest: &Forest,
    file: &str,
) -> Result<Vec<DMat4>, MeshError> {
    use gltf::scene::Transform;
    let mut world: Vec<DMat4> = guarded(file, "computing node transforms", || {
        root.nodes
            .iter()
            .map(|n| {
                let t = match n.matrix {
                    Some(m) => Transform::Matrix {
                        matrix: [
                            [m[0], m[1], m[2], m[3]],
                            [m[4], m[5], m[6], m[7]],
                            [m[8], m[9], m[10], m[11]],
                            [m[12], m[13], m[14], m[15]],
                        ],
                    },
                    None => Transform::Decomposed {
                        translation: n.translation.unwrap_or([0.0; 3]),
                        rotation: n.rotation.unwrap_or_default().0,
                        scale: n.scale.unwrap_or([1.0; 3]),
                    },
                };
                DMat4::from_cols_array_2d(&t.matrix().map(|c| c.map(f64::from)))
            })
            .collect()
    })?;
    for &i in &forest.order {
        if let Some(p) = forest.parent[i] {
            world[i] = world[p] * world[i];
        }
    }
    Ok(world)
}

/// Float `k` of little-endian bytes (zero past their end: an accessor without a view).
fn le_f32(bytes: &[u8], k: usize) -> f32 {
    let mut word = [0u8; 4];
    if let Some(b) = bytes.get(4 * k..4 * k + 4) {
        word.copy_from_slice(b);
    }
    f32::from_le_bytes(word)
}

/// An unsigned integer of `size` (1, 2 or 4) little-endian bytes (zero past their end).
fn le_uint(bytes: &[u8], size: usize) -> u32 {
    let mut word = [0u8; 4];
    if let Some(b) = bytes.get(..size.min(4)) {
        word[..b.len()].copy_from_slice(b);
    }
    u32::from_le_bytes(word)
}

/// Appends an accessor's elements, each decoded from its bytes (from none when the
/// accessor has no view: zeros), then puts its sparse values in their places.
fn read_accessor<T>(
    layout: &Layout,
    accessor: usize,
    buffers: &Buffers,
    decode: impl Fn(&[u8]) -> T,
    out: &mut Vec<T>,
) -> Result<(), MeshError> {
    let err = |problem| MeshError::Accessor { accessor, problem };
    let start = out.len();
    match layout.dense {
        Some((buffer, first, stride)) if layout.count > 0 => {
            // Checked against the view when the layout was made.
            let len = stride * (layout.count - 1) + layout.element;
            let span = buffers
                .span(buffer, first, len)
                .ok_or(err(AccessorProblem::Unreadable))?;
            out.extend(span.chunks(stride).map(&decode));
        }
        Some(_) => {}
        None => out.extend((0..layout.count).map(|_| decode(&[]))),
    }
    if let Some(s) = &layout.sparse {
        let unreadable = || err(AccessorProblem::Unreadable);
        let indices = buffers
            .span(s.indices.0, s.indices.1, s.count * s.index_size)
            .ok_or_else(unreadable)?;
        let values = buffers
            .span(s.values.0, s.values.1, s.count * layout.element)
            .ok_or_else(unreadable)?;
        let pairs = indices
            .chunks_exact(s.index_size)
            .zip(values.chunks_exact(layout.element));
        for (entry, (i, v)) in pairs.enumerate() {
            let index = le_uint(i, s.index_size);
            let slot = (index as usize)
                .checked_add(start)
                .filter(|_| (index as usize) < layout.count)
                .and_then(|k| out.get_mut(k))
                .ok_or(err(AccessorProblem::SparseIndex {
                    entry,
                    index,
                    count: layout.count as u64,
                }))?;
            *slot = decode(v);
        }
    }
    Ok(())
}

/// Every triangle primitive of every mesh node, positions placed by `world` (unskinned
/// nodes), into vectors of their final sizes.
fn read_meshes(
    root: &gltf::json::Root,
    layouts: &[Layout],
    buffers: &Buffers,
    world: &[DMat4],
    totals: &Totals,
) -> Result<MeshData, MeshError> {
    let mut out = MeshData {
        positions: Vec::with_capacity(totals.vertices),
        triangles: Vec::with_capacity(totals.indices / 3),
        ..MeshData::default()
    };
    let mut indices: Vec<u32> = Vec::with_capacity(totals.largest);
    for (n, node, m, mesh, p, prim) in triangle_primitives(root) {
        let xf = match node.skin {
            Some(_) => DMat4::IDENTITY,
            None => world.get(n).copied().unwrap_or(DMat4::IDENTITY),
        };
        let err = primitive_error(m, mesh, p);
        let a = position_accessor(prim, layouts).map_err(err)?;
        let base = out.positions.len() as u32;
        let first_triangle = out.triangles.len() as u32;
        let point = |b: &[u8]| {
            let p = [le_f32(b, 0), le_f32(b, 1), le_f32(b, 2)];
            xf.transform_point3(DVec3::from_array(p.map(f64::from)))
        };
        read_accessor(&layouts[a], a, buffers, point, &mut out.positions)?;
        let count = out.positions.len() as u32 - base;
        let name = node.name.clone().or(mesh.name.clone());
        let name = name.unwrap_or_else(|| format!("nodes[{n}]"));
        let several = mesh.primitives.iter().filter(|p| is_triangles(p)).count() > 1;
        out.parts.push(MeshPart {
            name: if several { format!("{name}/{p}") } else { name },
            first_triangle,
            triangle_count: 0,
            first_vertex: base,
            vertex_count: count,
        });
        out.part_nodes.push(n);
        let Some(ix) = prim.indices.map(|i| i.value()) else {
            let tris = (0..count / 3).map(|t| [0, 1, 2].map(|k| base + 3 * t + k));
            out.triangles.extend(tris);
            if let Some(part) = out.parts.last_mut() {
                part.triangle_count = out.triangles.len() as u32 - first_triangle;
            }
            continue;
        };
        let size = layouts[ix].component.size();
        indices.clear();
        read_accessor(
            &layouts[ix],
            ix,
            buffers,
            |b| le_uint(b, size),
            &mut indices,
        )?;
        for t in indices.chunks_exact(3) {
            if let Some(&index) = t.iter().find(|&&i| i >= count) {
                return Err(err(PrimitiveProblem::IndexOutOfRange {
                    index,
                    vertices: count,
                }));
            }
            out.triangles.push([t[0] + base, t[1] + base, t[2] + base]);
        }
        if let Some(part) = out.parts.last_mut() {
            part.triangle_count = out.triangles.len() as u32 - first_triangle;
        }
    }
    Ok(out)
}

/// Largest difference between skinning matrices at rest that still counts as none: on
/// their rotation and scale entries (relative to the largest), and on their translation
/// as a share of the mesh's extent (exporters' float rounding stays below 1e-5).
const SAME_MATRIX: f64 = 1e-4;

/// The transform every skinned vertex takes at rest when all of it is one: glTF shows a
/// skinned vertex at `Σ_k w_k · world_k · inverse_bind_k · v` (§3.7.3), and when every
/// joint's `world_k · inverse_bind_k` at rest is the same matrix `C` (the rest pose is
/// the bind pose) and `C` is not the identity, the file's bind space is not its world:
/// an armature node above the joints carries a unit scale or an axis turn. Then `C`
/// places the mesh as a viewer shows it; `None` when it is the identity, when a skin
/// gives no inverse bind matrices, or when the joints disagree (a rest pose other than
/// the bind pose, as an exporter leaves a take's frame in the nodes: the bind pose,
/// which the skin was made on, is kept).
fn rest_transform(
    root: &gltf::json::Root,
    layouts: &[Layout],
    buffers: &Buffers,
    world: &[DMat4],
    positions: &[DVec3],
) -> Result<Option<DMat4>, MeshError> {
    let skinned = root.nodes.iter().filter_map(|n| n.mesh.and(n.skin));
    let mut skins: Vec<usize> = skinned.map(|s| s.value()).collect();
    skins.sort_unstable();
    skins.dedup();
    let (lo, hi) = crate::geom::shapes::bounds(positions);
    let extent = (hi - lo).max_element().max(f64::MIN_POSITIVE);
    let mut common: Option<DMat4> = None;
    for s in skins {
        // A skin without inverse bind matrices defines no bind pose apart from its
        // joints: its stored positions are read as they are.
        if root.skins[s].inverse_bind_matrices.is_none() {
            return Ok(None);
        }
        let ibm = inverse_binds(root, s, layouts, buffers)?;
        for (j, ibm) in root.skins[s].joints.iter().zip(&ibm) {
            let m = world.get(j.value()).copied().unwrap_or(DMat4::IDENTITY) * *ibm;
            match common {
                None => common = Some(m),
                Some(c) if !same_matrix(&c, &m, extent) => return Ok(None),
                Some(_) => {}
            }
        }
    }
    Ok(common.filter(|c| c.is_finite() && !same_matrix(c, &DMat4::IDENTITY, extent)))
}

/// Whether `a` and `b` agree within [`SAME_MATRIX`] (`extent`: the mesh's, for the
/// translations).
fn same_matrix(a: &DMat4, b: &DMat4, extent: f64) -> bool {
    let size = (0..3)
        .map(|c| a.col(c).truncate().length())
        .fold(0.0, f64::max)
        .max(f64::MIN_POSITIVE);
    let d = *a - *b;
    let linear = (0..3).flat_map(|c| (0..3).map(move |r| (c, r)));
    linear.map(|(c, r)| d.col(c)[r].abs()).fold(0.0, f64::max) <= SAME_MATRIX * size
        && d.w_axis.truncate().abs().max_element() <= SAME_MATRIX * size * extent
}

/// A primitive's `JOINTS_0` (unsigned bytes or shorts) and `WEIGHTS_0` (floats, or
/// normalised unsigned bytes or shorts), non-finite and negative weights read as 0.
fn read_influences(
    prim: &gltf::json::mesh::Primitive,
    layouts: &[Layout],
    buffers: &Buffers,
    joints: &mut Vec<[u16; 4]>,
    weights: &mut Vec<[f32; 4]>,
) -> Result<(), String> {
    use gltf::json::accessor::{ComponentType, Type};
    use gltf::json::mesh::Semantic;
    use gltf::json::validation::Checked;
    let get = |sem: Semantic, what: &str| -> Result<(usize, &Layout), String> {
        let a = prim
            .attributes
            .get(&Checked::Valid(sem))
            .ok_or_else(|| format!("no {what}"))?
            .value();
        let l = layouts.get(a).ok_or_else(|| format!("no {what}"))?;
        if l.kind != Type::Vec4 {
            return Err(format!(
                "{what} accessors[{a}] is {}, not VEC4",
                type_name(l.kind)
            ));
        }
        Ok((a, l))
    };
    let (ja, jl) = get(Semantic::Joints(0), "JOINTS_0")?;
    let (wa, wl) = get(Semantic::Weights(0), "WEIGHTS_0")?;
    let jsize = match jl.component {
        ComponentType::U8 => 1,
        ComponentType::U16 => 2,
        c => {
            return Err(format!(
                "JOINTS_0 accessors[{ja}] has componentType {}",
                c.as_gl_enum()
            ))
        }
    };
    joints.clear();
    weights.clear();
    read_accessor(
        jl,
        ja,
        buffers,
        |b| std::array::from_fn(|k| le_uint(b.get(k * jsize..).unwrap_or(&[]), jsize) as u16),
        joints,
    )
    .map_err(|e| e.to_string())?;
    let clean = |x: f32| if x.is_finite() && x > 0.0 { x } else { 0.0 };
    let decoded = match wl.component {
        ComponentType::F32 => read_accessor(
            wl,
            wa,
            buffers,
            |b| std::array::from_fn(|k| clean(le_f32(b, k))),
            weights,
        ),
        ComponentType::U8 => read_accessor(
            wl,
            wa,
            buffers,
            |b| std::array::from_fn(|k| f32::from(*b.get(k).unwrap_or(&0)) / 255.0),
            weights,
        ),
        ComponentType::U16 => read_accessor(
            wl,
            wa,
            buffers,
            |b| std::array::from_fn(|k| le_uint(b.get(2 * k..).unwrap_or(&[]), 2) as f32 / 65535.0),
            weights,
        ),
        c => {
            return Err(format!(
                "WEIGHTS_0 accessors[{wa}] has componentType {}",
                c.as_gl_enum()
            ))
        }
    };
    decoded.map_err(|e| e.to_string())
}

/// Skin `s`'s inverse bind matrices (identities when it gives none).
fn inverse_binds(
    root: &gltf::json::Root,
    s: usize,
    layouts: &[Layout],
    buffers: &Buffers,
) -> Result<Vec<DMat4>, MeshError> {
    use gltf::json::accessor::{ComponentType, Type};
    let Some(skin) = root.skins.get(s) else {
        return Ok(Vec::new());
    };
    let err = |problem| MeshError::Skin { skin: s, problem };
    let joints = skin.joints.len();
    Ok(match skin.inverse_bind_matrices.map(|a| a.value()) {
        Some(a) => {
            let layout = &layouts[a];
            if layout.kind != Type::Mat4 || layout.component != ComponentType::F32 {
                return Err(err(SkinProblem::MatrixFormat {
                    accessor: a,
                    accessor_type: type_name(layout.kind),
                    component_type: layout.component.as_gl_enum(),
                }));
            }
            if layout.count != joints {
                return Err(err(SkinProblem::MatrixCount {
                    joints,
                    matrices: layout.count,
                }));
            }
            let matrix =
                |b: &[u8]| DMat4::from_cols_array(&std::array::from_fn(|k| le_f32(b, k).into()));
            let mut m = Vec::with_capacity(joints);
            read_accessor(layout, a, buffers, matrix, &mut m)?;
            m
        }
        None => vec![DMat4::IDENTITY; joints],
    })
}

/// Which vertices of `out` belong to skinned mesh nodes (the parts in the reader's
/// order: mesh nodes in document order, their triangle primitives in order).
fn skinned_vertices(root: &gltf::json::Root, out: &MeshData) -> Vec<bool> {
    let mut skinned = vec![false; out.positions.len()];
    for (part, (_, node, ..)) in triangle_primitives(root).enumerate() {
        if let (Some(q), true) = (out.parts.get(part), node.skin.is_some()) {
            let first = q.first_vertex as usize;
            let range = first..first + q.vertex_count as usize;
            skinned[range].iter_mut().for_each(|s| *s = true);
        }
    }
    skinned
}

/// The joints of skin `s`, parents first (by depth among the joints, the skin's order
/// among equals), each with the nearest ancestor that is a joint as its parent; placed
/// by the inverse bind matrices, or by the nodes' rest transforms `posed_at` when the
/// mesh was taken to the world ([`rest_transform`]); each marked weighted as
/// `influences` say, or when an unskinned mesh node hangs from it.
fn read_skin(
    root: &gltf::json::Root,
    s: usize,
    (layouts, buffers, forest): (&[Layout], &Buffers, &Forest),
    posed_at: Option<&[DMat4]>,
    influences: &Influences,
) -> Result<Vec<SkinJoint>, MeshError> {
    let Some(skin) = root.skins.get(s) else {
        return Ok(Vec::new());
    };
    let joints: Vec<usize> = skin.joints.iter().map(|j| j.value()).collect();
    let ibm = inverse_binds(root, s, layouts, buffers)?;
    let mut weighted: Vec<bool> = joints
        .iter()
        .map(|&n| !influences.read_any || influences.weighted_node.get(n).copied().unwrap_or(true))
        .collect();
    // Down the forest once: each node's nearest ancestor that is a joint, and each
    // joint's parent joint and depth among the joints.
    let slot: HashMap<usize, usize> = joints.iter().enumerate().map(|(k, &n)| (n, k)).collect();
    // A joint an unskinned mesh node hangs from carries that mesh (a head modelled
    // apart and parented to its joint) as a weighted joint carries its skin.
    for (n, node) in root.nodes.iter().enumerate() {
        if node.mesh.is_none() || node.skin.is_some() {
            continue;
        }
        let mut up = forest.parent.get(n).copied().flatten();
        while let Some(a) = up {
            if let Some(&k) = slot.get(&a) {
                if let Some(w) = weighted.get_mut(k) {
                    *w = true;
                }
                break;
            }
            up = forest.parent.get(a).copied().flatten();
        }
    }
    let mut nearest: Vec<Option<usize>> = vec![None; root.nodes.len()];
    let mut joint_parent: Vec<Option<usize>> = vec![None; joints.len()];
    let mut depth = vec![0usize; joints.len()];
    for &i in &forest.order {
        let up = forest.parent[i].and_then(|p| slot.get(&p).copied().or(nearest[p]));
        nearest[i] = up;
        if let Some(&k) = slot.get(&i) {
            joint_parent[k] = up;
            depth[k] = up.map_or(0, |p| depth[p] + 1);
        }
    }
    let mut order: Vec<usize> = (0..joints.len()).collect();
    order.sort_by_key(|&k| (depth[k], k));
    let mut new_index = vec![0; joints.len()];
    for (n, &k) in order.iter().enumerate() {
        new_index[k] = n;
    }
    // Names as the file gives them; a joint without a name, or whose name an earlier
    // joint already has, is named after its node (`joint12`, `Hand#12`): stable for the
    // file, and unique, as a skeleton's names must be.
    let mut taken = std::collections::HashSet::with_capacity(order.len());
    Ok(order
        .iter()
        .map(|&k| {
            let node = joints[k];
            let name = match &root.nodes[node].name {
                Some(n) if taken.insert(n.clone()) => n.clone(),
                Some(n) => format!("{n}#{node}"),
                None => format!("joint{node}"),
            };
            taken.insert(name.clone());
            SkinJoint {
                name,
                parent: joint_parent[k].map(|p| new_index[p]),
                world_from_joint: match posed_at {
                    Some(world) => world.get(node).copied().unwrap_or(DMat4::IDENTITY),
                    None => ibm[k].inverse(),
                },
                weighted: weighted.get(k).copied().unwrap_or(true),
            }
        })
        .collect())
}

/// The surface as one welded soup (positions closer than 1e-9 of its size merged, so
/// that parts split by UV seams count as one), its parts oriented outward
/// ([`orient_parts`]), and whether it was clean before (closed, manifold, consistently
/// oriented): what winding numbers and enclosed volumes need.
pub fn welded_outward(
    vertices: &[DVec3],
    triangles: &[[u32; 3]],
) -> (Vec<DVec3>, Vec<[u32; 3]>, bool) {
    let (lo, hi) = crate::geom::shapes::bounds(vertices);
    let (ids, unique) = weld(vertices, 1e-9 * (hi - lo).length());
    let welded: Vec<[u32; 3]> = triangles
        .iter()
        .map(|t| t.map(|i| ids[i as usize]))
        .collect();
    let clean = surface_issues(&welded).is_clean();
    let (oriented, _) = orient_parts(&unique, &welded);
    (unique, oriented, clean)
}

/// Welds positions closer than `tolerance`: returns, per input vertex, its welded index,
/// and the welded positions (first occurrence wins, file order kept).
pub fn weld(positions: &[DVec3], tolerance: f64) -> (Vec<u32>, Vec<DVec3>) {
    let cell = tolerance.max(f64::MIN_POSITIVE) * 2.0;
    let key = |p: DVec3| {
        let q = (p / cell).floor();
        (q.x as i64, q.y as i64, q.z as i64)
    };
    let mut grid: HashMap<(i64, i64, i64), Vec<u32>> = HashMap::new();
    let mut map = Vec::with_capacity(positions.len());
    let mut welded: Vec<DVec3> = Vec::new();
    for &p in positions {
        let (kx, ky, kz) = key(p);
        let mut hit = None;
        'search: for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(list) = grid.get(&(kx + dx, ky + dy, kz + dz)) {
                        for &w in list {
                            if (welded[w as usize] - p).length() <= tolerance {
                                hit = Some(w);
                                break 'search;
                            }
                        }
                    }
                }
            }
        }
        let w = hit.unwrap_or_else(|| {
            welded.push(p);
            let w = (welded.len() - 1) as u32;
            grid.entry((kx, ky, kz)).or_default().push(w);
            w
        });
        map.push(w);
    }
    (map, welded)
}

/// What is wrong with a surface for the solver (all counts; empty when closed,
/// manifold, consistently oriented and free of degenerate triangles).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SurfaceIssues {
    /// Edges used by one triangle only (holes), with one example edge.
    pub open_edges: usize,
    pub open_example: Option<(u32, u32)>,
    /// Edges used by more than two triangles.
    pub non_manifold_edges: usize,
    pub non_manifold_example: Option<(u32, u32)>,
    /// Edges whose two triangles run them in the same direction (flipped neighbours).
    pub inconsistent_edges: usize,
    /// Triangles with a repeated vertex.
    pub degenerate_triangles: usize,
}

impl SurfaceIssues {
    pub fn is_clean(&self) -> bool {
        self.open_edges == 0 && self.non_manifold_edges == 0 && self.inconsistent_edges == 0
    }
}

/// Checks a (welded) triangle surface.
pub fn surface_issues(triangles: &[[u32; 3]]) -> SurfaceIssues {
    let mut edges: HashMap<(u32, u32), (u32, i32)> = HashMap::new();
    let mut out = SurfaceIssues::default();
    for t in triangles {
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            out.degenerate_triangles += 1;
            continue;
        }
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let e = edges.entry((a.min(b), a.max(b))).or_default();
            e.0 += 1;
            e.1 += if a < b { 1 } else { -1 };
        }
    }
    let mut keys: Vec<_> = edges.into_iter().collect();
    keys.sort_unstable_by_key(|(k, _)| *k);
    for (e, (count, dir)) in keys {
        match count {
            1 => {
                out.open_edges += 1;
                out.open_example.get_or_insert(e);
            }
            2 if dir != 0 => out.inconsistent_edges += 1,
            2 => {}
            _ => {
                out.non_manifold_edges += 1;
                out.non_manifold_example.get_or_insert(e);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const CUBE: &str = "# a cube
o cube
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 2/1/1 3/1/1 7/1/1 6/1/1
f 3 4 8 7
f -4 -1 -5 -8
g helper
v 5 5 5
v 6 5 5
v 5 6 5
f 9 10 11
";

    #[test]
    fn obj_cube_is_closed_and_keeps_file_order() {
        let m = parse_obj(CUBE.as_bytes(), &["cube".into()]).unwrap();
        assert_eq!(m.positions.len(), 8);
        assert_eq!(m.triangles.len(), 12);
        assert_eq!(m.positions[6], DVec3::ONE);
        assert!(
            surface_issues(&m.triangles).is_clean(),
            "{:?}",
            surface_issues(&m.triangles)
        );
        let all = parse_obj(CUBE.as_bytes(), &[]).unwrap();
        assert_eq!((all.positions.len(), all.triangles.len()), (11, 13));
        let issues = surface_issues(&all.triangles);
        assert_eq!(issues.open_edges, 3, "the helper triangle is open");
        let part = |name: &str, t: [u32; 2], v: [u32; 2]| MeshPart {
            name: name.into(),
            first_triangle: t[0],
            triangle_count: t[1],
            first_vertex: v[0],
            vertex_count: v[1],
        };
        assert_eq!(m.parts, vec![part("cube", [0, 12], [0, 8])]);
        assert_eq!(
            all.parts,
            vec![
                part("cube", [0, 12], [0, 8]),
                part("helper", [12, 1], [8, 3])
            ]
        );
    }

    /// Each triangle primitive of each mesh node is a part, named by its node (its mesh
    /// when the node has no name), with `/K` when the mesh has several primitives.
    #[test]
    fn gltf_parts_are_the_primitives() {
        let dir = tempfile::tempdir().unwrap();
        let tri: Vec<u8> = [0f32, 0., 0., 1., 0., 0., 0., 1., 0.]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        std::fs::write(dir.path().join("b.bin"), tri.repeat(3)).unwrap();
        let acc = |k: usize| {
            format!(
                r#"{{"bufferView":0,"byteOffset":{},"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}"#,
                36 * k
            )
        };
        let doc = format!(
            r#"{{"asset":{{"version":"2.0"}},
            "buffers":[{{"uri":"b.bin","byteLength":108}}],
            "bufferViews":[{{"buffer":0,"byteLength":108}}],
            "accessors":[{},{},{}],
            "meshes":[{{"name":"bodymesh","primitives":[{{"attributes":{{"POSITION":0}}}},{{"attributes":{{"POSITION":1}}}}]}},
                      {{"name":"eye","primitives":[{{"attributes":{{"POSITION":2}}}}]}}],
            "nodes":[{{"name":"body","mesh":0}},{{"mesh":1}}]}}"#,
            acc(0),
            acc(1),
            acc(2)
        );
        let m = parse_gltf(doc.as_bytes(), Some(dir.path())).unwrap();
        let part = |name: &str, k: u32| MeshPart {
            name: name.into(),
            first_triangle: k,
            triangle_count: 1,
            first_vertex: 3 * k,
            vertex_count: 3,
        };
        assert_eq!(
            m.parts,
            vec![part("body/0", 0), part("body/1", 1), part("eye", 2)]
        );
    }

    #[test]
    fn obj_errors_name_the_line() {
        let bad = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n";
        let e = parse_obj(bad.as_bytes(), &[]).unwrap_err().to_string();
        assert!(
            e.starts_with("line 4:") && e.contains("outside the 3"),
            "{e}"
        );
        let e = parse_obj(b"v 0 nan 0\n", &[]).unwrap_err().to_string();
        assert!(e.starts_with("line 1:") && e.contains("not finite"), "{e}");
        let e = parse_obj(CUBE.as_bytes(), &["body".into()])
            .unwrap_err()
            .to_string();
        assert!(e.contains("\"body\"") && e.contains("\"cube\""), "{e}");
    }

    #[test]
    fn welding_merges_seam_duplicates_only() {
        let p = vec![
            DVec3::ZERO,
            DVec3::X,
            DVec3::new(1e-9, 0.0, 0.0),
            DVec3::new(0.5, 0.0, 0.0),
            DVec3::X * (1.0 + 1e-9),
        ];
        let (map, w) = weld(&p, 1e-6);
        assert_eq!(map, vec![0, 1, 0, 2, 1]);
        assert_eq!(w.len(), 3);
    }

    #[test]
    fn a_panic_in_the_crate_becomes_an_error_naming_the_file() {
        let e = guarded("hand.glb", "testing", || -> u32 { panic!("boom") }).unwrap_err();
        assert_eq!(
            e.to_string(),
            "hand.glb: the gltf crate panicked while testing: boom"
        );
        // The crate's validation itself, on the audit's document without our reference
        // check first: its hook indexes `accessors[5]` unchecked and panics.
        let doc = br#"{"asset":{"version":"2.0"},"meshes":[{"primitives":[{"attributes":{"POSITION":5}}]}]}"#;
        let root = read_json(doc, "oob.gltf").unwrap();
        match crate_validation(&root, "oob.gltf") {
            Err(MeshError::Panicked { file, stage, .. }) => {
                assert_eq!(
                    (file.as_str(), stage),
                    ("oob.gltf", "validating the document")
                )
            }
            other => panic!("{other:?}"),
        }
        assert!(matches!(
            check_references(&root),
            Err(MeshError::Reference { index: 5, .. })
        ));
    }

    #[test]
    fn base64_and_percent_decoding_refuse_what_they_cannot_decode() {
        assert_eq!(decode_base64(b"aGFuZA=="), Ok(b"hand".to_vec()));
        assert_eq!(decode_base64(b"aGFuZA"), Ok(b"hand".to_vec()));
        assert_eq!(decode_base64(b"aGFuZGE="), Ok(b"handa".to_vec()));
        assert_eq!(decode_base64(b""), Ok(Vec::new()));
        assert_eq!(decode_base64(b"aG Fu"), Err(2));
        assert_eq!(decode_base64(b"aGFuZ"), Err(4));
        assert_eq!(
            relative_path("a%20b/c.bin").unwrap(),
            std::path::PathBuf::from("a b/c.bin")
        );
        for (uri, absolute) in [
            ("%FF", false),
            ("a%2", false),
            ("%zz", false),
            ("%2Fetc", true),
        ] {
            match relative_path(uri) {
                Err(BufferProblem::Absolute { .. }) => assert!(absolute, "{uri}"),
                Err(BufferProblem::PercentEncoding { .. }) => assert!(!absolute, "{uri}"),
                other => panic!("{uri}: {other:?}"),
            }
        }
        assert!(matches!(
            relative_path("file:///dev/zero"),
            Err(BufferProblem::Scheme { .. })
        ));
        assert_eq!(
            shown_uri(&"é".repeat(100)),
            format!("{}...", "é".repeat(64))
        );
    }

    /// Every spelling of a way out of the folder is refused by the URI's text, with the
    /// URI named: `..` written or percent-encoded in either case, behind slashes or
    /// backslashes (written or encoded), after names it takes back; absolute paths,
    /// drives (written or encoded), NUL bytes. Paths that stay inside resolve to their
    /// plain names.
    #[test]
    fn buffer_uris_that_leave_the_folder_are_refused_by_their_text() {
        use std::path::PathBuf;
        let refusal = |uri: &str| match relative_path(uri) {
            Err(p @ BufferProblem::OutsideFolder { .. }) => ("outside", p),
            Err(p @ BufferProblem::Absolute { .. }) => ("absolute", p),
            Err(p @ BufferProblem::Scheme { .. }) => ("scheme", p),
            Err(p @ BufferProblem::NulByte { .. }) => ("nul", p),
            other => panic!("{uri}: {other:?}"),
        };
        for (uri, want) in [
            ("../../../../../../etc/passwd", "outside"),
            ("..", "outside"),
            ("%2e%2e/etc/passwd", "outside"),
            ("%2E%2e/etc/passwd", "outside"),
            (".%2E%2Fx", "outside"),
            ("..\\..\\x", "outside"),
            ("..%5cx", "outside"),
            ("%2e%2e%5C%2e%2e%5Cx", "outside"),
            ("a/../../x", "outside"),
            ("a\\b\\..\\..\\..\\x", "outside"),
            ("././/../x", "outside"),
            ("/etc/passwd", "absolute"),
            ("\\etc\\passwd", "absolute"),
            ("%2fetc/passwd", "absolute"),
            ("%5Cetc", "absolute"),
            ("C:\\x.bin", "scheme"),
            ("C%3a/x.bin", "scheme"),
            ("a%00/../b.bin", "nul"),
            ("a\0b.bin", "nul"),
        ] {
            let (got, problem) = refusal(uri);
            assert_eq!(got, want, "{uri}");
            // The URI is named as given (shortened past 64 characters), nothing else.
            let text = problem.to_string();
            assert!(
                text.starts_with(&format!("uri {:?}: ", shown_uri(uri))),
                "{text}"
            );
        }
        for (uri, want) in [
            ("a/../b.bin", "b.bin"),
            ("./sub//mesh.bin", "sub/mesh.bin"),
            ("sub\\mesh.bin", "sub/mesh.bin"),
            ("sub%5Cmesh.bin", "sub/mesh.bin"),
            ("sub%2F..%2Fmesh.bin", "mesh.bin"),
            ("..a/b..", "..a/b.."),
            ("...", "..."),
        ] {
            assert_eq!(relative_path(uri).unwrap(), PathBuf::from(want), "{uri}");
        }
    }

    /// What the test expects of a URI, computed another way than [`relative_path`]: the
    /// decoded text (`None` when an escape is bad or the bytes are not UTF-8), and the
    /// names it leaves inside the folder (`None` when it is refused: a colon, a NUL, a
    /// leading separator, or a `..` above the folder).
    fn expected_names(uri: &str) -> Option<Vec<String>> {
        let mut bytes = Vec::new();
        let mut rest = uri.as_bytes();
        while let Some((&c, tail)) = rest.split_first() {
            if c != b'%' {
                bytes.push(c);
                rest = tail;
                continue;
            }
            let hex = std::str::from_utf8(tail.get(..2)?).ok()?;
            bytes.push(u8::from_str_radix(hex, 16).ok()?);
            rest = &tail[2..];
        }
        let text = String::from_utf8(bytes).ok()?;
        if text.contains([':', '\0']) || text.starts_with(['/', '\\']) {
            return None;
        }
        let mut depth = 0usize;
        let mut names: Vec<String> = Vec::new();
        for name in text.replace('\\', "/").split('/') {
            if name == ".." {
                depth = depth.checked_sub(1)?;
                names.truncate(depth);
            } else if !name.is_empty() && name != "." {
                names.push(name.to_string());
                depth += 1;
            }
        }
        Some(names)
    }

    /// URI text made of the pieces a way out is spelled with, and anything else.
    fn uri_text() -> impl Strategy<Value = String> {
        let piece = prop_oneof![
            Just(".."),
            Just("."),
            Just("/"),
            Just("\\"),
            Just("%2e"),
            Just("%2E"),
            Just("%2f"),
            Just("%5C"),
            Just("%00"),
            Just("%3a"),
            Just("%FF"),
            Just("%"),
            Just("a"),
            Just("mesh.bin"),
            Just("é"),
        ];
        prop_oneof![
            prop::collection::vec(piece, 0..12).prop_map(|p| p.concat()),
            any::<String>(),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2048))]

        /// Whatever a URI says, what is accepted is plain names that stay in the folder
        /// (lexically, after decoding), exactly those another resolution finds; what it
        /// refuses, that one refuses too; nothing panics.
        #[test]
        fn accepted_buffer_paths_lie_inside_the_folder(uri in uri_text()) {
            use std::path::Component;
            let folder = Path::new("/mesh/folder");
            match relative_path(&uri) {
                Ok(path) => {
                    prop_assert!(
                        path.components().all(|c| matches!(c, Component::Normal(_))),
                        "{uri:?} gave {path:?}"
                    );
                    prop_assert!(folder.join(&path).starts_with(folder));
                    let names: Vec<String> = path
                        .components()
                        .map(|c| c.as_os_str().to_string_lossy().into_owned())
                        .collect();
                    prop_assert_eq!(Some(names), expected_names(&uri), "{:?}", uri);
                }
                Err(_) => prop_assert_eq!(expected_names(&uri), None, "{:?}", uri),
            }
        }
    }

    #[test]
    fn element_sizes_pad_matrix_columns() {
        use gltf::json::accessor::{ComponentType::*, Type::*};
        assert_eq!(element_size(Vec3, F32), 12);
        assert_eq!(element_size(Mat4, F32), 64);
        assert_eq!(element_size(Mat2, U8), 8);
        assert_eq!(element_size(Mat3, U8), 12);
        assert_eq!(element_size(Mat3, I16), 24);
        assert_eq!(element_size(Mat2, U16), 8);
        assert_eq!(element_size(Scalar, U16), 2);
    }

    proptest! {
        #[test]
        fn obj_parser_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..2048)) {
            let _ = parse_obj(&bytes, &[]);
        }

        #[test]
        fn obj_parser_never_panics_on_obj_like_text(
            lines in proptest::collection::vec(
                prop_oneof![
                    "v( -?[0-9]{1,3}(\\.[0-9])?){0,4}",
                    "f( -?[0-9]{1,2}(/[0-9]?){0,2}){0,5}",
                    "[go] [a-z]{0,3}",
                    "#.*",
                ],
                0..40,
            )
        ) {
            let text = lines.join("\n");
            let _ = parse_obj(text.as_bytes(), &[]);
        }

        #[test]
        fn gltf_parser_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..2048)) {
            let _ = parse_gltf(&bytes, None);
        }

        #[test]
        fn gltf_parser_never_panics_on_glb_like_bytes(tail in proptest::collection::vec(any::<u8>(), 0..512)) {
            let mut bytes = b"glTF\x02\x00\x00\x00".to_vec();
            bytes.extend((20 + tail.len() as u32).to_le_bytes());
            bytes.extend((tail.len() as u32).to_le_bytes());
            bytes.extend(b"JSON");
            bytes.extend(tail);
            let _ = parse_gltf(&bytes, None);
        }
    }
}
