//! The per-character frame solver (Le Naour et al., Section 4): ARAP local step, skeleton
//! step (bone lengths, straightness, joint limits, forward kinematics), global step; until
//! the paper's criterion converges, an iteration cap or the deadline. Then the full mesh
//! follows the control mesh. Warm-started from the previous frame; allocation-free per
//! frame.

use super::arap::{ArapState, StopReason, CONVERGENCE_ABS_FLOOR};
use super::polar::extract_rotation;
use crate::character::skeleton::clamp_to_limits;
use crate::markers::MarkerFrame;
use crate::rig::bind::Rig;
use glam::{DMat3, DQuat, DVec3};
use std::sync::Arc;
use std::time::Instant;

/// Solver settings.
#[derive(Clone, Copy, Debug)]
pub struct SolverParams {
    /// Iteration cap per frame.
    pub max_iterations: usize,
    /// Relative change of `0.5·rrms + 0.5·bone_length_error` below which a frame is done.
    pub tolerance: f64,
}

impl Default for SolverParams {
    fn default() -> Self {
        Self {
            max_iterations: 30,
            tolerance: 1e-3,
        }
    }
}

/// What one frame's solve did and how good it is (names as in DESIGN.md).
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct SolveReport {
    pub iterations: usize,
    pub stop: StopReason,
    pub rrms: f64,
    pub bone_length_error: f64,
    pub joint_limit_violation_deg: f64,
    pub marker_residual_rms_mm: f64,
    pub marker_residual_max_mm: f64,
    pub solve_ms: f64,
    pub gc_ms: f64,
}

/// A per-character solver: owns the mutable state, shares the rig.
pub struct Solver {
    rig: Arc<Rig>,
    params: SolverParams,
    st: ArapState,
    /// Per joint: estimated world rotation (warm start) and clamped world rotation.
    joint_est: Vec<DQuat>,
    joint_world: Vec<DQuat>,
    sample_pos: Vec<DVec3>,
}

impl Solver {
    pub fn new(rig: Arc<Rig>, params: SolverParams) -> Self {
        let st = rig.system.new_state();
        let nj = rig.skeleton.len();
        let ns = rig.samples.len();
        Self {
            rig,
            params,
            st,
            joint_est: vec![DQuat::IDENTITY; nj],
            joint_world: vec![DQuat::IDENTITY; nj],
            sample_pos: vec![DVec3::ZERO; ns],
        }
    }

    pub fn rig(&self) -> &Arc<Rig> {
        &self.rig
    }

    /// Current control-mesh positions.
    pub fn control_positions(&self) -> &[DVec3] {
        &self.st.positions
    }

    /// Forgets the previous frame (cold start at the rest pose).
    pub fn reset(&mut self) {
        self.st = self.rig.system.new_state();
        self.joint_est.fill(DQuat::IDENTITY);
        self.joint_world.fill(DQuat::IDENTITY);
    }

    /// Solves one frame, warm-started from the previous one, and writes the full-resolution
    /// vertices (file order, metres) into `vertices_out` (`len` = mesh vertex count).
    pub fn solve(
        &mut self,
        frame: &MarkerFrame,
        deadline: Instant,
        vertices_out: &mut [DVec3],
    ) -> SolveReport {
        let t0 = Instant::now();
        let rig = Arc::clone(&self.rig);
        let sys = &rig.system;
        for k in 0..rig.n_markers.min(frame.positions.len()) {
            if frame.present[k] && frame.positions[k].is_finite() {
                self.st.targets[k] = frame.positions[k];
            }
        }
        let mut prev: Option<f64> = None;
        let mut iterations = 0;
        let mut stop = StopReason::IterationCap;
        let (mut rrms, mut ble, mut jlv);
        loop {
            rrms = sys.rrms(sys.local_step(&mut self.st));
            jlv = self.skeleton_step();
            ble = self.bone_length_error();
            let crit = 0.5 * rrms + 0.5 * ble;
            if let Some(p) = prev {
                if (crit - p).abs() <= self.params.tolerance * p + CONVERGENCE_ABS_FLOOR {
                    stop = StopReason::Converged;
                    break;
                }
            }
            if iterations >= self.params.max_iterations {
                break;
            }
            if iterations > 0 && Instant::now() >= deadline {
                stop = StopReason::Deadline;
                break;
            }
            prev = Some(crit);
            sys.global_step(&mut self.st);
            iterations += 1;
        }
        let (mut sum2, mut max2) = (0.0f64, 0.0f64);
        for k in 0..rig.n_markers {
            let d2 = (sys.rows.eval(k, &self.st.positions) - self.st.targets[k]).length_squared();
            sum2 += d2;
            max2 = max2.max(d2);
        }
        let t1 = Instant::now();
        self.write_mesh(vertices_out);
        let t2 = Instant::now();
        SolveReport {
            iterations,
            stop,
            rrms,
            bone_length_error: ble,
            joint_limit_violation_deg: jlv.to_degrees(),
            marker_residual_rms_mm: (sum2 / rig.n_markers.max(1) as f64).sqrt() * 1e3,
            marker_residual_max_mm: max2.sqrt() * 1e3,
            solve_ms: (t1 - t0).as_secs_f64() * 1e3,
            gc_ms: (t2 - t1).as_secs_f64() * 1e3,
        }
    }

    /// Full mesh from the control mesh through the bind-time embedding.
    pub fn write_mesh(&self, out: &mut [DVec3]) {
        let p = &self.st.positions;
        for (o, (t, b)) in out.iter_mut().zip(&self.rig.embedding) {
            *o = p[t[0] as usize] * b[0]
                + p[t[1] as usize] * b[1]
                + p[t[2] as usize] * b[2]
                + p[t[3] as usize] * b[3];
        }
    }

    /// Mean relative length error of the skeleton sub-edges, from the sample positions the
    /// last [`Self::skeleton_step`] read off the current control mesh.
    fn bone_length_error(&self) -> f64 {
        let rig = &self.rig;
        let mut sum = 0.0;
        for e in &rig.edges {
            let d = (self.sample_pos[e.samples.1] - self.sample_pos[e.samples.0]).length();
            let d0 = e.rest.length();
            sum += (d - d0).abs() / d0;
        }
        sum / rig.edges.len().max(1) as f64
    }

    /// Skeleton step: reads each joint's rotation from the current control mesh (rotation
    /// average of its region, swung to the measured segment direction), expresses it in the
    /// parent's frame, clamps it to the joint's limits, composes clamped rotations down the
    /// tree (forward kinematics) and sets each skeleton edge's target `γ = Q_j · rest_edge`,
    /// which restores rest length and straightness. Returns the largest limit excess
    /// (radians) of the measured posture.
    fn skeleton_step(&mut self) -> f64 {
        let rig = &self.rig;
        let sk = &rig.skeleton;
        // Sample positions for segment directions.
        for (s, p) in self.sample_pos.iter_mut().enumerate() {
            *p = rig.samples.eval(s, &self.st.positions);
        }
        let mut worst = 0.0f64;
        let mut edge = 0;
        for j in 0..sk.len() {
            if rig.joint_region[j].is_empty() {
                continue;
            }
            // Rotation average of the region, plus the segments' directions (Kabsch).
            let mut m = DMat3::ZERO;
            for &v in &rig.joint_region[j] {
                m += self.st.rots[v as usize];
            }
            let region_weight = rig.joint_region[j].len() as f64;
            let first_edge = edge;
            let mut dir_pairs: [(DVec3, DVec3); 8] = [(DVec3::ZERO, DVec3::ZERO); 8];
            let mut n_dirs = 0;
            while edge < rig.edges.len() && rig.edges[edge].joint == j {
                // Group the segment's sub-edges: from its first to its last sample.
                let child = rig.edges[edge].child;
                let start = edge;
                while edge < rig.edges.len()
                    && rig.edges[edge].joint == j
                    && rig.edges[edge].child == child
                {
                    edge += 1;
                }
                let (a, b) = (rig.edges[start].samples.0, rig.edges[edge - 1].samples.1);
                let cur = self.sample_pos[b] - self.sample_pos[a];
                let rest = sk.joints[child].rest - sk.joints[j].rest;
                if n_dirs < dir_pairs.len() {
                    dir_pairs[n_dirs] = (cur.normalize_or_zero(), rest.normalize());
                    n_dirs += 1;
                }
                let (c, r) = (cur.normalize_or_zero(), rest.normalize());
                m += DMat3::from_cols(c * r.x, c * r.y, c * r.z) * (2.0 * region_weight);
            }
            let mut q = self.joint_est[j];
            extract_rotation(&m, &mut q);
            if n_dirs == 1 {
                // One segment: its measured direction is exact; keep the region's twist.
                let (c, r) = dir_pairs[0];
                if c != DVec3::ZERO {
                    q = (DQuat::from_rotation_arc((q * r).normalize(), c) * q).normalize();
                }
            }
            self.joint_est[j] = q;
            let parent_world = sk.joints[j]
                .parent
                .map(|p| self.joint_world[p])
                .unwrap_or(DQuat::IDENTITY);
            let mut local = parent_world.conjugate() * q;
            if let Some(lim) = &sk.joints[j].limits {
                let (clamped, excess) =
                    clamp_to_limits(local, rig.twist_axis[j], sk.joints[j].bend_axis, lim);
                local = clamped;
                worst = worst.max(excess);
            }
            let world = (parent_world * local).normalize();
            self.joint_world[j] = world;
            for e in &rig.edges[first_edge..edge] {
                self.st.targets[e.row] = world * e.rest;
            }
        }
        worst
    }
}
