//! The per-character frame solver (Le Naour et al., Section 4). Per frame:
//!
//! 1. Skeleton step: the posture (joint rotations inside their limits, see
//!    [`super::ik`]) that carries the markers onto their measured positions; its forward
//!    kinematics gives every skeleton sample a target (bone lengths and straightness
//!    restored, limits held by construction).
//! 2. Warm start: the previous frame's control mesh is carried along with each joint's
//!    change of pose (every control vertex moves rigidly with its owner joint), and its
//!    rotations with it.
//! 3. ARAP alternation (local step, global step) with the marker rows and the skeleton
//!    sample rows, until the paper's criterion (relative change of
//!    `0.5·rrms + 0.5·bone_length_error`) converges, an iteration cap or the deadline.
//!    Before each global step, volume restoration scales each control vertex's rotation
//!    (`SolverParams::volume_gain`), so that flesh compressed at a crease regains its
//!    volume (the ARAP minimum alone loses a few per cent at a full curl).
//! 4. Untangling: control tets folded below [`UNTANGLE_MIN_RATIO`] of their rest volume
//!    are projected back ([`crate::rig::tetmesh::Untangler`]).
//!
//! Then the full mesh follows the control mesh. Allocation-free per frame.

use super::arap::{ArapState, StopReason};
use super::harmonic::{HarmonicError, HarmonicParams, HarmonicRig, HarmonicState, SegmentClusters};
use super::ik::{IkParams, IkReport, IkState};
use crate::character::skeleton::clamp_to_limits;
use crate::geom::polar::{extract_rotation, rotation_angle_between};
use crate::markers::MarkerFrame;
use crate::rig::bind::Rig;
use crate::rig::green::GreenScratch;
use crate::rig::tetmesh::{Sweeps, Untangler};
use glam::{DMat3, DQuat, DVec3};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Which deformation follows the skeleton step (`solver.method` in a stage, `--method`
/// on the command line).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Volumetric ARAP on the control mesh, then Green coordinates (Le Naour et al.).
    #[default]
    Arap,
    /// Harmonic rotation fields and a Poisson rebuild on the full mesh (de Aguiar et al.,
    /// [`super::harmonic`]), driven by the fitted posture's joint rotations.
    Harmonic,
}

impl std::str::FromStr for Method {
    type Err = UnknownMethod;

    /// `arap` or `harmonic`.
    fn from_str(s: &str) -> Result<Self, UnknownMethod> {
        match s {
            "arap" => Ok(Method::Arap),
            "harmonic" => Ok(Method::Harmonic),
            _ => Err(UnknownMethod { name: s.to_owned() }),
        }
    }
}

/// A method name that is neither `arap` nor `harmonic`.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("unknown method {name:?} (expected arap or harmonic)")]
pub struct UnknownMethod {
    pub name: String,
}

impl Method {
    /// `"arap"` or `"harmonic"`, as configs and reports name it.
    pub fn name(self) -> &'static str {
        match self {
            Method::Arap => "arap",
            Method::Harmonic => "harmonic",
        }
    }
}

/// Solver settings.
#[derive(Clone, Copy, Debug)]
pub struct SolverParams {
    /// The deformation method.
    pub method: Method,
    /// The harmonic method's settings (unused by ARAP).
    pub harmonic: HarmonicParams,
    /// Iteration cap per frame.
    pub max_iterations: usize,
    /// Relative change of `0.5·rrms + 0.5·bone_length_error` below which a frame is done.
    pub tolerance: f64,
    /// The skeleton step's posture fit.
    pub ik: IkParams,
    /// Volume restoration (0: off): before each global step, each control vertex's
    /// rotation is scaled by `s_i`, which integrates `J_i^(−gain/3)` over iterations and
    /// frames (`J_i`: the volume of the vertex's tets over their rest volume), so that
    /// flesh compressed at a crease is given back its volume.
    pub volume_gain: f64,
}

impl Default for SolverParams {
    fn default() -> Self {
        Self {
            method: Method::Arap,
            harmonic: HarmonicParams::default(),
            max_iterations: 30,
            tolerance: 1e-3,
            ik: IkParams::default(),
            volume_gain: 1.0,
        }
    }
}

/// Absolute floor added to a frame's relative convergence test: a change of the
/// criterion `0.5·rrms + 0.5·bone_length_error` below it ends the frame. 2e-5 is the
/// relative tolerance (1e-3) of a moving body's criterion (about 0.02); without it a
/// character standing still, whose criterion is ten times smaller (sensor noise alone),
/// iterates towards the deadline for changes of micrometres per metre (the body's
/// range-of-motion replay: 6 deadline stops in its 1.5 s of rest and a frame p99 of
/// 6.3 ms with a floor of 1e-9; none and 2.7 to 3.6 ms with this one).
pub const FRAME_CONVERGENCE_ABS_FLOOR: f64 = 2e-5;

/// Iterations whose convergence criterion a report keeps.
pub const TRACE_LEN: usize = 32;

/// What one frame's solve did and how good it is (names as in DESIGN.md).
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct SolveReport {
    /// The convergence criterion `0.5·rrms + 0.5·bone_length_error` after each local
    /// step, first `trace_len` entries (at most [`TRACE_LEN`]): how the frame converged.
    pub trace: [f32; TRACE_LEN],
    pub trace_len: usize,
    /// ARAP iterations (local, global) this frame.
    pub iterations: usize,
    /// Levenberg–Marquardt iterations of the skeleton step's posture fit.
    pub ik_iterations: usize,
    /// RMS distance of the fitted skeleton's markers from the measured ones, mm.
    pub ik_marker_rms_mm: f64,
    /// Time spent in the skeleton step's posture fit, ms (part of `solve_ms`).
    pub ik_ms: f64,
    /// Why the iterations stopped.
    pub stop: StopReason,
    /// Relative ARAP residual of the control mesh (DESIGN.md).
    pub rrms: f64,
    /// Mean relative length error of the skeleton's sub-edges on the control mesh.
    pub bone_length_error: f64,
    /// Largest excess over any joint limit of the posture the control mesh shows, degrees.
    pub joint_limit_violation_deg: f64,
    /// RMS and largest distance between each marker and its bound point, mm.
    pub marker_residual_rms_mm: f64,
    pub marker_residual_max_mm: f64,
    /// Time from the call to the control mesh solved (skeleton step included), ms.
    pub solve_ms: f64,
    /// Time to move the full mesh with the Green coordinates, ms.
    pub gc_ms: f64,
    /// Folded control tets pushed back after the iterations (volume projections made;
    /// 0 on most frames).
    pub untangled: usize,
}

/// A control tet is taken as folded below this share of its rest volume, and pushed back
/// past it, to twice it ([`crate::rig::tetmesh::Untangler`]).
pub const UNTANGLE_MIN_RATIO: f64 = 0.02;

/// Bounds of a control vertex's volume scale.
pub const VOLUME_SCALE_MIN: f64 = 0.8;
pub const VOLUME_SCALE_MAX: f64 = 1.25;

/// Sweeps of the untangling projection per frame: at least the first (also on a frame
/// whose iterations ran to the deadline: a folded tet must not reach the mesh), then
/// until the deadline (less the full-mesh update's time), at most the second. A sweep
/// visits only the tets around vertices the previous one moved, so a hundred sweeps
/// around a few folded tets cost tens of microseconds; a limb pressed into the trunk at
/// the edge of its limits needs a few hundred.
pub const UNTANGLE_MIN_SWEEPS: usize = 100;
pub const UNTANGLE_MAX_SWEEPS: usize = 1000;

/// `x^(−1/3)` for a positive `x`, to 2e-13 relative (a quarter of `powf`'s time in the
/// volume restoration, where it runs for every control vertex each iteration): a first
/// guess within 8 % from the exponent bits (`4/3` of one's bits less a third of `x`'s),
/// then four steps of Newton's method on `y⁻³ = x`, `y ← y (4 − x y³) / 3`, each
/// squaring the relative error (doubled): 8e-2, 1e-2, 3e-4, 2e-7, 1e-13.
fn inv_cbrt(x: f64) -> f64 {
    const FOUR_THIRDS_OF_ONE: u64 = 0x5540_0000_0000_0000;
    let mut y = f64::from_bits(FOUR_THIRDS_OF_ONE.wrapping_sub(x.to_bits() / 3));
    for _ in 0..4 {
        y *= (4.0 - x * y * y * y) * (1.0 / 3.0);
    }
    y
}

/// A marker's weight in the posture fit, and its share of its target on the mesh, from
/// the marker buffer's confidence `c` (`exp(−gap/τ)` over a predicted gap): `c²`. The
/// prediction's error grows faster than the confidence falls (on the body walk: 2 mm
/// mean at 10 ms, 12 mm at 50 ms, 34 mm at 100 ms, docs/benchmarks.md), so a
/// weight that follows its inverse variance drops quickly.
fn trust(c: f64) -> f64 {
    c * c
}

/// How one frame's ARAP alternation ended.
struct ArapRun {
    /// ARAP iterations (local, global) made.
    iterations: usize,
    stop: StopReason,
    /// The last local step's relative residual and bone length error.
    rrms: f64,
    ble: f64,
    /// The convergence criterion after each local step, first `trace_len` entries.
    trace: [f32; TRACE_LEN],
    trace_len: usize,
}

/// A per-character solver: owns the mutable state, shares the rig.
pub struct Solver {
    rig: Arc<Rig>,
    params: SolverParams,
    st: ArapState,
    ik: IkState,
    /// Joint world rotations and positions of the previous frame's posture.
    prev_rot: Vec<DQuat>,
    prev_pos: Vec<DVec3>,
    /// Skeleton sample positions read off the control mesh.
    sample_pos: Vec<DVec3>,
    /// Joint world rotations read off the control mesh (joint limit measurement).
    measured_rot: Vec<DQuat>,
    /// Per joint, how far the posture the control mesh shows exceeds its limits, radians
    /// (0 inside; last measured by the frame's quality figures).
    limit_excess: Vec<f64>,
    green_scratch: GreenScratch,
    /// Marker targets handed to the posture fit (NaN where held).
    ik_targets: Vec<DVec3>,
    /// Each marker's last trusted target in its joint's frame (rest offset until first
    /// seen).
    held_local: Vec<DVec3>,
    /// Each marker's confidence this frame, in `[0, 1]` ([`MarkerFrame::confidence`],
    /// clamped).
    marker_confidence: Vec<f64>,
    /// Joint angles imposed after the marker fit, one per posture parameter (radians,
    /// NaN: free; see [`Self::set_pins`]).
    pins: Vec<f64>,
    any_pin: bool,
    /// The harmonic method's set-up and memory (`Method::Harmonic`).
    harmonic: Option<(HarmonicRig, HarmonicState)>,
    /// Harmonic method: the segments with marker clusters, and the joint rotations and
    /// positions handed to the deformation (the posture's, with those segments' own).
    clusters: SegmentClusters,
    segment_rot: Vec<DQuat>,
    segment_pos: Vec<DVec3>,
    /// Pushes folded control tets back after the iterations.
    untangler: Untangler,
    /// The last frame's full-mesh update, seconds: kept free before the deadline when
    /// untangling.
    last_gc_s: f64,
    /// Volume restoration: per control vertex, six times the rest volume of its tets,
    /// the same now (scratch), and its scale `s_i` (carried across frames).
    vertex_rest6: Vec<f64>,
    vertex_now6: Vec<f64>,
    volume_scale: Vec<f64>,
}

impl Solver {
    /// A solver for `params.method`; the harmonic method's set-up (Laplacian,
    /// correspondences, factor) happens here and can fail on meshes it cannot tie.
    pub fn try_new(rig: Arc<Rig>, params: SolverParams) -> Result<Self, HarmonicError> {
        let harmonic = match params.method {
            Method::Arap => None,
            Method::Harmonic => {
                let hr = HarmonicRig::new(
                    &rig.mesh_rest,
                    &rig.triangles,
                    &rig.skeleton,
                    &params.harmonic,
                    &rig.correspondences,
                )?;
                let st = hr.new_state();
                Some((hr, st))
            }
        };
        let mut s = Self::new(rig, params);
        s.params = params;
        s.harmonic = harmonic;
        Ok(s)
    }

    /// An ARAP solver (`params.method` is taken as [`Method::Arap`]; see
    /// [`Self::try_new`] for the harmonic method).
    pub fn new(rig: Arc<Rig>, params: SolverParams) -> Self {
        let st = rig.system.new_state();
        let ik = rig.ik.new_state();
        let nj = rig.skeleton.len();
        let ns = rig.samples.len();
        let green_scratch = rig.green.scratch();
        let nm = rig.n_markers;
        let held_local = rig.ik.marker_offsets().to_vec();
        let rig_params = rig.ik.n_params();
        let clusters = SegmentClusters::new(&rig.marker_joint, &rig.skeleton);
        let untangler = Untangler::new(&rig.control);
        let n_control = rig.control.positions.len();
        let mut vertex_rest6 = vec![0.0; n_control];
        rig.control
            .vertex_volumes6(&rig.control.positions, &mut vertex_rest6);
        Self {
            params: SolverParams {
                method: Method::Arap,
                ..params
            },
            prev_rot: ik.world_rot.clone(),
            prev_pos: ik.world_pos.clone(),
            rig,
            st,
            ik,
            sample_pos: vec![DVec3::ZERO; ns],
            measured_rot: vec![DQuat::IDENTITY; nj],
            limit_excess: vec![0.0; nj],
            green_scratch,
            ik_targets: vec![DVec3::ZERO; nm],
            held_local,
            marker_confidence: vec![1.0; nm],
            pins: vec![f64::NAN; rig_params],
            any_pin: false,
            harmonic: None,
            clusters,
            untangler,
            last_gc_s: 0.0,
            vertex_rest6,
            vertex_now6: vec![0.0; n_control],
            volume_scale: vec![1.0; n_control],
            segment_rot: vec![DQuat::IDENTITY; nj],
            segment_pos: vec![DVec3::ZERO; nj],
        }
    }

    pub fn rig(&self) -> &Arc<Rig> {
        &self.rig
    }

    /// Whether this solver deforms the control mesh (ARAP does; the harmonic method works
    /// on the full mesh alone).
    pub fn has_control_mesh(&self) -> bool {
        self.harmonic.is_none()
    }

    /// The segments whose rotation the harmonic method takes from their marker clusters.
    pub fn segment_clusters(&self) -> &SegmentClusters {
        &self.clusters
    }

    /// Harmonic method: the vertices tied to joint `j`'s segment (none with ARAP).
    pub fn harmonic_tied_to(&self, j: usize) -> impl Iterator<Item = usize> + '_ {
        self.harmonic.iter().flat_map(move |(hr, _)| hr.tied_to(j))
    }

    /// Harmonic method: the correspondences, `(vertex, joint)` per tied vertex (empty
    /// with ARAP).
    pub fn harmonic_tied(&self) -> &[(u32, u32)] {
        self.harmonic.as_ref().map_or(&[], |(hr, _)| hr.tied())
    }

    /// Harmonic method: writes, per vertex, the angle in degrees of the last frame's
    /// rotation field relative to the root segment's rotation (0 where the mesh turns
    /// with the root; a tied vertex reads its segment's angle). Returns false (and writes
    /// nothing) with ARAP. `out.len()` must be the vertex count.
    pub fn harmonic_field_deg(&self, out: &mut [f32]) -> bool {
        let Some((hr, st)) = &self.harmonic else {
            return false;
        };
        let reference = self.segment_rot[hr.root()];
        for (o, q) in out.iter_mut().zip(st.vertex_rotations()) {
            *o = rotation_angle_between(reference, *q).to_degrees() as f32;
        }
        true
    }

    /// Current control-mesh positions.
    pub fn control_positions(&self) -> &[DVec3] {
        &self.st.positions
    }

    /// The fitted posture: world rotation and position of every joint.
    pub fn joint_world(&self) -> (&[DQuat], &[DVec3]) {
        (&self.ik.world_rot, &self.ik.world_pos)
    }

    /// Joint angles that override the marker fit from the next frame on: one entry per
    /// posture parameter (see [`crate::rig::ik_model::IkModel::angle_params`]), radians, NaN
    /// where the fit decides. The angles are clamped to the joint limits; the skeleton
    /// samples then carry the pinned joints' positions to the control mesh (the paper's
    /// skeleton joints as control inputs). Entries beyond the parameter count are ignored.
    pub fn set_pins(&mut self, pins: &[f64]) {
        let n = pins.len().min(self.pins.len());
        self.pins[..n].copy_from_slice(&pins[..n]);
        self.any_pin = self.pins.iter().any(|v| v.is_finite());
    }

    /// Per joint, the last frame's excess over its limits on the solved mesh, radians
    /// (all 0 with the harmonic method, whose posture holds the limits by construction).
    pub fn joint_limit_excess(&self) -> &[f64] {
        &self.limit_excess
    }

    /// Forgets the previous frame (cold start at the rest pose).
    pub fn reset(&mut self) {
        self.st = self.rig.system.new_state();
        self.ik = self.rig.ik.new_state();
        self.held_local
            .copy_from_slice(self.rig.ik.marker_offsets());
    }

    /// Solves one frame, warm-started from the previous one, and writes the full-resolution
    /// vertices (file order, metres) into `vertices_out` (`len` = mesh vertex count).
    /// Held markers (see [`MarkerFrame::is_present`]) are left out of the posture fit and
    /// their bound points follow their bones; a marker trusted in part
    /// ([`MarkerFrame::confidence`]) weighs less (see `trust`).
    pub fn solve(
        &mut self,
        frame: &MarkerFrame,
        deadline: Instant,
        vertices_out: &mut [DVec3],
    ) -> SolveReport {
        let t0 = Instant::now();
        let rig = Arc::clone(&self.rig);
        let nm = rig.n_markers;
        let present = self.take_targets(&rig, frame);
        // 1. Skeleton step.
        let ik_rep = self.skeleton_step(&rig, present);
        let t_ik = Instant::now();
        if let Some(report) = self.deform_harmonic(&rig, vertices_out, &ik_rep, t0, t_ik) {
            return report;
        }
        self.sample_targets(&rig);
        // 2. Carry the control mesh along with each joint's change of pose.
        self.warm_start(&rig);
        self.hold_markers(&rig);
        // 3. ARAP alternation.
        // The full-mesh update must fit before the deadline too.
        let arap_deadline = deadline
            .checked_sub(Duration::from_secs_f64(self.last_gc_s))
            .unwrap_or(deadline);
        let arap = self.arap_iterations(&rig, arap_deadline);
        // 4. Untangling.
        let untangled = self.untangle(&rig, deadline);
        let (sum2, max2) = self.marker_residuals(&rig);
        let jlv = self.joint_limit_violation();
        let t1 = Instant::now();
        self.write_mesh(vertices_out);
        let t2 = Instant::now();
        self.last_gc_s = (t2 - t1).as_secs_f64();
        SolveReport {
            trace: arap.trace,
            trace_len: arap.trace_len,
            iterations: arap.iterations,
            ik_iterations: ik_rep.iterations,
            ik_marker_rms_mm: ik_rep.marker_rms_m * 1e3,
            ik_ms: (t_ik - t0).as_secs_f64() * 1e3,
            stop: arap.stop,
            rrms: arap.rrms,
            bone_length_error: arap.ble,
            joint_limit_violation_deg: jlv.to_degrees(),
            marker_residual_rms_mm: (sum2 / nm.max(1) as f64).sqrt() * 1e3,
            marker_residual_max_mm: max2.sqrt() * 1e3,
            solve_ms: (t1 - t0).as_secs_f64() * 1e3,
            gc_ms: self.last_gc_s * 1e3,
            untangled,
        }
    }

    /// Step 1 alone, the skeleton step: the fitted posture ([`Self::joint_world`]) and
    /// nothing else, for what reads only the posture (a BVH export). The posture
    /// is the one [`Self::solve`] fits on the same frames (the skeleton step reads
    /// nothing the later steps write); the control mesh and the full mesh stay as they
    /// were, so a solver is used one way or the other, not both. The report's marker
    /// residual is the fitted skeleton's (its markers from the measured ones); it counts
    /// no ARAP iteration.
    pub fn solve_posture(&mut self, frame: &MarkerFrame) -> SolveReport {
        let t0 = Instant::now();
        let rig = Arc::clone(&self.rig);
        let present = self.take_targets(&rig, frame);
        let ik_rep = self.skeleton_step(&rig, present);
        let solve_ms = t0.elapsed().as_secs_f64() * 1e3;
        self.skeleton_report(&rig, &ik_rep, solve_ms, solve_ms)
    }

    /// The report of a frame that fitted the posture and nothing on a control mesh (the
    /// posture alone, or the second method): the misfit is the fitted skeleton's, no
    /// ARAP iteration, and the skeleton is the posture's own (rigid segments, limits held
    /// by the fit), so it has no length error or limit excess.
    fn skeleton_report(
        &self,
        rig: &Rig,
        ik_rep: &IkReport,
        ik_ms: f64,
        solve_ms: f64,
    ) -> SolveReport {
        let (sum2, max2, counted) = self.skeleton_residuals(rig);
        SolveReport {
            trace: [0.0; TRACE_LEN],
            trace_len: 0,
            iterations: 0,
            ik_iterations: ik_rep.iterations,
            ik_marker_rms_mm: ik_rep.marker_rms_m * 1e3,
            ik_ms,
            stop: StopReason::Converged,
            rrms: 0.0,
            bone_length_error: 0.0,
            joint_limit_violation_deg: 0.0,
            marker_residual_rms_mm: (sum2 / counted.max(1) as f64).sqrt() * 1e3,
            marker_residual_max_mm: max2.sqrt() * 1e3,
            solve_ms,
            gc_ms: 0.0,
            untangled: 0,
        }
    }

    /// Sum and largest of the squared distances between the fitted skeleton's markers
    /// and the markers in view, and how many were counted: the fully trusted ones
    /// (measured or rigidly filled; a prediction the fit rightly weighs little would
    /// otherwise count as misfit), or every one in view when none is.
    fn skeleton_residuals(&self, rig: &Rig) -> (f64, f64, usize) {
        let mut out = (0.0f64, 0.0f64, 0usize);
        for trusted_only in [true, false] {
            for k in 0..rig.n_markers {
                if self.ik_targets[k].is_finite()
                    && (!trusted_only || self.marker_confidence[k] >= 1.0)
                {
                    let d2 = (self.ik.predicted[k] - self.ik_targets[k]).length_squared();
                    out = (out.0 + d2, out.1.max(d2), out.2 + 1);
                }
            }
            if out.2 > 0 {
                break;
            }
        }
        out
    }

    /// Takes the frame's marker positions as the targets of the present markers (ARAP rows
    /// and posture fit) and marks the others NaN for the fit; returns how many are present.
    fn take_targets(&mut self, rig: &Rig, frame: &MarkerFrame) -> usize {
        let nm = rig.n_markers;
        // `ik_targets[k]` is finite exactly where marker `k` is present this frame.
        let mut present = 0;
        let mut most_trusted = 0.0f64;
        for k in 0..nm {
            // Out of range or not finite counts as 0; a frame without confidences as 1.
            let c = frame.confidence.get(k).copied().unwrap_or(1.0);
            self.marker_confidence[k] = if c.is_finite() {
                c.clamp(0.0, 1.0)
            } else {
                0.0
            };
            if frame.is_present(k) {
                self.st.targets[k] = frame.positions[k];
                self.ik_targets[k] = frame.positions[k];
                self.ik.marker_weight[k] = trust(self.marker_confidence[k]);
                most_trusted = most_trusted.max(self.ik.marker_weight[k]);
                present += 1;
            } else {
                self.ik_targets[k] = DVec3::NAN;
            }
        }
        // Trust ranks the markers against each other: the posture priors are sized
        // against a fit of trusted markers, so when none is (every marker predicted)
        // the best trusted counts as one, and the priors do not take over (none
        // trusted at all: all count alike).
        if most_trusted < 1.0 {
            for (w, t) in self.ik.marker_weight.iter_mut().zip(&self.ik_targets) {
                if t.is_finite() {
                    *w = if most_trusted > 0.0 {
                        (*w / most_trusted).min(1.0)
                    } else {
                        1.0
                    };
                }
            }
        }
        present
    }

    /// Step 1, the skeleton step: remembers the previous posture and fits this frame's to
    /// the present markers, then imposes the pinned joint angles.
    fn skeleton_step(&mut self, rig: &Rig, present: usize) -> IkReport {
        self.prev_rot.copy_from_slice(&self.ik.world_rot);
        self.prev_pos.copy_from_slice(&self.ik.world_pos);
        rig.ik.begin_frame(&mut self.ik);
        // With no marker at all there is nothing to fit: the posture holds (the priors
        // alone would relax it towards rest).
        let ik_rep = if present > 0 {
            rig.ik
                .solve(&mut self.ik, &self.ik_targets, &self.params.ik)
        } else {
            IkReport::default()
        };
        if self.any_pin {
            rig.ik.pin(&mut self.ik, &self.pins);
        }
        ik_rep
    }

    /// The harmonic method (de Aguiar et al.): deforms the full mesh from the fitted
    /// posture and the marker clusters, and reports the frame. `None` with ARAP.
    fn deform_harmonic(
        &mut self,
        rig: &Rig,
        vertices_out: &mut [DVec3],
        ik_rep: &IkReport,
        t0: Instant,
        t_ik: Instant,
    ) -> Option<SolveReport> {
        let (hr, hst) = self.harmonic.as_mut()?;
        // The second method: the segments drive the full mesh directly, each turned
        // by its marker cluster where it has one in view, else by the posture.
        self.segment_rot.copy_from_slice(&self.ik.world_rot);
        self.segment_pos.copy_from_slice(&self.ik.world_pos);
        self.clusters.fit(
            &self.ik_targets,
            &rig.marker_rest,
            &mut self.segment_rot,
            &mut self.segment_pos,
        );
        hr.deform(hst, &self.segment_rot, &self.segment_pos, vertices_out);
        let t1 = Instant::now();
        Some(self.skeleton_report(
            rig,
            ik_rep,
            (t_ik - t0).as_secs_f64() * 1e3,
            (t1 - t0).as_secs_f64() * 1e3,
        ))
    }

    /// The skeleton step's forward kinematics: every skeleton sample row's target, carried
    /// rigidly by its segment's owner joint from its rest position.
    fn sample_targets(&mut self, rig: &Rig) {
        let nm = rig.n_markers;
        let (wr, wp) = (&self.ik.world_rot, &self.ik.world_pos);
        for (s, t) in self.st.targets[nm..].iter_mut().enumerate() {
            let o = rig.sample_owner[s];
            *t = wp[o] + wr[o] * (rig.sample_rest[s] - rig.skeleton.joints[o].rest);
        }
    }

    /// Step 2, the warm start: each control vertex (and its rotation) moves rigidly with
    /// its owner joint's change of pose since the previous frame.
    fn warm_start(&mut self, rig: &Rig) {
        let (wr, wp) = (&self.ik.world_rot, &self.ik.world_pos);
        for (i, (p, q)) in self
            .st
            .positions
            .iter_mut()
            .zip(self.st.quats.iter_mut())
            .enumerate()
        {
            let j = rig.control_label[i] as usize;
            let delta = wr[j] * self.prev_rot[j].conjugate();
            *p = wp[j] + delta * (*p - self.prev_pos[j]);
            *q = (delta * *q).normalize();
        }
    }

    /// The marker rows' targets of held and predicted markers, and the memory of trusted
    /// ones.
    fn hold_markers(&mut self, rig: &Rig) {
        let nm = rig.n_markers;
        let (wr, wp) = (&self.ik.world_rot, &self.ik.world_pos);
        // A held marker keeps its last trusted target where its bone takes it (so the
        // mesh holds its pose when nothing is seen, and the factorization never
        // changes); a trusted marker's target is remembered in its bone's frame for
        // when it is lost. A marker trusted in part (predicted) aims between the two, by
        // its trust: a prediction coasts to a stop while the body moves on, and its bone
        // knows better as the gap grows.
        for k in 0..nm {
            let j = rig.marker_joint[k];
            if self.ik_targets[k].is_finite() && self.marker_confidence[k] >= 1.0 {
                self.held_local[k] = wr[j].conjugate() * (self.st.targets[k] - wp[j]);
                continue;
            }
            let carried = wp[j] + wr[j] * self.held_local[k];
            self.st.targets[k] = if self.ik_targets[k].is_finite() {
                carried.lerp(self.st.targets[k], self.ik.marker_weight[k])
            } else {
                carried
            };
        }
    }

    /// Step 3, the ARAP alternation (local step, volume restoration, global step) until
    /// the paper's criterion `0.5·rrms + 0.5·bone_length_error` converges, the iteration
    /// cap or the deadline.
    fn arap_iterations(&mut self, rig: &Rig, deadline: Instant) -> ArapRun {
        let sys = &rig.system;
        let mut prev: Option<f64> = None;
        let mut iterations = 0;
        let mut stop = StopReason::IterationCap;
        let (mut rrms, mut ble);
        let (mut trace, mut trace_len) = ([0f32; TRACE_LEN], 0);
        loop {
            rrms = sys.rrms(sys.local_step(&mut self.st));
            ble = self.bone_length_error();
            let crit = 0.5 * rrms + 0.5 * ble;
            if trace_len < TRACE_LEN {
                trace[trace_len] = crit as f32;
                trace_len += 1;
            }
            if let Some(p) = prev {
                if (crit - p).abs() <= self.params.tolerance * p + FRAME_CONVERGENCE_ABS_FLOOR {
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
            if self.params.volume_gain > 0.0 {
                self.scale_for_volume();
            }
            sys.global_step(&mut self.st);
            iterations += 1;
        }
        ArapRun {
            iterations,
            stop,
            rrms,
            ble,
            trace,
            trace_len,
        }
    }

    /// Step 4, untangling: pushes folded control tets back; returns the projections made.
    fn untangle(&mut self, rig: &Rig, deadline: Instant) -> usize {
        // Per-vertex ARAP can fold a few tets at strongly flexed creases (the minimum of
        // its energy, not early stopping): push them back before the mesh is read, with
        // the time the full-mesh update needs kept free.
        let gc = Duration::from_secs_f64(self.last_gc_s);
        self.untangler.run(
            &rig.control,
            &mut self.st.positions,
            UNTANGLE_MIN_RATIO,
            Sweeps {
                min: UNTANGLE_MIN_SWEEPS,
                max: UNTANGLE_MAX_SWEEPS,
                deadline: Some(deadline.checked_sub(gc).unwrap_or(deadline)),
            },
        )
    }

    /// Sum and largest of the squared distances between each marker's bound point on the
    /// control mesh and its target.
    fn marker_residuals(&self, rig: &Rig) -> (f64, f64) {
        let sys = &rig.system;
        let (mut sum2, mut max2) = (0.0f64, 0.0f64);
        for k in 0..rig.n_markers {
            let d2 = (sys.rows.eval(k, &self.st.positions) - self.st.targets[k]).length_squared();
            sum2 += d2;
            max2 = max2.max(d2);
        }
        (sum2, max2)
    }

    /// Scales each control vertex's rotation (for the next global step) by its volume
    /// scale, after updating the scale from its tets' volume ratio.
    fn scale_for_volume(&mut self) {
        self.rig
            .control
            .vertex_volumes6(&self.st.positions, &mut self.vertex_now6);
        // J^(−gain/3); the default gain (1) needs no power. Two loops: with a test inside
        // one, the compiler computes the power for every vertex all the same.
        let gain = self.params.volume_gain;
        if gain == 1.0 {
            self.apply_volume_scale(inv_cbrt);
        } else {
            self.apply_volume_scale(|j| inv_cbrt(j).powf(gain));
        }
    }

    /// Multiplies each control vertex's volume scale by `factor(J_i)` (`J_i`: its tets'
    /// volume over their rest volume, at least 0.1), clamps it, and scales its rotation
    /// by it.
    #[inline(always)]
    fn apply_volume_scale(&mut self, factor: impl Fn(f64) -> f64) {
        for (i, s) in self.volume_scale.iter_mut().enumerate() {
            let j = (self.vertex_now6[i] / self.vertex_rest6[i]).max(0.1);
            *s = (*s * factor(j)).clamp(VOLUME_SCALE_MIN, VOLUME_SCALE_MAX);
            self.st.rots[i] *= *s;
        }
    }

    /// Where the last posture fit puts each marker, metres, world frame (the fitted
    /// skeleton's marker positions).
    pub fn fitted_markers(&self) -> &[DVec3] {
        &self.ik.predicted
    }

    /// Full mesh from the control mesh through its Green coordinates.
    pub fn write_mesh(&mut self, out: &mut [DVec3]) {
        self.rig
            .green
            .deform(&self.st.positions, &mut self.green_scratch, out);
    }

    /// Reads the skeleton samples off the current control mesh and returns the mean
    /// relative length error of the skeleton sub-edges.
    fn bone_length_error(&mut self) -> f64 {
        let rig = &self.rig;
        for (s, p) in self.sample_pos.iter_mut().enumerate() {
            *p = rig.samples.eval(s, &self.st.positions);
        }
        let mut sum = 0.0;
        for e in &rig.edges {
            let d = (self.sample_pos[e.samples.1] - self.sample_pos[e.samples.0]).length();
            sum += (d - e.rest_length_m).abs() / e.rest_length_m;
        }
        sum / rig.edges.len().max(1) as f64
    }

    /// Largest excess (radians) over any joint limit of the posture the control mesh
    /// shows: each joint's rotation is the fitted one, turned so that its segments point
    /// where the mesh's skeleton samples (last read by [`Self::bone_length_error`]) point
    /// (bone lines show no twist, so the twist is the fitted one), and expressed in its
    /// measured parent's frame.
    fn joint_limit_violation(&mut self) -> f64 {
        let rig = &self.rig;
        let sk = &rig.skeleton;
        let (wr, _) = (&self.ik.world_rot, &self.ik.world_pos);
        let mut worst = 0.0f64;
        let mut seg = 0;
        let segs = &rig.segment_samples;
        for j in 0..sk.len() {
            let parent = sk.joints[j].parent;
            let local = match parent {
                Some(p) => wr[p].conjugate() * wr[j],
                None => wr[j],
            };
            let pred = match parent {
                Some(p) => self.measured_rot[p] * local,
                None => local,
            };
            // Directions of the segments leaving j: predicted and measured.
            let mut m = DMat3::ZERO;
            let mut single: Option<(DVec3, DVec3)> = None;
            let mut count = 0;
            while seg < segs.len() && segs[seg].0 == j {
                let (_, child, first, n) = segs[seg];
                let d_pred = (pred * (sk.joints[child].rest - sk.joints[j].rest)).normalize();
                let d_meas =
                    (self.sample_pos[first + n - 1] - self.sample_pos[first]).normalize_or_zero();
                m += DMat3::from_cols(d_meas * d_pred.x, d_meas * d_pred.y, d_meas * d_pred.z);
                single = Some((d_pred, d_meas));
                count += 1;
                seg += 1;
            }
            let correction = match (count, single) {
                (1, Some((a, b))) if b != DVec3::ZERO => DQuat::from_rotation_arc(a, b),
                (c, _) if c > 1 => {
                    let mut q = DQuat::IDENTITY;
                    extract_rotation(&m, &mut q);
                    q
                }
                _ => DQuat::IDENTITY,
            };
            let measured = (correction * pred).normalize();
            self.measured_rot[j] = measured;
            if let (Some(lim), Some(p)) = (&sk.joints[j].limits, parent) {
                let local_meas = self.measured_rot[p].conjugate() * measured;
                let (_, excess) =
                    clamp_to_limits(local_meas, rig.twist_axis[j], sk.joints[j].bend_axis, lim);
                worst = worst.max(excess);
                self.limit_excess[j] = excess;
            }
        }
        worst
    }
}

#[cfg(test)]
mod tests {
    use super::inv_cbrt;

    /// The inverse cube root agrees with `powf` to 2.5e-13 relative (the bound of four
    /// Newton steps from an 8 % guess is 1.9e-13, reached near 0.3) over the volume
    /// ratios the restoration sees (its floor 0.1 to a hundredfold swelling), across
    /// exponent boundaries and at exact cubes (which it does not hit to the bit).
    #[test]
    fn inv_cbrt_matches_powf() {
        let mut x = 0.1f64;
        while x < 100.0 {
            let (got, want) = (inv_cbrt(x), x.powf(-1.0 / 3.0));
            assert!(
                (got - want).abs() <= 2.5e-13 * want,
                "{x}: {got} against {want}"
            );
            x *= 1.0007;
        }
        for (x, y) in [(0.125, 2.0), (1.0, 1.0), (8.0, 0.5), (27.0, 1.0 / 3.0)] {
            assert!((inv_cbrt(x) - y).abs() <= 2.5e-13 * y, "{x}");
        }
    }
}
