//! Linear-blend skin weights fitted to solved frames, for the glTF export: each vertex
//! gets up to four joints and weights with which an engine's skinning reproduces the
//! solved mesh as nearly as linear blend skinning can.
//!
//! This is the weight step of Le and Deng, "Smooth Skinning Decomposition with Rigid
//! Bones" (SIGGRAPH Asia 2012, Section 3.2), with the bones given (the fitted posture)
//! instead of estimated. Per vertex `i`, with candidate joints `k` and the frames `f` the
//! fit saw:
//!
//! ```text
//! min_w Σ_f ‖Σ_k w_k a_k(f) − x_i(f)‖²   subject to  w_k ≥ 0,  Σ_k w_k = 1
//! a_k(f) = R_k(f) (v_i − r_k) + P_k(f)
//! ```
//!
//! `v_i` the rest vertex, `x_i(f)` the solved one, `r_k` the joint's rest position,
//! `R_k(f)`, `P_k(f)` its world rotation from rest and position: glTF's skinning with an
//! inverse bind matrix that translates by `−r_k`. The frames are reduced as they come to
//! each vertex's normal equations (`G = Σ_f a_kᵀ a_l`, `h = Σ_f a_kᵀ x`, `Σ_f ‖x‖²`), so
//! memory does not grow with the take. The small constrained problem is solved exactly by
//! trying every subset of the candidates (at most 15) with the sum constraint by a
//! Lagrange multiplier, keeping the best one whose weights are all non-negative; a larger
//! subset must lower the residual by a relative [`MIN_GAIN`] to be kept, so joints that
//! moved together in the take do not split a vertex arbitrarily.
//!
//! Candidates: the joints owning the four bone segments nearest the rest vertex (the
//! nearest one's owner is the bind's rigid choice, [`crate::rig::bind::nearest_owner`]).

use crate::character::skeleton::Skeleton;
use glam::{DQuat, DVec3};

/// Joints a vertex may follow (glTF's one `JOINTS_0`/`WEIGHTS_0` set).
pub const MAX_INFLUENCES: usize = 4;

/// A larger set of joints is kept only if it lowers the vertex's squared residual by
/// this share of `frames × size²` (`size`: the rest mesh's bounding box diagonal): far
/// below the residual of any real bend, far above round-off, and the same wherever the
/// take stands on the stage.
pub const MIN_GAIN: f64 = 1e-12;

/// Entries of a packed upper triangle of a `MAX_INFLUENCES`-square matrix.
const PACKED: usize = MAX_INFLUENCES * (MAX_INFLUENCES + 1) / 2;

/// Per-vertex normal equations of the weight fit, accumulated frame by frame.
pub struct SkinFit {
    /// Rest vertices, metres.
    rest: Vec<DVec3>,
    /// Joints' rest positions.
    joint_rest: Vec<DVec3>,
    /// Per vertex: candidate joints (nearest segment's owner first) and how many.
    candidates: Vec<[u16; MAX_INFLUENCES]>,
    count: Vec<u8>,
    /// Per vertex: `G` (upper triangle, row by row) and `h`.
    gram: Vec<[f64; PACKED]>,
    rhs: Vec<[f64; MAX_INFLUENCES]>,
    /// The rest mesh's bounding box diagonal, squared (m²).
    size2_m2: f64,
    frames: usize,
}

/// Index of `(k, l)`, `k ≤ l`, in the upper triangle stored row by row.
const fn upper(k: usize, l: usize) -> usize {
    k * MAX_INFLUENCES - k * (k + 1) / 2 + l
}

impl SkinFit {
    /// A fit for the mesh `rest` on `skeleton`, with no frame yet.
    pub fn new(skeleton: &Skeleton, rest: &[DVec3]) -> Self {
        let segs = crate::rig::bind::segments(skeleton);
        let joint_rest: Vec<DVec3> = skeleton.joints.iter().map(|j| j.rest).collect();
        let mut candidates = Vec::with_capacity(rest.len());
        let mut count = Vec::with_capacity(rest.len());
        let mut ranked: Vec<(f64, usize)> = Vec::with_capacity(segs.len());
        for &p in rest {
            ranked.clear();
            for &seg in &segs {
                let d = crate::rig::bind::segment_distance2(skeleton, seg, p);
                ranked.push((d, seg.0));
            }
            ranked.sort_by(|x, y| x.0.total_cmp(&y.0));
            let mut c = [0u16; MAX_INFLUENCES];
            let mut n = 0;
            for &(_, a) in &ranked {
                if n == MAX_INFLUENCES {
                    break;
                }
                if !c[..n].contains(&(a as u16)) {
                    c[n] = a as u16;
                    n += 1;
                }
            }
            // A skeleton without segments: the first joint alone.
            candidates.push(c);
            count.push(n.max(1) as u8);
        }
        let nv = rest.len();
        let (lo, hi) = rest.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let size2_m2 = if nv > 0 {
            (hi - lo).length_squared()
        } else {
            0.0
        };
        Self {
            rest: rest.to_vec(),
            joint_rest,
            candidates,
            count,
            gram: vec![[0.0; PACKED]; nv],
            rhs: vec![[0.0; MAX_INFLUENCES]; nv],
            size2_m2,
            frames: 0,
        }
    }

    /// Frames taken in so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Takes in one solved frame: every joint's world rotation from rest and position,
    /// and the solved mesh (the rest mesh's vertex order). A frame of another size is
    /// ignored.
    pub fn add(&mut self, world_rot: &[DQuat], world_pos: &[DVec3], vertices: &[DVec3]) {
        let nj = self.joint_rest.len();
        if vertices.len() != self.rest.len() || world_rot.len() < nj || world_pos.len() < nj {
            return;
        }
        for (i, &x) in vertices.iter().enumerate() {
            let n = self.count[i] as usize;
            let mut a = [DVec3::ZERO; MAX_INFLUENCES];
            for (ak, &j) in a.iter_mut().zip(&self.candidates[i][..n]) {
                let j = j as usize;
                *ak = world_rot[j] * (self.rest[i] - self.joint_rest[j]) + world_pos[j];
            }
            let g = &mut self.gram[i];
            for k in 0..n {
                for l in k..n {
                    g[upper(k, l)] += a[k].dot(a[l]);
                }
                self.rhs[i][k] += a[k].dot(x);
            }
        }
        self.frames += 1;
    }

    /// Adds the frames another fit of the same mesh took in (a later part of a take).
    /// A fit of another mesh is ignored.
    pub fn merge(&mut self, other: &SkinFit) {
        if other.rest.len() != self.rest.len() || other.candidates != self.candidates {
            return;
        }
        for (g, o) in self.gram.iter_mut().zip(&other.gram) {
            g.iter_mut().zip(o).for_each(|(a, b)| *a += b);
        }
        for (h, o) in self.rhs.iter_mut().zip(&other.rhs) {
            h.iter_mut().zip(o).for_each(|(a, b)| *a += b);
        }
        self.frames += other.frames;
    }

    /// Each vertex's joints and weights (summing to 1; a joint it does not follow has
    /// weight zero): the fit's where it saw frames, else the nearest segment's owner
    /// alone.
    pub fn weights(&self) -> Vec<([u16; MAX_INFLUENCES], [f32; MAX_INFLUENCES])> {
        let margin = MIN_GAIN * self.frames as f64 * self.size2_m2;
        (0..self.rest.len())
            .map(|i| {
                let c = self.candidates[i];
                let w = if self.frames == 0 {
                    let mut w = [0.0; MAX_INFLUENCES];
                    w[0] = 1.0;
                    w
                } else {
                    solve_simplex(&self.gram[i], &self.rhs[i], self.count[i] as usize, margin)
                };
                (c, w.map(|x| x as f32))
            })
            .collect()
    }
}

/// The weights `w ≥ 0`, `Σ w = 1` over the first `n` candidates minimising
/// `wᵀ G w − 2 hᵀ w` (the residual less its constant), by trying every subset; a
/// larger subset must lower it by `margin` (m²).
fn solve_simplex(
    g: &[f64; PACKED],
    h: &[f64; MAX_INFLUENCES],
    n: usize,
    margin: f64,
) -> [f64; MAX_INFLUENCES] {
    let gk = |k: usize, l: usize| g[upper(k.min(l), k.max(l))];
    let cost = |w: &[f64; MAX_INFLUENCES]| {
        let mut c = 0.0;
        for k in 0..n {
            c -= 2.0 * h[k] * w[k];
            for l in 0..n {
                c += w[k] * gk(k, l) * w[l];
            }
        }
        c
    };
    let mut best = [0.0; MAX_INFLUENCES];
    best[0] = 1.0;
    let mut best_cost = cost(&best);
    let mut best_size = 1;
    // Subsets by size: a larger one must gain `margin` over the best so far.
    for size in 1..=n {
        for mask in 1u32..(1 << n) {
            if mask.count_ones() as usize != size {
                continue;
            }
            let mut idx = [0usize; MAX_INFLUENCES];
            let mut m = 0;
            for k in (0..n).filter(|k| mask & (1 << k) != 0) {
                idx[m] = k;
                m += 1;
            }
            let Some(w) = constrained_least_squares(&idx[..m], &gk, h) else {
                continue;
            };
            if w[..m].iter().any(|&x| x < 0.0) {
                continue;
            }
            let mut full = [0.0; MAX_INFLUENCES];
            for (&k, &x) in idx[..m].iter().zip(&w) {
                full[k] = x;
            }
            let c = cost(&full);
            let gain = if size > best_size { margin } else { 0.0 };
            if c < best_cost - gain {
                (best, best_cost, best_size) = (full, c, size);
            }
        }
    }
    best
}

/// `min wᵀ G w − 2 hᵀ w` over the candidates `idx` with `Σ w = 1`: the system
/// `[G 1; 1ᵀ 0] [w; λ] = [h; 1]` by Gauss–Jordan elimination with partial pivoting
/// (the weights in the first `idx.len()` entries); `None` where it is singular.
fn constrained_least_squares(
    idx: &[usize],
    gk: &dyn Fn(usize, usize) -> f64,
    h: &[f64; MAX_INFLUENCES],
) -> Option<[f64; MAX_INFLUENCES]> {
    let m = idx.len() + 1;
    let mut a = [[0.0f64; MAX_INFLUENCES + 2]; MAX_INFLUENCES + 1];
    for (r, &k) in idx.iter().enumerate() {
        for (c, &l) in idx.iter().enumerate() {
            a[r][c] = gk(k, l);
        }
        a[r][m - 1] = 1.0;
        a[r][m] = h[k];
    }
    // The last row: Σ w = 1.
    a[m - 1][..=m].fill(1.0);
    a[m - 1][m - 1] = 0.0;
    let scale = (0..m - 1).map(|r| a[r][r].abs()).fold(1.0f64, f64::max);
    for col in 0..m {
        let piv = (col..m).max_by(|&x, &y| a[x][col].abs().total_cmp(&a[y][col].abs()))?;
        if a[piv][col].abs() <= 1e-12 * scale {
            return None;
        }
        a.swap(col, piv);
        let pivot = a[col];
        for (r, row) in a.iter_mut().enumerate().take(m) {
            if r != col {
                let f = row[col] / pivot[col];
                for (x, p) in row[col..=m].iter_mut().zip(&pivot[col..=m]) {
                    *x -= f * p;
                }
            }
        }
    }
    let mut w = [0.0; MAX_INFLUENCES];
    for (r, x) in w.iter_mut().enumerate().take(idx.len()) {
        *x = a[r][m] / a[r][r];
    }
    Some(w)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::character::skeleton::{Joint, Skeleton};

    /// A two-bone chain along x: joints at 0, 1 and 2 m.
    fn chain() -> Skeleton {
        let joint = |name: &str, parent: Option<usize>, x: f64| Joint {
            name: name.into(),
            parent,
            rest: DVec3::new(x, 0.0, 0.0),
            limits: None,
            bend_axis: DVec3::Z,
        };
        Skeleton {
            joints: vec![
                joint("a", None, 0.0),
                joint("b", Some(0), 1.0),
                joint("c", Some(1), 2.0),
            ],
        }
    }

    /// Frames made by linear blend skinning with known weights are fitted back to those
    /// weights (to 1e-6: f32 output), and a vertex that follows one joint rigidly stays
    /// on it alone. Joints a and b own the chain's two segments; c owns none.
    #[test]
    fn weights_made_by_blend_skinning_are_recovered() {
        let sk = chain();
        let rest = vec![
            DVec3::new(0.9, 0.1, 0.0),
            DVec3::new(1.1, -0.1, 0.05),
            DVec3::new(0.3, 0.1, 0.0),
        ];
        let truth = [[0.3, 0.7, 0.0], [0.8, 0.2, 0.0], [1.0, 0.0, 0.0]];
        let mut fit = SkinFit::new(&sk, &rest);
        for f in 0..20 {
            let t = f as f64 * 0.15;
            let rot = [
                DQuat::from_rotation_y(0.2 * t.sin()),
                DQuat::from_rotation_z(0.9 * t.sin()) * DQuat::from_rotation_y(0.1 * t),
                DQuat::from_rotation_z(0.4 * t.cos()),
            ];
            let pos = [
                DVec3::new(0.1 * t, 0.0, 0.0),
                DVec3::new(1.0 + 0.1 * t, 0.2 * t.sin(), 0.0),
                DVec3::new(2.0, 0.5 * t.sin(), 0.1),
            ];
            let x: Vec<DVec3> = rest
                .iter()
                .zip(&truth)
                .map(|(&v, w)| {
                    (0..3)
                        .map(|j| (rot[j] * (v - sk.joints[j].rest) + pos[j]) * w[j])
                        .sum()
                })
                .collect();
            fit.add(&rot, &pos, &x);
        }
        assert_eq!(fit.frames(), 20);
        for ((joints, w), want) in fit.weights().iter().zip(&truth) {
            let sum: f32 = w.iter().sum();
            assert!((sum - 1.0).abs() < 1e-6, "{w:?}");
            for (j, want) in want.iter().enumerate() {
                let got: f64 = joints
                    .iter()
                    .zip(w)
                    .filter(|(&jj, _)| jj as usize == j)
                    .map(|(_, &x)| x as f64)
                    .sum();
                assert!((got - want).abs() < 1e-6, "joint {j}: {got} against {want}");
            }
        }
        // The third vertex follows joint a alone: b cannot lower its zero residual.
        let w = fit.weights()[2];
        assert_eq!((w.0[0], w.1[0]), (0, 1.0));
    }

    /// A star: a root with four limbs of two bones each, so a vertex near the root has
    /// four candidates. Weights over three of them are recovered, the fourth at zero,
    /// and two fits of halves of the frames, merged, equal one fit of all of them.
    #[test]
    fn four_candidates_and_merged_halves() {
        let dirs = [DVec3::X, DVec3::NEG_X, DVec3::Z, DVec3::NEG_Z];
        let mut joints = vec![Joint {
            name: "root".into(),
            parent: None,
            rest: DVec3::ZERO,
            limits: None,
            bend_axis: DVec3::Z,
        }];
        for (k, d) in dirs.iter().enumerate() {
            for (step, parent) in [(1.0, 0), (2.0, 1 + 2 * k)] {
                joints.push(Joint {
                    name: format!("limb{k}_{step}"),
                    parent: Some(parent),
                    rest: *d * step,
                    limits: None,
                    bend_axis: DVec3::Y,
                });
            }
        }
        let sk = Skeleton { joints };
        let rest = vec![DVec3::new(0.2, 0.1, 0.15)];
        let mut whole = SkinFit::new(&sk, &rest);
        let (mut first, mut second) = (SkinFit::new(&sk, &rest), SkinFit::new(&sk, &rest));
        let cands = whole.candidates[0];
        assert_eq!(whole.count[0], 4, "{cands:?}");
        let truth = [0.5, 0.3, 0.2, 0.0];
        for f in 0..30 {
            let t = f as f64 * 0.2;
            let rot: Vec<DQuat> = (0..sk.joints.len())
                .map(|j| {
                    DQuat::from_rotation_y(0.3 * (t + j as f64).sin())
                        * DQuat::from_rotation_x(0.2 * t.cos() * j as f64)
                })
                .collect();
            let pos: Vec<DVec3> = sk
                .joints
                .iter()
                .enumerate()
                .map(|(j, jt)| jt.rest + DVec3::new(0.05 * (t * j as f64).sin(), 0.1 * t, 0.0))
                .collect();
            let x: DVec3 = (0..4)
                .map(|k| {
                    let j = cands[k] as usize;
                    (rot[j] * (rest[0] - sk.joints[j].rest) + pos[j]) * truth[k]
                })
                .sum();
            whole.add(&rot, &pos, &[x]);
            if f < 15 { &mut first } else { &mut second }.add(&rot, &pos, &[x]);
        }
        first.merge(&second);
        let (w, merged) = (whole.weights()[0].1, first.weights()[0].1);
        for k in 0..4 {
            assert!((f64::from(w[k]) - truth[k]).abs() < 1e-5, "{w:?}");
            assert!((w[k] - merged[k]).abs() < 1e-6, "{w:?} {merged:?}");
        }
        assert_eq!(first.frames(), 30);
    }

    /// With no frame, every vertex follows its nearest segment's owner wholly.
    #[test]
    fn without_frames_the_skin_is_rigid() {
        let sk = chain();
        let fit = SkinFit::new(&sk, &[DVec3::new(1.6, 0.2, 0.0), DVec3::new(0.2, 0.0, 0.0)]);
        let w = fit.weights();
        assert_eq!((w[0].0[0], w[0].1), (1, [1.0, 0.0, 0.0, 0.0]));
        assert_eq!((w[1].0[0], w[1].1), (0, [1.0, 0.0, 0.0, 0.0]));
    }
}
