//! Character meshes from files: Wavefront OBJ (our own reader: `v`, `f`, `g`/`o`, so the
//! output keeps the file's vertex order) and glTF 2.0 (`gltf` crate: triangle primitives,
//! node transforms, the first skin's joints); unit and up-axis conversion; welding of
//! coincident positions; the closed-manifold check the solver needs.
//!
//! The parsers take bytes and return typed data or an error naming the line (OBJ) or the
//! primitive (glTF); they never panic on hostile input and never allocate more than a
//! small multiple of the input's size.

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
}

/// A joint of a glTF skin at its bind pose.
#[derive(Clone, Debug)]
pub struct SkinJoint {
    pub name: String,
    /// Index into `skin_joints` of the nearest ancestor that is also a joint.
    pub parent: Option<usize>,
    /// Bind-pose world matrix (inverse of the inverse bind matrix), mesh space.
    pub world_from_joint: DMat4,
}

/// Errors reading a mesh file.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("line {line}: {message}")]
    Obj { line: usize, message: String },
    #[error("glTF: {0}")]
    Gltf(String),
    #[error("the file has no triangles{}", if .groups.is_empty() { String::new() } else { format!(" in groups {:?}", .groups) })]
    NoTriangles { groups: Vec<String> },
    #[error("OBJ groups not found: {missing:?} (the file has {found:?})")]
    MissingGroups {
        missing: Vec<String>,
        found: Vec<String>,
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
    let mut faces: Vec<[u32; 3]> = Vec::new();
    let mut found: Vec<String> = Vec::new();
    let mut keep = groups.is_empty();
    let mut poly: Vec<u32> = Vec::new();
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
            }
            Some("g") | Some("o") => {
                let names: Vec<&str> = it.collect();
                for n in &names {
                    if !found.iter().any(|f| f == n) {
                        found.push(n.to_string());
                    }
                }
                keep = groups.is_empty() || names.iter().any(|n| groups.iter().any(|g| g == n));
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
    for (i, p) in positions.iter().enumerate() {
        if used[i] {
            remap[i] = out.len() as u32;
            out.push(*p);
        }
    }
    Ok(MeshData {
        positions: out,
        triangles: faces.iter().map(|f| f.map(|i| remap[i as usize])).collect(),
        source_positions: positions,
        skin_joints: Vec::new(),
    })
}

/// Reads a glTF 2.0 file (`.glb` or `.gltf` with its buffers next to it): every triangle
/// primitive of every mesh node in the default scene (or all nodes), in document order;
/// unskinned nodes are placed by their world transform, skinned ones stay in bind space
/// (as the glTF specification says). Images are not decoded.
pub fn read_gltf(path: &Path) -> Result<MeshData, MeshError> {
    let bytes = std::fs::read(path).map_err(|source| MeshError::Io {
        path: path.display().to_string(),
        source,
    })?;
    parse_gltf(&bytes, path.parent())
}

/// [`read_gltf`] on bytes; `base` is the folder external buffers are relative to (none:
/// only embedded or GLB buffers).
pub fn parse_gltf(bytes: &[u8], base: Option<&Path>) -> Result<MeshData, MeshError> {
    let g = gltf::Gltf::from_slice(bytes).map_err(|e| MeshError::Gltf(e.to_string()))?;
    let buffers = gltf::import_buffers(&g.document, base, g.blob.clone())
        .map_err(|e| MeshError::Gltf(e.to_string()))?;
    let doc = &g.document;
    let n_nodes = doc.nodes().len();
    let mut parent: Vec<Option<usize>> = vec![None; n_nodes];
    for n in doc.nodes() {
        for c in n.children() {
            if c.index() < n_nodes {
                parent[c.index()] = Some(n.index());
            }
        }
    }
    // World transforms (depth-limited walk up the parents: a cycle cannot hang us).
    let local: Vec<DMat4> = doc
        .nodes()
        .map(|n| DMat4::from_cols_array_2d(&n.transform().matrix().map(|c| c.map(f64::from))))
        .collect();
    let world = |mut i: usize| {
        let mut m = local[i];
        for _ in 0..n_nodes {
            match parent[i] {
                Some(p) => {
                    m = local[p] * m;
                    i = p;
                }
                None => break,
            }
        }
        m
    };
    let mut out = MeshData::default();
    let mut first_skin = None;
    for node in doc.nodes() {
        let Some(mesh) = node.mesh() else { continue };
        let xf = if node.skin().is_some() {
            DMat4::IDENTITY
        } else {
            world(node.index())
        };
        if first_skin.is_none() {
            first_skin = node.skin();
        }
        for (pi, prim) in mesh.primitives().enumerate() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                continue;
            }
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(pos) = reader.read_positions() else {
                return Err(MeshError::Gltf(format!(
                    "mesh {:?} primitive {pi} has no positions",
                    mesh.name().unwrap_or("")
                )));
            };
            let base_index = out.positions.len() as u32;
            let before = out.positions.len();
            out.positions
                .extend(pos.map(|p| xf.transform_point3(DVec3::from_array(p.map(f64::from)))));
            let count = (out.positions.len() - before) as u32;
            let idx: Vec<u32> = match reader.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..count).collect(),
            };
            for t in idx.chunks_exact(3) {
                if t.iter().any(|&i| i >= count) {
                    return Err(MeshError::Gltf(format!(
                        "mesh {:?} primitive {pi}: index {} is outside its {count} vertices",
                        mesh.name().unwrap_or(""),
                        t.iter().max().copied().unwrap_or(0)
                    )));
                }
                out.triangles
                    .push([t[0] + base_index, t[1] + base_index, t[2] + base_index]);
            }
        }
    }
    if out.triangles.is_empty() {
        return Err(MeshError::NoTriangles { groups: Vec::new() });
    }
    out.source_positions = out.positions.clone();
    if let Some(skin) = first_skin {
        let joints: Vec<gltf::Node> = skin.joints().collect();
        let ibm: Vec<DMat4> = match skin
            .reader(|b| buffers.get(b.index()).map(|d| &d.0[..]))
            .read_inverse_bind_matrices()
        {
            Some(r) => r
                .map(|m| DMat4::from_cols_array_2d(&m.map(|c| c.map(f64::from))))
                .collect(),
            None => vec![DMat4::IDENTITY; joints.len()],
        };
        if ibm.len() != joints.len() {
            return Err(MeshError::Gltf(format!(
                "skin has {} joints but {} inverse bind matrices",
                joints.len(),
                ibm.len()
            )));
        }
        let slot: HashMap<usize, usize> = joints
            .iter()
            .enumerate()
            .map(|(k, n)| (n.index(), k))
            .collect();
        // Parent joint: nearest ancestor node that is a joint.
        let joint_parent = |k: usize| {
            let mut i = joints[k].index();
            for _ in 0..n_nodes {
                i = parent[i]?;
                if let Some(&s) = slot.get(&i) {
                    return Some(s);
                }
            }
            None
        };
        // Order parents first (by depth), keeping the skin's order among equals.
        let depth = |k: usize| {
            let mut d = 0;
            let mut j = k;
            while let Some(p) = joint_parent(j) {
                d += 1;
                j = p;
                if d > joints.len() {
                    break;
                }
            }
            d
        };
        let mut order: Vec<usize> = (0..joints.len()).collect();
        order.sort_by_key(|&k| (depth(k), k));
        let mut new_index = vec![0; joints.len()];
        for (n, &k) in order.iter().enumerate() {
            new_index[k] = n;
        }
        for &k in &order {
            out.skin_joints.push(SkinJoint {
                name: joints[k]
                    .name()
                    .map(str::to_string)
                    .unwrap_or_else(|| format!("joint{}", joints[k].index())),
                parent: joint_parent(k).map(|p| new_index[p]),
                world_from_joint: ibm[k].inverse(),
            });
        }
    }
    Ok(out)
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
