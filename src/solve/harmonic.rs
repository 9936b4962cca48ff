//! The second method: harmonic rotation-field deformation of the full-resolution mesh
//! (de Aguiar, Zayer, Theobalt, Seidel, Magnor, "A Simple Framework for Natural Animation
//! of Digitized Models", SIBGRAPI 2007, Sections 3–4).
//!
//! Precomputation ([`HarmonicRig::new`]): the mesh's cotangent Laplacian `L` (`n x n`,
//! positive semi-definite: `L_ij = −½(cot α_ij + cot β_ij)`, `L_ii = −Σ_j L_ij`, so
//! `L·1 = 0`); the correspondences (each vertex whose nearest bone segment holds it at a
//! distance from both joints of at least `margin` of the segment's length is tied to that
//! segment's owner joint; the others are free, and the margin sets how far a bend spreads,
//! as the paper's Figure 5 shows; a character file may give a joint's triangles instead,
//! see [`Correspondence`]); and one sparse Cholesky factor of `L_ff`, the free
//! vertices' block, shared by every solve below.
//!
//! Per frame ([`HarmonicRig::deform`]), given each joint's world rotation and position
//! (from the posture fit of the markers):
//!
//! 1. Rotation field (Section 3.1): each of the four quaternion components is a harmonic
//!    scalar field, `L_ff q_f = −L_fc q_c`, with the tied vertices' quaternions as
//!    constraints. The constraints are expressed relative to a reference (the root's
//!    rotation) and put in one hemisphere (`w ≥ 0`). When one of them is farther than
//!    150° from the reference (its `w` below `cos 75°`), interpolation would pass near
//!    the 180° singularity the paper describes; such a frame uses the paper's first
//!    remedy instead, the previous frame as reference: the field interpolates each
//!    segment's change since the previous frame, and every vertex composes it with its
//!    previous rotation.
//! 2. Rebuild (Section 3.2): every triangle turns by the normalized mean of its vertices'
//!    quaternions, `R_t`; the positions solve the Poisson system
//!    `L x = b`, `b_i = Σ_t Σ_(i,j)∈t w_ij^t R_t (r_i − r_j)` (the divergence of the
//!    rotated gradients, with `r` the rest positions and `w_ij^t = ½ cot` of the angle
//!    opposite edge `ij` in `t`), with the tied vertices placed rigidly by their joints
//!    (hard positional constraints, which also fix the translation).
//!
//! Allocation-free per frame. With identity rotations at the rest positions the rebuild
//! returns the rest mesh, since `b = L r`.

use crate::character::skeleton::Skeleton;
use crate::character::Correspondence;
use crate::rig::factor::{FactorError, FactorKind, SparseCholesky};
use glam::{DMat3, DQuat, DVec3};

/// Settings of the correspondence set-up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HarmonicParams {
    /// Share of each bone segment's length, at each end, whose vertices stay free (the
    /// paper: the distance of the correspondences from the joint sets the bend's
    /// sharpness).
    pub margin: f64,
}

impl Default for HarmonicParams {
    fn default() -> Self {
        Self { margin: 0.2 }
    }
}

/// Why a mesh cannot be set up for the harmonic method.
#[derive(Debug, thiserror::Error)]
pub enum HarmonicError {
    #[error("the skeleton has no bone segment to tie the mesh to")]
    NoSegments,
    #[error("no vertex lies along a bone within the margins: lower the margin ({margin})")]
    NoCorrespondences { margin: f64 },
    #[error("a part of the mesh ({vertices} vertices, e.g. vertex {example}) has no correspondence: every connected part needs one")]
    UntiedComponent { vertices: usize, example: usize },
    #[error("correspondence of joint {joint}: triangle {triangle} or the joint is out of range")]
    BadCorrespondence { joint: usize, triangle: usize },
    #[error(transparent)]
    Factor(#[from] FactorError),
}

/// What one deformation did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HarmonicReport {
    /// The frame used the previous frame as reference (a constraint was near the 180°
    /// singularity relative to the root).
    pub previous_reference: bool,
}

/// The immutable part: Laplacian blocks, correspondences, factor.
pub struct HarmonicRig {
    rest: Vec<DVec3>,
    triangles: Vec<[u32; 3]>,
    /// Per triangle, `½ cot` of the angle at each corner: the weight of the opposite edge
    /// `[w_bc, w_ca, w_ab]`.
    tri_w: Vec<[f64; 3]>,
    /// Free rows to vertices.
    free_vertex: Vec<u32>,
    /// Tied vertices: (vertex, owner joint).
    tied: Vec<(u32, u32)>,
    /// Per free row (CSR): `(tied index, L_fc entry)`.
    fc_start: Vec<u32>,
    fc: Vec<(u32, f64)>,
    factor: SparseCholesky,
    joint_rest: Vec<DVec3>,
    root: usize,
}

/// The capture's segments (de Aguiar et al., Section 3: a group of three or more markers
/// per segment): per joint, the markers its segment carries, when there are at least
/// three. Each frame, such a segment's rotation is the best fit of its rest cluster onto
/// the current one (Kabsch, through the polar rotation of the cross-covariance), instead
/// of the posture fit's.
#[derive(Clone, Debug)]
pub struct SegmentClusters {
    /// `(joint, its rest position, marker indices)`, for joints with three or more
    /// markers.
    clusters: Vec<(usize, DVec3, Vec<usize>)>,
}

/// A cluster whose present markers are nearly collinear cannot fix a rotation about
/// their line: its cross-covariance's rank-2 part (the adjugate) must exceed this share
/// of its size squared, else the posture fit's rotation stays.
const CLUSTER_RANK_RATIO: f64 = 1e-6;

impl SegmentClusters {
    /// The clusters of markers carried by `marker_joint[k]` (one joint of `sk` per
    /// marker).
    pub fn new(marker_joint: &[usize], sk: &Skeleton) -> Self {
        let mut per_joint = vec![Vec::new(); sk.len()];
        for (k, &j) in marker_joint.iter().enumerate() {
            if let Some(v) = per_joint.get_mut(j) {
                v.push(k);
            }
        }
        Self {
            clusters: per_joint
                .into_iter()
                .enumerate()
                .filter(|(_, m)| m.len() >= 3)
                .map(|(j, m)| (j, sk.joints[j].rest, m))
                .collect(),
        }
    }

    /// Joints whose rotation comes from their cluster when it is seen.
    pub fn joints(&self) -> impl Iterator<Item = usize> + '_ {
        self.clusters.iter().map(|(j, _, _)| *j)
    }

    /// Replaces `rot[j]`, `pos[j]` (world rotation and position of joint `j`, as the
    /// posture fit left them; also the warm start) by the rigid motion that best takes
    /// the rest cluster `marker_rest` onto `targets` (NaN where a marker is not present),
    /// for every cluster with three or more present markers that are not collinear.
    /// Returns how many segments it set.
    pub fn fit(
        &self,
        targets: &[DVec3],
        marker_rest: &[DVec3],
        rot: &mut [DQuat],
        pos: &mut [DVec3],
    ) -> usize {
        let mut set = 0;
        for (j, joint_rest, markers) in &self.clusters {
            let j = *j;
            let (mut n, mut c_rest, mut c_now) = (0usize, DVec3::ZERO, DVec3::ZERO);
            for &k in markers {
                if targets[k].is_finite() {
                    n += 1;
                    c_rest += marker_rest[k];
                    c_now += targets[k];
                }
            }
            if n < 3 {
                continue;
            }
            c_rest /= n as f64;
            c_now /= n as f64;
            // A = Σ (x_k − c_now)(r_k − c_rest)ᵀ: R maximising tr(Rᵀ A) is the fit.
            let mut a = DMat3::ZERO;
            for &k in markers {
                if targets[k].is_finite() {
                    let (x, r) = (targets[k] - c_now, marker_rest[k] - c_rest);
                    a += DMat3::from_cols(x * r.x, x * r.y, x * r.z);
                }
            }
            let adjugate = a.x_axis.cross(a.y_axis).length_squared()
                + a.y_axis.cross(a.z_axis).length_squared()
                + a.z_axis.cross(a.x_axis).length_squared();
            let size2 =
                a.x_axis.length_squared() + a.y_axis.length_squared() + a.z_axis.length_squared();
            if adjugate.sqrt() <= CLUSTER_RANK_RATIO * size2 {
                continue;
            }
            let mut q = rot[j];
            crate::geom::polar::extract_rotation(&a, &mut q);
            rot[j] = q;
            pos[j] = c_now - q * (c_rest - *joint_rest);
            set += 1;
        }
        set
    }
}

impl HarmonicState {
    /// Each vertex's world rotation from the last deformation (the normalized rotation
    /// field, composed with the frame's reference).
    pub fn vertex_rotations(&self) -> &[DQuat] {
        &self.vertex_rot
    }
}

/// Per-solver memory.
pub struct HarmonicState {
    /// Per vertex rotation of the previous frame (world).
    vertex_rot: Vec<DQuat>,
    /// Per joint world rotation of the previous frame.
    prev_joint_rot: Vec<DQuat>,
    /// Constraint quaternions of the tied vertices (relative to the frame's reference).
    tied_q: Vec<DQuat>,
    /// Free solves: xyz and w components, positions; and a substitution workspace.
    rhs_xyz: Vec<DVec3>,
    rhs_w: Vec<DVec3>,
    rhs_x: Vec<DVec3>,
    work: Vec<DVec3>,
    /// Divergence of the rotated gradients, per vertex.
    div: Vec<DVec3>,
    tied_x: Vec<DVec3>,
}

/// Triangles with twice their area below this share of their longest edge squared are
/// needles or slivers left by mesh simplification: their cotangents are unbounded, so
/// they are left out of the Laplacian altogether (all three weights zero, which keeps
/// `L` the stiffness matrix of the remaining triangles and `b = L r` at rest).
const DEGENERATE_AREA_RATIO: f64 = 1e-10;

/// `½ cot` of the angles at `a`, `b`, `c` of a triangle: the weights of the opposite
/// edges `[w_bc, w_ca, w_ab]`; zeros for a degenerate triangle.
fn half_cots(a: DVec3, b: DVec3, c: DVec3) -> [f64; 3] {
    let twice_area = (b - a).cross(c - a).length();
    let longest2 = (b - a)
        .length_squared()
        .max((c - b).length_squared())
        .max((a - c).length_squared());
    if twice_area <= DEGENERATE_AREA_RATIO * longest2 {
        return [0.0; 3];
    }
    let cot = |p: DVec3, q: DVec3, r: DVec3| 0.5 * (q - p).dot(r - p) / twice_area;
    [cot(a, b, c), cot(b, c, a), cot(c, a, b)]
}

/// Distance from `p` to segment `a..b` and the projection parameter along it (0..1).
fn segment_distance(p: DVec3, a: DVec3, b: DVec3) -> (f64, f64) {
    let d = b - a;
    let l2 = d.length_squared();
    let t = if l2 > 0.0 {
        ((p - a).dot(d) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    ((p - (a + d * t)).length(), t)
}

impl HarmonicRig {
    /// Sets up `vertices` / `triangles` (the full-resolution mesh at rest, metres) for the
    /// skeleton `sk` (its rest pose matching the mesh). `given`: correspondences from the
    /// character file; each replaces its joint's automatic ones, and its vertices follow
    /// that joint whatever the automatic choice said.
    pub fn new(
        vertices: &[DVec3],
        triangles: &[[u32; 3]],
        sk: &Skeleton,
        params: &HarmonicParams,
        given: &[Correspondence],
    ) -> Result<Self, HarmonicError> {
        let n = vertices.len();
        let segments: Vec<(usize, usize)> = sk
            .joints
            .iter()
            .enumerate()
            .filter_map(|(c, j)| j.parent.map(|p| (p, c)))
            .collect();
        if segments.is_empty() {
            return Err(HarmonicError::NoSegments);
        }
        // Correspondences: the nearest segment, within its margins.
        let mut owner = vec![u32::MAX; n];
        for (v, p) in vertices.iter().enumerate() {
            let mut best = (f64::INFINITY, 0.0, 0usize);
            for &(a, b) in &segments {
                let (d, t) = segment_distance(*p, sk.joints[a].rest, sk.joints[b].rest);
                if d < best.0 {
                    best = (d, t, a);
                }
            }
            if best.1 >= params.margin && best.1 <= 1.0 - params.margin {
                owner[v] = best.2 as u32;
            }
        }
        for c in given {
            for o in owner.iter_mut().filter(|o| **o as usize == c.joint) {
                *o = u32::MAX;
            }
        }
        for c in given {
            for &t in &c.triangles {
                let Some(tri) = triangles.get(t as usize) else {
                    return Err(HarmonicError::BadCorrespondence {
                        joint: c.joint,
                        triangle: t as usize,
                    });
                };
                for &v in tri {
                    owner[v as usize] = c.joint as u32;
                }
            }
            if c.joint >= sk.len() {
                return Err(HarmonicError::BadCorrespondence {
                    joint: c.joint,
                    triangle: 0,
                });
            }
        }
        let tied: Vec<(u32, u32)> = owner
            .iter()
            .enumerate()
            .filter(|(_, o)| **o != u32::MAX)
            .map(|(v, o)| (v as u32, *o))
            .collect();
        if tied.is_empty() {
            return Err(HarmonicError::NoCorrespondences {
                margin: params.margin,
            });
        }
        let mut free_row = vec![u32::MAX; n];
        let mut free_vertex = Vec::new();
        for v in 0..n {
            if owner[v] == u32::MAX {
                free_row[v] = free_vertex.len() as u32;
                free_vertex.push(v as u32);
            }
        }
        let mut tied_index = vec![u32::MAX; n];
        for (k, &(v, _)) in tied.iter().enumerate() {
            tied_index[v as usize] = k as u32;
        }
        // Cotangent weights and the Laplacian's entries.
        let mut tri_w = Vec::with_capacity(triangles.len());
        let mut edges: Vec<(u32, u32, f64)> = Vec::with_capacity(triangles.len() * 3);
        for t in triangles {
            let [a, b, c] = t.map(|i| vertices[i as usize]);
            let w = half_cots(a, b, c);
            tri_w.push(w);
            edges.push((t[1], t[2], w[0]));
            edges.push((t[2], t[0], w[1]));
            edges.push((t[0], t[1], w[2]));
        }
        // Every free vertex must reach a tied one (else L_ff is singular there).
        check_components(n, &edges, &owner)?;
        let mut upper: Vec<(usize, usize, f64)> = Vec::with_capacity(edges.len() * 2);
        let mut fc_rows: Vec<Vec<(u32, f64)>> = vec![Vec::new(); free_vertex.len()];
        for &(i, j, w) in &edges {
            let (fi, fj) = (free_row[i as usize], free_row[j as usize]);
            if fi != u32::MAX {
                upper.push((fi as usize, fi as usize, w));
            }
            if fj != u32::MAX {
                upper.push((fj as usize, fj as usize, w));
            }
            match (fi != u32::MAX, fj != u32::MAX) {
                (true, true) => upper.push((fi.min(fj) as usize, fi.max(fj) as usize, -w)),
                (true, false) => fc_rows[fi as usize].push((tied_index[j as usize], -w)),
                (false, true) => fc_rows[fj as usize].push((tied_index[i as usize], -w)),
                (false, false) => {}
            }
        }
        let nf = free_vertex.len();
        let factor = if nf > 0 {
            SparseCholesky::factor_upper(nf, &upper, FactorKind::Simplicial)?
        } else {
            SparseCholesky::factor_upper(1, &[(0, 0, 1.0)], FactorKind::Simplicial)?
        };
        let mut fc_start = Vec::with_capacity(nf + 1);
        let mut fc = Vec::new();
        fc_start.push(0);
        for mut row in fc_rows {
            row.sort_unstable_by_key(|e| e.0);
            let start = fc.len();
            for (k, w) in row {
                let n = fc.len();
                match fc.last_mut() {
                    Some((lk, lw)) if n > start && *lk == k => *lw += w,
                    _ => fc.push((k, w)),
                }
            }
            fc_start.push(fc.len() as u32);
        }
        let root = sk
            .joints
            .iter()
            .position(|j| j.parent.is_none())
            .unwrap_or(0);
        Ok(Self {
            rest: vertices.to_vec(),
            triangles: triangles.to_vec(),
            tri_w,
            free_vertex,
            tied,
            fc_start,
            fc,
            factor,
            joint_rest: sk.joints.iter().map(|j| j.rest).collect(),
            root,
        })
    }

    /// The skeleton's root joint: the frame's reference rotation.
    pub fn root(&self) -> usize {
        self.root
    }

    /// The correspondences: `(vertex, joint)` for every tied vertex.
    pub fn tied(&self) -> &[(u32, u32)] {
        &self.tied
    }

    /// The vertices tied to joint `j`'s segment.
    pub fn tied_to(&self, j: usize) -> impl Iterator<Item = usize> + '_ {
        self.tied
            .iter()
            .filter(move |(_, o)| *o as usize == j)
            .map(|(v, _)| *v as usize)
    }

    /// Vertices tied to a joint (the correspondences) and all vertices.
    pub fn tied_count(&self) -> (usize, usize) {
        (self.tied.len(), self.rest.len())
    }

    pub fn new_state(&self) -> HarmonicState {
        let nf = self.free_vertex.len().max(1);
        HarmonicState {
            vertex_rot: vec![DQuat::IDENTITY; self.rest.len()],
            prev_joint_rot: vec![DQuat::IDENTITY; self.joint_rest.len()],
            tied_q: vec![DQuat::IDENTITY; self.tied.len()],
            rhs_xyz: vec![DVec3::ZERO; nf],
            rhs_w: vec![DVec3::ZERO; nf],
            rhs_x: vec![DVec3::ZERO; nf],
            work: vec![DVec3::ZERO; nf],
            div: vec![DVec3::ZERO; self.rest.len()],
            tied_x: vec![DVec3::ZERO; self.tied.len()],
        }
    }

    /// Solves `L_ff y = −L_fc c` for one field per component of `c` (three at once).
    fn harmonic3(&self, c: impl Fn(usize) -> DVec3, rhs: &mut [DVec3], work: &mut [DVec3]) {
        for (r, out) in rhs.iter_mut().enumerate() {
            let (a, b) = (self.fc_start[r] as usize, self.fc_start[r + 1] as usize);
            *out = self.fc[a..b].iter().map(|&(k, w)| -c(k as usize) * w).sum();
        }
        self.factor.solve3(rhs, work);
    }

    /// Deforms the mesh for joint world rotations `rot` and positions `pos` (one per
    /// skeleton joint; the rest pose is identity rotations at the rest positions) into
    /// `out` (`len` = vertex count).
    pub fn deform(
        &self,
        st: &mut HarmonicState,
        rot: &[DQuat],
        pos: &[DVec3],
        out: &mut [DVec3],
    ) -> HarmonicReport {
        // 1. Constraint quaternions relative to the root's rotation, one hemisphere.
        let reference = rot[self.root];
        let inv_ref = reference.conjugate();
        let mut worst_w = 1.0f64;
        for (q, &(_, j)) in st.tied_q.iter_mut().zip(&self.tied) {
            let mut c = inv_ref * rot[j as usize];
            if c.w < 0.0 {
                c = -c;
            }
            worst_w = worst_w.min(c.w);
            *q = c;
        }
        let previous_reference = worst_w < 75f64.to_radians().cos();
        if previous_reference {
            // The paper's remedy: interpolate each segment's change since the previous
            // frame (small, far from the singularity) instead.
            for (q, &(_, j)) in st.tied_q.iter_mut().zip(&self.tied) {
                let j = j as usize;
                let mut c = rot[j] * st.prev_joint_rot[j].conjugate();
                if c.w < 0.0 {
                    c = -c;
                }
                *q = c;
            }
        }
        let tied_q = &st.tied_q;
        self.harmonic3(
            |k| DVec3::new(tied_q[k].x, tied_q[k].y, tied_q[k].z),
            &mut st.rhs_xyz,
            &mut st.work,
        );
        self.harmonic3(
            |k| DVec3::new(tied_q[k].w, 0.0, 0.0),
            &mut st.rhs_w,
            &mut st.work,
        );
        // Per-vertex world rotation (unnormalized interpolants are normalized per
        // triangle below; here per vertex too, for the next frame's reference).
        let compose = |field: DQuat, prev: DQuat| {
            let f = field.normalize();
            if previous_reference {
                (f * prev).normalize()
            } else {
                reference * f
            }
        };
        for (r, &v) in self.free_vertex.iter().enumerate() {
            let q = DQuat::from_xyzw(
                st.rhs_xyz[r].x,
                st.rhs_xyz[r].y,
                st.rhs_xyz[r].z,
                st.rhs_w[r].x,
            );
            let v = v as usize;
            st.vertex_rot[v] = compose(q, st.vertex_rot[v]);
        }
        for (k, &(v, _)) in self.tied.iter().enumerate() {
            let v = v as usize;
            st.vertex_rot[v] = compose(st.tied_q[k], st.vertex_rot[v]);
        }
        // 2. Divergence of the rotated gradients.
        st.div.fill(DVec3::ZERO);
        for (t, w) in self.triangles.iter().zip(&self.tri_w) {
            let [a, b, c] = t.map(|i| i as usize);
            let (qa, mut qb, mut qc) = (st.vertex_rot[a], st.vertex_rot[b], st.vertex_rot[c]);
            if qa.dot(qb) < 0.0 {
                qb = -qb;
            }
            if qa.dot(qc) < 0.0 {
                qc = -qc;
            }
            let r = DMat3::from_quat((qa + qb + qc).normalize());
            for (&(i, j), wij) in [(b, c), (c, a), (a, b)].iter().zip(w) {
                let e = r * (self.rest[i] - self.rest[j]) * *wij;
                st.div[i] += e;
                st.div[j] -= e;
            }
        }
        for (x, &(v, j)) in st.tied_x.iter_mut().zip(&self.tied) {
            let j = j as usize;
            *x = pos[j] + rot[j] * (self.rest[v as usize] - self.joint_rest[j]);
        }
        for (r, &v) in self.free_vertex.iter().enumerate() {
            let (a, b) = (self.fc_start[r] as usize, self.fc_start[r + 1] as usize);
            st.rhs_x[r] = st.div[v as usize]
                - self.fc[a..b]
                    .iter()
                    .map(|&(k, w)| st.tied_x[k as usize] * w)
                    .sum::<DVec3>();
        }
        if !self.free_vertex.is_empty() {
            self.factor.solve3(&mut st.rhs_x, &mut st.work);
        }
        for (r, &v) in self.free_vertex.iter().enumerate() {
            out[v as usize] = st.rhs_x[r];
        }
        for (k, &(v, _)) in self.tied.iter().enumerate() {
            out[v as usize] = st.tied_x[k];
        }
        st.prev_joint_rot.copy_from_slice(rot);
        HarmonicReport { previous_reference }
    }
}

/// Fails when a connected part of the mesh has no tied vertex.
fn check_components(
    n: usize,
    edges: &[(u32, u32, f64)],
    owner: &[u32],
) -> Result<(), HarmonicError> {
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn find(p: &mut [u32], mut x: u32) -> u32 {
        while p[x as usize] != x {
            p[x as usize] = p[p[x as usize] as usize];
            x = p[x as usize];
        }
        x
    }
    for &(a, b, _) in edges {
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        if ra != rb {
            parent[ra as usize] = rb;
        }
    }
    let mut tied_root = vec![false; n];
    for (v, o) in owner.iter().enumerate() {
        if *o != u32::MAX {
            let r = find(&mut parent, v as u32) as usize;
            tied_root[r] = true;
        }
    }
    let mut untied = std::collections::HashMap::<u32, (usize, usize)>::new();
    for v in 0..n {
        let r = find(&mut parent, v as u32);
        if !tied_root[r as usize] {
            let e = untied.entry(r).or_insert((0, v));
            e.0 += 1;
        }
    }
    match untied.values().max_by_key(|e| e.0) {
        Some(&(vertices, example)) => Err(HarmonicError::UntiedComponent { vertices, example }),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::character::demo::demo_hand;

    fn setup() -> (crate::character::Character, HarmonicRig) {
        let ch = demo_hand();
        let rig = hand_rig(&ch, &[]).unwrap();
        (ch, rig)
    }

    /// The hand's rig with the given correspondences.
    fn hand_rig(
        ch: &crate::character::Character,
        given: &[Correspondence],
    ) -> Result<HarmonicRig, HarmonicError> {
        HarmonicRig::new(
            &ch.vertices,
            &ch.triangles,
            &ch.skeleton,
            &HarmonicParams::default(),
            given,
        )
    }

    /// The index of the joint named `name`.
    fn joint(sk: &crate::character::skeleton::Skeleton, name: &str) -> usize {
        sk.joints.iter().position(|jt| jt.name == name).unwrap()
    }

    #[test]
    fn cotangent_weights_give_the_dirichlet_energy_of_linear_functions() {
        // For a piecewise-linear f, Σ_t Σ_ij w_ij (f_i − f_j)² = Σ_t area_t |∇f|² (the
        // cotangent formula); for f = x, y, z the gradient is the coordinate axis
        // projected onto each triangle's plane. A constant has zero energy (L·1 = 0).
        let (ch, rig) = setup();
        for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
            let (mut energy, mut integral) = (0.0, 0.0);
            for (t, w) in rig.triangles.iter().zip(&rig.tri_w) {
                let [a, b, c] = t.map(|i| ch.vertices[i as usize]);
                let f = |p: DVec3| p.dot(axis);
                energy += w[0] * (f(b) - f(c)).powi(2)
                    + w[1] * (f(c) - f(a)).powi(2)
                    + w[2] * (f(a) - f(b)).powi(2);
                let n = (b - a).cross(c - a);
                // Degenerate triangles are out of the Laplacian (zero weights).
                let area = if w == &[0.0; 3] {
                    0.0
                } else {
                    0.5 * n.length()
                };
                let unit = n.normalize_or_zero();
                let g = axis - unit * axis.dot(unit);
                integral += area * g.length_squared();
            }
            assert!(
                (energy - integral).abs() <= 1e-9 * integral,
                "{energy} vs {integral}"
            );
        }
        let (tied, all) = rig.tied_count();
        assert!(tied > all / 4 && tied < all, "{tied} of {all} tied");
    }

    #[test]
    fn the_rest_pose_rebuilds_the_rest_mesh() {
        let (ch, rig) = setup();
        let mut st = rig.new_state();
        let sk = &ch.skeleton;
        let rot = vec![DQuat::IDENTITY; sk.len()];
        let pos: Vec<DVec3> = sk.joints.iter().map(|j| j.rest).collect();
        let mut out = vec![DVec3::ZERO; ch.vertices.len()];
        rig.deform(&mut st, &rot, &pos, &mut out);
        let worst = out
            .iter()
            .zip(&ch.vertices)
            .map(|(a, b)| (*a - *b).length())
            .fold(0.0, f64::max);
        // The bound: 1e-9 (metres, on a 0.2 m hand).
        assert!(worst < 1e-9, "{worst}");
    }

    #[test]
    fn a_rigid_motion_of_every_joint_moves_the_mesh_rigidly() {
        let (ch, rig) = setup();
        let mut st = rig.new_state();
        let sk = &ch.skeleton;
        let q = DQuat::from_axis_angle(DVec3::new(1.0, 2.0, -0.5).normalize(), 1.1);
        let t = DVec3::new(0.3, -0.2, 0.1);
        let rot = vec![q; sk.len()];
        let pos: Vec<DVec3> = sk.joints.iter().map(|j| q * j.rest + t).collect();
        let mut out = vec![DVec3::ZERO; ch.vertices.len()];
        rig.deform(&mut st, &rot, &pos, &mut out);
        let worst = out
            .iter()
            .zip(&ch.vertices)
            .map(|(a, b)| (*a - (q * *b + t)).length())
            .fold(0.0, f64::max);
        assert!(worst < 1e-9, "{worst}");
    }

    #[test]
    fn harmonic_fields_stay_within_their_constraint_values() {
        // Maximum principle: with non-negative weights each free value is a weighted mean
        // of its neighbours, so it lies between the constraints' extremes. Cotangent
        // weights can be negative on obtuse triangles; the procedural meshes keep the
        // excursion within round-off of the bounds plus 1 %.
        let (ch, rig) = setup();
        let mut st = rig.new_state();
        let k = rig.tied.len();
        let values: Vec<f64> = (0..k).map(|i| ((i * 37) % 101) as f64 / 100.0).collect();
        let (lo, hi) = values
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(*v), b.max(*v)));
        rig.harmonic3(|i| DVec3::splat(values[i]), &mut st.rhs_xyz, &mut st.work);
        let span = hi - lo;
        for v in &st.rhs_xyz {
            assert!(
                v.x >= lo - 0.01 * span && v.x <= hi + 0.01 * span,
                "{} outside [{lo}, {hi}]",
                v.x
            );
        }
        let _ = ch;
    }

    #[test]
    fn a_bent_finger_bends_the_mesh_near_it_only() {
        let (ch, rig) = setup();
        let mut st = rig.new_state();
        let sk = &ch.skeleton;
        let j = joint(sk, "index_2");
        let mut local = vec![DQuat::IDENTITY; sk.len()];
        local[j] = DQuat::from_axis_angle(sk.joints[j].bend_axis, 1.2);
        let (mut rot, mut pos) = (vec![DQuat::IDENTITY; sk.len()], vec![DVec3::ZERO; sk.len()]);
        sk.forward(&local, DVec3::ZERO, &mut rot, &mut pos);
        let mut out = vec![DVec3::ZERO; ch.vertices.len()];
        let rep = rig.deform(&mut st, &rot, &pos, &mut out);
        assert!(!rep.previous_reference);
        // The thumb does not move; the index tip does.
        let moved = |name: &str| {
            let jt = joint(sk, name);
            ch.vertices
                .iter()
                .zip(&out)
                .filter(|(v, _)| (**v - sk.joints[jt].rest).length() < 0.008)
                .map(|(a, b)| (*a - *b).length())
                .fold(0.0, f64::max)
        };
        assert!(moved("thumb_tip") < 1e-6, "{}", moved("thumb_tip"));
        assert!(moved("index_tip") > 0.01, "{}", moved("index_tip"));
    }

    /// The 180° remedy: the index finger bent at its knuckle in 10° steps from rest to
    /// 200°, each frame from the last. Up to 150° from the root the field interpolates
    /// from the root; past it (160° on) each frame interpolates the change since the
    /// previous one. Through 180°, where the hemisphere of the root-relative constraint
    /// flips, every vertex moves on smoothly: no step moves it more than twice its
    /// median step plus 1 mm (the root-relative field, kept past 180°, turns the
    /// knuckle's vertices the other way round at once).
    #[test]
    fn a_finger_bent_through_180_degrees_moves_smoothly() {
        let (ch, rig) = setup();
        let mut st = rig.new_state();
        let sk = &ch.skeleton;
        let j = joint(sk, "index_1");
        let (mut rot, mut pos) = (vec![DQuat::IDENTITY; sk.len()], vec![DVec3::ZERO; sk.len()]);
        let mut local = vec![DQuat::IDENTITY; sk.len()];
        let mut frames = vec![ch.vertices.clone()];
        for step in 1..=20 {
            let deg = 10.0 * step as f64;
            local[j] = DQuat::from_axis_angle(sk.joints[j].bend_axis, deg.to_radians());
            sk.forward(&local, DVec3::ZERO, &mut rot, &mut pos);
            let mut out = vec![DVec3::ZERO; ch.vertices.len()];
            let rep = rig.deform(&mut st, &rot, &pos, &mut out);
            assert_eq!(rep.previous_reference, deg > 150.0, "at {deg}°");
            frames.push(out);
        }
        let mut worst = (0.0, 0, 0);
        for v in 0..ch.vertices.len() {
            let steps: Vec<f64> = frames
                .windows(2)
                .map(|w| (w[1][v] - w[0][v]).length())
                .collect();
            let mut sorted = steps.clone();
            sorted.sort_by(f64::total_cmp);
            let bound = 2.0 * sorted[sorted.len() / 2] + 1e-3;
            for (k, m) in steps.iter().enumerate() {
                if m / bound > worst.0 {
                    worst = (m / bound, v, 10 * (k + 1));
                }
            }
        }
        let (ratio, v, deg) = worst;
        assert!(
            ratio <= 1.0,
            "vertex {v} jumps at {deg}°: {ratio} times its bound"
        );
    }

    #[test]
    fn correspondences_from_the_file_replace_the_automatic_ones_of_their_joint() {
        let (ch, auto) = setup();
        // The first 40 triangles, tied to the joint that owns the most automatic ties.
        let j = (0..ch.skeleton.len())
            .max_by_key(|&j| auto.tied_to(j).count())
            .unwrap();
        let given = Correspondence {
            joint: j,
            triangles: (0..40).collect(),
        };
        let rig = hand_rig(&ch, std::slice::from_ref(&given)).unwrap();
        let mut expected: Vec<usize> = ch.triangles[..40]
            .iter()
            .flatten()
            .map(|&v| v as usize)
            .collect();
        expected.sort_unstable();
        expected.dedup();
        let mut got: Vec<usize> = rig.tied_to(j).collect();
        got.sort_unstable();
        assert_eq!(got, expected);
        // Every other joint keeps its automatic ties, less the vertices now given to j.
        for k in (0..ch.skeleton.len()).filter(|&k| k != j) {
            let kept: Vec<usize> = auto
                .tied_to(k)
                .filter(|v| expected.binary_search(v).is_err())
                .collect();
            assert_eq!(rig.tied_to(k).collect::<Vec<_>>(), kept, "joint {k}");
        }
        // Out of range: an error, not a panic.
        let bad = Correspondence {
            joint: j,
            triangles: vec![ch.triangles.len() as u32],
        };
        assert!(matches!(
            hand_rig(&ch, &[bad]),
            Err(HarmonicError::BadCorrespondence { .. })
        ));
    }
}
