//! The precomputed ARAP system a rig carries: the control mesh's cotangent weights
//! ([`ArapOperator`]), the soft constraint rows ([`LinearRows`]) and the factored matrix
//! of the global step ([`ArapSystem`]). Built once at bind time; solve's local/global
//! alternation (`solve::arap`) reads it every frame.
//!
//! Energy (Le Naour et al., Eq. 5 and Eq. 11):
//!
//! ```text
//! E(V') = (w_l / h) Σ_i Σ_{j∈N(i)} w_ij ‖(v'_i − v'_j) − R_i (v_i − v_j)‖²
//!       + Σ_r ω_r ‖a_rᵀ V' − t_r‖²
//! ```
//!
//! - `w_ij` are the volumetric cotangent weights `(1/6) Σ_k l_kl cot θ_kl` over the tets
//!   sharing edge `ij`, computed as the linear-FEM stiffness `−(N_i·N_j) / (9 V)` (`N_i`:
//!   area-weighted outward normal of the face opposite `i`). Negative weights (slivers)
//!   are clamped to zero, and counted, because per-vertex ARAP inverts tets with them.
//! - `h` is the mean rest edge length, so the energy balance, and hence every result, is
//!   unchanged when the whole problem is scaled.
//! - Rows `a_r` are sparse (marker barycentric rows, skeleton difference rows, fixed
//!   vertices); their weights `ω_r` and sparsity are fixed at bind time, only targets `t_r`
//!   change per frame or per iteration.
//!
//! The global step's matrix (∂E/∂V' = 0, divided by 2) is
//! `2 (w_l/h) L + Σ_r ω_r a_r a_rᵀ`, with `L` the weighted graph Laplacian
//! (`L_ii = Σ_j w_ij`, `L_ij = −w_ij`); it does not depend on the rotations or the
//! targets, so it is factored once, here.

use super::factor::{FactorError, FactorKind, SparseCholesky};
use super::tetmesh::TetMesh;
use glam::{DMat3, DVec3};

/// Cotangent weights of a tet mesh as a symmetric adjacency (CSR, both directions).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ArapOperator {
    /// Rest positions `v_i`.
    pub rest: Vec<DVec3>,
    /// CSR row starts, `n + 1` entries.
    pub start: Vec<u32>,
    /// Neighbour index per adjacency entry.
    pub nbr: Vec<u32>,
    /// Clamped cotangent weight per adjacency entry (`w_ij ≥ 0`).
    pub weight: Vec<f64>,
    /// Rest edge `v_i − v_j` per adjacency entry.
    pub rest_edge: Vec<DVec3>,
    /// Per vertex `Σ_j w_ij (v_i − v_j)` (so the right-hand side needs `R_i` once).
    pub rest_sum: Vec<DVec3>,
    /// Per vertex `Σ_j w_ij ‖v_i − v_j‖²`.
    pub rest_sq: Vec<f64>,
    /// Σ_i Σ_j w_ij ‖v_i − v_j‖² (denominator of rrms).
    pub rest_energy_scale: f64,
    /// Mean rest edge length `h`.
    pub mean_edge_length: f64,
    /// Number of edges whose summed cotangent weight was negative and clamped to zero.
    pub clamped_weights: usize,
    /// Number of undirected edges (with or without weight).
    pub n_edges: usize,
}

/// Systems up to this many unknowns use the simplicial factor and its interleaved
/// three-column substitution; larger ones faer's supernodal factor. Measured here
/// (global step, ms): 1,854 unknowns 0.42 simplicial vs 0.46 supernodal; 9,427: 5.5 vs
/// 4.3; 28,524: 39 vs 32, and a 3.8 s simplicial factorization against 0.45 s.
pub const SIMPLICIAL_MAX_N: usize = 5_000;

/// Edge weights at or below this fraction of the largest are treated as zero (round-off
/// of an exact zero, e.g. an edge whose dihedral angles are all 90°) and left out of the
/// adjacency.
pub const ZERO_WEIGHT_FRACTION: f64 = 1e-12;

impl ArapOperator {
    /// Computes clamped cotangent weights for `mesh` (rest = its positions).
    pub fn new(mesh: &TetMesh) -> Self {
        let n = mesh.positions.len();
        let p = &mesh.positions;
        let mut edges: Vec<(u32, u32, f64)> = Vec::with_capacity(mesh.tets.len() * 6);
        for t in &mesh.tets {
            let x = t.map(|i| p[i as usize]);
            let vol6 = super::tetmesh::signed_volume6(x[0], x[1], x[2], x[3]);
            let vol = vol6 / 6.0;
            // Area-weighted outward normal of the face opposite each vertex.
            let mut nrm = [DVec3::ZERO; 4];
            for (k, nk) in nrm.iter_mut().enumerate() {
                let [a, b, c] = FACE_OPPOSITE[k].map(|s| x[s]);
                *nk = 0.5 * (b - a).cross(c - a);
            }
            for (a, b) in super::tetmesh::EDGE_PAIRS {
                let w = -nrm[a].dot(nrm[b]) / (9.0 * vol);
                let (i, j) = (t[a].min(t[b]), t[a].max(t[b]));
                edges.push((i, j, w));
            }
        }
        edges.sort_unstable_by_key(|&(i, j, _)| (i, j));
        let mut merged: Vec<(u32, u32, f64)> = Vec::with_capacity(edges.len() / 3);
        for (i, j, w) in edges {
            match merged.last_mut() {
                Some(e) if e.0 == i && e.1 == j => e.2 += w,
                _ => merged.push((i, j, w)),
            }
        }
        let mut clamped = 0;
        for e in &mut merged {
            if e.2 < 0.0 {
                e.2 = 0.0;
                clamped += 1;
            }
        }
        // h counts every edge; the adjacency keeps only edges with weight (clamped ones
        // and the 90°-only edges of a Kuhn lattice add nothing to any sum).
        let n_edges = merged.len();
        let len_sum: f64 = merged
            .iter()
            .map(|&(i, j, _)| (p[i as usize] - p[j as usize]).length())
            .sum();
        let max_w = merged.iter().map(|e| e.2).fold(0.0, f64::max);
        merged.retain(|e| e.2 > ZERO_WEIGHT_FRACTION * max_w);
        let mut degree = vec![0u32; n + 1];
        for &(i, j, _) in &merged {
            degree[i as usize + 1] += 1;
            degree[j as usize + 1] += 1;
        }
        for k in 0..n {
            degree[k + 1] += degree[k];
        }
        let start = degree;
        let mut fill = start.clone();
        let total = start[n] as usize;
        let mut nbr = vec![0u32; total];
        let mut weight = vec![0.0; total];
        let mut rest_edge = vec![DVec3::ZERO; total];
        let mut rest_sum = vec![DVec3::ZERO; n];
        let mut rest_sq = vec![0.0; n];
        for &(i, j, w) in &merged {
            let e = p[i as usize] - p[j as usize];
            rest_sum[i as usize] += e * w;
            rest_sum[j as usize] -= e * w;
            rest_sq[i as usize] += w * e.length_squared();
            rest_sq[j as usize] += w * e.length_squared();
            for (a, b, ev) in [(i, j, e), (j, i, -e)] {
                let slot = fill[a as usize] as usize;
                fill[a as usize] += 1;
                nbr[slot] = b;
                weight[slot] = w;
                rest_edge[slot] = ev;
            }
        }
        let rest_energy_scale = weight
            .iter()
            .zip(&rest_edge)
            .map(|(w, e)| w * e.length_squared())
            .sum();
        Self {
            rest: p.clone(),
            start,
            nbr,
            weight,
            rest_edge,
            rest_sum,
            rest_sq,
            rest_energy_scale,
            mean_edge_length: if n_edges > 0 {
                len_sum / n_edges as f64
            } else {
                1.0
            },
            clamped_weights: clamped,
            n_edges,
        }
    }

    /// Number of vertices.
    pub fn n(&self) -> usize {
        self.rest.len()
    }

    /// `L · x` for a scalar field `x` (`L_ii = Σ_j w_ij`, `L_ij = −w_ij`).
    pub fn apply_laplacian(&self, x: &[f64], out: &mut [f64]) {
        for i in 0..self.n() {
            let mut s = 0.0;
            for k in self.start[i] as usize..self.start[i + 1] as usize {
                s += self.weight[k] * (x[i] - x[self.nbr[k] as usize]);
            }
            out[i] = s;
        }
    }

    /// The shape energy `Σ_i Σ_j w_ij ‖(v'_i − v'_j) − R_i (v_i − v_j)‖²` (without
    /// `w_l / h`), evaluated directly (used by tests and metrics, not the hot path).
    pub fn shape_energy(&self, positions: &[DVec3], rotations: &[DMat3]) -> f64 {
        let mut e = 0.0;
        for i in 0..self.n() {
            for k in self.start[i] as usize..self.start[i + 1] as usize {
                let j = self.nbr[k] as usize;
                let d = (positions[i] - positions[j]) - rotations[i] * self.rest_edge[k];
                e += self.weight[k] * d.length_squared();
            }
        }
        e
    }
}

/// Vertex slots of the face opposite each vertex slot of a tet. Orientation does not
/// matter for the weights (the product of two normals flips sign twice).
const FACE_OPPOSITE: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

/// Sparse soft-constraint rows `a_r` with fixed weights `ω_r` (CSR over rows).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct LinearRows {
    /// Row starts, `rows + 1` entries (starts with 0).
    pub start: Vec<u32>,
    /// Column (vertex) index per entry.
    pub idx: Vec<u32>,
    /// Coefficient per entry.
    pub coef: Vec<f64>,
    /// Weight `ω_r` per row (unitless).
    pub weight: Vec<f64>,
}

impl LinearRows {
    pub fn new() -> Self {
        Self {
            start: vec![0],
            ..Default::default()
        }
    }
    /// Appends a row; returns its index.
    pub fn push(&mut self, entries: &[(u32, f64)], weight: f64) -> usize {
        for &(i, c) in entries {
            self.idx.push(i);
            self.coef.push(c);
        }
        self.start.push(self.idx.len() as u32);
        self.weight.push(weight);
        self.weight.len() - 1
    }
    pub fn len(&self) -> usize {
        self.weight.len()
    }
    pub fn is_empty(&self) -> bool {
        self.weight.is_empty()
    }
    /// Entries of row `r`.
    #[inline]
    pub fn row(&self, r: usize) -> impl Iterator<Item = (usize, f64)> + '_ {
        let s = self.start[r] as usize..self.start[r + 1] as usize;
        self.idx[s.clone()]
            .iter()
            .zip(&self.coef[s])
            .map(|(&i, &c)| (i as usize, c))
    }
    /// `a_rᵀ V`.
    #[inline]
    pub fn eval(&self, r: usize, positions: &[DVec3]) -> DVec3 {
        self.row(r).map(|(i, c)| positions[i] * c).sum()
    }
}

/// Precomputed, immutable ARAP system: operator, constraint rows and factored matrix.
/// Serializes as its parts (operator, rows, `w_l`); deserializing factors the matrix
/// again, so a cached rig never carries a stale or foreign factorization.
/// The per-frame local/global iteration on it is in `solve::arap`.
#[derive(serde::Deserialize)]
#[serde(try_from = "ArapSystemParts")]
pub struct ArapSystem {
    pub op: ArapOperator,
    pub rows: LinearRows,
    /// `w_l`.
    pub w_shape: f64,
    /// `w_l / h`: the shape weight per unit of cotangent weight.
    pub shape_scale: f64,
    pub(crate) chol: SparseCholesky,
}

/// What [`ArapSystem`] serializes: everything but the factorization.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct ArapSystemParts {
    pub op: ArapOperator,
    pub rows: LinearRows,
    pub w_shape: f64,
}

impl TryFrom<ArapSystemParts> for ArapSystem {
    type Error = FactorError;
    fn try_from(p: ArapSystemParts) -> Result<Self, FactorError> {
        ArapSystem::new(p.op, p.rows, p.w_shape)
    }
}

impl serde::Serialize for ArapSystem {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        #[derive(serde::Serialize)]
        struct Ref<'a> {
            op: &'a ArapOperator,
            rows: &'a LinearRows,
            w_shape: f64,
        }
        Ref {
            op: &self.op,
            rows: &self.rows,
            w_shape: self.w_shape,
        }
        .serialize(s)
    }
}

impl ArapSystem {
    /// Factors `2 (w_l/h) L + Σ_r ω_r a_r a_rᵀ`.
    pub fn new(op: ArapOperator, rows: LinearRows, w_shape: f64) -> Result<Self, FactorError> {
        let n = op.n();
        let shape_scale = w_shape / op.mean_edge_length;
        let mut upper: Vec<(usize, usize, f64)> =
            Vec::with_capacity(n + op.n_edges + rows.idx.len() * 4);
        for i in 0..n {
            let mut diag = 0.0;
            for k in op.start[i] as usize..op.start[i + 1] as usize {
                let j = op.nbr[k] as usize;
                let w = 2.0 * shape_scale * op.weight[k];
                diag += w;
                if i < j && w != 0.0 {
                    upper.push((i, j, -w));
                }
            }
            upper.push((i, i, diag));
        }
        for r in 0..rows.len() {
            let w = rows.weight[r];
            for (a, ca) in rows.row(r) {
                for (b, cb) in rows.row(r) {
                    if a <= b {
                        upper.push((a, b, w * ca * cb));
                    }
                }
            }
        }
        let kind = if n <= SIMPLICIAL_MAX_N {
            FactorKind::Simplicial
        } else {
            FactorKind::Auto
        };
        let chol = SparseCholesky::factor_upper(n, &upper, kind)?;
        Ok(Self {
            op,
            rows,
            w_shape,
            shape_scale,
            chol,
        })
    }

    /// Fill of the factor (number of stored values).
    pub fn factor_len(&self) -> usize {
        self.chol.factor_len()
    }
}

#[cfg(test)]
pub(crate) mod tests_support {
    use super::*;
    use crate::rig::lattice::box_lattice;

    /// A bar of 8x2x2 cells with both end faces pinned by soft rows.
    pub fn bar(scale: f64) -> (ArapSystem, Vec<usize>) {
        let lm = box_lattice(DVec3::ZERO, DVec3::new(4.0, 1.0, 1.0) * scale, [8, 2, 2]);
        let op = ArapOperator::new(&lm.mesh);
        let mut rows = LinearRows::new();
        let mut pinned = Vec::new();
        for (i, p) in lm.mesh.positions.iter().enumerate() {
            if p.x < 1e-9 * scale || p.x > 4.0 * scale - 1e-9 * scale {
                rows.push(&[(i as u32, 1.0)], 100.0);
                pinned.push(i);
            }
        }
        (ArapSystem::new(op, rows, 1.0).unwrap(), pinned)
    }
}

#[cfg(test)]
mod tests {
    use super::tests_support::bar;

    #[test]
    fn laplacian_annihilates_constants() {
        let (sys, _) = bar(1.0);
        let ones = vec![1.0; sys.op.n()];
        let mut out = vec![0.0; sys.op.n()];
        sys.op.apply_laplacian(&ones, &mut out);
        let wmax = sys.op.weight.iter().cloned().fold(0.0, f64::max);
        // Each entry sums at most ~30 weights exactly cancelling: 1e-12 relative is generous.
        assert!(
            out.iter().all(|v| v.abs() <= 1e-12 * wmax),
            "L·1 = {:?}",
            out.iter().cloned().fold(0.0, f64::max)
        );
    }

    #[test]
    fn kuhn_lattice_needs_no_clamping() {
        let (sys, _) = bar(1.0);
        assert_eq!(sys.op.clamped_weights, 0);
        assert!(sys.op.weight.iter().all(|&w| w >= 0.0));
    }
}
