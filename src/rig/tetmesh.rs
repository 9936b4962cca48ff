//! Tetrahedral meshes: the control mesh type, its quality measures (signed volumes,
//! dihedral angles), and the reader for the benchmark capsule format of
//! `../shared/data/tetmesh` (a parser of untrusted bytes: it never panics and never
//! allocates more than the input can hold).
//!
//! Sign convention: a tet `[a, b, c, d]` is positively oriented when
//! `det(b − a, c − a, d − a) > 0`; [`TetMesh::new`] reorients every tet to that.

use crate::runtime::files::{read_bounded, MAX_DATA_BYTES};
use glam::DVec3;
use std::path::Path;
use std::time::Instant;

/// A tetrahedral mesh in metres (or the file's units for benchmark meshes).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TetMesh {
    /// Vertex positions, `n` of them.
    pub positions: Vec<DVec3>,
    /// Vertex indices of each tet, positively oriented.
    pub tets: Vec<[u32; 4]>,
}

/// Errors building or reading a tet mesh.
#[derive(Debug, thiserror::Error)]
pub enum TetMeshError {
    #[error("tet {tet} references vertex {index} but the mesh has {n_vertices} vertices")]
    IndexOutOfRange {
        tet: usize,
        index: i64,
        n_vertices: usize,
    },
    #[error("tet {tet} is degenerate (zero volume)")]
    Degenerate { tet: usize },
    #[error("vertex {vertex} has a non-finite coordinate")]
    NonFinite { vertex: usize },
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: {what} at byte {offset}")]
    Format {
        path: String,
        what: String,
        offset: usize,
    },
}

/// Six times the signed volume of tet `(a, b, c, d)`.
#[inline]
pub fn signed_volume6(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> f64 {
    (b - a).cross(c - a).dot(d - a)
}

impl TetMesh {
    /// Builds a mesh, checking indices and finiteness and orienting every tet positively.
    pub fn new(positions: Vec<DVec3>, mut tets: Vec<[u32; 4]>) -> Result<Self, TetMeshError> {
        if let Some(vertex) = positions.iter().position(|p| !p.is_finite()) {
            return Err(TetMeshError::NonFinite { vertex });
        }
        let n = positions.len();
        for (t, tet) in tets.iter_mut().enumerate() {
            if let Some(&index) = tet.iter().find(|&&i| i as usize >= n) {
                return Err(TetMeshError::IndexOutOfRange {
                    tet: t,
                    index: index as i64,
                    n_vertices: n,
                });
            }
            let [a, b, c, d] = tet.map(|i| positions[i as usize]);
            let v6 = signed_volume6(a, b, c, d);
            if v6 == 0.0 {
                return Err(TetMeshError::Degenerate { tet: t });
            }
            if v6 < 0.0 {
                tet.swap(2, 3);
            }
        }
        Ok(Self { positions, tets })
    }

    /// Six times the volume of each vertex's tets at `positions`, summed per vertex into
    /// `out` (`len` = vertex count; overwritten). No allocation.
    pub fn vertex_volumes6(&self, positions: &[DVec3], out: &mut [f64]) {
        out.fill(0.0);
        for t in &self.tets {
            let [a, b, c, d] = t.map(|i| positions[i as usize]);
            let v6 = signed_volume6(a, b, c, d);
            for &i in t {
                out[i as usize] += v6;
            }
        }
    }

    /// Number of tets whose signed volume under `positions` is not positive.
    pub fn inverted_tets(&self, positions: &[DVec3]) -> usize {
        self.tets
            .iter()
            .filter(|t| {
                let p = |k: usize| positions[t[k] as usize];
                signed_volume6(p(0), p(1), p(2), p(3)) <= 0.0
            })
            .count()
    }

    /// The smallest ratio of a tet's signed volume at `positions` to its volume at rest
    /// (1 for a rigid motion; negative for an inverted tet: −0.03 means a fold of 3 % of
    /// its rest volume).
    pub fn min_volume_ratio(&self, positions: &[DVec3]) -> f64 {
        self.tets
            .iter()
            .map(|t| {
                let [a, b, c, d] = t.map(|i| positions[i as usize]);
                let [ra, rb, rc, rd] = t.map(|i| self.positions[i as usize]);
                signed_volume6(a, b, c, d) / signed_volume6(ra, rb, rc, rd)
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// Smallest and largest dihedral angle over all tets, in degrees.
    pub fn dihedral_range_deg(&self) -> (f64, f64) {
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for t in &self.tets {
            let p = t.map(|i| self.positions[i as usize]);
            for (e0, e1) in EDGE_PAIRS {
                let ang = dihedral_angle(p, e0, e1);
                lo = lo.min(ang);
                hi = hi.max(ang);
            }
        }
        (lo.to_degrees(), hi.to_degrees())
    }

    /// Total volume (sum of tet volumes at `positions`).
    pub fn volume(&self, positions: &[DVec3]) -> f64 {
        self.tets
            .iter()
            .map(|t| {
                let [a, b, c, d] = t.map(|i| positions[i as usize]);
                signed_volume6(a, b, c, d) / 6.0
            })
            .sum()
    }

    /// Largest extent of the bounding box.
    pub fn extent(&self) -> f64 {
        let (lo, hi) = bounds(&self.positions);
        (hi - lo).max_element()
    }
}

pub use crate::geom::shapes::bounds;

/// The six edges of a tet as vertex-slot pairs.
pub const EDGE_PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];

/// Interior dihedral angle (radians) of tet `p` at edge `(e0, e1)`.
pub fn dihedral_angle(p: [DVec3; 4], e0: usize, e1: usize) -> f64 {
    let others: Vec<usize> = (0..4).filter(|&k| k != e0 && k != e1).collect();
    let axis = (p[e1] - p[e0]).normalize();
    let u = p[others[0]] - p[e0];
    let v = p[others[1]] - p[e0];
    let u = u - axis * u.dot(axis);
    let v = v - axis * v.dot(axis);
    u.angle_between(v)
}

/// A benchmark problem from `../shared/data/tetmesh`: mesh plus fixed-position constraints.
#[derive(Clone, Debug)]
pub struct CapsuleProblem {
    pub mesh: TetMesh,
    /// Constrained vertex indices.
    pub constrained: Vec<u32>,
    /// Their target positions.
    pub targets: Vec<DVec3>,
}

/// Reads a capsule benchmark file (layout in `../shared/data/README.md`).
pub fn read_capsule(path: &Path) -> Result<CapsuleProblem, TetMeshError> {
    let bytes = read_bounded(path, MAX_DATA_BYTES).map_err(|source| TetMeshError::Io {
        path: path.display().to_string(),
        source,
    })?;
    parse_capsule(&bytes).map_err(|(what, offset)| TetMeshError::Format {
        path: path.display().to_string(),
        what,
        offset,
    })
}

/// Pure parser of the capsule layout: little-endian `i32 n, m, k`, `n*3 f64` positions,
/// `m*4 i32` tets, `k i32` constrained indices, `k*3 f64` targets. Errors carry the byte
/// offset at fault. Counts are checked against the input length before any allocation.
pub fn parse_capsule(bytes: &[u8]) -> Result<CapsuleProblem, (String, usize)> {
    let mut r = Reader { bytes, pos: 0 };
    let n = r.count("vertex count")?;
    let m = r.count("tet count")?;
    let k = r.count("constraint count")?;
    let need = n
        .checked_mul(24)
        .and_then(|a| m.checked_mul(16).and_then(|b| a.checked_add(b)))
        .and_then(|a| k.checked_mul(28).and_then(|b| a.checked_add(b)))
        .ok_or_else(|| ("counts overflow".to_string(), 0usize))?;
    if bytes.len() - 12 != need {
        return Err((
            format!(
                "expected {} bytes for n={n}, m={m}, k={k}, file has {}",
                need + 12,
                bytes.len()
            ),
            12,
        ));
    }
    let positions: Vec<DVec3> = (0..n)
        .map(|_| DVec3::new(r.f64(), r.f64(), r.f64()))
        .collect();
    let mut tets = Vec::with_capacity(m);
    for t in 0..m {
        let at = r.pos;
        let idx = [r.i32(), r.i32(), r.i32(), r.i32()];
        if let Some(bad) = idx.iter().find(|&&i| i < 0 || i as usize >= n) {
            return Err((format!("tet {t} has vertex index {bad} outside 0..{n}"), at));
        }
        tets.push(idx.map(|i| i as u32));
    }
    let mut constrained = Vec::with_capacity(k);
    for c in 0..k {
        let at = r.pos;
        let i = r.i32();
        if i < 0 || i as usize >= n {
            return Err((
                format!("constraint {c} has vertex index {i} outside 0..{n}"),
                at,
            ));
        }
        constrained.push(i as u32);
    }
    let targets: Vec<DVec3> = (0..k)
        .map(|_| DVec3::new(r.f64(), r.f64(), r.f64()))
        .collect();
    let mesh = TetMesh::new(positions, tets).map_err(|e| (e.to_string(), 12))?;
    if targets.iter().any(|t| !t.is_finite()) {
        return Err((
            "non-finite constraint target".into(),
            12 + n * 24 + m * 16 + k * 4,
        ));
    }
    Ok(CapsuleProblem {
        mesh,
        constrained,
        targets,
    })
}

struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl Reader<'_> {
    fn count(&mut self, what: &str) -> Result<usize, (String, usize)> {
        let at = self.pos;
        if self.bytes.len() < at + 4 {
            return Err((format!("file ends before the {what}"), at));
        }
        let v = self.i32();
        usize::try_from(v).map_err(|_| (format!("negative {what} {v}"), at))
    }
    // Callers have checked the length up front, so these index in range.
    fn i32(&mut self) -> i32 {
        let v = i32::from_le_bytes(
            self.bytes[self.pos..self.pos + 4]
                .try_into()
                .expect("4 bytes"),
        );
        self.pos += 4;
        v
    }
    fn f64(&mut self) -> f64 {
        let v = f64::from_le_bytes(
            self.bytes[self.pos..self.pos + 8]
                .try_into()
                .expect("8 bytes"),
        );
        self.pos += 8;
        v
    }
}

/// How many sweeps [`Untangler::run`] makes: `min` at least, then until `deadline` (if
/// any), `max` at most.
#[derive(Clone, Copy, Debug)]
pub struct Sweeps {
    pub min: usize,
    pub max: usize,
    pub deadline: Option<Instant>,
}

/// Pushes folded tets of a [`TetMesh`] back to a small positive volume: every tet whose
/// signed volume is below `min_ratio` of its rest volume has its four vertices moved
/// along the volume's gradient, by the least squared motion that brings it to twice that
/// ratio (to first order: the volume constraint projection of position-based dynamics,
/// Müller et al. 2007, Sec. 3.3, with unit masses, over-relaxed so that a neighbour's
/// projection does not fold it straight back). Moving shared vertices can tip a
/// neighbour below the threshold, so after the first sweep over all tets the tets
/// around every moved vertex are checked again: `sweeps.min` sweeps at least, then
/// until the deadline, `sweeps.max` at most.
///
/// Precomputed per mesh (rest volumes, the tets around each vertex) and allocation-free
/// per call.
#[derive(Clone, Debug)]
pub struct Untangler {
    /// Six times each tet's rest volume.
    rest6: Vec<f64>,
    /// Tets around each vertex (CSR).
    vertex_tets_start: Vec<u32>,
    vertex_tets: Vec<u32>,
    /// The tets to check in the current and the next sweep, and the sweep that last
    /// queued each tet.
    check: Vec<u32>,
    next: Vec<u32>,
    queued: Vec<u32>,
}

impl Untangler {
    pub fn new(mesh: &TetMesh) -> Self {
        let rest6 = mesh
            .tets
            .iter()
            .map(|t| {
                let [a, b, c, d] = t.map(|i| mesh.positions[i as usize]);
                signed_volume6(a, b, c, d)
            })
            .collect();
        let n = mesh.positions.len();
        let mut count = vec![0u32; n + 1];
        for t in &mesh.tets {
            for &v in t {
                count[v as usize + 1] += 1;
            }
        }
        for i in 0..n {
            count[i + 1] += count[i];
        }
        let mut fill = count.clone();
        let mut vertex_tets = vec![0u32; mesh.tets.len() * 4];
        for (k, t) in mesh.tets.iter().enumerate() {
            for &v in t {
                vertex_tets[fill[v as usize] as usize] = k as u32;
                fill[v as usize] += 1;
            }
        }
        let nt = mesh.tets.len();
        Self {
            rest6,
            vertex_tets_start: count,
            vertex_tets,
            check: Vec::with_capacity(nt),
            next: Vec::with_capacity(nt),
            queued: vec![u32::MAX; nt],
        }
    }

    /// Unfolds the tets of `mesh` at `positions` (see the type's doc). Returns the number
    /// of projections made (0: nothing was folded; positions untouched).
    pub fn run(
        &mut self,
        mesh: &TetMesh,
        positions: &mut [DVec3],
        min_ratio: f64,
        sweeps: Sweeps,
    ) -> usize {
        let mut projections = 0;
        self.check.clear();
        self.check.extend(0..mesh.tets.len() as u32);
        for sweep in 0..sweeps.max as u32 {
            if sweep as usize >= sweeps.min && sweeps.deadline.is_some_and(|d| Instant::now() >= d)
            {
                break;
            }
            self.next.clear();
            for &t in &self.check {
                let t = t as usize;
                let [ia, ib, ic, id] = mesh.tets[t].map(|i| i as usize);
                let [a, b, c, d] = [positions[ia], positions[ib], positions[ic], positions[id]];
                let (ab, ac, ad) = (b - a, c - a, d - a);
                let v6 = ab.cross(ac).dot(ad);
                let goal6 = min_ratio * self.rest6[t];
                if v6 >= goal6 {
                    continue;
                }
                // ∂V6/∂b, ∂c, ∂d, and ∂a = −(their sum).
                let gb = ac.cross(ad);
                let gc = ad.cross(ab);
                let gd = ab.cross(ac);
                let ga = -(gb + gc + gd);
                let norm2 = ga.length_squared()
                    + gb.length_squared()
                    + gc.length_squared()
                    + gd.length_squared();
                if norm2 <= f64::MIN_POSITIVE {
                    continue;
                }
                // Pushed past the threshold, to twice it: the slack keeps a neighbour's
                // projection from folding it straight back (without it, tets squeezed
                // between two limbs trade volume back and forth for hundreds of sweeps).
                let lambda = (2.0 * goal6 - v6) / norm2;
                positions[ia] += ga * lambda;
                positions[ib] += gb * lambda;
                positions[ic] += gc * lambda;
                positions[id] += gd * lambda;
                projections += 1;
                // Everything around the moved vertices is checked next sweep (this one
                // included: the linearised step may fall short).
                for v in [ia, ib, ic, id] {
                    let (lo, hi) = (
                        self.vertex_tets_start[v] as usize,
                        self.vertex_tets_start[v + 1] as usize,
                    );
                    for &k in &self.vertex_tets[lo..hi] {
                        if self.queued[k as usize] != sweep {
                            self.queued[k as usize] = sweep;
                            self.next.push(k);
                        }
                    }
                }
            }
            if self.next.is_empty() {
                break;
            }
            std::mem::swap(&mut self.check, &mut self.next);
        }
        // Sweep numbers restart at 0 on the next call.
        if projections > 0 {
            self.queued.fill(u32::MAX);
        }
        projections
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Two tets sharing the face (1, 2, 3), apexes 0 and 4 on either side.
    fn two_tets() -> TetMesh {
        TetMesh::new(
            vec![
                DVec3::new(0.0, 0.0, -1.0),
                DVec3::new(0.0, 0.0, 0.0),
                DVec3::new(1.0, 0.0, 0.0),
                DVec3::new(0.0, 1.0, 0.0),
                DVec3::new(0.2, 0.2, 1.0),
            ],
            vec![[0, 1, 2, 3], [4, 1, 2, 3]],
        )
        .unwrap()
    }

    const TEN: Sweeps = Sweeps {
        min: 10,
        max: 10,
        deadline: None,
    };

    #[test]
    fn untangling_leaves_good_tets_alone_and_unfolds_a_folded_one() {
        let m = two_tets();
        let mut u = Untangler::new(&m);
        let rest6 = u.rest6.clone();
        assert!(rest6.iter().all(|v| *v > 0.0));
        let mut p = m.positions.clone();
        assert_eq!(u.run(&m, &mut p, 0.02, TEN), 0);
        assert_eq!(p, m.positions);
        // Push apex 4 through the shared face: that tet folds to −30 % of its volume.
        p[4] = DVec3::new(0.2, 0.2, -0.3);
        assert_eq!(m.inverted_tets(&p), 1);
        let n = u.run(&m, &mut p, 0.02, TEN);
        assert!(n >= 1);
        assert_eq!(m.inverted_tets(&p), 0);
        for (t, r6) in m.tets.iter().zip(&rest6) {
            let [a, b, c, d] = t.map(|i| p[i as usize]);
            // At least the asked ratio, less the linearisation's round-off.
            assert!(
                signed_volume6(a, b, c, d) >= 0.02 * r6 * (1.0 - 1e-6),
                "{p:?}"
            );
        }
    }

    fn unit_tet_bytes() -> Vec<u8> {
        let mut b = Vec::new();
        for v in [4i32, 1, 1] {
            b.extend(v.to_le_bytes());
        }
        for p in [
            [0.0f64, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ] {
            for c in p {
                b.extend(c.to_le_bytes());
            }
        }
        for i in [0i32, 1, 3, 2] {
            b.extend(i.to_le_bytes());
        }
        b.extend(2i32.to_le_bytes());
        for c in [0.5f64, 0.5, 0.5] {
            b.extend(c.to_le_bytes());
        }
        b
    }

    #[test]
    fn parses_and_orients() {
        let p = parse_capsule(&unit_tet_bytes()).unwrap();
        assert_eq!(p.mesh.positions.len(), 4);
        // [0,1,3,2] is negatively oriented; it must come back positive.
        assert_eq!(p.mesh.inverted_tets(&p.mesh.positions), 0);
        assert!((p.mesh.volume(&p.mesh.positions) - 1.0 / 6.0).abs() < 1e-15);
        assert_eq!(p.constrained, vec![2]);
    }

    #[test]
    fn rejects_bad_index_with_offset() {
        let mut b = unit_tet_bytes();
        // first tet index lives right after the header and 4 positions
        let at = 12 + 4 * 24;
        b[at..at + 4].copy_from_slice(&9i32.to_le_bytes());
        let (msg, off) = parse_capsule(&b).unwrap_err();
        assert_eq!(off, at);
        assert!(msg.contains("vertex index 9"), "{msg}");
    }

    #[test]
    fn huge_counts_do_not_allocate() {
        let mut b = Vec::new();
        for v in [i32::MAX, i32::MAX, i32::MAX] {
            b.extend(v.to_le_bytes());
        }
        // Refused by the length check at byte 12, which comes before any buffer is
        // sized by a count: the counts promise 2^31 × 68 bytes, the file has 12.
        let (why, at) = parse_capsule(&b).unwrap_err();
        assert_eq!(at, 12, "{why}");
        assert!(
            why.contains("n=2147483647, m=2147483647, k=2147483647, file has 12"),
            "{why}"
        );
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
            let _ = parse_capsule(&bytes);
        }

        #[test]
        fn mutated_valid_file_never_panics(pos in 0usize..200, val in any::<u8>()) {
            let mut b = unit_tet_bytes();
            let p = pos % b.len();
            b[p] = val;
            let _ = parse_capsule(&b);
        }
    }
}
