//! The marker buffer: a short history of timestamped samples per marker, from any input,
//! and [`MarkerBuffer::sample_at`], which turns it into a full [`MarkerFrame`] with every
//! gap filled and labelled ([`FillState`]).
//!
//! Policies, in order, for a marker with no sample in the last `measured_window_secs`:
//! 1. `rigid_filled`: three or more markers of the same body segment (same joint) are
//!    measured now, spread in a plane: the missing one moves with them, by the best-fit
//!    rigid motion (Kabsch) from their reference layout (the last frame where the whole
//!    segment was measured, or the rest layout) to now. Used once the gap is longer than
//!    `rigid_after_secs`.
//! 2. `predicted`: gaps up to `predict_max_gap_secs`: constant velocity (least-squares
//!    slope over the last `velocity_window_secs`), with the velocity decaying as
//!    `exp(-gap / prediction_decay_secs)`, so the marker coasts to a stop instead of
//!    flying off; the frame's `confidence` ([`MarkerFrame::confidence`]) is that same
//!    factor.
//! 3. `held`: no information; the solver leaves the marker's bound point where its bone
//!    takes it.
//!
//! A plausibility bound comes first: a sample outside the stage volume (`volume_min_m`
//! to `volume_max_m`) is dropped and counted, and the first one of each marker is logged;
//! so is any gap-filled position that would leave the volume (it is held instead). Then
//! an innovation gate rejects samples that land too far from the marker's own
//! prediction (jumps, and label swaps: a rejected sample near another marker's prediction
//! is counted as a swap); a marker whose rejected samples agree with each other for
//! `reacquire_samples` samples is re-acquired there (never outside the volume: those
//! samples never reach the gate). So no non-finite or out-of-volume position reaches the
//! solver, whatever a sender sends.
//!
//! On a stage of several actors an identity gate comes after the volume check
//! ([`MarkerBuffer::set_body`]): the actor's last solved body says where each marker
//! should be, and a sample whose offset from there jumps by more than
//! `identity_gate_m` (plus `gate_max_speed_m_s` times the solve's age) from the marker's
//! usual offset is not this actor's (a vendor's label swap between two performers
//! standing close): it is dropped and counted, and never starts a re-acquisition.
//!
//! No allocation after construction: histories are fixed rings, frames are filled in
//! place. Time is passed in; nothing here reads a clock.

use super::{FillState, MarkerFrame, MarkerSample};
use crate::geom::polar::rotation_of;
use glam::{DMat3, DVec3};

/// Gap filling and gating settings (the `[buffer]` table of a stage config).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BufferConfig {
    /// A marker whose newest sample is at most this old counts as measured, seconds
    /// (cover one source period plus jitter).
    pub measured_window_secs: f64,
    /// Longest gap filled by prediction, seconds; longer gaps are held.
    pub predict_max_gap_secs: f64,
    /// Time constant of the predicted velocity's decay (and of the confidence), seconds.
    pub prediction_decay_secs: f64,
    /// Span of recent samples the velocity is fitted over, seconds.
    pub velocity_window_secs: f64,
    /// Gaps longer than this are filled rigidly when the segment allows, seconds
    /// (shorter ones are predicted).
    pub rigid_after_secs: f64,
    /// Samples kept per marker.
    pub history_len: usize,
    /// Innovation gate: a sample farther than `gate_floor_m + ½·gate_max_accel_m_s2·dt²`
    /// from the marker's prediction is rejected (`dt`: time since its last sample).
    pub gate_floor_m: f64,
    /// See `gate_floor_m`, metres per second squared.
    pub gate_max_accel_m_s2: f64,
    /// Fastest a marker plausibly moves, metres per second: while its velocity is not
    /// known yet (its first samples, and those after a re-acquisition), its gate widens
    /// by this speed times `dt`, and a run of rejected samples agrees within that
    /// radius. 10 m/s is a runner's foot in its swing.
    pub gate_max_speed_m_s: f64,
    /// Consecutive rejected samples that agree with each other before the marker is
    /// re-acquired at their position.
    pub reacquire_samples: u32,
    /// Identity gate (stages of several actors): a sample whose offset from where the
    /// actor's solved body puts its marker jumps by more than this from the marker's
    /// usual offset, metres (plus `gate_max_speed_m_s` times the solve's age), is
    /// another performer's: dropped and counted. 0 turns it off.
    pub identity_gate_m: f64,
    /// The stage volume's lowest corner `[x, y, z]`, metres, world frame (Y up): a sample
    /// outside the volume is implausible (dropped, counted), as is a filled position.
    pub volume_min_m: [f64; 3],
    /// The stage volume's highest corner `[x, y, z]`, metres, world frame (Y up).
    pub volume_max_m: [f64; 3],
}

impl Default for BufferConfig {
    fn default() -> Self {
        Self {
            measured_window_secs: 0.025,
            predict_max_gap_secs: 0.25,
            prediction_decay_secs: 0.1,
            velocity_window_secs: 0.05,
            rigid_after_secs: 0.0,
            history_len: 32,
            gate_floor_m: 0.02,
            gate_max_accel_m_s2: 200.0,
            gate_max_speed_m_s: 10.0,
            reacquire_samples: 3,
            identity_gate_m: 0.1,
            volume_min_m: [-20.0, -5.0, -20.0],
            volume_max_m: [20.0, 10.0, 20.0],
        }
    }
}

impl BufferConfig {
    /// Gate radius for a prediction `dt` seconds past the last sample, metres; wider
    /// by `gate_max_speed_m_s · dt` when the prediction knows no velocity.
    pub fn gate_m(&self, dt: f64, velocity_known: bool) -> f64 {
        let coast = if velocity_known {
            0.0
        } else {
            self.gate_max_speed_m_s * dt
        };
        self.gate_floor_m + coast + 0.5 * self.gate_max_accel_m_s2 * dt * dt
    }

    /// Whether `p` is finite and inside the stage volume (bounds included).
    pub fn in_volume(&self, p: DVec3) -> bool {
        let (lo, hi) = (
            DVec3::from(self.volume_min_m),
            DVec3::from(self.volume_max_m),
        );
        p.cmpge(lo).all() && p.cmple(hi).all()
    }

    /// Every problem with these settings (empty when valid), each naming its key.
    pub fn problems(&self) -> Vec<(String, String)> {
        let mut out = Vec::new();
        let mut positive = |name: &str, v: f64| {
            if !(v.is_finite() && v > 0.0) {
                out.push((
                    name.to_owned(),
                    format!("must be a positive number of seconds or metres, got {v}"),
                ));
            }
        };
        positive("measured_window_secs", self.measured_window_secs);
        positive("predict_max_gap_secs", self.predict_max_gap_secs);
        positive("prediction_decay_secs", self.prediction_decay_secs);
        positive("velocity_window_secs", self.velocity_window_secs);
        positive("gate_floor_m", self.gate_floor_m);
        positive("gate_max_accel_m_s2", self.gate_max_accel_m_s2);
        positive("gate_max_speed_m_s", self.gate_max_speed_m_s);
        if !(self.identity_gate_m.is_finite() && self.identity_gate_m >= 0.0) {
            out.push((
                "identity_gate_m".into(),
                format!(
                    "must be zero (off) or more metres, got {:?}",
                    self.identity_gate_m
                ),
            ));
        }
        if !(self.rigid_after_secs.is_finite() && self.rigid_after_secs >= 0.0) {
            out.push((
                "rigid_after_secs".into(),
                format!("must be zero or more, got {:?}", self.rigid_after_secs),
            ));
        }
        if !(2..=4096).contains(&self.history_len) {
            out.push((
                "history_len".into(),
                format!("must be between 2 and 4096, got {:?}", self.history_len),
            ));
        }
        if self.reacquire_samples == 0 {
            out.push(("reacquire_samples".into(), "must be at least 1".into()));
        }
        let (lo, hi) = (self.volume_min_m, self.volume_max_m);
        for (key, corner) in [("volume_min_m", lo), ("volume_max_m", hi)] {
            if !corner.iter().all(|v| v.is_finite()) {
                out.push((
                    key.into(),
                    format!("must be three finite metres, got {corner:?}"),
                ));
            }
        }
        let axes = ["x", "y", "z"];
        let empty: Vec<&str> = (0..3)
            .filter(|&i| lo[i] >= hi[i])
            .map(|i| axes[i])
            .collect();
        if lo.iter().chain(&hi).all(|v| v.is_finite()) && !empty.is_empty() {
            out.push((
                "volume_max_m".into(),
                format!(
                    "must be above volume_min_m on every axis, but is not on {} ({hi:?} against {lo:?})",
                    empty.join(", ")
                ),
            ));
        }
        out
    }
}

/// What happened to every sample and frame since the buffer was made (monotonic).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct BufferCounters {
    /// Samples accepted into a history.
    pub accepted: u64,
    /// Samples flagged occluded or with a non-finite position.
    pub occluded: u64,
    /// Samples with a finite position outside the stage volume (dropped).
    pub implausible: u64,
    /// Gap-filled positions (predicted or rigid) that fell outside the stage volume; the
    /// marker was held instead.
    pub implausible_fills: u64,
    /// Samples naming a marker outside the layout, or with a non-finite time.
    pub invalid: u64,
    /// Samples older than the marker's newest (dropped).
    pub late: u64,
    /// Samples rejected by the innovation gate (label swaps included).
    pub gate_rejected: u64,
    /// Rejected samples that matched another marker's prediction.
    pub label_swaps: u64,
    /// Markers re-acquired after consistent rejected samples.
    pub reacquired: u64,
    /// Samples the identity gate dropped as another performer's.
    pub identity_gated: u64,
    /// Frames produced by `sample_at`.
    pub frames: u64,
    /// Marker-frames per fill state, indexed by the state's code.
    pub filled: [u64; 4],
}

/// Per-marker state.
#[derive(Clone, Debug)]
struct Track {
    /// Ring of `(time_s, position)`, `len` valid entries ending at `head - 1`.
    ring: Vec<(f64, DVec3)>,
    head: usize,
    len: usize,
    /// Newest occlusion report newer than the newest sample (time), if any.
    occluded_at: Option<f64>,
    /// A run of rejected samples that agree with each other: newest time, position, count.
    candidate: Option<(f64, DVec3, u32)>,
    /// An implausible sample of this marker has been logged (once per marker).
    warned: bool,
}

impl Track {
    fn newest(&self) -> Option<(f64, DVec3)> {
        (self.len > 0).then(|| self.ring[(self.head + self.ring.len() - 1) % self.ring.len()])
    }

    /// The `i`-th newest sample (0 = newest), `i < len`.
    fn nth_newest(&self, i: usize) -> (f64, DVec3) {
        let cap = self.ring.len();
        self.ring[(self.head + cap - 1 - i) % cap]
    }

    fn push(&mut self, t: f64, p: DVec3) {
        let cap = self.ring.len();
        self.ring[self.head] = (t, p);
        self.head = (self.head + 1) % cap;
        self.len = (self.len + 1).min(cap);
    }

    /// Drops the newest sample.
    fn pop(&mut self) {
        if self.len > 0 {
            let cap = self.ring.len();
            self.head = (self.head + cap - 1) % cap;
            self.len -= 1;
        }
    }

    fn clear(&mut self) {
        self.len = 0;
        self.occluded_at = None;
        self.candidate = None;
    }

    /// Least-squares velocity over the samples within `window_s` of the newest, m/s;
    /// `None` (not known) with fewer than two, or when they span less than half the
    /// window. Receive times are what the samples carry, and a network stall delivers
    /// its queued packets microseconds apart: a slope over such a burst would be the real
    /// motion over the stall divided by microseconds, and the prediction would fly off
    /// with it.
    fn velocity(&self, window_s: f64) -> Option<DVec3> {
        let (t_new, _) = self.newest()?;
        let (mut n, mut st, mut sp) = (0usize, 0.0, DVec3::ZERO);
        while n < self.len {
            let (t, p) = self.nth_newest(n);
            if t_new - t > window_s {
                break;
            }
            st += t;
            sp += p;
            n += 1;
        }
        if n < 2 || t_new - self.nth_newest(n - 1).0 < 0.5 * window_s {
            return None;
        }
        let (tm, pm) = (st / n as f64, sp / n as f64);
        let (mut stt, mut stp) = (0.0, DVec3::ZERO);
        for i in 0..n {
            let (t, p) = self.nth_newest(i);
            stt += (t - tm) * (t - tm);
            stp += (p - pm) * (t - tm);
        }
        (stt > 0.0).then(|| stp / stt)
    }

    /// Damped constant-velocity prediction at `t` (at rest where the velocity is not
    /// known), its confidence in `(0, 1]`, and the gate radius about it.
    fn predict(&self, t: f64, cfg: &BufferConfig) -> Option<Prediction> {
        let (t_last, p_last) = self.newest()?;
        let gap = (t - t_last).max(0.0);
        let tau = cfg.prediction_decay_secs;
        let decay = (-gap / tau).exp();
        let v = self.velocity(cfg.velocity_window_secs);
        Some(Prediction {
            position_m: p_last + v.unwrap_or(DVec3::ZERO) * (tau * (1.0 - decay)),
            confidence: decay,
            gate_m: cfg.gate_m(gap, v.is_some()),
        })
    }
}

/// A track's prediction at some time.
#[derive(Clone, Copy, Debug)]
struct Prediction {
    position_m: DVec3,
    /// In `(0, 1]`: `exp(−gap / prediction_decay_secs)`.
    confidence: f64,
    /// The innovation gate's radius about `position_m`.
    gate_m: f64,
}

/// Markers of one body segment (same joint) and their reference layout.
#[derive(Clone, Debug)]
struct Segment {
    markers: Vec<usize>,
    /// Reference position per marker of the segment (same order).
    reference: Vec<DVec3>,
}

/// Per-marker sample history and gap filling for one character's marker layout.
#[derive(Clone, Debug)]
pub struct MarkerBuffer {
    cfg: BufferConfig,
    tracks: Vec<Track>,
    segments: Vec<Segment>,
    /// Segment index of each marker.
    segment_of: Vec<usize>,
    counters: BufferCounters,
    /// Marker names for logs (`#k` where none is given).
    names: Vec<String>,
    /// The source time of the most recently received sample (a frame's source time), and
    /// that sample's receive time. The newest, not the largest: a largest would let one
    /// sample with a far-future time pin every later frame's.
    source_time_s: f64,
    source_at_s: f64,
    /// The receive time of the newest sample taken, daemon clock (−∞: none yet).
    received_at_s: f64,
    /// Scratch for the rigid fill.
    scratch_ref: Vec<DVec3>,
    scratch_cur: Vec<DVec3>,
    /// The identity gate's body: where the last trusted solve put each marker, and when
    /// (NaN: no body, the gate is open).
    body_m: Vec<DVec3>,
    body_at_s: f64,
    /// Whether that solve saw each marker (only then does a sample teach the marker's
    /// usual offset).
    body_saw: Vec<bool>,
    /// Each marker's usual offset from the body (a running mean of accepted samples'),
    /// once known; learnt again after a gap longer than `predict_max_gap_secs` (the body
    /// placed a marker it did not see only roughly).
    body_offset_m: Vec<Option<DVec3>>,
    /// When each marker's newest identity-gated sample came (−∞: none): a run of gated
    /// samples is no gap, so a label stuck on another performer stays gated.
    gated_at_s: Vec<f64>,
    /// Samples taken, and those identity-gated, since the body was last set.
    since_body: (u64, u64),
    /// Where the other actors' bodies put their markers (NaN where they do not know),
    /// metres, this buffer's frame ([`Self::set_others`]).
    others_m: Vec<DVec3>,
}

impl MarkerBuffer {
    /// A buffer for a layout: each marker's rest position and the joint that carries it
    /// (markers with the same joint form a rigid segment).
    pub fn new(cfg: BufferConfig, marker_rest: &[DVec3], marker_joint: &[usize]) -> Self {
        let n = marker_rest.len();
        let cap = cfg.history_len.max(2);
        let track = Track {
            ring: vec![(f64::NEG_INFINITY, DVec3::ZERO); cap],
            head: 0,
            len: 0,
            occluded_at: None,
            candidate: None,
            warned: false,
        };
        let mut segments: Vec<Segment> = Vec::new();
        let mut joints: Vec<usize> = Vec::new();
        let mut segment_of = vec![0; n];
        for k in 0..n {
            let j = marker_joint.get(k).copied().unwrap_or(usize::MAX);
            let s = match joints.iter().position(|&x| x == j) {
                Some(s) => s,
                None => {
                    joints.push(j);
                    segments.push(Segment {
                        markers: Vec::new(),
                        reference: Vec::new(),
                    });
                    segments.len() - 1
                }
            };
            segments[s].markers.push(k);
            segments[s].reference.push(marker_rest[k]);
            segment_of[k] = s;
        }
        let widest = segments.iter().map(|s| s.markers.len()).max().unwrap_or(0);
        Self {
            cfg,
            tracks: vec![track; n],
            segments,
            segment_of,
            counters: BufferCounters::default(),
            names: Vec::new(),
            source_time_s: 0.0,
            source_at_s: f64::NEG_INFINITY,
            received_at_s: f64::NEG_INFINITY,
            scratch_ref: Vec::with_capacity(widest),
            scratch_cur: Vec::with_capacity(widest),
            body_m: vec![DVec3::ZERO; n],
            body_at_s: f64::NAN,
            body_saw: vec![false; n],
            body_offset_m: vec![None; n],
            gated_at_s: vec![f64::NEG_INFINITY; n],
            since_body: (0, 0),
            others_m: Vec::new(),
        }
    }

    /// Tells the identity gate where the other actors' bodies put their markers
    /// (metres, this buffer's frame; NaN where unknown): a sample nearer one of those
    /// than to where this actor's body puts its marker, and not within
    /// `identity_gate_m` of the latter, is another performer's. Copied; no allocation
    /// once the count is steady.
    pub fn set_others(&mut self, others_m: &[DVec3]) {
        self.others_m.clear();
        self.others_m.extend_from_slice(others_m);
    }

    /// Arms the identity gate with the actor's solved body: `predicted[k]` is where the
    /// solve at `t_s` (daemon clock) put marker `k`, metres (the buffer's frame), and
    /// `states[k]` how that solve had the marker (held: not seen).
    pub fn set_body(&mut self, t_s: f64, predicted: &[DVec3], states: &[FillState]) {
        let n = self.body_m.len();
        if self.cfg.identity_gate_m <= 0.0 || predicted.len() != n || states.len() != n {
            return;
        }
        self.body_m.copy_from_slice(predicted);
        for (saw, st) in self.body_saw.iter_mut().zip(states) {
            *saw = *st != FillState::Held;
        }
        self.body_at_s = t_s;
        self.since_body = (0, 0);
    }

    /// Opens the identity gate and forgets the usual offsets (the body is not trusted:
    /// the actor left, or the whole of it moved at once).
    pub fn clear_body(&mut self) {
        self.body_at_s = f64::NAN;
        self.body_offset_m.iter_mut().for_each(|o| *o = None);
    }

    /// Samples that reached the identity gate since the body was last set, and those it
    /// dropped.
    pub fn since_body(&self) -> (u64, u64) {
        self.since_body
    }

    /// Whether the identity gate drops `s` (of marker `k`) as another performer's; counts
    /// it, and learns the marker's usual offset from the ones it lets through.
    fn identity_gated(&mut self, k: usize, s: &MarkerSample) -> bool {
        if self.body_at_s.is_nan() {
            return false;
        }
        self.since_body.0 += 1;
        let offset = s.position_m - self.body_m[k];
        let last_s = self.tracks[k]
            .newest()
            .map_or(f64::NEG_INFINITY, |(t, _)| t)
            .max(self.gated_at_s[k]);
        if s.time_s - last_s > self.cfg.predict_max_gap_secs {
            self.body_offset_m[k] = None;
        }
        let age_s = (s.time_s - self.body_at_s).max(0.0);
        let radius = self.cfg.identity_gate_m + self.cfg.gate_max_speed_m_s * age_s;
        let usual = self.body_offset_m[k];
        // Off the marker's usual place on the body (while it is followed), or nearer
        // another performer's marker than to where this body puts it.
        let own_m = (offset - usual.unwrap_or(DVec3::ZERO)).length();
        let off_usual = usual.is_some() && own_m > radius;
        let nearer_other = own_m > self.cfg.identity_gate_m
            && self
                .others_m
                .iter()
                .any(|q| (s.position_m - *q).length() < own_m);
        if off_usual || nearer_other {
            self.gated_at_s[k] = s.time_s;
            self.counters.identity_gated += 1;
            self.since_body.1 += 1;
            return true;
        }
        // A running mean over about ten samples, of those the body was fitted to.
        if self.body_saw[k] {
            self.body_offset_m[k] = Some(match self.body_offset_m[k] {
                Some(usual) => usual + (offset - usual) * 0.1,
                None => offset,
            });
        }
        false
    }

    /// Names the markers (layout order) in what the buffer logs.
    pub fn with_names(mut self, names: &[String]) -> Self {
        self.names = names.to_vec();
        self
    }

    pub fn len(&self) -> usize {
        self.tracks.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tracks.is_empty()
    }

    pub fn config(&self) -> &BufferConfig {
        &self.cfg
    }

    pub fn counters(&self) -> &BufferCounters {
        &self.counters
    }

    /// Forgets every sample (the reference layouts are kept).
    pub fn clear(&mut self) {
        for t in &mut self.tracks {
            t.clear();
        }
    }

    /// Takes one sample from an input.
    pub fn push(&mut self, s: &MarkerSample) {
        let k = s.marker as usize;
        if k >= self.tracks.len() || !s.time_s.is_finite() {
            self.counters.invalid += 1;
            return;
        }
        self.received_at_s = self.received_at_s.max(s.time_s);
        if s.source_time_s.is_finite() && s.time_s >= self.source_at_s {
            self.source_time_s = s.source_time_s;
            self.source_at_s = s.time_s;
        }
        let newest = self.tracks[k].newest();
        if let Some((t_last, _)) = newest {
            if s.time_s < t_last {
                self.counters.late += 1;
                return;
            }
        }
        if s.occluded || !s.position_m.is_finite() {
            self.counters.occluded += 1;
            let tr = &mut self.tracks[k];
            if newest.is_none_or(|(t_last, _)| s.time_s > t_last) {
                tr.occluded_at = Some(s.time_s);
            }
            return;
        }
        if !self.cfg.in_volume(s.position_m) {
            self.implausible(k, s.position_m);
            return;
        }
        if self.identity_gated(k, s) {
            return;
        }
        // Innovation gate (only while the marker's own prediction means something).
        if let Some((t_last, _)) = newest {
            let dt = s.time_s - t_last;
            if dt <= self.cfg.predict_max_gap_secs {
                let pred = self.tracks[k]
                    .predict(s.time_s, &self.cfg)
                    .expect("track has a sample");
                if (s.position_m - pred.position_m).length() > pred.gate_m {
                    self.reject(k, s);
                    return;
                }
            }
        }
        let tr = &mut self.tracks[k];
        if newest.is_some_and(|(t_last, _)| t_last == s.time_s) {
            // Same instant again: the newer report replaces the older.
            tr.pop();
        }
        tr.push(s.time_s, s.position_m);
        tr.occluded_at = None;
        tr.candidate = None;
        self.counters.accepted += 1;
    }

    /// Counts a sample outside the stage volume; logs the first of each marker.
    fn implausible(&mut self, k: usize, p: DVec3) {
        self.counters.implausible += 1;
        let tr = &mut self.tracks[k];
        if !tr.warned {
            tr.warned = true;
            let (lo, hi) = (self.cfg.volume_min_m, self.cfg.volume_max_m);
            match self.names.get(k) {
                Some(name) => tracing::warn!(
                    marker = %name, position_m = %p, volume_min_m = ?lo, volume_max_m = ?hi,
                    "a sample of marker {name} outside the stage volume was dropped (counted as implausible; this marker is not logged again)"
                ),
                None => tracing::warn!(
                    marker = k, position_m = %p, volume_min_m = ?lo, volume_max_m = ?hi,
                    "a sample of marker #{k} outside the stage volume was dropped (counted as implausible; this marker is not logged again)"
                ),
            }
        }
    }

    /// Handles a sample the gate rejected: counts it, checks for a label swap, and
    /// re-acquires the marker once enough rejected samples agree.
    fn reject(&mut self, k: usize, s: &MarkerSample) {
        self.counters.gate_rejected += 1;
        let swapped = (0..self.tracks.len()).any(|o| {
            o != k
                && self.tracks[o]
                    .predict(s.time_s, &self.cfg)
                    .is_some_and(|p| (p.position_m - s.position_m).length() <= p.gate_m)
        });
        if swapped {
            self.counters.label_swaps += 1;
        }
        let cfg = &self.cfg;
        let tr = &mut self.tracks[k];
        let run = match tr.candidate {
            Some((t, p, count))
                if (s.position_m - p).length() <= cfg.gate_m(s.time_s - t, false) =>
            {
                count + 1
            }
            _ => 1,
        };
        tr.candidate = Some((s.time_s, s.position_m, run));
        if run >= cfg.reacquire_samples {
            tr.clear();
            tr.push(s.time_s, s.position_m);
            self.counters.reacquired += 1;
            self.counters.accepted += 1;
        }
    }

    /// Fills `out` (resized to the layout once, then reused) with every marker at time `t`
    /// (daemon clock, seconds): positions, fill states and confidences.
    pub fn sample_at(&mut self, t: f64, out: &mut MarkerFrame) {
        let n = self.tracks.len();
        out.positions.resize(n, DVec3::ZERO);
        out.states.resize(n, FillState::Held);
        out.confidence.resize(n, 0.0);
        out.source_time_s = self.source_time_s;
        out.received_at_s = self.received_at_s;
        let cfg = &self.cfg;
        // Measured markers first: the rigid fill needs them.
        for (k, tr) in self.tracks.iter().enumerate() {
            let measured = match tr.newest() {
                Some((t_last, p)) => {
                    let fresh = t - t_last <= cfg.measured_window_secs;
                    let occluded = tr.occluded_at.is_some_and(|to| to <= t);
                    out.positions[k] = p;
                    fresh && !occluded
                }
                None => false,
            };
            out.states[k] = if measured {
                FillState::Measured
            } else {
                FillState::Held
            };
            out.confidence[k] = if measured { 1.0 } else { 0.0 };
        }
        // Reference layouts from segments seen whole, at one instant (a stale sample
        // would bend the layout by the distance moved since).
        for seg in &mut self.segments {
            let (mut t_min, mut t_max) = (f64::INFINITY, f64::NEG_INFINITY);
            let mut whole = seg.markers.len() >= 4;
            for &k in &seg.markers {
                whole &= out.states[k] == FillState::Measured;
                if let Some((t_k, _)) = self.tracks[k].newest() {
                    t_min = t_min.min(t_k);
                    t_max = t_max.max(t_k);
                }
            }
            if whole && t_max - t_min <= REFERENCE_SYNC_SECS {
                for (r, &k) in seg.reference.iter_mut().zip(&seg.markers) {
                    *r = out.positions[k];
                }
            }
        }
        for k in 0..n {
            if out.states[k] == FillState::Measured {
                continue;
            }
            let tr = &self.tracks[k];
            let gap = tr.newest().map_or(f64::INFINITY, |(t_last, _)| t - t_last);
            if gap > cfg.rigid_after_secs {
                if let Some(p) = rigid_fill(
                    &self.segments[self.segment_of[k]],
                    k,
                    out,
                    &mut self.scratch_ref,
                    &mut self.scratch_cur,
                ) {
                    out.positions[k] = p;
                    out.states[k] = FillState::RigidFilled;
                    out.confidence[k] = 1.0;
                    continue;
                }
            }
            if gap <= cfg.predict_max_gap_secs {
                if let Some(p) = tr.predict(t, cfg) {
                    out.positions[k] = p.position_m;
                    out.states[k] = FillState::Predicted;
                    out.confidence[k] = p.confidence;
                }
            }
        }
        // A fill that leaves the volume (a rigid layout or a prediction gone wrong) is
        // worth nothing to the solver: the marker is held at its last sample instead.
        for (k, tr) in self.tracks.iter().enumerate() {
            if out.states[k] != FillState::Held && !cfg.in_volume(out.positions[k]) {
                self.counters.implausible_fills += 1;
                out.states[k] = FillState::Held;
                out.positions[k] = tr.newest().map_or(DVec3::ZERO, |(_, p)| p);
                out.confidence[k] = 0.0;
            }
        }
        self.counters.frames += 1;
        for s in &out.states {
            self.counters.filled[*s as usize] += 1;
        }
    }
}

/// Samples of a segment taken at most this far apart count as one instant for its
/// reference layout, seconds.
const REFERENCE_SYNC_SECS: f64 = 1e-3;

/// Smallest spread of the visible markers, as a fraction of the squared largest distance
/// between them, below which they are too close to a line to carry a rotation.
const RIGID_MIN_PLANARITY: f64 = 0.05;

/// Position of marker `k` carried by the measured markers of its segment (Kabsch: the
/// rotation maximising `tr(Rᵀ Σ c rᵀ)` over centred current `c` and reference `r`
/// positions), or `None` when fewer than three are measured or they are nearly collinear.
fn rigid_fill(
    seg: &Segment,
    k: usize,
    frame: &MarkerFrame,
    refs: &mut Vec<DVec3>,
    curs: &mut Vec<DVec3>,
) -> Option<DVec3> {
    refs.clear();
    curs.clear();
    let mut target_ref = None;
    for (&m, &r) in seg.markers.iter().zip(&seg.reference) {
        if m == k {
            target_ref = Some(r);
        } else if frame.states[m] == FillState::Measured {
            refs.push(r);
            curs.push(frame.positions[m]);
        }
    }
    let target_ref = target_ref?;
    if curs.len() < 3 {
        return None;
    }
    let nf = curs.len() as f64;
    let rc = refs.iter().sum::<DVec3>() / nf;
    let cc = curs.iter().sum::<DVec3>() / nf;
    let (mut span2, mut area2) = (0.0f64, 0.0f64);
    for i in 0..curs.len() {
        for j in i + 1..curs.len() {
            span2 = span2.max((curs[j] - curs[i]).length_squared());
            for l in j + 1..curs.len() {
                area2 = area2.max((curs[j] - curs[i]).cross(curs[l] - curs[i]).length());
            }
        }
    }
    if area2 < RIGID_MIN_PLANARITY * span2 {
        return None;
    }
    let mut a = DMat3::ZERO;
    for (r, c) in refs.iter().zip(curs.iter()) {
        let (r, c) = (*r - rc, *c - cc);
        a += DMat3::from_cols(c * r.x, c * r.y, c * r.z);
    }
    let rot = rotation_of(&a);
    Some(cc + rot * (target_ref - rc))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;

    /// Four markers on one segment (a tetrahedron 10 cm across) and one alone.
    fn layout() -> (Vec<DVec3>, Vec<usize>) {
        let rest = vec![
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(0.1, 0.0, 0.0),
            DVec3::new(0.0, 0.1, 0.0),
            DVec3::new(0.0, 0.0, 0.1),
            DVec3::new(0.5, 0.5, 0.5),
        ];
        (rest, vec![0, 0, 0, 0, 1])
    }

    fn sample(k: u32, t: f64, p: DVec3) -> MarkerSample {
        MarkerSample {
            marker: k,
            time_s: t,
            source_time_s: t,
            position_m: p,
            occluded: false,
        }
    }

    /// The segment's rigid motion at time `t`: rotating about Y at 1 rad/s, moving along X
    /// at 0.3 m/s.
    fn motion(t: f64, p: DVec3) -> DVec3 {
        DQuat::from_rotation_y(t) * p + DVec3::new(0.3 * t, 0.0, 0.0)
    }

    #[test]
    fn measured_markers_come_back_as_pushed() {
        let (rest, joint) = layout();
        let mut b = MarkerBuffer::new(BufferConfig::default(), &rest, &joint);
        for (k, p) in rest.iter().enumerate() {
            b.push(&sample(k as u32, 1.0, *p));
        }
        let mut f = MarkerFrame::empty(0);
        b.sample_at(1.01, &mut f);
        assert_eq!(f.positions, rest);
        assert!(f.states.iter().all(|s| *s == FillState::Measured));
        assert_eq!(b.counters().accepted, 5);
        assert_eq!(b.counters().filled[FillState::Measured as usize], 5);
    }

    #[test]
    fn rigid_fill_is_exact_for_a_rigid_segment() {
        let (rest, joint) = layout();
        let mut b = MarkerBuffer::new(BufferConfig::default(), &rest, &joint);
        let mut f = MarkerFrame::empty(0);
        // 1 s at 100 Hz; marker 3 vanishes after 0.2 s.
        for i in 0..100 {
            let t = i as f64 * 0.01;
            for k in 0..4 {
                if k != 3 || t < 0.2 {
                    b.push(&sample(k, t, motion(t, rest[k as usize])));
                }
            }
            b.sample_at(t, &mut f);
        }
        assert_eq!(f.states[3], FillState::RigidFilled);
        // Exact up to the rotation extraction's tolerance (1e-10 rad on 0.1 m).
        let err = (f.positions[3] - motion(0.99, rest[3])).length();
        assert!(err < 1e-9, "rigid fill error {err} m");
    }

    #[test]
    fn prediction_follows_constant_velocity_then_coasts() {
        let (rest, joint) = layout();
        let cfg = BufferConfig::default();
        let mut b = MarkerBuffer::new(cfg.clone(), &rest, &joint);
        let v = DVec3::new(1.0, 0.0, 0.0);
        for i in 0..20 {
            let t = i as f64 * 0.01;
            b.push(&sample(4, t, rest[4] + v * t));
        }
        let mut f = MarkerFrame::empty(0);
        // A 50 ms gap: damped displacement τ(1 − e^(−gap/τ)) · v.
        b.sample_at(0.24, &mut f);
        assert_eq!(f.states[4], FillState::Predicted);
        let gap: f64 = 0.05;
        let tau = cfg.prediction_decay_secs;
        let expected = rest[4] + v * 0.19 + v * tau * (1.0 - (-gap / tau).exp());
        assert!((f.positions[4] - expected).length() < 1e-12);
        assert!((f.confidence[4] - (-gap / tau).exp()).abs() < 1e-12);
        // Past the longest predicted gap the marker is held at its last position.
        b.sample_at(0.19 + cfg.predict_max_gap_secs + 0.01, &mut f);
        assert_eq!(f.states[4], FillState::Held);
        assert!((f.positions[4] - (rest[4] + v * 0.19)).length() < 1e-12);
        assert_eq!(f.confidence[4], 0.0);
    }

    #[test]
    fn occlusion_flags_and_nan_end_measurement_at_once() {
        let (rest, joint) = layout();
        let mut b = MarkerBuffer::new(BufferConfig::default(), &rest, &joint);
        b.push(&sample(4, 0.0, rest[4]));
        b.push(&MarkerSample {
            occluded: true,
            ..sample(4, 0.008, rest[4])
        });
        b.push(&sample(0, 0.008, DVec3::NAN));
        let mut f = MarkerFrame::empty(0);
        b.sample_at(0.01, &mut f);
        assert_eq!(f.states[4], FillState::Predicted);
        assert_eq!(b.counters().occluded, 2);
        assert_eq!(b.counters().accepted, 1);
    }

    /// A marker already moving fast when its track starts (a take or a stream joined
    /// mid-run, a marker back from occlusion) is followed from its first sample: the gate
    /// allows for the velocity it cannot know yet. Without the allowance (the speed set
    /// to 1 mm/s) the same samples are rejected in runs and re-acquired from rest.
    #[test]
    fn a_marker_moving_from_its_first_sample_is_followed() {
        let (rest, joint) = layout();
        // A runner's foot: 5.6 m/s, 47 mm a frame at 120 Hz (the soldier's run).
        let v = DVec3::new(5.6, 0.0, 0.0);
        let rate_hz = 120.0;
        let run = |cfg: BufferConfig| {
            let mut b = MarkerBuffer::new(cfg, &rest, &joint);
            for i in 0..24 {
                let t = i as f64 / rate_hz;
                b.push(&sample(4, t, rest[4] + v * t));
            }
            b.counters().gate_rejected
        };
        assert_eq!(run(BufferConfig::default()), 0);
        let blind = BufferConfig {
            gate_max_speed_m_s: 1e-3,
            ..BufferConfig::default()
        };
        assert!(
            run(blind) >= 8,
            "the check would pass without the allowance"
        );
        // The allowance is for speed, not for jumps: 20 cm at the second sample (24 m/s)
        // is still rejected.
        let mut b = MarkerBuffer::new(BufferConfig::default(), &rest, &joint);
        b.push(&sample(4, 0.0, rest[4]));
        b.push(&sample(
            4,
            1.0 / rate_hz,
            rest[4] + DVec3::new(0.2, 0.0, 0.0),
        ));
        assert_eq!(b.counters().gate_rejected, 1);
    }

    #[test]
    fn gate_rejects_jumps_counts_swaps_and_reacquires() {
        let (rest, joint) = layout();
        let mut b = MarkerBuffer::new(BufferConfig::default(), &rest, &joint);
        for i in 0..10 {
            let t = i as f64 * 0.01;
            b.push(&sample(0, t, rest[0]));
            b.push(&sample(1, t, rest[1]));
        }
        // Labels 0 and 1 swap for one frame: both rejected, both counted as swaps.
        b.push(&sample(0, 0.1, rest[1]));
        b.push(&sample(1, 0.1, rest[0]));
        assert_eq!(b.counters().gate_rejected, 2);
        assert_eq!(b.counters().label_swaps, 2);
        // Marker 0 really moved 30 cm: rejected twice, re-acquired on the third sample.
        let far = rest[0] + DVec3::new(0.3, 0.0, 0.0);
        b.push(&sample(0, 0.11, far));
        b.push(&sample(0, 0.12, far));
        let mut f = MarkerFrame::empty(0);
        b.sample_at(0.12, &mut f);
        assert_eq!(f.positions[0], rest[0]);
        b.push(&sample(0, 0.13, far));
        b.sample_at(0.13, &mut f);
        assert_eq!(f.positions[0], far);
        assert_eq!(f.states[0], FillState::Measured);
        assert_eq!(b.counters().reacquired, 1);
    }

    #[test]
    fn bad_samples_cost_only_themselves() {
        let (rest, joint) = layout();
        let mut b = MarkerBuffer::new(BufferConfig::default(), &rest, &joint);
        b.push(&sample(99, 0.0, rest[0]));
        b.push(&sample(0, f64::NAN, rest[0]));
        b.push(&sample(0, 1.0, rest[0]));
        b.push(&sample(0, 0.5, rest[1]));
        assert_eq!(b.counters().invalid, 2);
        assert_eq!(b.counters().late, 1);
        assert_eq!(b.counters().accepted, 1);
    }

    #[test]
    fn samples_outside_the_volume_are_dropped_counted_and_never_reacquired() {
        let (rest, joint) = layout();
        let mut b = MarkerBuffer::new(BufferConfig::default(), &rest, &joint);
        for i in 0..10 {
            b.push(&sample(0, i as f64 * 0.01, rest[0]));
        }
        // Three agreeing samples at 1e30 m (what re-acquires a marker inside the volume),
        // and one just past a corner (x = 20.001 m, the default bound being 20 m).
        let far = DVec3::splat(1e30);
        for i in 10..13 {
            b.push(&sample(0, i as f64 * 0.01, far));
        }
        b.push(&sample(0, 0.13, DVec3::new(20.001, 0.0, 0.0)));
        let c = *b.counters();
        assert_eq!((c.implausible, c.gate_rejected, c.reacquired), (4, 0, 0));
        assert_eq!(c.accepted, 10);
        let mut f = MarkerFrame::empty(0);
        b.sample_at(0.13, &mut f);
        // The marker coasts on its own history (still, at rest).
        assert_eq!(f.states[0], FillState::Predicted);
        assert_eq!(f.positions[0], rest[0]);
        // A real sample is taken again at once: the implausible ones left no trace.
        b.push(&sample(0, 0.14, rest[0]));
        assert_eq!(b.counters().accepted, 11);
        // On the volume's boundary is inside.
        let edge = BufferConfig::default();
        assert!(edge.in_volume(DVec3::new(20.0, 10.0, -20.0)));
        assert!(!edge.in_volume(DVec3::new(0.0, -5.000_001, 0.0)));
        assert!(!edge.in_volume(DVec3::new(f64::INFINITY, 0.0, 0.0)));
    }

    #[test]
    fn an_implausible_marker_is_logged_once_with_its_name_and_value() {
        let (rest, joint) = layout();
        let names: Vec<String> = (0..5).map(|k| format!("M{k}")).collect();
        let mut b = MarkerBuffer::new(BufferConfig::default(), &rest, &joint).with_names(&names);
        let ((), text) = crate::runtime::logs::captured(|| {
            for i in 0..100 {
                b.push(&sample(0, i as f64 * 0.01, DVec3::splat(1e30)));
            }
            b.push(&sample(3, 0.0, DVec3::new(0.0, 50.0, 0.0)));
            b.push(&sample(3, 0.01, DVec3::new(0.0, 60.0, 0.0)));
        });
        assert_eq!(b.counters().implausible, 102);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 2, "one line per marker:\n{text}");
        assert!(lines[0].contains("WARN"), "{text}");
        assert!(lines[0].contains("marker M0"), "{text}");
        assert!(
            lines[0].contains("1000000000000000000000000000000"),
            "{text}"
        );
        assert!(
            lines[1].contains("marker M3") && lines[1].contains("50"),
            "{text}"
        );
    }

    #[test]
    fn a_frame_carries_the_newest_samples_source_time_not_the_largest() {
        let (rest, joint) = layout();
        let mut b = MarkerBuffer::new(BufferConfig::default(), &rest, &joint);
        let mut f = MarkerFrame::empty(0);
        let at = |t: f64, source: f64| MarkerSample {
            source_time_s: source,
            ..sample(4, t, rest[4])
        };
        b.push(&at(0.00, 100.00));
        b.sample_at(0.00, &mut f);
        assert_eq!(f.source_time_s, 100.00);
        // One sample with a far-future source time (an OSC time tag of 0xFFFFFFFF s):
        // its frame shows it, the next frames do not.
        b.push(&at(0.01, 2_085_978_495.0));
        b.sample_at(0.01, &mut f);
        assert_eq!(f.source_time_s, 2_085_978_495.0);
        b.push(&at(0.02, 100.02));
        b.sample_at(0.02, &mut f);
        assert_eq!(f.source_time_s, 100.02);
        // Non-finite source times are ignored, and a sample received before the newest
        // does not win.
        b.push(&at(0.03, f64::NAN));
        b.push(&MarkerSample {
            marker: 0,
            ..at(0.015, 7.0)
        });
        b.sample_at(0.03, &mut f);
        assert_eq!(f.source_time_s, 100.02);
    }

    #[test]
    fn a_burst_of_samples_microseconds_apart_does_not_send_the_prediction_flying() {
        let (rest, joint) = layout();
        let mut b = MarkerBuffer::new(BufferConfig::default(), &rest, &joint);
        // Marker 4 moves at 1 m/s along X, sent at 120 Hz; the network stalls for 100 ms
        // and then delivers the 12 queued packets within 120 µs (10 µs apart, as a
        // receive clock stamps them); then the marker is occluded.
        let v = DVec3::X;
        for i in 0..12 {
            let t = i as f64 / 120.0;
            b.push(&sample(4, t, rest[4] + v * t));
        }
        let t_stall = 11.0 / 120.0 + 0.1;
        for i in 12..24 {
            let sent = i as f64 / 120.0;
            b.push(&sample(
                4,
                t_stall + (i - 12) as f64 * 1e-5,
                rest[4] + v * sent,
            ));
        }
        assert_eq!(b.counters().gate_rejected, 0);
        let last = rest[4] + v * (23.0 / 120.0);
        // 50 ms later: the burst spans 110 µs, less than half the 50 ms velocity window,
        // so no velocity comes of it and the marker coasts where it was last seen. (Before:
        // a slope of ~0.09 m over 110 µs, ~800 m/s, predicted ~30 m away.)
        let mut f = MarkerFrame::empty(0);
        b.sample_at(t_stall + 0.05, &mut f);
        assert_eq!(f.states[4], FillState::Predicted);
        assert_eq!(f.positions[4], last);
    }

    #[test]
    fn a_fill_outside_the_volume_is_held_and_counted() {
        let (rest, joint) = layout();
        let cfg = BufferConfig {
            volume_max_m: [0.52, 10.0, 20.0],
            ..BufferConfig::default()
        };
        let mut b = MarkerBuffer::new(cfg, &rest, &joint);
        // Marker 4 moves at 1 m/s along X from x = 0.3 to 0.49 m, 3 cm inside the volume;
        // 30 ms later its prediction is 0.49 + 0.1 · (1 − e^−0.3) = 0.516 m, inside; 50 ms
        // later 0.49 + 0.1 · (1 − e^−0.5) = 0.529 m, outside.
        let v = DVec3::X;
        let start = DVec3::new(0.3, 0.5, 0.5);
        for i in 0..20 {
            let t = i as f64 * 0.01;
            b.push(&sample(4, t, start + v * t));
        }
        let mut f = MarkerFrame::empty(0);
        b.sample_at(0.22, &mut f);
        assert_eq!(f.states[4], FillState::Predicted, "30 ms on: still inside");
        b.sample_at(0.24, &mut f);
        assert_eq!(f.states[4], FillState::Held);
        assert_eq!(f.positions[4], start + v * 0.19);
        assert_eq!(f.confidence[4], 0.0);
        assert_eq!(b.counters().implausible_fills, 1);
    }

    #[test]
    fn volume_problems_are_reported_by_key() {
        let cfg = BufferConfig {
            volume_min_m: [0.0, f64::NAN, 0.0],
            ..BufferConfig::default()
        };
        assert_eq!(cfg.problems().len(), 1, "{:?}", cfg.problems());
        assert_eq!(cfg.problems()[0].0, "volume_min_m");
        let cfg = BufferConfig {
            volume_min_m: [1.0, 0.0, 3.0],
            volume_max_m: [1.0, 1.0, 2.0],
            ..BufferConfig::default()
        };
        let p = cfg.problems();
        assert_eq!(p.len(), 1, "{p:?}");
        assert_eq!(p[0].0, "volume_max_m");
        assert!(p[0].1.contains("not on x, z"), "{}", p[0].1);
    }

    #[test]
    fn config_problems_are_all_reported() {
        let cfg = BufferConfig {
            measured_window_secs: 0.0,
            history_len: 1,
            gate_floor_m: f64::NAN,
            ..BufferConfig::default()
        };
        let p = cfg.problems();
        assert_eq!(p.len(), 3, "{p:?}");
        assert!(BufferConfig::default().problems().is_empty());
    }
}
