//! Volumetric as-rigid-as-possible deformation of a tet mesh with soft linear constraints:
//! the per-frame local/global alternation on the system a rig carries
//! ([`crate::rig::arap_system`], built and factored at bind time).
//!
//! Energy (Le Naour et al., Eq. 5 and Eq. 11; Sorkine & Alexa 2007 for the alternation):
//!
//! ```text
//! E(V') = (w_l / h) Σ_i Σ_{j∈N(i)} w_ij ‖(v'_i − v'_j) − R_i (v_i − v_j)‖²
//!       + Σ_r ω_r ‖a_rᵀ V' − t_r‖²
//! ```
//!
//! (`w_ij`, `h`, the rows `a_r` and their weights `ω_r`: see [`crate::rig::arap_system`].)
//!
//! Global step (∂E/∂V' = 0, divided by 2):
//! `(2 (w_l/h) L + Σ_r ω_r a_r a_rᵀ) V' = (w_l/h) b(R) + Σ_r ω_r a_r t_rᵀ`, with
//! `L` the weighted graph Laplacian (`L_ii = Σ_j w_ij`, `L_ij = −w_ij`) and
//! `b_i = Σ_j w_ij (R_i + R_j)(v_i − v_j)`. The matrix is factored once, at bind time.

use crate::geom::polar::{extract_rotation, extract_rotations4};
use crate::rig::arap_system::ArapSystem;
use glam::{DMat3, DQuat, DVec3};

/// Per-solver mutable state of the ARAP alternation. Allocated once; iterating does not
/// allocate.
pub struct ArapState {
    /// Current positions `v'_i`.
    pub positions: Vec<DVec3>,
    /// Current per-vertex rotations (warm start for the next local step).
    pub quats: Vec<DQuat>,
    /// The same rotations as matrices.
    pub rots: Vec<DMat3>,
    /// Per-row targets `t_r`.
    pub targets: Vec<DVec3>,
    /// Total polar-extraction iterations in the last local step.
    pub polar_iters: usize,
    /// Right-hand side rows, then the solution (`n`).
    rhs: Vec<DVec3>,
    /// Substitution scratch (`n`).
    work: Vec<DVec3>,
}

impl ArapSystem {
    /// A fresh state at the rest pose with identity rotations and rest targets.
    pub fn new_state(&self) -> ArapState {
        let n = self.op.n();
        let targets = (0..self.rows.len())
            .map(|r| self.rows.eval(r, &self.op.rest))
            .collect();
        ArapState {
            positions: self.op.rest.clone(),
            quats: vec![DQuat::IDENTITY; n],
            rots: vec![DMat3::IDENTITY; n],
            targets,
            polar_iters: 0,
            rhs: vec![DVec3::ZERO; n],
            work: vec![DVec3::ZERO; n],
        }
    }

    /// Local step: per-vertex rotations `R_i = polar(Σ_j w_ij e'_ij e_ijᵀ)` from the current
    /// positions, warm-started from the previous rotations.
    ///
    /// Returns the shape energy of the current positions with the new rotations,
    /// `Σ_i Σ_j w_ij ‖e'_ij − R_i e_ij‖²` (without `w_l / h`), obtained for free as
    /// `Σ w‖e'‖² − 2 tr(R_iᵀ A_i) + Σ w‖e‖²`.
    pub fn local_step(&self, st: &mut ArapState) -> f64 {
        let op = &self.op;
        let n = op.n();
        let mut energy = 0.0;
        let mut polar_iters = 0;
        // Four vertices at a time: their rotation extractions run side by side.
        let mut a4 = [DMat3::ZERO; 4];
        let mut e2_4 = [0.0; 4];
        let mut q4 = [DQuat::IDENTITY; 4];
        for first in (0..n).step_by(4) {
            let lanes = (n - first).min(4);
            for l in 0..lanes {
                let i = first + l;
                let pi = st.positions[i];
                let mut a = DMat3::ZERO;
                let mut e2 = op.rest_sq[i];
                for k in op.start[i] as usize..op.start[i + 1] as usize {
                    let w = op.weight[k];
                    let ed = pi - st.positions[op.nbr[k] as usize];
                    let er = op.rest_edge[k];
                    let wd = ed * w;
                    a.x_axis += wd * er.x;
                    a.y_axis += wd * er.y;
                    a.z_axis += wd * er.z;
                    e2 += w * ed.length_squared();
                }
                a4[l] = a;
                e2_4[l] = e2;
                q4[l] = st.quats[i];
            }
            if lanes == 4 {
                polar_iters += extract_rotations4(&a4, &mut q4);
            } else {
                for l in 0..lanes {
                    polar_iters += extract_rotation(&a4[l], &mut q4[l]);
                }
            }
            for l in 0..lanes {
                let i = first + l;
                st.quats[i] = q4[l];
                let r = DMat3::from_quat(q4[l]);
                st.rots[i] = r;
                let a = &a4[l];
                let tr = r.x_axis.dot(a.x_axis) + r.y_axis.dot(a.y_axis) + r.z_axis.dot(a.z_axis);
                energy += e2_4[l] - 2.0 * tr;
            }
        }
        st.polar_iters = polar_iters;
        energy.max(0.0)
    }

    /// Global step: solves for new positions given the current rotations and targets.
    pub fn global_step(&self, st: &mut ArapState) {
        let op = &self.op;
        let s = self.shape_scale;
        let rhs = &mut st.rhs;
        for (i, out) in rhs.iter_mut().enumerate() {
            // Σ_j w_ij (R_i + R_j) e_ij = R_i Σ_j w_ij e_ij + Σ_j R_j (w_ij e_ij).
            let mut b = st.rots[i] * op.rest_sum[i];
            for k in op.start[i] as usize..op.start[i + 1] as usize {
                let j = op.nbr[k] as usize;
                b += st.rots[j] * (op.rest_edge[k] * op.weight[k]);
            }
            *out = b * s;
        }
        for r in 0..self.rows.len() {
            let t = st.targets[r] * self.rows.weight[r];
            for (i, c) in self.rows.row(r) {
                rhs[i] += t * c;
            }
        }
        self.chol.solve3(rhs, &mut st.work);
        st.positions.copy_from_slice(rhs);
    }

    /// Total energy (shape with `w_l/h`, plus constraint rows) at the current state.
    pub fn total_energy(&self, st: &ArapState) -> f64 {
        let shape = self.shape_scale * self.op.shape_energy(&st.positions, &st.rots);
        let rows: f64 = (0..self.rows.len())
            .map(|r| {
                self.rows.weight[r]
                    * (self.rows.eval(r, &st.positions) - st.targets[r]).length_squared()
            })
            .sum();
        shape + rows
    }

    /// rrms of the shape energy value returned by [`Self::local_step`] (DESIGN.md).
    pub fn rrms(&self, shape_energy: f64) -> f64 {
        (shape_energy / self.op.rest_energy_scale).sqrt()
    }
}

/// How an iteration loop ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// The relative change of the error criterion fell below the tolerance.
    Converged,
    /// The iteration cap was reached first.
    IterationCap,
    /// The frame's deadline was reached first.
    Deadline,
}

/// Absolute floor added to the relative convergence test, so an exactly reproducible
/// (zero-energy) pose converges instead of chasing round-off.
pub const CONVERGENCE_ABS_FLOOR: f64 = 1e-9;

impl ArapSystem {
    /// Plain ARAP alternation (no skeleton step) until the relative change of rrms falls
    /// below `rel_tol`, or `max_iters`. Returns (iterations, last rrms, reason).
    pub fn iterate(
        &self,
        st: &mut ArapState,
        max_iters: usize,
        rel_tol: f64,
    ) -> (usize, f64, StopReason) {
        let mut prev: Option<f64> = None;
        for it in 0..max_iters {
            let rr = self.rrms(self.local_step(st));
            if let Some(p) = prev {
                if (rr - p).abs() <= rel_tol * p + CONVERGENCE_ABS_FLOOR {
                    return (it, rr, StopReason::Converged);
                }
            }
            prev = Some(rr);
            self.global_step(st);
        }
        let rr = self.rrms(self.local_step(st));
        (max_iters, rr, StopReason::IterationCap)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::arap_system::tests_support::bar;
    use crate::rig::lattice::box_lattice;

    fn bend_targets(sys: &ArapSystem, st: &mut ArapState, scale: f64) {
        // Rotate the far end by 60° about z around (3, 0, 0) and lift it.
        let q = DQuat::from_rotation_z(60f64.to_radians());
        for r in 0..sys.rows.len() {
            let rest = sys.rows.eval(r, &sys.op.rest);
            st.targets[r] = if rest.x > 2.0 * scale {
                let c = DVec3::new(3.0, 0.0, 0.0) * scale;
                c + q * (rest - c) + DVec3::new(0.0, 0.3, 0.0) * scale
            } else {
                rest
            };
        }
    }

    #[test]
    fn rigid_motion_costs_zero_energy() {
        let (sys, _) = bar(1.0);
        let mut st = sys.new_state();
        let q = DQuat::from_axis_angle(DVec3::new(1.0, 2.0, -0.5).normalize(), 1.3);
        let t = DVec3::new(0.5, -2.0, 3.0);
        let rigid: Vec<DVec3> = sys.op.rest.iter().map(|r| q * *r + t).collect();
        for (r, tr) in st.targets.iter_mut().enumerate() {
            *tr = sys.rows.eval(r, &rigid);
        }
        st.positions.clone_from(&rigid);
        let e = sys.local_step(&mut st) / sys.op.rest_energy_scale;
        // Relative energy of an exactly rigid pose: only round-off (1e-12 relative).
        assert!(e < 1e-12, "relative energy {e}");
        assert!(st
            .quats
            .iter()
            .all(|r| crate::geom::polar::rotation_angle_between(*r, q) < 1e-9));
        // The rigid pose is a fixed point of the alternation.
        let (iters, _, reason) = sys.iterate(&mut st, 10, 1e-9);
        assert_eq!(reason, StopReason::Converged);
        assert!(iters <= 2);
        let max_err = st
            .positions
            .iter()
            .zip(&rigid)
            .map(|(p, r)| (*p - *r).length())
            .fold(0.0, f64::max);
        // 1e-12 of the bar length: a direct solve of a consistent system.
        assert!(max_err < 4e-12, "max distance to rigid pose {max_err}");
    }

    #[test]
    fn rigid_targets_from_rest_converge_to_rigid_pose() {
        let (sys, _) = bar(1.0);
        let mut st = sys.new_state();
        let q = DQuat::from_axis_angle(DVec3::new(0.0, 0.0, 1.0), 0.5);
        for (r, tr) in st.targets.iter_mut().enumerate() {
            *tr = q * sys.rows.eval(r, &sys.op.rest);
        }
        sys.iterate(&mut st, 2000, 1e-12);
        let max_err = st
            .positions
            .iter()
            .zip(&sys.op.rest)
            .map(|(p, r)| (*p - q * *r).length())
            .fold(0.0, f64::max);
        // 1e-6 of the bar length: the alternation converges linearly; 2000 iterations and a
        // 1e-12 relative stop put it far below this.
        assert!(max_err < 4e-6, "max distance to rigid pose {max_err}");
    }

    #[test]
    fn energy_never_increases() {
        let (sys, _) = bar(1.0);
        let mut st = sys.new_state();
        bend_targets(&sys, &mut st, 1.0);
        sys.local_step(&mut st);
        let mut prev = f64::INFINITY;
        for _ in 0..30 {
            sys.global_step(&mut st);
            sys.local_step(&mut st);
            let e = sys.total_energy(&st);
            // Each half-step minimises E over its block exactly; 1e-12 relative slack for round-off.
            assert!(e <= prev * (1.0 + 1e-12), "energy rose from {prev} to {e}");
            prev = e;
        }
    }

    #[test]
    fn results_do_not_change_under_scaling() {
        let solve = |s: f64| {
            let (sys, _) = bar(s);
            let mut st = sys.new_state();
            bend_targets(&sys, &mut st, s);
            sys.iterate(&mut st, 40, 0.0);
            st.positions.iter().map(|p| *p / s).collect::<Vec<_>>()
        };
        let base = solve(1.0);
        for s in [1e-3, 1e3] {
            let other = solve(s);
            let d = base
                .iter()
                .zip(&other)
                .map(|(a, b)| (*a - *b).length())
                .fold(0.0, f64::max);
            // Same iterations on a scaled copy: only round-off differs (1e-9 of the length 4).
            assert!(d < 4e-9, "scale {s}: max difference {d}");
        }
    }

    #[test]
    fn warm_start_needs_no_more_iterations_than_cold() {
        let (sys, _) = bar(1.0);
        let mut warm = sys.new_state();
        bend_targets(&sys, &mut warm, 1.0);
        sys.iterate(&mut warm, 500, 1e-8);
        // Next frame: the targets move a little further.
        let q = DQuat::from_rotation_z(2f64.to_radians());
        let moved: Vec<DVec3> = warm
            .targets
            .iter()
            .map(|t| if t.x > 2.0 { q * *t } else { *t })
            .collect();
        warm.targets.clone_from(&moved);
        let (warm_iters, _, _) = sys.iterate(&mut warm, 500, 1e-6);
        let mut cold = sys.new_state();
        cold.targets.clone_from(&moved);
        let (cold_iters, _, _) = sys.iterate(&mut cold, 500, 1e-6);
        assert!(
            warm_iters <= cold_iters,
            "warm {warm_iters} > cold {cold_iters}"
        );
        assert!(
            warm_iters < cold_iters / 2,
            "warm start should save most iterations: warm {warm_iters}, cold {cold_iters}"
        );
    }

    #[test]
    fn bending_does_not_invert_tets() {
        let (sys, _) = bar(1.0);
        let mut st = sys.new_state();
        bend_targets(&sys, &mut st, 1.0);
        sys.iterate(&mut st, 100, 1e-6);
        let lm = box_lattice(DVec3::ZERO, DVec3::new(4.0, 1.0, 1.0), [8, 2, 2]);
        assert_eq!(lm.mesh.inverted_tets(&st.positions), 0);
    }
}
