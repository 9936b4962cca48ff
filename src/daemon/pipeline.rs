//! The fixed-rate loop: every `1 / rate_hz` seconds, drain the input channel into the
//! marker buffer, sample a gap-filled frame, solve it warm-started within the frame's
//! deadline, and publish an `Arc<DeformedFrame>` to every sink's latest-value slot.
//!
//! [`Pipeline::tick`] is one frame with time passed in (tests call it directly with a
//! manual clock); [`run_loop`] paces it on a [`Clock`]. The per-frame path does not
//! allocate once warm: published frames come back to a pool when every sink has let go.

use super::input_rates::InputRates;
use crate::input::SourceCounters;
use crate::markers::buffer::MarkerBuffer;
use crate::markers::{FillState, MarkerFrame, MarkerSample};
use crate::output::frame::DeformedFrame;
use crate::protocol::vertex_stream::StopCode;
use crate::rig::bind::Rig;
use crate::runtime::clock::Clock;
use crate::runtime::slot::{LatestSlot, PinSlot};
use crate::runtime::stats::percentile;
use crate::solve::arap::StopReason;
use crate::solve::frame::{SolveReport, Solver, TRACE_LEN};
use crossbeam_channel::{Receiver, Sender};
use glam::DVec3;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// A solve whose markers fit within this RMS, mm, arms the identity gate
/// ([`Pipeline::with_identity_gate`]): a body fitted worse than this says too little of
/// where its markers belong.
pub const IDENTITY_TRUST_MM: f64 = 30.0;

/// Where each actor of a stage puts its markers (its last trusted solve's fitted
/// markers, capture metres; NaN when it has none), for the other actors' identity gates.
/// One lock per actor, held for a copy of its markers.
#[derive(Debug)]
pub struct ActorBoard {
    slots: Vec<std::sync::Mutex<Vec<DVec3>>>,
}

impl ActorBoard {
    /// A board for actors of `markers[i]` markers each, none known yet.
    pub fn new(markers: &[usize]) -> Self {
        Self {
            slots: markers
                .iter()
                .map(|&n| std::sync::Mutex::new(vec![DVec3::NAN; n]))
                .collect(),
        }
    }

    /// Copies every actor's markers but `me`'s into `out` (cleared first), scaled by
    /// `scale`.
    fn others(&self, me: usize, scale: f64, out: &mut Vec<DVec3>) {
        out.clear();
        let others = self.slots.iter().enumerate().filter(|(j, _)| *j != me);
        for (_, slot) in others {
            let m = slot.lock().unwrap_or_else(|e| e.into_inner());
            out.extend(m.iter().map(|p| *p * scale));
        }
    }

    /// Sets `me`'s markers to `markers` divided by `scale` (NaN: unknown).
    fn set(&self, me: usize, markers: Option<&[DVec3]>, scale: f64) {
        let Some(slot) = self.slots.get(me) else {
            return;
        };
        let mut m = slot.lock().unwrap_or_else(|e| e.into_inner());
        match markers {
            Some(p) if p.len() == m.len() => {
                for (o, p) in m.iter_mut().zip(p) {
                    *o = *p / scale;
                }
            }
            _ => m.iter_mut().for_each(|o| *o = DVec3::NAN),
        }
    }
}

/// Published frames kept for reuse.
const POOL_LEN: usize = 8;
/// Frame times kept for the status line's percentiles.
const WINDOW_LEN: usize = 1024;

/// Running figures for the status line, refreshed by the loop about once a second.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct LoopStatus {
    /// Frames solved so far.
    pub frames: u64,
    /// Frames per second over the last status interval.
    pub frame_rate_hz: f64,
    /// Whole-frame time (buffer, solve, full mesh, publish) over the last up to 1,024
    /// frames: median and 99th percentile, ms.
    pub frame_ms_p50: f64,
    pub frame_ms_p99: f64,
    /// The solve alone (control mesh), same window, ms.
    pub solve_ms_p50: f64,
    pub solve_ms_p99: f64,
    /// Mean ARAP iterations over the last interval.
    pub iterations_mean: f64,
    /// Frames stopped by their deadline, in all.
    pub deadline_stops: u64,
    /// Ticks skipped because the loop fell more than a period behind, in all.
    pub overruns: u64,
    /// Markers in each fill state in the newest frame (measured, predicted, rigid-filled,
    /// held).
    pub fill_now: [usize; 4],
    /// Samples taken from the channel, in all.
    pub samples: u64,
    /// The buffer's counters.
    pub buffer: crate::markers::buffer::BufferCounters,
    /// Samples the session recorder had no room for, in all.
    pub record_dropped: u64,
    /// Marker residual (distance from each marker to its bound point on the solved
    /// mesh) over every frame so far: RMS and largest, mm.
    pub marker_residual_mm_rms: f64,
    pub marker_residual_mm_max: f64,
    /// The solved mesh's lowest vertex above the take's floor (`y = 0`, the capture
    /// volume's ground), metres, over the frames with a marker in view: the median
    /// frame's (to the millimetre) and the lowest; `None` before such a frame or when
    /// the posture alone is fitted.
    pub lowest_vertex_m_median: Option<f64>,
    pub lowest_vertex_m_min: Option<f64>,
    /// The character's limbs ([`limb_markers`]) and the share of frames with a marker in
    /// view in which every limb had one measured or filled; `None` without limbs.
    pub limbs: usize,
    pub all_limbs_driven_share: Option<f64>,
}

/// Each limb of `rig`'s skeleton (arms and legs: an upper arm or upper leg joint by the
/// role its name gives, [`crate::character::roles::recognise`], with every joint below
/// it) as the markers its joints carry.
fn limb_markers(rig: &crate::rig::bind::Rig) -> Vec<Vec<usize>> {
    use crate::character::roles::{recognise, Part};
    let sk = &rig.skeleton;
    let roles = recognise(&sk.joints, &[]);
    let mut limbs = Vec::new();
    for (j, role) in roles.iter().enumerate() {
        if !role.is_some_and(|r| matches!(r.part, Part::UpperArm | Part::UpperLeg)) {
            continue;
        }
        let inside = sk.subtree(j);
        limbs.push(
            (0..rig.marker_joint.len())
                .filter(|&m| inside[rig.marker_joint[m]])
                .collect(),
        );
    }
    limbs
}

/// Millimetre bins of the lowest-vertex histogram, from [`LOWEST_FROM_M`] up (heights
/// beyond count in the end bins): 4 m of heights in 16 KiB, however long the run.
const LOWEST_BINS: usize = 4001;
const LOWEST_FROM_M: f64 = -2.0;

/// How the body stood over a run: its limbs driven, its lowest vertex.
#[derive(Clone, Debug)]
pub struct BodyTally {
    limbs: Vec<Vec<usize>>,
    frames: u64,
    all_limbs_driven: u64,
    lowest_bins: Vec<u32>,
    lowest_min_m: f64,
}

impl BodyTally {
    pub fn new(rig: &crate::rig::bind::Rig) -> Self {
        Self {
            limbs: limb_markers(rig),
            frames: 0,
            all_limbs_driven: 0,
            lowest_bins: vec![0; LOWEST_BINS],
            lowest_min_m: f64::INFINITY,
        }
    }

    /// Counts a frame with markers in `states` and the solved `vertices` (none: the
    /// posture alone was fitted).
    fn count(&mut self, states: &[FillState], vertices: Option<&[DVec3]>) {
        self.frames += 1;
        let driven = |limb: &Vec<usize>| limb.iter().any(|&m| states[m] != FillState::Held);
        self.all_limbs_driven += self.limbs.iter().all(driven) as u64;
        if let Some(v) = vertices {
            let lowest = v.iter().map(|p| p.y).fold(f64::INFINITY, f64::min);
            if lowest.is_finite() {
                self.lowest_min_m = self.lowest_min_m.min(lowest);
                let bin = ((lowest - LOWEST_FROM_M) * 1e3).round();
                self.lowest_bins[bin.clamp(0.0, (LOWEST_BINS - 1) as f64) as usize] += 1;
            }
        }
    }

    /// Forgets the frames counted so far.
    pub fn clear(&mut self) {
        self.frames = 0;
        self.all_limbs_driven = 0;
        self.lowest_bins.iter_mut().for_each(|b| *b = 0);
        self.lowest_min_m = f64::INFINITY;
    }

    /// Adds another run's frames (a later part of an export).
    pub fn merge(&mut self, o: &BodyTally) {
        self.frames += o.frames;
        self.all_limbs_driven += o.all_limbs_driven;
        for (a, b) in self.lowest_bins.iter_mut().zip(&o.lowest_bins) {
            *a += b;
        }
        self.lowest_min_m = self.lowest_min_m.min(o.lowest_min_m);
    }

    /// The median frame's lowest vertex (to the bin), the lowest, the limbs and the
    /// share of frames with all of them driven.
    pub fn figures(&self) -> (Option<f64>, Option<f64>, usize, Option<f64>) {
        let counted: u64 = self.lowest_bins.iter().map(|&c| u64::from(c)).sum();
        let mut seen = 0u64;
        let median = self.lowest_bins.iter().position(|&c| {
            seen += u64::from(c);
            2 * seen >= counted
        });
        let median = median
            .filter(|_| counted > 0)
            .map(|b| LOWEST_FROM_M + b as f64 * 1e-3);
        let share = (!self.limbs.is_empty() && self.frames > 0)
            .then(|| self.all_limbs_driven as f64 / self.frames as f64);
        (
            median,
            self.lowest_min_m.is_finite().then_some(self.lowest_min_m),
            self.limbs.len(),
            share,
        )
    }
}

/// One frame's outcome.
#[derive(Clone, Copy, Debug)]
pub struct TickReport {
    pub frame: u64,
    /// Samples drained from the channel this tick.
    pub samples: usize,
    pub solve: SolveReport,
    /// Whole tick, ms.
    pub frame_ms: f64,
}

/// Everything the solver thread owns.
pub struct Pipeline {
    solver: Solver,
    buffer: MarkerBuffer,
    rx: Receiver<MarkerSample>,
    slots: Vec<Arc<LatestSlot<DeformedFrame>>>,
    /// Character metres per capture metre, applied to every drained sample.
    marker_scale: f64,
    /// Every drained sample also goes here (the session recorder), without blocking.
    recorder: Option<Sender<MarkerSample>>,
    /// Added to a sample's marker index on its way to the recorder (an actor's first
    /// marker's index among the stage's).
    recorder_offset: u32,
    /// Samples the recorder's channel had no room for.
    record_dropped: u64,
    markers: MarkerFrame,
    vertices: Vec<DVec3>,
    pool: Vec<Arc<DeformedFrame>>,
    /// The tick this frame is solved at, counting from 0: solved ticks and those the
    /// loop skipped when it fell a period behind ([`Self::skip_ticks`]).
    frame_no: u64,
    /// Ticks skipped so far (`frame_no` less these is the frames solved).
    skipped: u64,
    samples: u64,
    /// Recent whole-frame and solve times, ms (rings of `WINDOW_LEN`).
    window_ms: Vec<f64>,
    window_solve_ms: Vec<f64>,
    window_at: usize,
    deadline_stops: u64,
    /// Sum over frames of the squared marker residual RMS (mm²), the frames summed (those
    /// with a finite residual), and the largest residual (mm).
    residual_sq_sum: f64,
    residual_frames: u64,
    residual_max_mm: f64,
    /// Limbs driven and the lowest vertex over the frames with a marker in view.
    body: BodyTally,
    interval_frames: u64,
    interval_iterations: u64,
    /// Joint angles from a glove source, the version last copied, and the copy.
    pin_slot: Option<Arc<PinSlot>>,
    pin_version: u64,
    pins: Vec<f64>,
    /// Copy the control mesh into published frames ([`Self::with_control_mesh`]).
    control_mesh: bool,
    /// Publish the harmonic rotation field ([`Self::with_harmonic_field`]).
    harmonic_field: bool,
    /// The inputs' rate windows ([`Self::with_input_rates`]).
    input_rates: InputRates,
    /// Fit the posture alone ([`Self::posture_only`]).
    posture_only: bool,
    /// Arm the buffer's identity gate with each trusted solve ([`Self::with_identity_gate`]).
    identity_gate: bool,
    /// The stage's actor board and this actor's place on it ([`Self::with_board`]), and
    /// the others' markers read from it each tick.
    board: Option<(Arc<ActorBoard>, usize)>,
    others: Vec<DVec3>,
    /// Every published frame also goes here ([`Self::with_frame_log`]), and the frames
    /// its full channel had no room for.
    frame_log: Option<Sender<Arc<DeformedFrame>>>,
    frames_unlogged: u64,
    /// The actor's index on the stage, stamped on every frame ([`Self::as_actor`]).
    actor: u8,
}

impl Pipeline {
    pub fn new(
        solver: Solver,
        buffer: MarkerBuffer,
        rx: Receiver<MarkerSample>,
        slots: Vec<Arc<LatestSlot<DeformedFrame>>>,
    ) -> Self {
        let rig = Arc::clone(solver.rig());
        let (nm, nv) = (rig.n_markers, rig.mesh_rest.len());
        Self {
            solver,
            buffer,
            rx,
            slots,
            marker_scale: 1.0,
            recorder: None,
            recorder_offset: 0,
            record_dropped: 0,
            markers: MarkerFrame::empty(nm),
            vertices: vec![DVec3::ZERO; nv],
            pool: Vec::with_capacity(POOL_LEN),
            frame_no: 0,
            skipped: 0,
            samples: 0,
            window_ms: Vec::with_capacity(WINDOW_LEN),
            window_solve_ms: Vec::with_capacity(WINDOW_LEN),
            window_at: 0,
            deadline_stops: 0,
            residual_sq_sum: 0.0,
            residual_frames: 0,
            residual_max_mm: 0.0,
            body: BodyTally::new(&rig),
            interval_frames: 0,
            interval_iterations: 0,
            pin_slot: None,
            pin_version: 0,
            pins: Vec::new(),
            control_mesh: false,
            harmonic_field: false,
            input_rates: InputRates::default(),
            posture_only: false,
            identity_gate: false,
            board: None,
            others: Vec::new(),
            frame_log: None,
            frames_unlogged: 0,
            actor: 0,
        }
    }

    pub fn rig(&self) -> &Arc<Rig> {
        self.solver.rig()
    }

    /// Sends every sample the loop drains to `tx` as well (a session recorder); a full
    /// channel drops the copy and counts it, never blocking the loop.
    pub fn with_recorder(mut self, tx: Sender<MarkerSample>) -> Self {
        self.recorder = Some(tx);
        self
    }

    /// [`Self::with_recorder`] for one actor of several: its samples are recorded under
    /// the stage's marker indices, its own plus `offset`.
    pub fn with_recorder_at(mut self, tx: Sender<MarkerSample>, offset: u32) -> Self {
        self.recorder = Some(tx);
        self.recorder_offset = offset;
        self
    }

    /// Sends `s` to the recorder, if there is one, under the stage's index.
    fn record(&mut self, s: MarkerSample) {
        if let Some(tx) = &self.recorder {
            let s = MarkerSample {
                marker: s.marker + self.recorder_offset,
                ..s
            };
            if tx.try_send(s).is_err() {
                self.record_dropped += 1;
            }
        }
    }

    /// Imposes the joint angles a source writes into `slot` (a data glove) on every
    /// frame's posture, from the tick after they change.
    pub fn with_pins(mut self, slot: Arc<PinSlot>) -> Self {
        self.pins = vec![f64::NAN; self.solver.rig().ik.n_params()];
        self.pin_slot = Some(slot);
        self
    }

    /// Scales every incoming marker position by `marker_scale` (character metres per
    /// capture metre, from a calibration) before the buffer sees it.
    pub fn with_marker_scale(mut self, marker_scale: f64) -> Self {
        self.marker_scale = marker_scale;
        self
    }

    /// Publishes the deformed control mesh with every frame (for a wireframe view; the
    /// ARAP method only, the harmonic method has none).
    pub fn with_control_mesh(mut self) -> Self {
        self.control_mesh = self.solver.has_control_mesh();
        self
    }

    /// Publishes the harmonic method's rotation field with every frame (per vertex, its
    /// angle from the root segment; nothing with ARAP).
    pub fn with_harmonic_field(mut self) -> Self {
        self.harmonic_field = !self.solver.has_control_mesh();
        self
    }

    /// Measures the packet rate and gaps of the inputs whose counters are `counters`
    /// (in the config's order) on every tick, and publishes the recent windows with every
    /// frame.
    pub fn with_input_rates(mut self, counters: &[Arc<SourceCounters>]) -> Self {
        self.input_rates = InputRates::new(counters);
        self
    }

    /// Fits only the skeleton's posture each tick ([`Solver::solve_posture`]): for an
    /// export of the posture alone, which reads neither mesh. The vertices are never
    /// written (they stay zero) and there is no control mesh to read.
    pub fn posture_only(mut self) -> Self {
        self.posture_only = true;
        self
    }

    /// Gates samples by the actor's own solved body (a stage of several actors: a label
    /// swap between two performers must not pull one towards the other). After each
    /// solve that fits its markers within [`IDENTITY_TRUST_MM`] RMS the buffer's identity
    /// gate takes the fitted marker positions; when it drops most of a tick's samples
    /// the body, not the labels, is what moved, and the gate opens until the next
    /// trusted solve.
    pub fn with_identity_gate(mut self) -> Self {
        self.identity_gate = true;
        self
    }

    /// Shares this actor's fitted markers on `board` as actor `me`, and gates its
    /// samples by the others' too: one nearer another performer's marker than to where
    /// this body puts it is not this actor's. With [`Self::with_identity_gate`].
    pub fn with_board(mut self, board: Arc<ActorBoard>, me: usize) -> Self {
        self.board = Some((board, me));
        self
    }

    /// Sends every published frame to `tx` as well, without blocking (a full channel
    /// drops it): an in-process reader that must see every frame (tests, benchmarks).
    pub fn with_frame_log(mut self, tx: Sender<Arc<DeformedFrame>>) -> Self {
        self.frame_log = Some(tx);
        self
    }

    /// Stamps every frame as actor `index`'s (its index in the stage's config).
    pub fn as_actor(mut self, index: u8) -> Self {
        self.actor = index;
        self
    }

    /// Frames the frame log's full channel had no room for.
    pub fn frames_unlogged(&self) -> u64 {
        self.frames_unlogged
    }

    pub fn buffer(&self) -> &MarkerBuffer {
        &self.buffer
    }

    /// The newest marker frame (after gap filling).
    pub fn markers(&self) -> &MarkerFrame {
        &self.markers
    }

    /// The deformed control mesh of the newest frame (`None` with the harmonic method,
    /// which has none), metres.
    pub fn control_positions(&self) -> Option<&[DVec3]> {
        (self.solver.has_control_mesh() && !self.posture_only)
            .then(|| self.solver.control_positions())
    }

    /// The newest full-resolution vertices, metres.
    pub fn vertices(&self) -> &[DVec3] {
        &self.vertices
    }

    /// The newest fitted posture: every joint's world rotation from rest and world
    /// position (metres).
    pub fn joint_world(&self) -> (&[glam::DQuat], &[DVec3]) {
        self.solver.joint_world()
    }

    /// The first half of a tick: drains the received samples into the buffer (and the
    /// recorder) and samples the buffer at `t_s`; returns the samples drained. Alone, it
    /// brings the buffer's history (gap filling, gating) up to `t_s` without solving: an
    /// export's part that starts mid-take replays the take's earlier samples this way.
    pub fn feed(&mut self, t_s: f64) -> usize {
        // What is queued now, and no more: a sender faster than the loop (a flood) must
        // not keep the drain going. What it sends meanwhile waits for the next frame;
        // what the queue has no room for, the input drops and counts.
        let queued = self.rx.len();
        let mut drained = 0;
        while drained < queued {
            let Ok(s) = self.rx.try_recv() else {
                break;
            };
            // The buffer works in the character's metres; the recorder keeps the
            // capture's.
            self.buffer.push(&MarkerSample {
                position_m: s.position_m * self.marker_scale,
                ..s
            });
            self.record(s);
            drained += 1;
        }
        self.samples += drained as u64;
        self.buffer.sample_at(t_s, &mut self.markers);
        drained
    }

    /// Counts `n` ticks the loop skipped (it fell more than a period behind): the next
    /// frame's number is its tick's, so a client sees the gap, and every actor of a
    /// stage numbers the same tick alike.
    pub fn skip_ticks(&mut self, n: u64) {
        self.frame_no += n;
        self.skipped += n;
    }

    /// One frame at time `t_s` on the daemon's clock: drain, sample, solve (until
    /// `deadline`), publish (stamped with `unix_now()`, read just before publishing).
    pub fn tick(&mut self, t_s: f64, deadline: Instant, unix_now: &dyn Fn() -> f64) -> TickReport {
        let start = Instant::now();
        if let Some((board, me)) = &self.board {
            board.others(*me, self.marker_scale, &mut self.others);
            self.buffer.set_others(&self.others);
        }
        let drained = self.feed(t_s);
        self.input_rates.tick(self.frame_no, t_s, &|| {
            unix_now() - start.elapsed().as_secs_f64()
        });
        if let Some(slot) = &self.pin_slot {
            if slot.read_if_newer(&mut self.pin_version, &mut self.pins) {
                self.solver.set_pins(&self.pins);
            }
        }
        let solve = if self.posture_only {
            self.solver.solve_posture(&self.markers)
        } else {
            self.solver
                .solve(&self.markers, deadline, &mut self.vertices)
        };
        if self.identity_gate {
            self.arm_identity_gate(t_s, &solve);
        }
        // Off line (an export, a check) nothing reads the frame: it is not built.
        if !self.slots.is_empty() || self.frame_log.is_some() {
            self.publish(t_s, start, &solve, unix_now);
        }
        let frame_ms = start.elapsed().as_secs_f64() * 1e3;
        if self.window_ms.len() < WINDOW_LEN {
            self.window_ms.push(frame_ms);
            self.window_solve_ms.push(solve.solve_ms);
        } else {
            self.window_ms[self.window_at] = frame_ms;
            self.window_solve_ms[self.window_at] = solve.solve_ms;
        }
        self.window_at = (self.window_at + 1) % WINDOW_LEN;
        self.deadline_stops += (solve.stop == StopReason::Deadline) as u64;
        // Ticks with no marker in view (before a replay starts, after it ends) say nothing
        // of the fit.
        let in_view = self.markers.states.iter().any(|s| *s != FillState::Held);
        if in_view && solve.marker_residual_rms_mm.is_finite() {
            self.residual_sq_sum += solve.marker_residual_rms_mm * solve.marker_residual_rms_mm;
            self.residual_frames += 1;
            self.residual_max_mm = self.residual_max_mm.max(solve.marker_residual_max_mm);
        }
        if in_view {
            let mesh = (!self.posture_only).then_some(self.vertices.as_slice());
            self.body.count(&self.markers.states, mesh);
        }
        self.interval_frames += 1;
        self.interval_iterations += solve.iterations as u64;
        let report = TickReport {
            frame: self.frame_no,
            samples: drained,
            solve,
            frame_ms,
        };
        self.frame_no += 1;
        report
    }

    /// Arms the buffer's identity gate with this tick's solve when it is trusted, and
    /// opens it when it dropped most of what arrived since the last one.
    fn arm_identity_gate(&mut self, t_s: f64, solve: &SolveReport) {
        let (taken, gated) = self.buffer.since_body();
        let in_view = self
            .markers
            .states
            .iter()
            .filter(|s| **s != FillState::Held)
            .count();
        let trusted = in_view >= 3 && solve.marker_residual_rms_mm < IDENTITY_TRUST_MM;
        if gated >= 3 && 2 * gated > taken {
            self.buffer.clear_body();
        } else if trusted {
            self.buffer
                .set_body(t_s, self.solver.fitted_markers(), &self.markers.states);
        }
        if let Some((board, me)) = &self.board {
            let fitted = trusted.then(|| self.solver.fitted_markers());
            board.set(*me, fitted, self.marker_scale);
        }
    }

    /// Limbs driven and the lowest vertex over the frames with a marker in view.
    pub fn body(&self) -> &BodyTally {
        &self.body
    }

    /// Starts [`Self::body`]'s count again (an export's part after its warm-up).
    pub fn clear_body(&mut self) {
        self.body.clear();
    }

    /// Passes the samples still queued to the recorder (at shutdown, so that a session
    /// file holds every sample that arrived).
    pub fn flush_to_recorder(&mut self) {
        while let Ok(s) = self.rx.try_recv() {
            self.record(s);
        }
    }

    /// A pooled frame no sink holds any more, or a new one while the pool fills.
    /// Fills a pooled frame with the tick's solve (stamped with `unix_now()`) and
    /// publishes it to every slot.
    fn publish(
        &mut self,
        t_s: f64,
        start: Instant,
        solve: &SolveReport,
        unix_now: &dyn Fn() -> f64,
    ) {
        let mut frame = self.recycled_frame();
        {
            let f = Arc::get_mut(&mut frame).expect("a recycled frame is unshared");
            f.frame = self.frame_no;
            f.actor = self.actor;
            f.source_time_s = self.markers.source_time_s;
            f.publish_time_s = unix_now();
            // The newest sample's age on the daemon's clock, to the publish time's clock:
            // the tick started at `t_s`, `start` on the monotonic clock.
            let age_s = t_s - self.markers.received_at_s + start.elapsed().as_secs_f64();
            f.received_time_s = if age_s.is_finite() {
                f.publish_time_s - age_s
            } else {
                0.0
            };
            let s = &mut f.status;
            s.iterations = solve.iterations.min(u16::MAX as usize) as u16;
            s.stop = match solve.stop {
                StopReason::Converged => StopCode::Converged,
                StopReason::IterationCap => StopCode::IterationCap,
                StopReason::Deadline => StopCode::Deadline,
            };
            s.solve_ms = solve.solve_ms as f32;
            s.gc_ms = solve.gc_ms as f32;
            s.rrms = solve.rrms as f32;
            s.bone_length_error = solve.bone_length_error as f32;
            s.joint_limit_violation_deg = solve.joint_limit_violation_deg as f32;
            s.marker_residual_rms_mm = solve.marker_residual_rms_mm as f32;
            s.marker_residual_max_mm = solve.marker_residual_max_mm as f32;
            f.untangle_projections = solve.untangled.min(u32::MAX as usize) as u32;
            f.marker_states.copy_from_slice(&self.markers.states);
            for (o, p) in f.markers_m.iter_mut().zip(&self.markers.positions) {
                *o = p.as_vec3();
            }
            for (o, p) in f.vertices_m.iter_mut().zip(&self.vertices) {
                *o = p.as_vec3();
            }
            let (_, joints) = self.solver.joint_world();
            // Sized once per pooled frame; no allocation after.
            f.joints_m.resize(joints.len(), glam::Vec3::ZERO);
            for (o, p) in f.joints_m.iter_mut().zip(joints) {
                *o = p.as_vec3();
            }
            let excess = self.solver.joint_limit_excess();
            f.joint_limit_excess_deg.resize(excess.len(), 0.0);
            for (o, e) in f.joint_limit_excess_deg.iter_mut().zip(excess) {
                *o = e.to_degrees() as f32;
            }
            if self.control_mesh {
                let c = self.solver.control_positions();
                f.control_m.resize(c.len(), glam::Vec3::ZERO);
                for (o, p) in f.control_m.iter_mut().zip(c) {
                    *o = p.as_vec3();
                }
            }
            if self.harmonic_field {
                f.field_deg.resize(self.vertices.len(), 0.0);
                self.solver.harmonic_field_deg(&mut f.field_deg);
            }
            // Sized on a pooled frame's first use; no allocation after.
            f.input_windows.clear();
            f.input_windows.extend(self.input_rates.recent());
            // Within the capacity reserved at creation: no allocation.
            f.convergence.clear();
            f.convergence
                .extend_from_slice(&solve.trace[..solve.trace_len]);
        }
        for slot in &self.slots {
            slot.publish(Arc::clone(&frame));
        }
        if let Some(tx) = &self.frame_log {
            // A reader that falls behind loses frames; the loop never waits.
            if tx.try_send(Arc::clone(&frame)).is_err() {
                self.frames_unlogged += 1;
            }
        }
        self.keep_for_reuse(frame);
    }

    fn recycled_frame(&mut self) -> Arc<DeformedFrame> {
        if let Some(i) = self.pool.iter_mut().position(|f| Arc::get_mut(f).is_some()) {
            return self.pool.swap_remove(i);
        }
        let rig = self.solver.rig();
        Arc::new(DeformedFrame::with_sizes(
            rig.n_markers,
            rig.mesh_rest.len(),
            TRACE_LEN,
        ))
    }

    fn keep_for_reuse(&mut self, frame: Arc<DeformedFrame>) {
        if self.pool.len() >= POOL_LEN {
            // Every pooled frame is still held by a slow sink: forget the oldest.
            self.pool.remove(0);
        }
        self.pool.push(frame);
    }

    /// Status since the last call (interval figures) and in all; `overruns` and
    /// `interval_s` come from the loop. Sorts copies of the time windows: it allocates,
    /// once per status interval (a second), never per frame.
    pub fn status(&mut self, interval_s: f64, overruns: u64) -> LoopStatus {
        // 0 before the first frame (a status line shows no time rather than NaN).
        let pct = |v: &[f64], q: f64| {
            if v.is_empty() {
                0.0
            } else {
                percentile(&mut v.to_vec(), q)
            }
        };
        let mut fill_now = [0usize; 4];
        for s in &self.markers.states {
            fill_now[*s as usize] += 1;
        }
        let mut st = LoopStatus {
            frames: self.frame_no - self.skipped,
            frame_rate_hz: self.interval_frames as f64 / interval_s.max(1e-9),
            frame_ms_p50: pct(&self.window_ms, 0.5),
            frame_ms_p99: pct(&self.window_ms, 0.99),
            solve_ms_p50: pct(&self.window_solve_ms, 0.5),
            solve_ms_p99: pct(&self.window_solve_ms, 0.99),
            iterations_mean: self.interval_iterations as f64 / self.interval_frames.max(1) as f64,
            deadline_stops: self.deadline_stops,
            overruns,
            fill_now,
            samples: self.samples,
            buffer: *self.buffer.counters(),
            record_dropped: self.record_dropped,
            marker_residual_mm_rms: (self.residual_sq_sum / self.residual_frames.max(1) as f64)
                .sqrt(),
            marker_residual_mm_max: self.residual_max_mm,
            lowest_vertex_m_median: None,
            lowest_vertex_m_min: None,
            limbs: 0,
            all_limbs_driven_share: None,
        };
        (
            st.lowest_vertex_m_median,
            st.lowest_vertex_m_min,
            st.limbs,
            st.all_limbs_driven_share,
        ) = self.body.figures();
        self.interval_frames = 0;
        self.interval_iterations = 0;
        st
    }
}

/// How the loop runs.
#[derive(Clone, Copy, Debug)]
pub struct LoopParams {
    /// The first tick, seconds on the clock.
    pub start_s: f64,
    pub rate_hz: f64,
    /// Fraction of the period a frame's solve may use before it stops at its deadline.
    pub deadline_fraction: f64,
    /// Stop after this time on the clock, seconds (`None`: until `stop`).
    pub end_s: Option<f64>,
    /// Seconds between status updates.
    pub status_interval_s: f64,
}

/// Paces [`Pipeline::tick`] at `rate_hz` on `clock` from `start_s` until `stop` is set
/// or `end_s`; a tick more than one period late is skipped (counted as an overrun),
/// never bunched. Status goes to `status` about every `status_interval_s`. Returns the
/// final status.
pub fn run_loop(
    p: &mut Pipeline,
    clock: &dyn Clock,
    params: LoopParams,
    stop: &AtomicBool,
    status: &LatestSlot<LoopStatus>,
) -> LoopStatus {
    let mut last = run_loop_many(
        std::slice::from_mut(p),
        clock,
        params,
        stop,
        std::slice::from_ref(&status),
    );
    last.pop().unwrap_or_default()
}

/// [`run_loop`] for several pipelines (actors) on one thread: each tick solves them in
/// turn, each within its own share of the tick's budget (the time until
/// `deadline_fraction` of the period, split evenly among the thread's actors), or less
/// when the ones before it left less than that: an actor's frame time does not grow
/// with how quickly the others converged. `status[i]` hears `pipelines[i]`'s status.
/// Returns each one's final status.
pub fn run_loop_many(
    pipelines: &mut [Pipeline],
    clock: &dyn Clock,
    params: LoopParams,
    stop: &AtomicBool,
    status: &[&LatestSlot<LoopStatus>],
) -> Vec<LoopStatus> {
    let period = 1.0 / params.rate_hz;
    // Tick `k` is due at `start_s + k · period` (computed, not accumulated, so a long run
    // does not drift). The last tick is the last one due by `end_s`, its index computed
    // once (a millionth of a period of slack for rounding).
    let due = |k: u64| params.start_s + k as f64 * period;
    let last_k = params
        .end_s
        .map(|e| ((e - params.start_s) / period + 1e-6).floor().max(-1.0));
    let past_end = |k: u64| last_k.is_some_and(|last| k as f64 > last);
    let mut k = 0u64;
    let mut overruns = 0u64;
    // The first tick covers the period before it, so rates come out exact.
    let mut last_status = due(0) - period;
    while !stop.load(Ordering::Relaxed) && !past_end(k) {
        clock.sleep_until(due(k));
        let late = clock.now_s() - due(k);
        if late > period {
            let behind = (late / period).floor() as u64;
            overruns += behind;
            k += behind;
            for p in pipelines.iter_mut() {
                p.skip_ticks(behind);
            }
            if past_end(k) {
                break;
            }
        }
        let next = due(k);
        let end_s = next + period * params.deadline_fraction;
        let n = pipelines.len();
        let own_s = period * params.deadline_fraction / n as f64;
        for (i, p) in pipelines.iter_mut().enumerate() {
            let left_s = (end_s - clock.now_s()).max(0.0) / (n - i) as f64;
            let share = left_s.min(own_s);
            p.tick(next, clock.deadline_at(clock.now_s() + share), &|| {
                clock.unix_s(clock.now_s())
            });
        }
        if next - last_status >= params.status_interval_s {
            for (p, slot) in pipelines.iter_mut().zip(status) {
                slot.publish(Arc::new(p.status(next - last_status, overruns)));
            }
            last_status = next;
        }
        k += 1;
    }
    let interval_s = (clock.now_s() - last_status).max(1e-9);
    pipelines
        .iter_mut()
        .map(|p| p.status(interval_s, overruns))
        .collect()
}
