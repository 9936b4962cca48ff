//! Binding a character: the labelled lattice control mesh, marker and skeleton-sample
//! rows, the embedding of the full mesh, and the factored ARAP system. The result, a
//! [`Rig`], is immutable and shared by every solver of that character.
//!
//! Labelled lattice (virtual nodes, after Nesme et al. 2009, "Preserving topology and
//! elasticity for embedded deformable models"): every surface sample, mesh vertex, skeleton
//! sample and interior cell gets a label, the owner joint of the nearest skeleton segment.
//! A grid cell is instanced once per label present in it, and cell instances share a grid
//! node only when their labels are compatible (the same joint, or parent and child).
//! So two fingers that pass through the same cells get separate copies of those cells and
//! are free to move apart, while each finger stays connected to its parent segment.

use super::arap_system::{ArapOperator, ArapSystem, LinearRows};
use super::factor::FactorError;
use super::green::{GreenCoefficients, GreenCoefficientsError, GreenEmbedding};
use super::ik_model::IkModel;
use super::lattice::{barycentric, sample_surface, solid_or, surface_cells, surface_samples};
use super::tetmesh::{bounds, TetMesh, TetMeshError};
use crate::character::bind_params::BindParams;
use crate::character::file::{fnv1a, point_bytes};
use crate::character::mesh::welded_outward;
use crate::character::skeleton::Skeleton;
use crate::character::Character;
use crate::geom::lattice::{Grid, KUHN};
use crate::geom::winding::WindingNumber;
use glam::DVec3;
use std::collections::HashMap;

/// The stages of binding, in order (for progress reports).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BindStage {
    /// Lattice, virtual nodes, locating vertices, markers and skeleton samples.
    Lattice,
    /// Green coordinates of every mesh vertex (the long stage on large meshes).
    GreenCoordinates,
    /// Cotangent weights and the sparse Cholesky factorization.
    Factorization,
}

/// What binding measured (printed by `rigless bake`).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct BindStats {
    /// Vertices of the control mesh (the solver's unknowns).
    pub control_vertices: usize,
    /// Tets of the control mesh.
    pub control_tets: usize,
    /// Lattice cells, counting a cell once per skeleton segment it is instanced for.
    pub cell_instances: usize,
    /// Cell instances beyond the first of their cell (parts kept apart: virtual nodes).
    pub duplicated_cells: usize,
    /// Smallest dihedral angle of any control tet, degrees.
    pub min_dihedral_deg: f64,
    /// Edges whose cotangent weight was negative and clamped to zero.
    pub clamped_weights: usize,
    /// Vertices of the full-resolution mesh (the file's count).
    pub mesh_vertices: usize,
    /// Of those, the ones inside the control tet that carries them.
    pub mesh_vertices_inside: usize,
    /// Points sampled along the skeleton's bones (each an ARAP row), anchors included.
    pub skeleton_samples: usize,
    /// Parts of the control mesh no marker or bone reaches (parts hanging in the air),
    /// each pinned to its nearest joint's motion by up to four anchor samples.
    #[serde(default)]
    pub free_parts: usize,
    /// Stored values of the Cholesky factor (its fill).
    pub factor_len: usize,
    /// Mesh vertices whose Green coordinates fell back to barycentric ones.
    pub green_fallback_vertices: usize,
    /// Largest rest reproduction error of the embedding, metres.
    pub green_max_rest_error_m: f64,
    /// Seconds for the lattice, virtual nodes and locating every point in it.
    pub seconds_lattice: f64,
    /// Seconds for the Green coordinates.
    pub seconds_green: f64,
    /// Seconds for the cotangent weights and the factorization.
    pub seconds_weights_factor: f64,
}

/// Errors binding a character.
#[derive(Debug, thiserror::Error)]
pub enum BindError {
    #[error("marker {name:?} is {distance_m:.3} m from the control mesh (limit {limit_m} m): is it on this character?")]
    MarkerTooFar {
        name: String,
        distance_m: f64,
        limit_m: f64,
    },
    #[error("mesh vertex {vertex} lies in no control tet")]
    VertexOutside { vertex: usize },
    #[error("skeleton joint {joint:?} lies outside the control mesh")]
    JointOutside { joint: String },
    #[error("control mesh: {0}")]
    Mesh(#[from] TetMeshError),
    #[error("factorization: {0}")]
    Factor(#[from] FactorError),
    #[error("the mesh has no vertices or triangles")]
    EmptyMesh,
    /// The lattice over the mesh's bounds would be too large to build.
    #[error("a lattice of {cell_size_m:?} m cells over a mesh {extent_m:?} m across would have {cells:.3e} cells ({per_axis:?} a side; at most {MAX_AXIS_CELLS} a side and {MAX_CELLS} in all): choose a larger [bind] cell_size_m, or check the mesh's units and stray vertices")]
    LatticeTooLarge {
        cell_size_m: f64,
        extent_m: [f64; 3],
        per_axis: [f64; 3],
        cells: f64,
    },
    /// Sampling the surface or the skeleton at the cell size would take too many points.
    #[error("{what}: {samples:.3e} points at {step_m} m apart, more than {MAX_SAMPLES}: choose a larger [bind] cell_size_m or skeleton_step_m")]
    TooManySamples {
        what: &'static str,
        samples: f64,
        step_m: f64,
    },
}

/// Most lattice cells along one axis.
pub const MAX_AXIS_CELLS: usize = 4096;
/// Most lattice cells in all (the grid's flags and flood fill take a few bytes a cell).
pub const MAX_CELLS: usize = 1 << 25;
/// Most surface or skeleton sample points a bind takes (each a few nanoseconds).
pub const MAX_SAMPLES: usize = 1 << 28;

/// One skeleton sub-edge between consecutive samples along a segment (for
/// `bone_length_error`).
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct SkeletonEdge {
    /// Sample row indices `(a, b)` in [`Rig::samples`].
    pub samples: (usize, usize),
    /// Rest length `‖s_b − s_a‖`, metres.
    pub rest_length_m: f64,
}

/// An immutable, bound character. The bake cache stores only its Green coordinates
/// ([`Rig::stored_green`]); everything else is rebuilt on load.
pub struct Rig {
    pub skeleton: Skeleton,
    /// Rest twist axis per joint ([`Skeleton::twist_axis`]), precomputed for the solver.
    pub twist_axis: Vec<DVec3>,
    pub marker_names: Vec<String>,
    /// Rest position of each marker, metres, world frame (the gap filler's default
    /// rigid layout).
    pub marker_rest: Vec<DVec3>,
    /// Full-resolution mesh at rest, in the file's vertex order.
    pub mesh_rest: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
    /// The mesh file's parts, with their vertex and triangle ranges.
    pub parts: Vec<crate::character::mesh::MeshPart>,
    pub control: TetMesh,
    pub system: ArapSystem,
    /// ARAP rows `0..n_markers` are the markers.
    pub n_markers: usize,
    /// The joint whose segments carry each marker.
    pub marker_joint: Vec<usize>,
    /// Skeleton samples as unweighted barycentric rows (to read their positions). Sample
    /// `s` is also ARAP row `n_markers + s`, an absolute positional row of weight `w_d`.
    pub samples: LinearRows,
    /// Per sample: the joint owning its segment, and its rest position.
    pub sample_owner: Vec<usize>,
    pub sample_rest: Vec<DVec3>,
    /// Per segment (owner joint, child joint): its samples' first index and count.
    pub segment_samples: Vec<(usize, usize, usize, usize)>,
    pub edges: Vec<SkeletonEdge>,
    /// Owner joint of each control vertex (the label of the cell instance it came from),
    /// used to carry the previous frame's control mesh along with the new posture.
    pub control_label: Vec<u32>,
    /// The posture problem of the skeleton step.
    pub ik: IkModel,
    /// The full mesh's Green coordinates in the control tets.
    pub green: GreenEmbedding,
    pub stats: BindStats,
    /// Character height (bounding box extent along Y), metres.
    pub height_m: f64,
    /// The harmonic method's correspondences given by the character file.
    pub correspondences: Vec<crate::character::Correspondence>,
    /// Hash of the control mesh, the vertices' tets and the mesh vertices: the key of
    /// the Green coordinates in the bake cache.
    pub lattice_key: u64,
}

/// Segments of a skeleton: `(owner joint, child joint)`, grouped by owner (ascending).
pub fn segments(sk: &Skeleton) -> Vec<(usize, usize)> {
    let mut s: Vec<(usize, usize)> = sk
        .joints
        .iter()
        .enumerate()
        .filter_map(|(c, j)| j.parent.map(|p| (p, c)))
        .collect();
    s.sort_unstable();
    s
}

/// The joint whose bone segment (of `segs`, [`segments`]) lies nearest to `p`: the part
/// of the control mesh `p` belongs to.
pub(crate) fn nearest_owner(sk: &Skeleton, segs: &[(usize, usize)], p: DVec3) -> u32 {
    let mut best = (f64::INFINITY, 0u32);
    for &seg in segs {
        let d = segment_distance2(sk, seg, p);
        if d < best.0 {
            best = (d, seg.0 as u32);
        }
    }
    best.1
}

/// Squared distance from `p` to the rest bone segment `(a, b)` (of [`segments`]; a
/// zero-length one is its point).
pub(crate) fn segment_distance2(sk: &Skeleton, (a, b): (usize, usize), p: DVec3) -> f64 {
    let (pa, pb) = (sk.joints[a].rest, sk.joints[b].rest);
    let ab = pb - pa;
    let t = ((p - pa).dot(ab) / ab.length_squared().max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
    (p - (pa + ab * t)).length_squared()
}

fn compatible(sk: &Skeleton, a: u32, b: u32) -> bool {
    a == b
        || sk.joints[a as usize].parent == Some(b as usize)
        || sk.joints[b as usize].parent == Some(a as usize)
}

fn find(parent: &mut [usize], mut x: usize) -> usize {
    while parent[x] != x {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    x
}

/// A point located in the control mesh: the tet's vertices, the point's barycentric
/// coordinates in it, the smallest of those (negative outside the tet) and the tet's index.
type Located = ([u32; 4], [f64; 4], f64, usize);

/// A skeleton segment's samples: `(owner joint, child joint, first sample, count)`.
type SegmentSamples = (usize, usize, usize, usize);

/// The labelled lattice's cell instances: a grid cell once per label present in it.
#[derive(Default)]
struct CellInstances {
    /// Instance index of each `(cell, label)`.
    index: HashMap<(usize, u32), usize>,
    /// `(cell, label)` of each instance, in order of creation.
    list: Vec<(usize, u32)>,
}

impl CellInstances {
    /// The instance of `(cell, label)`, created if it is new.
    fn add(&mut self, cell: usize, label: u32) -> usize {
        let list = &mut self.list;
        *self.index.entry((cell, label)).or_insert_with(|| {
            list.push((cell, label));
            list.len() - 1
        })
    }
}

/// The lattice over the mesh bounds `lo..hi`, with cells of `params.cell_size_m`, if it
/// stays within [`MAX_AXIS_CELLS`] a side and [`MAX_CELLS`] in all (counted in `f64`
/// before any integer conversion, so no size overflows).
fn lattice_grid(lo: DVec3, hi: DVec3, params: &BindParams) -> Result<Grid, BindError> {
    let cell = params.cell_size_m;
    let extent = hi - lo;
    // The grid's cells a side: the extent's, the offset's one and the padding's four.
    let per_axis = [0, 1, 2].map(|a| (extent[a] / cell).floor() + 6.0);
    let cells = per_axis.iter().product::<f64>();
    let fits = |n: f64| n.is_finite() && n <= MAX_AXIS_CELLS as f64;
    let sane = cell.is_finite() && cell > 0.0 && per_axis.iter().all(|&n| fits(n));
    if !sane || cells > MAX_CELLS as f64 {
        return Err(BindError::LatticeTooLarge {
            cell_size_m: cell,
            extent_m: extent.to_array(),
            per_axis,
            cells,
        });
    }
    // The lattice is offset from the mesh bounds by a fraction of a cell that no
    // rational ratio reaches (1/π, (√2 − 1)/2, √2 − 1): meshes made on a grid (marching cubes or tets) would
    // otherwise put vertices exactly on lattice planes, where Green coordinates lose
    // precision and fall back to barycentric ones.
    use std::f64::consts::{FRAC_1_PI, SQRT_2};
    let offset = DVec3::new(FRAC_1_PI, (SQRT_2 - 1.0) / 2.0, SQRT_2 - 1.0) * params.cell_size_m;
    Ok(Grid::covering(lo - offset, hi, params.cell_size_m, 2))
}

/// Refuses sampling `what` at `step_m` when it would take more than [`MAX_SAMPLES`]
/// points (`samples`, counted in `f64`).
fn check_samples(what: &'static str, samples: f64, step_m: f64) -> Result<(), BindError> {
    if samples.is_finite() && samples <= MAX_SAMPLES as f64 {
        Ok(())
    } else {
        Err(BindError::TooManySamples {
            what,
            samples,
            step_m,
        })
    }
}

/// Cell instances of the surface samples and of the interior cells, each labelled with
/// the owner joint of the nearest skeleton segment.
fn label_cells(ch: &Character, segs: &[(usize, usize)], grid: &Grid) -> CellInstances {
    let sk = &ch.skeleton;
    let mut inst = CellInstances::default();
    sample_surface(grid.cell_size, &ch.vertices, &ch.triangles, |p| {
        let c = grid.cell_index(grid.cell_of(p));
        inst.add(c, nearest_owner(sk, segs, p));
    });
    // Vertices on no triangle (a file may hold them) get their cell too.
    for &v in &ch.vertices {
        inst.add(grid.cell_index(grid.cell_of(v)), nearest_owner(sk, segs, v));
    }
    let surface = surface_cells(grid, &ch.vertices, &ch.triangles);
    let keep = solid_or(grid, &surface, winding_of(ch).as_ref());
    for z in 0..grid.dims[2] {
        for y in 0..grid.dims[1] {
            for x in 0..grid.dims[0] {
                let k = grid.cell_index([x, y, z]);
                if keep[k] && !surface[k] {
                    let center = grid.node_position([x, y, z]) + DVec3::splat(0.5 * grid.cell_size);
                    inst.add(k, nearest_owner(sk, segs, center));
                }
            }
        }
    }
    inst
}

/// Control vertices to pin to their owner joints' motion, for every part of the control
/// mesh that no row reaches (a hat or a prop hanging in the air, a stray vertex): the
/// ARAP system has no unique solution for such a part, so up to four of its vertices,
/// spread as far apart as possible (two, then the farthest from their line, then the
/// farthest from their plane), become skeleton samples that follow the owner joint of
/// their cell rigidly, like the bone samples. A part with rows is left alone.
fn anchors_of_free_parts(control: &TetMesh, rows: &LinearRows) -> (Vec<usize>, usize) {
    let n = control.positions.len();
    let mut parent: Vec<usize> = (0..n).collect();
    for t in &control.tets {
        for k in 1..4 {
            let (a, b) = (
                find(&mut parent, t[0] as usize),
                find(&mut parent, t[k] as usize),
            );
            parent[a] = b;
        }
    }
    let mut reached = vec![false; n];
    for &i in &rows.idx {
        let r = find(&mut parent, i as usize);
        reached[r] = true;
    }
    let mut parts: HashMap<usize, Vec<usize>> = HashMap::new();
    for v in 0..n {
        let r = find(&mut parent, v);
        if !reached[r] {
            parts.entry(r).or_default().push(v);
        }
    }
    let mut roots: Vec<usize> = parts.keys().copied().collect();
    let free_parts = roots.len();
    roots.sort_unstable();
    let p = &control.positions;
    let mut anchors = Vec::new();
    for r in roots {
        let part = &parts[&r];
        let farthest = |score: &dyn Fn(DVec3) -> f64| {
            part.iter()
                .copied()
                .max_by(|&a, &b| score(p[a]).total_cmp(&score(p[b])))
                .unwrap_or(part[0])
        };
        let a = part[0];
        let b = farthest(&|x| (x - p[a]).length_squared());
        let line = (p[b] - p[a]).normalize_or_zero();
        let c = farthest(&|x| (x - p[a]).reject_from_normalized(line).length_squared());
        let normal = (p[b] - p[a]).cross(p[c] - p[a]).normalize_or_zero();
        let d = farthest(&|x| (x - p[a]).dot(normal).abs());
        for v in [a, b, c, d] {
            if !anchors.contains(&v) {
                anchors.push(v);
            }
        }
    }
    (anchors, free_parts)
}

/// The generalized winding number of the character's surface, its parts oriented
/// outward first (seams and duplicated vertices welded at 1e-9 of its size, so that
/// parts split by UV seams still orient as one); `None` for a closed, manifold,
/// consistently oriented surface, whose inside the flood fill alone finds exactly (and
/// at no cost).
fn winding_of(ch: &Character) -> Option<WindingNumber> {
    let (unique, oriented, clean) = welded_outward(&ch.vertices, &ch.triangles);
    (!clean).then(|| WindingNumber::new(&unique, &oriented))
}

/// Skeleton samples, each in a cell instance labelled by its segment's owner: their
/// positions and labels, and per segment `(owner, child, first, count)`.
fn sample_skeleton(
    sk: &Skeleton,
    segs: &[(usize, usize)],
    grid: &Grid,
    params: &BindParams,
    inst: &mut CellInstances,
) -> (Vec<(DVec3, u32)>, Vec<SegmentSamples>) {
    let mut sample_pos: Vec<(DVec3, u32)> = Vec::new();
    let mut seg_samples: Vec<SegmentSamples> = Vec::new(); // (owner, child, first, count)
    for &(a, b) in segs {
        let (pa, pb) = (sk.joints[a].rest, sk.joints[b].rest);
        let len = (pb - pa).length();
        let n = ((len / params.skeleton_step_m).ceil() as usize).max(1);
        let first = sample_pos.len();
        // The joints themselves, and interior samples at least a cell from both ends:
        // samples of two segments closer than that to their shared joint would pin
        // neighbouring tets to two rigid motions and crush the flexion crease.
        let clear = grid.cell_size.min(0.5 * len);
        for k in 0..=n {
            let t = k as f64 / n as f64;
            let interior = k > 0 && k < n;
            if interior && (t * len < clear || (1.0 - t) * len < clear) {
                continue;
            }
            let p = pa + (pb - pa) * t;
            sample_pos.push((p, a as u32));
            inst.add(grid.cell_index(grid.cell_of(p)), a as u32);
        }
        seg_samples.push((a, b, first, sample_pos.len() - first));
    }
    (sample_pos, seg_samples)
}

/// Per grid node, the cell instances around it: `(instance, corner bits)`, the bits
/// giving the node's corner of the instance's cell.
fn instances_at_nodes(
    grid: &Grid,
    inst_list: &[(usize, u32)],
) -> HashMap<usize, Vec<(usize, usize)>> {
    let mut at_node: HashMap<usize, Vec<(usize, usize)>> = HashMap::new(); // node -> (instance, corner bits)
    let cell_coord = |k: usize| {
        [
            k % grid.dims[0],
            (k / grid.dims[0]) % grid.dims[1],
            k / (grid.dims[0] * grid.dims[1]),
        ]
    };
    for (ii, &(cell, _)) in inst_list.iter().enumerate() {
        let c = cell_coord(cell);
        for bits in 0..8 {
            let nc = [
                c[0] + (bits & 1),
                c[1] + ((bits >> 1) & 1),
                c[2] + ((bits >> 2) & 1),
            ];
            at_node
                .entry(grid.node_index(nc))
                .or_default()
                .push((ii, bits));
        }
    }
    at_node
}

/// The control mesh (virtual nodes, Nesme et al. 2009): per grid node, the cell
/// instances around it that have compatible labels are united into one control vertex;
/// then six Kuhn tets per instance. Returns the mesh and each control vertex's label.
fn control_mesh(
    sk: &Skeleton,
    grid: &Grid,
    inst_list: &[(usize, u32)],
) -> Result<(TetMesh, Vec<u32>), BindError> {
    let at_node = instances_at_nodes(grid, inst_list);
    let mut corner_node = vec![[u32::MAX; 8]; inst_list.len()];
    let mut positions: Vec<DVec3> = Vec::new();
    let mut control_label: Vec<u32> = Vec::new();
    let mut nodes: Vec<(&usize, &Vec<(usize, usize)>)> = at_node.iter().collect();
    nodes.sort_unstable_by_key(|(n, _)| **n);
    for (&node, list) in nodes {
        let m = list.len();
        let nx1 = grid.dims[0] + 1;
        let ny1 = grid.dims[1] + 1;
        let nc = [node % nx1, (node / nx1) % ny1, node / (nx1 * ny1)];
        let mut parent: Vec<usize> = (0..m).collect();
        for x in 0..m {
            for y in x + 1..m {
                if compatible(sk, inst_list[list[x].0].1, inst_list[list[y].0].1) {
                    let (rx, ry) = (find(&mut parent, x), find(&mut parent, y));
                    parent[rx] = ry;
                }
            }
        }
        let pos = grid.node_position(nc);
        let mut root_id: HashMap<usize, u32> = HashMap::new();
        for (x, &(ii, bits)) in list.iter().enumerate() {
            let r = find(&mut parent, x);
            let id = *root_id.entry(r).or_insert_with(|| {
                positions.push(pos);
                control_label.push(inst_list[ii].1);
                (positions.len() - 1) as u32
            });
            corner_node[ii][bits] = id;
        }
    }
    let mut tets = Vec::with_capacity(inst_list.len() * 6);
    for corners in &corner_node {
        for kt in KUHN {
            tets.push(kt.map(|b| corners[b]));
        }
    }
    let control = TetMesh::new(positions, tets)?;
    Ok((control, control_label))
}

/// Locates points in the control mesh: the tet of instance (cell, label) that holds a
/// point, or the nearest compatible tet around it (for markers off the skin).
struct Locator<'a> {
    sk: &'a Skeleton,
    grid: &'a Grid,
    control: &'a TetMesh,
    /// Instance index of each `(cell, label)`.
    inst: &'a HashMap<(usize, u32), usize>,
    /// Per cell, its instances as `(label, instance)`.
    by_cell: HashMap<usize, Vec<(u32, usize)>>,
}

impl<'a> Locator<'a> {
    /// A locator over `control`, built from the instances `inst` of `grid`.
    fn new(
        sk: &'a Skeleton,
        grid: &'a Grid,
        control: &'a TetMesh,
        inst: &'a CellInstances,
    ) -> Self {
        let mut by_cell: HashMap<usize, Vec<(u32, usize)>> = HashMap::new();
        for (ii, &(cell, label)) in inst.list.iter().enumerate() {
            by_cell.entry(cell).or_default().push((label, ii));
        }
        Self {
            sk,
            grid,
            control,
            inst: &inst.index,
            by_cell,
        }
    }

    /// The tet of instance `ii` whose smallest barycentric coordinate of `p` is largest.
    fn locate_in(&self, ii: usize, p: DVec3) -> Located {
        let control = self.control;
        let mut best = ([0u32; 4], [0.0; 4], f64::NEG_INFINITY, 0);
        for (k, t) in control.tets[ii * 6..ii * 6 + 6].iter().enumerate() {
            let b = barycentric(t.map(|i| control.positions[i as usize]), p);
            let m = b.iter().cloned().fold(f64::INFINITY, f64::min);
            if m > best.2 {
                best = (*t, b, m, ii * 6 + k);
            }
        }
        best
    }

    /// The tet of instance (cell of `p`, `label`) if it holds `p`, else the best tet of
    /// the instances compatible with `label` within `search_cells` cells.
    fn locate(&self, p: DVec3, label: u32, search_cells: usize) -> Option<Located> {
        let grid = self.grid;
        let c = grid.cell_of(p);
        if let Some(&ii) = self.inst.get(&(grid.cell_index(c), label)) {
            let r = self.locate_in(ii, p);
            if r.2 >= -1e-9 {
                return Some(r);
            }
        }
        // The cells within `search_cells` of `c`, clamped to the grid per axis.
        let r = search_cells;
        let span = |a: usize| c[a].saturating_sub(r)..=(c[a] + r).min(grid.dims[a] - 1);
        let mut best: Option<Located> = None;
        for z in span(2) {
            for y in span(1) {
                for x in span(0) {
                    let k = grid.cell_index([x, y, z]);
                    for &(l, ii) in self.by_cell.get(&k).map_or(&[][..], |v| &v[..]) {
                        if !compatible(self.sk, l, label) {
                            continue;
                        }
                        let cand = self.locate_in(ii, p);
                        if best.is_none_or(|b| cand.2 > b.2) {
                            best = Some(cand);
                        }
                    }
                }
            }
        }
        best
    }
}

/// The control tet of every mesh vertex, and how many vertices lie inside theirs.
fn locate_vertices(
    ch: &Character,
    segs: &[(usize, usize)],
    loc: &Locator,
) -> Result<(Vec<usize>, usize), BindError> {
    let sk = &ch.skeleton;
    let mut vertex_tets = Vec::with_capacity(ch.vertices.len());
    let mut inside = 0;
    for (vi, &v) in ch.vertices.iter().enumerate() {
        let label = nearest_owner(sk, segs, v);
        let (_, _, m, t) = loc
            .locate(v, label, 1)
            .ok_or(BindError::VertexOutside { vertex: vi })?;
        if m >= -1e-9 {
            inside += 1;
        }
        vertex_tets.push(t);
    }
    Ok((vertex_tets, inside))
}

/// The markers' ARAP rows (weight `w_marker`), each in the tet of its joint's instances
/// nearest its rest position, and the joint carrying each marker.
fn marker_rows(
    ch: &Character,
    segs: &[(usize, usize)],
    params: &BindParams,
    loc: &Locator,
) -> Result<(LinearRows, Vec<usize>), BindError> {
    let sk = &ch.skeleton;
    let (grid, control) = (loc.grid, loc.control);
    let mut rows = LinearRows::new();
    // At most the grid's largest side: no cell beyond it holds anything.
    let largest_side = grid.dims.iter().copied().max().unwrap_or(1);
    let search = ((params.max_marker_distance_m / grid.cell_size).ceil() + 1.0)
        .min(largest_side as f64) as usize;
    let mut marker_joint = Vec::with_capacity(ch.markers.len());
    for m in &ch.markers {
        let label = m
            .joint
            .map(|j| j as u32)
            .unwrap_or_else(|| nearest_owner(sk, segs, m.rest));
        marker_joint.push(label as usize);
        let too_far = |d: f64| BindError::MarkerTooFar {
            name: m.name.clone(),
            distance_m: d,
            limit_m: params.max_marker_distance_m,
        };
        let (t, b, _, _) = loc
            .locate(m.rest, label, search)
            .ok_or_else(|| too_far(f64::INFINITY))?;
        let centroid: DVec3 = t
            .iter()
            .map(|&i| control.positions[i as usize])
            .sum::<DVec3>()
            / 4.0;
        let d = (centroid - m.rest).length() - grid.cell_size;
        if d > params.max_marker_distance_m {
            return Err(too_far(d));
        }
        let entries: Vec<(u32, f64)> = (0..4).map(|q| (t[q], b[q])).collect();
        rows.push(&entries, params.w_marker);
    }
    Ok((rows, marker_joint))
}

/// The skeleton samples' rows: returned unweighted (to read their positions), and
/// appended to `rows` as absolute positional rows of weight `w_skeleton`.
fn sample_rows(
    sk: &Skeleton,
    params: &BindParams,
    sample_pos: &[(DVec3, u32)],
    loc: &Locator,
    rows: &mut LinearRows,
) -> Result<LinearRows, BindError> {
    let mut samples = LinearRows::new();
    for &(p, label) in sample_pos {
        let (t, b, _, _) = loc
            .locate(p, label, 2)
            .ok_or_else(|| BindError::JointOutside {
                joint: sk.joints[label as usize].name.clone(),
            })?;
        let entries: Vec<(u32, f64)> = (0..4).map(|q| (t[q], b[q])).collect();
        samples.push(&entries, 1.0);
        rows.push(&entries, params.w_skeleton);
    }
    Ok(samples)
}

/// The skeleton's sub-edges between consecutive samples of each segment, with their rest
/// lengths.
fn skeleton_edges(
    seg_samples: &[SegmentSamples],
    sample_pos: &[(DVec3, u32)],
) -> Vec<SkeletonEdge> {
    let mut edges = Vec::new();
    for &(_, _, first, count) in seg_samples {
        for k in first..first + count - 1 {
            edges.push(SkeletonEdge {
                samples: (k, k + 1),
                rest_length_m: (sample_pos[k + 1].0 - sample_pos[k].0).length(),
            });
        }
    }
    edges
}

/// What the lattice stage binds: the control mesh and every point located in it (the
/// ARAP rows themselves are returned beside it, for the factorization to take).
struct LatticeBinding {
    control: TetMesh,
    /// Owner joint of each control vertex.
    control_label: Vec<u32>,
    /// Parts of the control mesh pinned by anchors ([`anchors_of_free_parts`]).
    free_parts: usize,
    /// Cell instances, and the distinct cells among them.
    cell_instances: usize,
    distinct_cells: usize,
    /// The control tet of each mesh vertex, and how many vertices lie inside theirs.
    vertex_tets: Vec<usize>,
    inside: usize,
    /// Skeleton samples as unweighted rows.
    samples: LinearRows,
    marker_joint: Vec<usize>,
    /// Skeleton sample positions and labels, and per segment `(owner, child, first, count)`.
    sample_pos: Vec<(DVec3, u32)>,
    seg_samples: Vec<SegmentSamples>,
    edges: Vec<SkeletonEdge>,
}

impl Rig {
    /// Binds a character.
    pub fn bind(ch: &Character, params: &BindParams) -> Result<Self, BindError> {
        Self::bind_with_progress(ch, params, &mut |_, _| {})
    }

    /// [`Self::bind`], reporting each stage and its fraction done to `progress`.
    pub fn bind_with_progress(
        ch: &Character,
        params: &BindParams,
        progress: &mut dyn FnMut(BindStage, f64),
    ) -> Result<Self, BindError> {
        Self::bind_reusing(ch, params, progress, None).map(|(rig, _)| rig)
    }

    /// [`Self::bind_with_progress`], taking the Green coordinates from `stored` (the
    /// bake cache) when they were computed for this very lattice and mesh (the same
    /// [`Rig::lattice_key`]) and fit it. Everything else is rebuilt, so stored data never
    /// supplies an index. Returns the rig and, when `stored` was given but not used, why.
    pub fn bind_reusing(
        ch: &Character,
        params: &BindParams,
        progress: &mut dyn FnMut(BindStage, f64),
        stored: Option<StoredGreen>,
    ) -> Result<(Self, Option<StoredGreenMiss>), BindError> {
        if ch.vertices.is_empty() || ch.triangles.is_empty() {
            return Err(BindError::EmptyMesh);
        }
        let t0 = std::time::Instant::now();
        progress(BindStage::Lattice, 0.0);
        let (lo, hi) = bounds(&ch.vertices);
        let (lattice, rows) = Self::bind_lattice(ch, params, lo, hi)?;
        let seconds_lattice = t0.elapsed().as_secs_f64();
        let t_gc = std::time::Instant::now();
        let height_m = hi.y - lo.y;
        let lattice_key = lattice_key(&lattice, &ch.vertices);
        let (green, miss) = match stored.map(|s| reuse(&lattice, lattice_key, s)) {
            Some(Ok(green)) => (green, None),
            computed => {
                let green = GreenEmbedding::new_with_progress(
                    &lattice.control,
                    &ch.vertices,
                    &lattice.vertex_tets,
                    height_m,
                    &mut |f| progress(BindStage::GreenCoordinates, f),
                );
                (green, computed.and_then(Result::err))
            }
        };
        let seconds_green = t_gc.elapsed().as_secs_f64();
        progress(BindStage::Factorization, 0.0);
        let t_factor = std::time::Instant::now();
        let op = ArapOperator::new(&lattice.control);
        let system = ArapSystem::new(op, rows, params.w_shape)?;
        let seconds_weights_factor = t_factor.elapsed().as_secs_f64();
        let stats = BindStats {
            control_vertices: lattice.control.positions.len(),
            control_tets: lattice.control.tets.len(),
            cell_instances: lattice.cell_instances,
            duplicated_cells: lattice.cell_instances - lattice.distinct_cells,
            min_dihedral_deg: lattice.control.dihedral_range_deg().0,
            clamped_weights: system.op.clamped_weights,
            mesh_vertices: ch.vertices.len(),
            mesh_vertices_inside: lattice.inside,
            skeleton_samples: lattice.sample_pos.len(),
            free_parts: lattice.free_parts,
            factor_len: system.factor_len(),
            green_fallback_vertices: green.fallback_vertices,
            green_max_rest_error_m: green.max_rest_error_m,
            seconds_lattice,
            seconds_green,
            seconds_weights_factor,
        };
        let mut rig = Self::assemble(ch, lattice, green, system, stats, height_m);
        rig.lattice_key = lattice_key;
        Ok((rig, miss))
    }

    /// The Green coordinates to store, with the key of the lattice they belong to.
    pub fn stored_green(&self) -> StoredGreen {
        StoredGreen {
            lattice_key: self.lattice_key,
            coefficients: self.green.coefficients(),
        }
    }

    /// The lattice stage ([`BindStage::Lattice`]): the labelled lattice's cell instances
    /// and virtual nodes, the control mesh, and every mesh vertex, marker and skeleton
    /// sample located in it. Returns the binding and the ARAP rows (markers, then
    /// skeleton samples).
    fn bind_lattice(
        ch: &Character,
        params: &BindParams,
        lo: DVec3,
        hi: DVec3,
    ) -> Result<(LatticeBinding, LinearRows), BindError> {
        let sk = &ch.skeleton;
        let segs = segments(sk);
        let grid = lattice_grid(lo, hi, params)?;
        check_samples(
            "the surface",
            surface_samples(grid.cell_size, &ch.vertices, &ch.triangles),
            0.5 * grid.cell_size,
        )?;
        let skeleton_samples: f64 = segs
            .iter()
            .map(|&(a, b)| {
                let len = (sk.joints[b].rest - sk.joints[a].rest).length();
                (len / params.skeleton_step_m).ceil() + 1.0
            })
            .sum();
        check_samples("the skeleton", skeleton_samples, params.skeleton_step_m)?;
        // 1. Cell instances (cell, label); skeleton samples, each in a cell instance
        // labelled by its segment's owner.
        let mut inst = label_cells(ch, &segs, &grid);
        let (sample_pos, seg_samples) = sample_skeleton(sk, &segs, &grid, params, &mut inst);
        // 2. Nodes: per grid node, union compatible instances among the cells around it.
        let (control, control_label) = control_mesh(sk, &grid, &inst.list)?;
        let distinct_cells = {
            let mut cells: Vec<usize> = inst.list.iter().map(|i| i.0).collect();
            cells.sort_unstable();
            cells.dedup();
            cells.len()
        };
        // 3. Locate points: the tet of instance (cell, label) that holds p, or the nearest
        // compatible tet around it (for markers off the skin).
        let loc = Locator::new(sk, &grid, &control, &inst);
        let (vertex_tets, inside) = locate_vertices(ch, &segs, &loc)?;
        // 4. Rows: markers, then skeleton samples (absolute positions).
        let (mut rows, marker_joint) = marker_rows(ch, &segs, params, &loc)?;
        let mut samples = sample_rows(sk, params, &sample_pos, &loc, &mut rows)?;
        let mut sample_pos = sample_pos;
        let (anchors, free_parts) = anchors_of_free_parts(&control, &rows);
        for v in anchors {
            let entry = [(v as u32, 1.0)];
            samples.push(&entry, 1.0);
            rows.push(&entry, params.w_skeleton);
            sample_pos.push((control.positions[v], control_label[v]));
        }
        let edges = skeleton_edges(&seg_samples, &sample_pos);
        let lattice = LatticeBinding {
            control,
            control_label,
            free_parts,
            cell_instances: inst.list.len(),
            distinct_cells,
            vertex_tets,
            inside,
            samples,
            marker_joint,
            sample_pos,
            seg_samples,
            edges,
        };
        Ok((lattice, rows))
    }

    /// The rig from the three stages' results: the lattice binding, the Green
    /// coordinates and the factored system, with the skeleton step's posture problem.
    fn assemble(
        ch: &Character,
        lattice: LatticeBinding,
        green: GreenEmbedding,
        system: ArapSystem,
        stats: BindStats,
        height_m: f64,
    ) -> Self {
        let sk = &ch.skeleton;
        let twist_axis: Vec<DVec3> = (0..sk.len()).map(|j| sk.twist_axis(j)).collect();
        let marker_rest: Vec<DVec3> = ch.markers.iter().map(|m| m.rest).collect();
        let ik = IkModel::new(
            sk,
            &twist_axis,
            &lattice.marker_joint,
            &marker_rest,
            height_m,
        );
        Rig {
            skeleton: sk.clone(),
            twist_axis,
            marker_names: ch.markers.iter().map(|m| m.name.clone()).collect(),
            marker_rest: marker_rest.clone(),
            mesh_rest: ch.vertices.clone(),
            triangles: ch.triangles.clone(),
            parts: ch.parts.clone(),
            control: lattice.control,
            system,
            n_markers: ch.markers.len(),
            marker_joint: lattice.marker_joint,
            samples: lattice.samples,
            sample_owner: lattice
                .sample_pos
                .iter()
                .map(|&(_, o)| o as usize)
                .collect(),
            sample_rest: lattice.sample_pos.iter().map(|&(p, _)| p).collect(),
            segment_samples: lattice.seg_samples,
            edges: lattice.edges,
            control_label: lattice.control_label,
            ik,
            green,
            stats,
            height_m,
            correspondences: ch.correspondences.clone(),
            lattice_key: 0,
        }
    }
}

/// Green coordinates as the bake cache stores them: computed for the lattice and mesh
/// of key `lattice_key`.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct StoredGreen {
    pub lattice_key: u64,
    pub coefficients: GreenCoefficients,
}

/// Why stored Green coordinates were not used.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum StoredGreenMiss {
    #[error("they were computed for another control mesh")]
    OtherLattice,
    #[error(transparent)]
    Unfit(#[from] GreenCoefficientsError),
}

/// A hash of what the Green coordinates depend on: the control mesh, the tet of each
/// mesh vertex, and the mesh vertices.
fn lattice_key(lattice: &LatticeBinding, vertices: &[DVec3]) -> u64 {
    let tets: Vec<u8> = lattice
        .control
        .tets
        .iter()
        .flatten()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let vertex_tets: Vec<u8> = lattice
        .vertex_tets
        .iter()
        .flat_map(|&t| (t as u64).to_le_bytes())
        .collect();
    fnv1a(&[
        &point_bytes(&lattice.control.positions),
        &tets,
        &vertex_tets,
        &point_bytes(vertices),
    ])
}

/// The embedding from stored coordinates, if they belong to this lattice and fit it.
fn reuse(
    lattice: &LatticeBinding,
    key: u64,
    stored: StoredGreen,
) -> Result<GreenEmbedding, StoredGreenMiss> {
    if stored.lattice_key != key {
        return Err(StoredGreenMiss::OtherLattice);
    }
    Ok(GreenEmbedding::from_coefficients(
        &lattice.control,
        &lattice.vertex_tets,
        stored.coefficients,
    )?)
}
