//! Green coordinates (Lipman, Levin, Cohen-Or, "Green Coordinates", SIGGRAPH 2008): the
//! full-resolution mesh follows the control mesh as
//!
//! ```text
//! x' = Σ_i φ_i(x) v'_i + Σ_j ψ_j(x) s_j n(t'_j)
//! ```
//!
//! with `φ` per cage vertex, `ψ` per cage face, `n(t'_j)` the deformed face's unit outward
//! normal and `s_j` its stretch factor (Section 3.2, the 3D case:
//! `s = sqrt(‖u'‖²‖v‖² − 2(u'·v')(u·v) + ‖v'‖²‖u‖²) / (√8 area(t))`, `u, v` two edges).
//! The coordinates are computed once at bind time, in f64, by the paper's Algorithm 1
//! (with `GCTriInt`); angles are taken with `atan2` instead of `acos`, which keeps full
//! precision near 0 and π.
//!
//! The cage of each mesh vertex is the control tet that holds it (the per-tet form of Le
//! Naour et al.: four φ and four ψ per vertex, so the per-frame product stays sparse).
//! Green coordinates reproduce linear functions for points inside the cage; a vertex whose
//! coordinates do not reproduce it to [`REPRODUCTION_TOLERANCE`] of the character's size
//! (on or too near a face plane, or outside its tet) falls back to barycentric
//! coordinates (`ψ = 0`), which reproduce it exactly, and is counted.

use super::tetmesh::TetMesh;
use glam::DVec3;
use std::collections::HashMap;
use std::f64::consts::PI;

/// Largest rest reproduction error accepted, as a fraction of the character's height.
pub const REPRODUCTION_TOLERANCE: f64 = 1e-9;

/// Outward faces of a positively oriented tet `[a, b, c, d]` (`det(b−a, c−a, d−a) > 0`):
/// face `k` is opposite vertex slot `k`.
pub const TET_FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

/// `GCTriInt(p, v1, v2, η)` of Lipman et al. 2008 (Algorithm 1): the integral over the
/// triangle `(p, v1, v2)` used to assemble the coordinates.
fn gc_tri_int(p: DVec3, v1: DVec3, v2: DVec3, eta: DVec3) -> f64 {
    let angle = |a: DVec3, b: DVec3| a.cross(b).length().atan2(a.dot(b));
    let (e, q) = (v2 - v1, p - v1);
    let (e2, q2) = (e.length_squared(), q.length_squared());
    if e2 == 0.0 || q2 == 0.0 {
        return 0.0;
    }
    let alpha = angle(e, q);
    let beta = angle(v1 - p, v2 - p);
    if beta.abs() < 1e-300 {
        return 0.0;
    }
    // λ = ‖p − v1‖² sin²α: the squared distance from p to the line v1 v2.
    let lambda = q.cross(e).length_squared() / e2;
    let c = (p - eta).length_squared();
    let (sc, sl) = (c.sqrt(), lambda.sqrt());
    let integral = |theta: f64| {
        let (s, co) = theta.sin_cos();
        let atan_term = 2.0 * sc * (sc * co / (lambda + s * s * c).sqrt()).atan();
        let log_term = if sl > 0.0 && s != 0.0 {
            let a = 2.0 * sl * s * s / ((1.0 - co) * (1.0 - co));
            let b = 1.0
                - 2.0 * c * co
                    / (c * (1.0 + co) + lambda + (lambda * lambda + lambda * c * s * s).sqrt());
            sl * (a * b).ln()
        } else {
            0.0
        };
        -0.5 * s.signum() * (atan_term + log_term)
    };
    let i1 = integral(PI - alpha);
    let i2 = integral(PI - alpha - beta);
    -(i1 - i2 - sc * beta).abs() / (4.0 * PI)
}

/// Green coordinates of `eta` with respect to a closed, outward-oriented triangle cage:
/// fills `phi` (one per cage vertex) and `psi` (one per face). Algorithm 1 of Lipman et
/// al. 2008.
pub fn green_coordinates(
    cage: &[DVec3],
    faces: &[[usize; 3]],
    eta: DVec3,
    phi: &mut [f64],
    psi: &mut [f64],
) {
    phi.fill(0.0);
    for (j, f) in faces.iter().enumerate() {
        let v = f.map(|i| cage[i] - eta);
        let n = (v[1] - v[0]).cross(v[2] - v[0]).normalize();
        let p = n * v[0].dot(n);
        let mut s = [0.0; 3];
        let mut i_l = [0.0; 3];
        let mut ii_l = [0.0; 3];
        let mut nl = [DVec3::ZERO; 3];
        for l in 0..3 {
            let (a, b) = (v[l], v[(l + 1) % 3]);
            s[l] = (a - p).cross(b - p).dot(n).signum();
            i_l[l] = gc_tri_int(p, a, b, DVec3::ZERO);
            ii_l[l] = gc_tri_int(DVec3::ZERO, b, a, DVec3::ZERO);
            nl[l] = b.cross(a).normalize_or_zero();
        }
        let i_sum = -(s[0] * i_l[0] + s[1] * i_l[1] + s[2] * i_l[2]).abs();
        psi[j] = -i_sum;
        let w = n * i_sum + nl[0] * ii_l[0] + nl[1] * ii_l[1] + nl[2] * ii_l[2];
        if w.length() > 1e-300 {
            for l in 0..3 {
                let nn = nl[(l + 1) % 3];
                let den = nn.dot(v[l]);
                if den != 0.0 {
                    phi[f[l]] += nn.dot(w) / den;
                }
            }
        }
    }
}

/// Rest data of one cage face, for its stretch factor: `(u·v, ‖u‖², ‖v‖², 8 area²)` with
/// `u = b − a`, `v = c − a`.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
struct FaceRest {
    uv: f64,
    uu: f64,
    vv: f64,
    eight_area_sq: f64,
}

/// The full mesh's Green coordinates in its control tets (bind-time, immutable).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct GreenEmbedding {
    /// Control tets used by at least one vertex (positively oriented vertex indices).
    tets: Vec<[u32; 4]>,
    /// Per used tet, its four faces ([`TET_FACES`] order) as indices into `faces`: a face
    /// two used tets share is deformed once per frame.
    tet_faces: Vec<[u32; 4]>,
    /// The used tets' distinct faces, each oriented as outward from the first tet that
    /// uses it (vertex indices), with its rest data.
    faces: Vec<[u32; 3]>,
    faces_rest: Vec<FaceRest>,
    /// Per mesh vertex: index into `tets`, `φ` per tet vertex, `ψ` per tet face
    /// ([`TET_FACES`] order; negated where the face is stored oriented for the tet on its
    /// other side, so that the stored face's normal serves both).
    vertex_tet: Vec<u32>,
    phi: Vec<[f64; 4]>,
    psi: Vec<[f64; 4]>,
    /// Vertices that fell back to barycentric coordinates.
    pub fallback_vertices: usize,
    /// Largest rest reproduction error, metres.
    pub max_rest_error_m: f64,
}

/// The per-vertex part of a [`GreenEmbedding`]: what is expensive to compute.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct GreenCoefficients {
    /// Per vertex, `φ` per vertex of its tet.
    pub phi: Vec<[f64; 4]>,
    /// Per vertex, `ψ` per face of its tet ([`TET_FACES`] order, signed for the stored
    /// face orientation the embedding's layout gives).
    pub psi: Vec<[f64; 4]>,
    pub fallback_vertices: usize,
    pub max_rest_error_m: f64,
}

/// Why stored coordinates do not fit a control mesh's vertices.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GreenCoefficientsError {
    #[error("{phi} φ and {psi} ψ rows for {vertices} vertices")]
    Count {
        phi: usize,
        psi: usize,
        vertices: usize,
    },
    #[error("the coordinates of vertex {vertex} are not finite")]
    NotFinite { vertex: usize },
}

/// Per-solver scratch of [`GreenEmbedding::deform`]: `s_j n(t'_j)` per distinct face.
#[derive(Clone, Debug, Default)]
pub struct GreenScratch {
    face_terms: Vec<DVec3>,
}

impl GreenEmbedding {
    /// Computes the coordinates of every vertex in its tet (`vertex_tets[i]`, indices into
    /// `control.tets`). `size_m` sets the reproduction tolerance
    /// (`REPRODUCTION_TOLERANCE · size_m`).
    pub fn new(control: &TetMesh, vertices: &[DVec3], vertex_tets: &[usize], size_m: f64) -> Self {
        Self::new_with_progress(control, vertices, vertex_tets, size_m, &mut |_| {})
    }

    /// [`Self::new`], calling `progress` with the fraction done every 1,024 vertices.
    pub fn new_with_progress(
        control: &TetMesh,
        vertices: &[DVec3],
        vertex_tets: &[usize],
        size_m: f64,
        progress: &mut dyn FnMut(f64),
    ) -> Self {
        let (mut out, face_sign) = Self::structure(control, vertex_tets);
        let tol = REPRODUCTION_TOLERANCE * size_m;
        let mut phi = [0.0; 4];
        let mut psi = [0.0; 4];
        out.phi.reserve_exact(vertices.len());
        out.psi.reserve_exact(vertices.len());
        for (vi, (&x, &t)) in vertices.iter().zip(vertex_tets).enumerate() {
            if vi % 1024 == 0 {
                progress(vi as f64 / vertices.len() as f64);
            }
            let cage = control.tets[t].map(|i| control.positions[i as usize]);
            green_coordinates(&cage, &TET_FACES, x, &mut phi, &mut psi);
            let normals =
                TET_FACES.map(|[a, b, c]| (cage[b] - cage[a]).cross(cage[c] - cage[a]).normalize());
            let rebuilt: DVec3 = (0..4).map(|k| cage[k] * phi[k] + normals[k] * psi[k]).sum();
            let err = (rebuilt - x).length();
            if err.is_nan() || err > tol {
                // Barycentric coordinates reproduce x exactly (ψ = 0).
                phi = super::lattice::barycentric(cage, x);
                psi = [0.0; 4];
                out.fallback_vertices += 1;
                let rebuilt: DVec3 = (0..4).map(|k| cage[k] * phi[k]).sum();
                out.max_rest_error_m = out.max_rest_error_m.max((rebuilt - x).length());
            } else {
                out.max_rest_error_m = out.max_rest_error_m.max(err);
            }
            // A face stored oriented for the neighbouring tet has the opposite normal.
            let slot = out.vertex_tet[vi] as usize;
            for (p, sign) in psi.iter_mut().zip(face_sign[slot]) {
                *p *= sign;
            }
            out.phi.push(phi);
            out.psi.push(psi);
        }
        out
    }

    /// The embedding's tets and faces for vertices in `vertex_tets` (indices into
    /// `control.tets`), with no coordinates yet; and per used tet, +1 or −1 per face:
    /// whether the stored face is oriented outward from that tet (else its normal is the
    /// opposite of the tet's). Deterministic: the same inputs give the same layout.
    fn structure(control: &TetMesh, vertex_tets: &[usize]) -> (Self, Vec<[f64; 4]>) {
        let mut index: HashMap<usize, u32> = HashMap::new();
        // Distinct faces by their sorted vertex triple: (face index, stored orientation).
        let mut face_index: HashMap<[u32; 3], (u32, [u32; 3])> = HashMap::new();
        let mut face_sign: Vec<[f64; 4]> = Vec::new();
        let mut out = Self::default();
        out.vertex_tet.reserve_exact(vertex_tets.len());
        for &t in vertex_tets {
            let tv = control.tets[t];
            let slot = *index.entry(t).or_insert_with(|| {
                out.tets.push(tv);
                let faces = TET_FACES.map(|[a, b, c]| {
                    let oriented = [tv[a], tv[b], tv[c]];
                    let mut key = oriented;
                    key.sort_unstable();
                    let &mut (f, stored) = face_index.entry(key).or_insert_with(|| {
                        out.faces.push(oriented);
                        let p = oriented.map(|i| control.positions[i as usize]);
                        let (u, v) = (p[1] - p[0], p[2] - p[0]);
                        out.faces_rest.push(FaceRest {
                            uv: u.dot(v),
                            uu: u.length_squared(),
                            vv: v.length_squared(),
                            eight_area_sq: 2.0 * u.cross(v).length_squared(),
                        });
                        ((out.faces.len() - 1) as u32, oriented)
                    });
                    let sign = if same_orientation(stored, oriented) {
                        1.0
                    } else {
                        -1.0
                    };
                    (f, sign)
                });
                out.tet_faces.push(faces.map(|(f, _)| f));
                face_sign.push(faces.map(|(_, sign)| sign));
                (out.tets.len() - 1) as u32
            });
            out.vertex_tet.push(slot);
        }
        (out, face_sign)
    }

    /// The per-vertex coordinates and what computing them measured, to store (the bake
    /// cache) and give back to [`Self::from_coefficients`] with the same control mesh and
    /// vertex tets.
    pub fn coefficients(&self) -> GreenCoefficients {
        GreenCoefficients {
            phi: self.phi.clone(),
            psi: self.psi.clone(),
            fallback_vertices: self.fallback_vertices,
            max_rest_error_m: self.max_rest_error_m,
        }
    }

    /// The embedding of vertices in `vertex_tets` with stored coordinates `c`, if they fit
    /// (one `φ` and one `ψ` per vertex, all finite). The tets and faces are rebuilt from
    /// `control`, never read, so stored data can hold no out-of-range index.
    pub fn from_coefficients(
        control: &TetMesh,
        vertex_tets: &[usize],
        c: GreenCoefficients,
    ) -> Result<Self, GreenCoefficientsError> {
        let n = vertex_tets.len();
        if c.phi.len() != n || c.psi.len() != n {
            return Err(GreenCoefficientsError::Count {
                phi: c.phi.len(),
                psi: c.psi.len(),
                vertices: n,
            });
        }
        let finite = |v: &[f64; 4]| v.iter().all(|x| x.is_finite());
        if let Some(vertex) = (0..n).find(|&i| !finite(&c.phi[i]) || !finite(&c.psi[i])) {
            return Err(GreenCoefficientsError::NotFinite { vertex });
        }
        let (mut out, _) = Self::structure(control, vertex_tets);
        out.phi = c.phi;
        out.psi = c.psi;
        out.fallback_vertices = c.fallback_vertices;
        out.max_rest_error_m = c.max_rest_error_m;
        Ok(out)
    }

    /// Scratch sized for this embedding.
    pub fn scratch(&self) -> GreenScratch {
        GreenScratch {
            face_terms: vec![DVec3::ZERO; self.faces.len()],
        }
    }

    /// Writes the deformed mesh for deformed control positions `control` into `out`
    /// (`len` = mesh vertex count). No allocation.
    pub fn deform(&self, control: &[DVec3], scratch: &mut GreenScratch, out: &mut [DVec3]) {
        for ((f, r), term) in self
            .faces
            .iter()
            .zip(&self.faces_rest)
            .zip(scratch.face_terms.iter_mut())
        {
            let p0 = control[f[0] as usize];
            let (u, v) = (control[f[1] as usize] - p0, control[f[2] as usize] - p0);
            // s n̂ = n · sqrt(s_num² / (8 A² ‖n‖²)): one square root, one division.
            let n = u.cross(v);
            let s2 = u.length_squared() * r.vv - 2.0 * u.dot(v) * r.uv + v.length_squared() * r.uu;
            let den = r.eight_area_sq * n.length_squared();
            *term = if den > 0.0 {
                n * (s2.max(0.0) / den).sqrt()
            } else {
                DVec3::ZERO
            };
        }
        for (o, ((&t, phi), psi)) in out
            .iter_mut()
            .zip(self.vertex_tet.iter().zip(&self.phi).zip(&self.psi))
        {
            let tv = self.tets[t as usize];
            let tf = self.tet_faces[t as usize];
            let mut x = DVec3::ZERO;
            for k in 0..4 {
                x += control[tv[k] as usize] * phi[k] + scratch.face_terms[tf[k] as usize] * psi[k];
            }
            *o = x;
        }
    }
}

/// Whether two vertex triples of the same face list it with the same orientation (one
/// is a cyclic rotation of the other).
fn same_orientation(a: [u32; 3], b: [u32; 3]) -> bool {
    a == b || a == [b[1], b[2], b[0]] || a == [b[2], b[0], b[1]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;

    fn unit_tet() -> [DVec3; 4] {
        [
            DVec3::new(0.1, -0.2, 0.05),
            DVec3::new(1.2, 0.1, -0.1),
            DVec3::new(0.3, 1.1, 0.2),
            DVec3::new(0.2, 0.3, 1.3),
        ]
    }

    fn points_inside(cage: &[DVec3; 4]) -> Vec<DVec3> {
        let mut v = Vec::new();
        for &(a, b, c) in &[
            (0.25, 0.25, 0.25),
            (0.1, 0.2, 0.3),
            (0.7, 0.1, 0.1),
            (0.01, 0.02, 0.03),
            (0.4, 0.4, 0.15),
        ] {
            let d = 1.0 - a - b - c;
            v.push(cage[0] * d + cage[1] * a + cage[2] * b + cage[3] * c);
        }
        v
    }

    #[test]
    fn a_face_shared_by_two_tets_is_deformed_once_for_both() {
        // Two tets on either side of the face (1, 2, 3); points in both.
        let mut positions = unit_tet().to_vec();
        positions.push(DVec3::new(1.0, 1.0, 1.0));
        let mesh = TetMesh::new(positions, vec![[0, 1, 2, 3], [4, 3, 2, 1]]).unwrap();
        let cages = mesh
            .tets
            .iter()
            .map(|t| t.map(|i| mesh.positions[i as usize]))
            .collect::<Vec<_>>();
        let (mut points, mut tet_of) = (Vec::new(), Vec::new());
        for (t, cage) in cages.iter().enumerate() {
            for x in points_inside(cage) {
                points.push(x);
                tet_of.push(t);
            }
        }
        let g = GreenEmbedding::new(&mesh, &points, &tet_of, 1.0);
        assert_eq!(g.faces.len(), 7, "4 + 4 faces, one shared");
        // A non-affine deformation: every vertex moved differently.
        let moved: Vec<DVec3> = mesh
            .positions
            .iter()
            .enumerate()
            .map(|(i, p)| *p * 1.1 + DVec3::new(0.05, -0.1, 0.2) * (i as f64 * 1.3).sin())
            .collect();
        let mut out = vec![DVec3::ZERO; points.len()];
        g.deform(&moved, &mut g.scratch(), &mut out);
        // Reference: each tet on its own, Lipman's formula with its own outward faces.
        let (mut phi, mut psi) = ([0.0; 4], [0.0; 4]);
        for ((x, &t), o) in points.iter().zip(&tet_of).zip(&out) {
            let tv = mesh.tets[t];
            green_coordinates(&cages[t], &TET_FACES, *x, &mut phi, &mut psi);
            let p = tv.map(|i| moved[i as usize]);
            let mut want = DVec3::ZERO;
            for (k, [a, b, c]) in TET_FACES.into_iter().enumerate() {
                let rest = cages[t];
                let (u0, v0) = (rest[b] - rest[a], rest[c] - rest[a]);
                let (u, v) = (p[b] - p[a], p[c] - p[a]);
                let stretch = (u.length_squared() * v0.length_squared()
                    - 2.0 * u.dot(v) * u0.dot(v0)
                    + v.length_squared() * u0.length_squared())
                .sqrt()
                    / (8f64.sqrt() * 0.5 * u0.cross(v0).length());
                want += p[k] * phi[k] + u.cross(v).normalize() * stretch * psi[k];
            }
            // Round-off only: the same sums in another order.
            assert!((*o - want).length() < 1e-12, "{o} against {want}");
        }
    }

    #[test]
    fn coordinates_sum_to_one_and_reproduce_linear_functions() {
        let cage = unit_tet();
        let (mut phi, mut psi) = ([0.0; 4], [0.0; 4]);
        let normals =
            TET_FACES.map(|[a, b, c]| (cage[b] - cage[a]).cross(cage[c] - cage[a]).normalize());
        for x in points_inside(&cage) {
            green_coordinates(&cage, &TET_FACES, x, &mut phi, &mut psi);
            let sum: f64 = phi.iter().sum();
            // Σφ = 1 and Σψ n = 0 (constants); Σφ v + Σψ n = x (linear functions). The
            // tet is 1.3 units across; f64 round-off through logs and atans stays ~1e-14.
            assert!((sum - 1.0).abs() < 1e-12, "Σφ = {sum} at {x}");
            let n_sum: DVec3 = (0..4).map(|k| normals[k] * psi[k]).sum();
            let rebuilt: DVec3 = (0..4).map(|k| cage[k] * phi[k]).sum::<DVec3>() + n_sum;
            assert!((rebuilt - x).length() < 1e-12, "rebuilt {rebuilt} for {x}");
        }
    }

    #[test]
    fn a_similarity_of_the_cage_moves_points_by_the_same_similarity() {
        let cage = unit_tet();
        let mesh = TetMesh::new(cage.to_vec(), vec![[0, 1, 2, 3]]).unwrap();
        let pts = points_inside(&cage);
        let emb = GreenEmbedding::new(&mesh, &pts, &vec![0; pts.len()], 1.3);
        assert_eq!(emb.fallback_vertices, 0);
        // Green coordinates are exact for rotations with uniform scale (Lipman 2008, §3).
        let q = DQuat::from_scaled_axis(DVec3::new(0.3, -0.8, 0.5));
        let (s, t) = (1.7, DVec3::new(2.0, -1.0, 0.5));
        let moved: Vec<DVec3> = mesh.positions.iter().map(|&p| q * p * s + t).collect();
        let mut out = vec![DVec3::ZERO; pts.len()];
        emb.deform(&moved, &mut emb.scratch(), &mut out);
        for (o, p) in out.iter().zip(&pts) {
            let expect = q * *p * s + t;
            assert!((*o - expect).length() < 1e-12, "{o} vs {expect}");
        }
    }

    #[test]
    fn a_cube_cage_reproduces_interior_points() {
        // A closed cube of 12 outward triangles: the whole-cage form.
        let v: Vec<DVec3> = (0..8)
            .map(|b| DVec3::new((b & 1) as f64, ((b >> 1) & 1) as f64, ((b >> 2) & 1) as f64))
            .collect();
        let faces = [
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6],
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7],
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5],
        ];
        let normals: Vec<DVec3> = faces
            .iter()
            .map(|&[a, b, c]: &[usize; 3]| (v[b] - v[a]).cross(v[c] - v[a]).normalize())
            .collect();
        let (mut phi, mut psi) = (vec![0.0; 8], vec![0.0; 12]);
        for x in [
            DVec3::splat(0.5),
            DVec3::new(0.1, 0.8, 0.3),
            DVec3::new(0.95, 0.05, 0.5),
        ] {
            green_coordinates(&v, &faces, x, &mut phi, &mut psi);
            let rebuilt: DVec3 = (0..8).map(|k| v[k] * phi[k]).sum::<DVec3>()
                + (0..12).map(|k| normals[k] * psi[k]).sum::<DVec3>();
            assert!((rebuilt - x).length() < 1e-12, "rebuilt {rebuilt} for {x}");
            assert!((phi.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        }
    }
}
