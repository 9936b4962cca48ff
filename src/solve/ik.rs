//! The skeleton step's posture: joint rotations, inside every joint's limits, that carry
//! the markers onto their measured positions. A small box-constrained nonlinear least
//! squares problem (Levenberg–Marquardt, Marquardt's diagonal scaling, projection onto
//! the limits with a binding set as in Bertsekas' projected Newton method), warm-started
//! from the previous frame. Allocation-free after [`IkModel::new_state`].
//!
//! Why a fit instead of reading the posture off the deformed skeleton vertices (Le Naour
//! et al., Section 4.2): measured on the procedural hand, the read posture drifts (the
//! per-vertex ARAP rotations carry a twist the bone lines cannot show, up to 45° where the
//! limit is 5°), and a soft skeleton cannot hold limits (91° of violation). The fit holds
//! the limits exactly and restores bone lengths and straightness by construction
//! (forward kinematics of rigid segments); the control mesh then gets this posture as
//! targets for its skeleton samples and ARAP carries the flesh around it.
//!
//! Unknowns `θ` (per root joint a world rotation increment and a position; per other
//! joint with children its swing-twist angles, boxed by its limits): see
//! [`crate::rig::ik_model`], which builds the problem at bind time.
//!
//! Objective, with `h` the character height so that nothing changes with scale:
//!
//! ```text
//! E(θ) = Σ_k c_k ‖p_k(θ) − m_k‖² + (ε_rest h)² Σ_j ‖θ_j‖² + (ε_prev h)² Σ_j ‖θ_j − θ_j^prev‖²
//! p_k(θ) = P_J + Q_J (m_k^rest − r_J)        (marker k rigidly carried by its joint J)
//! ```
//!
//! `c_k ∈ [0, 1]` ([`IkState::marker_weight`], 1 unless the caller says otherwise) is how
//! far marker `k`'s position is trusted: the solver gives a predicted marker less weight
//! the longer its gap.
//!
//! The rest prior picks the least bent posture among those that fit equally well (one
//! marker on a three-joint finger leaves one degree of freedom free); the previous-frame
//! prior holds joints that no marker observes.
//!
//! Jacobian: a change `dθ` of joint `j` turns everything below it about `P_j` with the
//! world angular velocity `ω = Q_parent ω_local`, so `∂p_k/∂θ = ω × (p_k − P_j)`, with
//! `ω_local = S a` for the twist (`S` the swing) and `ω_local = J_l(v) u` for the swing
//! components (`v` the swing vector, `u` its bend or side axis, `J_l` the left Jacobian
//! of SO(3)).

use crate::character::skeleton::{compose, SwingTwist};
use crate::rig::ik_model::{Dofs, IkModel};
use glam::{DQuat, DVec3};

/// Relative weights of the posture priors (dimensionless; multiplied by the character
/// height, see the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IkParams {
    /// `ε_rest`: metres of marker misfit (per metre of height) that one radian of joint
    /// rotation away from rest is worth.
    pub rest_prior: f64,
    /// `ε_prev`: the same for one radian of change from the previous frame.
    pub prev_prior: f64,
    /// Levenberg–Marquardt iteration cap per frame.
    pub max_iterations: usize,
    /// Stop when no angle moves more than this in one step, in radians.
    pub step_tolerance_rad: f64,
    /// Or when one step lowers the objective by less than this fraction of it.
    pub cost_tolerance: f64,
}

impl Default for IkParams {
    fn default() -> Self {
        Self {
            rest_prior: 2e-3,
            prev_prior: 2e-3,
            max_iterations: 30,
            step_tolerance_rad: 2e-3,
            cost_tolerance: 1e-6,
        }
    }
}

/// Prior weights `(ε_rest h)², (ε_prev h)²`.
#[derive(Clone, Copy)]
struct Priors {
    rest: f64,
    prev: f64,
}

/// Per-solver posture state and scratch memory.
#[derive(Clone, Debug)]
pub struct IkState {
    /// Swing-twist angles per parameter (root entries unused).
    pub angles: Vec<f64>,
    /// The previous frame's angles (the prior's centre).
    prev_angles: Vec<f64>,
    /// Per parameter, a factor on the rest prior (1 unless a caller holds some joints
    /// near rest: a calibration's rest-like frame).
    pub(crate) rest_scale: Vec<f64>,
    /// World rotation and position of each root joint (unused for other joints).
    root_rot: Vec<DQuat>,
    root_pos: Vec<DVec3>,
    /// Forward kinematics of the current posture: world rotation and position per joint.
    pub world_rot: Vec<DQuat>,
    pub world_pos: Vec<DVec3>,
    /// World angular velocity of each unknown of each joint (Angles joints only).
    omega: Vec<[DVec3; 3]>,
    /// Current marker positions `p_k`.
    pub predicted: Vec<DVec3>,
    /// Each marker's weight `c_k` in the fit, in `[0, 1]` (all 1 at first).
    pub marker_weight: Vec<f64>,
    trial: Box<Trial>,
    hess: Vec<f64>,
    chol: Vec<f64>,
    grad: Vec<f64>,
    step: Vec<f64>,
    /// The step in elimination order (`n_params`).
    work: Vec<f64>,
    free: Vec<bool>,
    /// Jacobian columns of one marker (capacity: the longest chain's unknowns).
    cols: Vec<(usize, DVec3)>,
    mu: f64,
}

#[derive(Clone, Debug)]
struct Trial {
    angles: Vec<f64>,
    root_rot: Vec<DQuat>,
    root_pos: Vec<DVec3>,
    world_rot: Vec<DQuat>,
    world_pos: Vec<DVec3>,
    predicted: Vec<DVec3>,
}

/// What one posture fit did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct IkReport {
    pub iterations: usize,
    /// RMS distance between fitted and measured markers, metres.
    pub marker_rms_m: f64,
}

/// The markers' targets `m_k` (metres; non-finite: left out) and weights `c_k`.
#[derive(Clone, Copy)]
struct Targets<'a> {
    positions: &'a [DVec3],
    weight: &'a [f64],
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// `J_l(v) u`, the left Jacobian of SO(3) at rotation vector `v` applied to `u`.
fn left_jacobian_apply(v: DVec3, u: DVec3) -> DVec3 {
    let t2 = v.length_squared();
    let (a, b) = if t2 < 1e-8 {
        (0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0)
    } else {
        let t = t2.sqrt();
        ((1.0 - t.cos()) / t2, (t - t.sin()) / (t2 * t))
    };
    let vu = v.cross(u);
    u + vu * a + v.cross(vu) * b
}

impl IkModel {
    /// The most unknowns that move one marker (sizes the Jacobian scratch).
    fn max_chain_params(&self) -> usize {
        (0..self.marker_joint.len())
            .map(|k| {
                self.chain[self.chain_start[k]..self.chain_start[k + 1]]
                    .iter()
                    .map(|&j| self.dofs[j].params().len())
                    .sum::<usize>()
            })
            .max()
            .unwrap_or(0)
    }

    /// A state at the rest posture.
    pub fn new_state(&self) -> IkState {
        let nj = self.rest.len();
        let np = self.n_params;
        let nm = self.marker_joint.len();
        let trial = Trial {
            angles: vec![0.0; np],
            root_rot: vec![DQuat::IDENTITY; nj],
            root_pos: self.rest.clone(),
            world_rot: vec![DQuat::IDENTITY; nj],
            world_pos: self.rest.clone(),
            predicted: vec![DVec3::ZERO; nm],
        };
        let mut st = IkState {
            angles: vec![0.0; np],
            prev_angles: vec![0.0; np],
            rest_scale: vec![1.0; np],
            root_rot: vec![DQuat::IDENTITY; nj],
            root_pos: self.rest.clone(),
            world_rot: vec![DQuat::IDENTITY; nj],
            world_pos: self.rest.clone(),
            omega: vec![[DVec3::ZERO; 3]; nj],
            predicted: vec![DVec3::ZERO; nm],
            marker_weight: vec![1.0; nm],
            trial: Box::new(trial),
            hess: vec![0.0; np * np],
            chol: vec![0.0; np * np],
            grad: vec![0.0; np],
            step: vec![0.0; np],
            work: vec![0.0; np],
            free: vec![true; np],
            cols: Vec::with_capacity(self.max_chain_params()),
            mu: 1e-3,
        };
        self.refresh(&mut st);
        st
    }

    /// Recomputes the forward kinematics (`world_rot`, `world_pos`, `predicted`) of the
    /// state's own posture.
    pub(crate) fn refresh(&self, st: &mut IkState) {
        self.forward(
            &st.angles,
            &st.root_rot,
            &st.root_pos,
            &mut st.world_rot,
            &mut st.world_pos,
            &mut st.predicted,
        );
    }

    /// Local rotation of an Angles joint from its parameters.
    fn local(&self, j: usize, first: usize, angles: &[f64]) -> DQuat {
        let [a, b, _] = self.axes[j];
        compose(
            SwingTwist {
                twist: angles[first],
                bend: angles[first + 1],
                side: angles[first + 2],
            },
            a,
            b,
        )
    }

    /// Forward kinematics: joint world rotations and positions, and marker positions.
    fn forward(
        &self,
        angles: &[f64],
        root_rot: &[DQuat],
        root_pos: &[DVec3],
        world_rot: &mut [DQuat],
        world_pos: &mut [DVec3],
        predicted: &mut [DVec3],
    ) {
        for j in 0..self.rest.len() {
            match self.parent[j] {
                None => {
                    world_rot[j] = root_rot[j];
                    world_pos[j] = root_pos[j];
                }
                Some(p) => {
                    world_pos[j] = world_pos[p] + world_rot[p] * (self.rest[j] - self.rest[p]);
                    world_rot[j] = match self.dofs[j] {
                        Dofs::Angles { first } => {
                            (world_rot[p] * self.local(j, first, angles)).normalize()
                        }
                        _ => world_rot[p],
                    };
                }
            }
        }
        for (k, out) in predicted.iter_mut().enumerate() {
            let j = self.marker_joint[k];
            *out = world_pos[j] + world_rot[j] * self.marker_offset[k];
        }
    }

    /// Objective value of a posture (see the module doc).
    fn objective(
        &self,
        w: Priors,
        angles: &[f64],
        prev: &[f64],
        rest_scale: &[f64],
        predicted: &[DVec3],
        m: Targets<'_>,
    ) -> f64 {
        let fit: f64 = predicted
            .iter()
            .zip(m.positions)
            .zip(m.weight)
            .filter(|((_, t), _)| t.is_finite())
            .map(|((p, t), c)| c * (*p - *t).length_squared())
            .sum();
        let mut prior = 0.0;
        for d in &self.dofs {
            if let Dofs::Angles { first } = *d {
                for i in first..first + 3 {
                    prior += w.rest * rest_scale[i] * angles[i] * angles[i]
                        + w.prev * (angles[i] - prev[i]).powi(2);
                }
            }
        }
        fit + prior
    }

    /// Imposes the finite entries of `pins` (one per parameter, radians; NaN: free) on the
    /// posture, clamped to the joint limits, and recomputes its forward kinematics. The
    /// joints a data glove drives take their angles this way after the marker fit.
    pub fn pin(&self, st: &mut IkState, pins: &[f64]) {
        for (i, &v) in pins.iter().enumerate().take(self.n_params) {
            if v.is_finite() {
                st.angles[i] = v.clamp(self.lo[i], self.hi[i]);
            }
        }
        self.refresh(st);
    }

    /// Moves the whole posture rigidly: every root joint gets the world rotation `q`
    /// and the position `q · r_root + t` (its rest position moved by `x ↦ q x + t`);
    /// the joint angles are kept. Recomputes the forward kinematics.
    pub fn place_roots(&self, st: &mut IkState, q: DQuat, t: DVec3) {
        for (j, d) in self.dofs.iter().enumerate() {
            if let Dofs::Root { .. } = d {
                st.root_rot[j] = q;
                st.root_pos[j] = q * self.rest[j] + t;
            }
        }
        self.refresh(st);
    }

    /// Gives `to` the posture of `from` (a state of a model of the same skeleton, with
    /// other markers) and recomputes its forward kinematics.
    pub fn copy_posture(&self, to: &mut IkState, from: &IkState) {
        to.angles.copy_from_slice(&from.angles);
        to.prev_angles.copy_from_slice(&from.prev_angles);
        to.root_rot.copy_from_slice(&from.root_rot);
        to.root_pos.copy_from_slice(&from.root_pos);
        self.refresh(to);
    }

    /// The prior weights `((ε_rest h)², (ε_prev h)²)` of [`Self::solve`] with `params`:
    /// what it adds to the diagonal of the normal equations per angle unknown.
    pub(crate) fn prior_weights(&self, params: &IkParams) -> (f64, f64) {
        (
            (params.rest_prior * self.height_m).powi(2),
            (params.prev_prior * self.height_m).powi(2),
        )
    }

    /// Marks the start of a new frame: the current posture becomes the prior's centre.
    pub fn begin_frame(&self, st: &mut IkState) {
        st.prev_angles.copy_from_slice(&st.angles);
    }

    /// Fits the posture to the marker targets `m` (one per marker, metres), warm-started
    /// from the state's posture. A non-finite target is a marker with no information: it
    /// is left out of the fit (the priors keep the posture determinate). On return
    /// `st.world_rot`/`st.world_pos` hold its forward kinematics.
    pub fn solve(&self, st: &mut IkState, m: &[DVec3], params: &IkParams) -> IkReport {
        let np = self.n_params;
        let (rest, prev) = self.prior_weights(params);
        let w = Priors { rest, prev };
        let mut cost = self.objective(
            w,
            &st.angles,
            &st.prev_angles,
            &st.rest_scale,
            &st.predicted,
            Targets {
                positions: m,
                weight: &st.marker_weight,
            },
        );
        let mut iterations = 0;
        st.mu = st.mu.clamp(1e-9, 1e3);
        while iterations < params.max_iterations {
            iterations += 1;
            let cost_before = cost;
            self.build_normal_equations(st, m, w);
            // Binding set: parameters on a bound whose descent direction leaves the box.
            for i in 0..np {
                let at_lo = st.angles[i] <= self.lo[i] && st.grad[i] > 0.0;
                let at_hi = st.angles[i] >= self.hi[i] && st.grad[i] < 0.0;
                st.free[i] = !(at_lo || at_hi);
            }
            let mut accepted = false;
            let mut max_step = 0.0f64;
            for _ in 0..12 {
                if !self.lm_step_on_active_set(st) {
                    st.mu *= 8.0;
                    continue;
                }
                let t = &mut *st.trial;
                t.angles.copy_from_slice(&st.angles);
                t.root_rot.copy_from_slice(&st.root_rot);
                t.root_pos.copy_from_slice(&st.root_pos);
                max_step = 0.0;
                for (j, d) in self.dofs.iter().enumerate() {
                    match *d {
                        Dofs::None => {}
                        Dofs::Root { first } => {
                            let w =
                                DVec3::new(st.step[first], st.step[first + 1], st.step[first + 2]);
                            max_step = max_step.max(w.length());
                            t.root_rot[j] =
                                (DQuat::from_scaled_axis(w) * st.root_rot[j]).normalize();
                            t.root_pos[j] += DVec3::new(
                                st.step[first + 3],
                                st.step[first + 4],
                                st.step[first + 5],
                            );
                        }
                        Dofs::Angles { first } => {
                            for i in first..first + 3 {
                                let v = (st.angles[i] + st.step[i]).clamp(self.lo[i], self.hi[i]);
                                max_step = max_step.max((v - st.angles[i]).abs());
                                t.angles[i] = v;
                            }
                        }
                    }
                }
                self.forward(
                    &t.angles,
                    &t.root_rot,
                    &t.root_pos,
                    &mut t.world_rot,
                    &mut t.world_pos,
                    &mut t.predicted,
                );
                let c = self.objective(
                    w,
                    &t.angles,
                    &st.prev_angles,
                    &st.rest_scale,
                    &t.predicted,
                    Targets {
                        positions: m,
                        weight: &st.marker_weight,
                    },
                );
                if c <= cost {
                    std::mem::swap(&mut st.angles, &mut t.angles);
                    std::mem::swap(&mut st.root_rot, &mut t.root_rot);
                    std::mem::swap(&mut st.root_pos, &mut t.root_pos);
                    std::mem::swap(&mut st.world_rot, &mut t.world_rot);
                    std::mem::swap(&mut st.world_pos, &mut t.world_pos);
                    std::mem::swap(&mut st.predicted, &mut t.predicted);
                    cost = c;
                    st.mu = (st.mu / 3.0).max(1e-9);
                    accepted = true;
                    break;
                }
                st.mu = (st.mu * 8.0).min(1e9);
            }
            let converged = max_step < params.step_tolerance_rad
                || cost_before - cost <= params.cost_tolerance * cost_before;
            if !accepted || converged {
                break;
            }
        }
        let n = m.iter().filter(|t| t.is_finite()).count().max(1) as f64;
        let fit: f64 = st
            .predicted
            .iter()
            .zip(m)
            .filter(|(_, t)| t.is_finite())
            .map(|(p, t)| (*p - *t).length_squared())
            .sum();
        IkReport {
            iterations,
            marker_rms_m: (fit / n).sqrt(),
        }
    }

    /// Fills `st.hess = JᵀJ + priors` and `st.grad = Jᵀr + priors` at the current posture
    /// (the Gauss–Newton model of `E/2`).
    fn build_normal_equations(&self, st: &mut IkState, m: &[DVec3], w: Priors) {
        let np = self.n_params;
        st.hess.fill(0.0);
        st.grad.fill(0.0);
        self.update_omega(st);
        // Per marker: 3 rows, nonzero only in its chain's columns.
        let mut cols = std::mem::take(&mut st.cols);
        for (k, &target) in m.iter().enumerate().take(self.marker_joint.len()) {
            if !target.is_finite() {
                continue;
            }
            let c = st.marker_weight[k];
            let r = (st.predicted[k] - target) * c;
            self.marker_columns(st, k, &mut cols);
            for &(ix, cx) in cols.iter() {
                st.grad[ix] += cx.dot(r);
                let cxc = cx * c;
                for &(iy, cy) in cols.iter() {
                    st.hess[ix * np + iy] += cxc.dot(cy);
                }
            }
        }
        st.cols = cols;
        for d in &self.dofs {
            if let Dofs::Angles { first } = *d {
                for i in first..first + 3 {
                    let rest = w.rest * st.rest_scale[i];
                    st.hess[i * np + i] += rest + w.prev;
                    st.grad[i] += rest * st.angles[i] + w.prev * (st.angles[i] - st.prev_angles[i]);
                }
            }
        }
    }

    /// Recomputes the world angular velocity of every angle unknown at the state's
    /// posture (what [`Self::marker_columns`] reads).
    pub(crate) fn update_omega(&self, st: &mut IkState) {
        for (j, d) in self.dofs.iter().enumerate() {
            if let Dofs::Angles { first } = *d {
                let [a, b, s] = self.axes[j];
                let v = b * st.angles[first + 1] + s * st.angles[first + 2];
                let swing = DQuat::from_scaled_axis(v);
                let qp = self.parent[j].map_or(DQuat::IDENTITY, |p| st.world_rot[p]);
                st.omega[j] = [
                    qp * (swing * a),
                    qp * left_jacobian_apply(v, b),
                    qp * left_jacobian_apply(v, s),
                ];
            }
        }
    }

    /// The nonzero Jacobian columns of marker `k`'s predicted position, `(unknown,
    /// ∂p_k/∂θ_unknown)` (a root's rotation increment and position, then each joint's
    /// angles down the chain), at the state's posture; [`Self::update_omega`] must have
    /// run on it.
    pub(crate) fn marker_columns(&self, st: &IkState, k: usize, cols: &mut Vec<(usize, DVec3)>) {
        let p = st.predicted[k];
        cols.clear();
        for &j in &self.chain[self.chain_start[k]..self.chain_start[k + 1]] {
            let arm = p - st.world_pos[j];
            match self.dofs[j] {
                Dofs::Root { first } => {
                    for (i, e) in [DVec3::X, DVec3::Y, DVec3::Z].into_iter().enumerate() {
                        cols.push((first + i, e.cross(arm)));
                        cols.push((first + 3 + i, e));
                    }
                }
                Dofs::Angles { first } => {
                    for i in 0..3 {
                        cols.push((first + i, st.omega[j][i].cross(arm)));
                    }
                }
                Dofs::None => {}
            }
        }
    }

    /// [`Self::lm_step`], then fixes the unknowns that sit on a bound and whose step
    /// would leave the box (the coupled step can push out a variable whose own gradient
    /// points inwards; clipping it after the fact would stall the others), and solves
    /// again, until the step stays inside for every variable on a bound.
    fn lm_step_on_active_set(&self, st: &mut IkState) -> bool {
        for _ in 0..8 {
            if !self.lm_step(st) {
                return false;
            }
            let mut changed = false;
            for i in 0..self.n_params {
                let a = st.angles[i];
                let out =
                    (a <= self.lo[i] && st.step[i] < 0.0) || (a >= self.hi[i] && st.step[i] > 0.0);
                if st.free[i] && out {
                    st.free[i] = false;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        true
    }

    /// Solves `(H + μ diag H) δ = −g` over the free unknowns (bound ones get `δ = 0`)
    /// into `st.step`, by a Cholesky factorization of the damped matrix in `st.chol`
    /// (row-major lower triangle, rows and columns in [`Self::order`], each row stored
    /// only from its envelope's first column: the tree's structure makes everything left
    /// of it zero). Returns false when it is not positive definite.
    fn lm_step(&self, st: &mut IkState) -> bool {
        let np = self.n_params;
        let (order, first) = (&self.order, &self.envelope_first);
        let max_diag = (0..np).map(|i| st.hess[i * np + i]).fold(0.0, f64::max);
        let floor = 1e-12 * max_diag + f64::MIN_POSITIVE;
        let l = &mut st.chol;
        let x = &mut st.work;
        for (i, &pi) in order.iter().enumerate() {
            for j in first[i]..i {
                let pj = order[j];
                l[i * np + j] = if st.free[pi] && st.free[pj] {
                    st.hess[pi * np + pj]
                } else {
                    0.0
                };
            }
            let d = st.hess[pi * np + pi].max(floor);
            if st.free[pi] {
                l[i * np + i] = d * (1.0 + st.mu);
                x[i] = -st.grad[pi];
            } else {
                l[i * np + i] = 1.0;
                x[i] = 0.0;
            }
        }
        // Envelope Cholesky, row by row (L[j][k] = (A[j][k] − L[j][s..k]·L[k][s..k]) / L[k][k]
        // with s the later of the two rows' first columns).
        for j in 0..np {
            let (done, rest) = l.split_at_mut(j * np);
            let row_j = &mut rest[..np];
            let fj = first[j];
            for k in fj..j {
                let s = fj.max(first[k]);
                let row_k = &done[k * np..k * np + k + 1];
                let v = row_j[k] - dot(&row_j[s..k], &row_k[s..k]);
                row_j[k] = v / row_k[k];
            }
            let d = row_j[j] - dot(&row_j[fj..j], &row_j[fj..j]);
            if d.is_nan() || d <= 0.0 {
                return false;
            }
            row_j[j] = d.sqrt();
        }
        for i in 0..np {
            let fi = first[i];
            let row = &l[i * np..i * np + i + 1];
            x[i] = (x[i] - dot(&row[fi..i], &x[fi..i])) / row[i];
        }
        for i in (0..np).rev() {
            let fi = first[i];
            let row = &l[i * np..i * np + i + 1];
            x[i] /= row[i];
            let xi = x[i];
            for (xk, lk) in x[fi..i].iter_mut().zip(&row[fi..i]) {
                *xk -= lk * xi;
            }
        }
        for (i, &pi) in order.iter().enumerate() {
            st.step[pi] = x[i];
        }
        true
    }
}

#[cfg(test)]
pub(crate) mod tests_support {
    use super::*;
    use crate::character::skeleton::{Joint, JointLimits, Skeleton};

    /// A root with two chains of three joints (one bent at rest), limits on some joints.
    pub fn skeleton() -> Skeleton {
        let lim = JointLimits {
            twist: (-0.3, 0.3),
            bend: (-0.2, 1.8),
            side: (-0.4, 0.4),
        };
        let j = |name: &str, parent: Option<usize>, rest: DVec3, limits| Joint {
            name: name.into(),
            parent,
            rest,
            limits,
            bend_axis: DVec3::X,
        };
        Skeleton::new(vec![
            j("root", None, DVec3::ZERO, None),
            j("a1", Some(0), DVec3::new(0.0, 0.1, 0.0), Some(lim)),
            j("a2", Some(1), DVec3::new(0.0, 0.2, 0.0), None),
            j("a3", Some(2), DVec3::new(0.0, 0.28, 0.03), Some(lim)),
            j("atip", Some(3), DVec3::new(0.0, 0.33, 0.05), None),
            j("b1", Some(0), DVec3::new(0.05, 0.05, 0.0), Some(lim)),
            j("btip", Some(5), DVec3::new(0.1, 0.12, 0.0), None),
        ])
        .unwrap()
    }

    pub fn model() -> (Skeleton, IkModel, Vec<DVec3>) {
        let sk = skeleton();
        let axes: Vec<DVec3> = (0..sk.len()).map(|j| sk.twist_axis(j)).collect();
        let mj = vec![0, 0, 0, 1, 2, 3, 3, 5];
        let rest = vec![
            DVec3::new(0.02, 0.0, 0.01),
            DVec3::new(-0.02, 0.03, -0.01),
            DVec3::new(0.0, 0.05, 0.02),
            DVec3::new(0.01, 0.15, 0.01),
            DVec3::new(0.0, 0.24, -0.01),
            DVec3::new(0.0, 0.31, 0.05),
            DVec3::new(0.01, 0.3, 0.03),
            DVec3::new(0.08, 0.1, 0.01),
        ];
        let m = IkModel::new(&sk, &axes, &mj, &rest, 0.33);
        (sk, m, rest)
    }

    /// Perturbs unknown `i` by `h` (increments for roots, angles otherwise).
    pub fn perturbed(m: &IkModel, st: &IkState, i: usize, h: f64) -> IkState {
        let mut s = st.clone();
        for (j, d) in m.dofs.iter().enumerate() {
            if let Dofs::Root { first } = *d {
                if (first..first + 3).contains(&i) {
                    let mut w = DVec3::ZERO;
                    w[i - first] = h;
                    s.root_rot[j] = (DQuat::from_scaled_axis(w) * s.root_rot[j]).normalize();
                } else if (first + 3..first + 6).contains(&i) {
                    s.root_pos[j][i - first - 3] += h;
                }
            }
        }
        if !matches!(
            m.dofs.iter().find_map(|d| match *d {
                Dofs::Root { first } if (first..first + 6).contains(&i) => Some(()),
                _ => None,
            }),
            Some(())
        ) {
            s.angles[i] += h;
        }
        m.refresh(&mut s);
        s
    }
}

#[cfg(test)]
mod tests {
    use super::tests_support::*;
    use super::*;

    #[test]
    fn gradient_matches_finite_differences() {
        let (_, m, _) = model();
        let mut st = m.new_state();
        // A bent, twisted posture away from rest.
        for (i, a) in st.angles.iter_mut().enumerate() {
            *a = 0.3 * ((i as f64) * 1.7).sin();
        }
        st.prev_angles.iter_mut().for_each(|a| *a = 0.05);
        st.root_rot[0] = DQuat::from_scaled_axis(DVec3::new(0.2, -0.4, 0.3));
        st.root_pos[0] = DVec3::new(0.01, 0.02, -0.03);
        m.refresh(&mut st);
        // Markers trusted unequally (one not at all), as predicted ones are.
        for (k, c) in st.marker_weight.iter_mut().enumerate() {
            *c = (k % 4) as f64 / 3.0;
        }
        let targets: Vec<DVec3> = st
            .predicted
            .iter()
            .enumerate()
            .map(|(k, p)| *p + DVec3::new(0.01, -0.02, 0.005) * (k as f64 * 0.3).cos())
            .collect();
        let params = IkParams::default();
        let w = Priors {
            rest: (params.rest_prior * m.height_m).powi(2),
            prev: (params.prev_prior * m.height_m).powi(2),
        };
        m.build_normal_equations(&mut st, &targets, w);
        let h = 1e-6;
        for i in 0..m.n_params() {
            let e = |s: &IkState| {
                0.5 * m.objective(
                    w,
                    &s.angles,
                    &s.prev_angles,
                    &s.rest_scale,
                    &s.predicted,
                    Targets {
                        positions: &targets,
                        weight: &s.marker_weight,
                    },
                )
            };
            let fd = (e(&perturbed(&m, &st, i, h)) - e(&perturbed(&m, &st, i, -h))) / (2.0 * h);
            // Central differences at h = 1e-6 on an objective of size ~1e-3: error ~1e-12.
            assert!(
                (fd - st.grad[i]).abs() < 1e-8 + 1e-5 * fd.abs(),
                "unknown {i}: analytic {} finite difference {fd}",
                st.grad[i]
            );
        }
    }

    #[test]
    fn envelope_step_solves_the_damped_normal_equations() {
        let (_, m, _) = model();
        // Post-order: the two chains' unknowns before the root's six.
        let root_first = m.order.len() - 6;
        assert!(
            m.order[root_first..].iter().all(|&p| p < 6),
            "{:?}",
            m.order
        );
        let mut st = m.new_state();
        for (i, a) in st.angles.iter_mut().enumerate() {
            *a = 0.2 * ((i as f64) * 0.9).cos();
        }
        m.refresh(&mut st);
        let targets: Vec<DVec3> = st
            .predicted
            .iter()
            .enumerate()
            .map(|(k, p)| *p + DVec3::new(-0.01, 0.02, 0.01) * (k as f64 * 0.7).sin())
            .collect();
        let w = Priors {
            rest: 1e-6,
            prev: 1e-6,
        };
        m.build_normal_equations(&mut st, &targets, w);
        let np = m.n_params();
        // Entries outside the envelopes are structurally zero in H (the chains do not
        // couple them), so the envelope factor is the whole factor.
        for i in 0..np {
            for j in 0..m.envelope_first[i] {
                assert_eq!(st.hess[m.order[i] * np + m.order[j]], 0.0, "({i}, {j})");
            }
        }
        // One unknown on a bound (left out of the solve), then the dense residual of
        // (H + μ diag H) δ = −g over the free unknowns.
        st.free[7] = false;
        st.mu = 0.1;
        assert!(m.lm_step(&mut st));
        assert_eq!(st.step[7], 0.0);
        let scale = st.grad.iter().map(|g| g.abs()).fold(0.0, f64::max);
        for i in (0..np).filter(|&i| st.free[i]) {
            let mut r = st.grad[i] + st.mu * st.hess[i * np + i] * st.step[i];
            for j in (0..np).filter(|&j| st.free[j]) {
                r += st.hess[i * np + j] * st.step[j];
            }
            // 1e-10 of the gradient: round-off of a well-conditioned 24-unknown solve.
            assert!(r.abs() < 1e-10 * scale, "row {i}: residual {r}");
        }
    }

    #[test]
    fn exact_markers_are_fitted_quadratically_from_rest() {
        let (_, m, _) = model();
        let mut truth = m.new_state();
        for (i, a) in truth.angles.iter_mut().enumerate() {
            *a = (0.25 * ((i as f64) * 1.3).sin()).clamp(m.lo[i] + 0.01, m.hi[i] - 0.01);
        }
        truth.root_rot[0] = DQuat::from_scaled_axis(DVec3::new(0.1, 0.3, -0.2));
        truth.root_pos[0] = DVec3::new(0.02, -0.01, 0.03);
        m.refresh(&mut truth);
        let mut st = m.new_state();
        let params = IkParams {
            rest_prior: 0.0,
            prev_prior: 0.0,
            max_iterations: 1,
            step_tolerance_rad: 0.0,
            cost_tolerance: 0.0,
        };
        let mut rms = Vec::new();
        for _ in 0..8 {
            rms.push(m.solve(&mut st, &truth.predicted, &params).marker_rms_m);
        }
        // Gauss–Newton on a zero-residual problem: the error squares (about) every step
        // once close; 8 steps from rest reach round-off of the 0.33 m skeleton.
        assert!(rms[7] < 1e-12, "{rms:?}");
        let fast = rms
            .windows(2)
            .any(|w| w[0] < 1e-4 && w[1] < w[0] * w[0] * 1e3);
        assert!(fast, "no quadratic step in {rms:?}");
    }

    #[test]
    fn fitted_posture_stays_inside_the_limits() {
        let (sk, m, _) = model();
        let mut st = m.new_state();
        // Targets that ask for far more bend than the limits allow.
        let targets: Vec<DVec3> = st
            .predicted
            .iter()
            .map(|p| DVec3::new(p.x, p.y * 0.3, p.z + 0.2 * p.y))
            .collect();
        m.solve(&mut st, &targets, &IkParams::default());
        for (j, d) in m.dofs.iter().enumerate() {
            if let (Dofs::Angles { first }, Some(l)) = (*d, sk.joints[j].limits) {
                let [t, b, s] = [0, 1, 2].map(|k| st.angles[first + k]);
                assert!(
                    (l.twist.0..=l.twist.1).contains(&t)
                        && (l.bend.0..=l.bend.1).contains(&b)
                        && (l.side.0..=l.side.1).contains(&s),
                    "joint {j}: twist {t} bend {b} side {s} outside {l:?}"
                );
            }
        }
    }
}
