//! A recording through the live pipeline off line: the fixed-rate loop of a stage
//! (buffer, gap filling, solve, full mesh, publish) ticked on a manual clock at the
//! stage's rate, each tick given its live deadline, as fast as the solver goes. It tells
//! a user how well a marker layout carries a take (labels fed, samples held, misfit)
//! and what the character does (inverted tets, limits, bone lengths, frame time),
//! without waiting the take's length; `rigless calibrate --check` and the calibration
//! benchmark use it. Without deadlines it exports a take: every frame's full mesh to a
//! point cache, or the fitted skeleton to BVH ([`export_take`], `rigless replay
//! --export`).

use super::pipeline::{BodyTally, Pipeline, TickReport};
use crate::markers::buffer::{BufferConfig, MarkerBuffer};
use crate::markers::index::{LabelMap, MarkerIndex};
use crate::markers::{FillState, MarkerSample};
use crate::output::export::{BvhWriter, ExportFormat, GlbWriter, Pc2Writer};
use crate::output::skin_fit::SkinFit;
use crate::replay::bvh::BvhSkeleton;
use crate::replay::recording::Recording;
use crate::rig::bind::Rig;
use crate::solve::arap::StopReason;
use crate::solve::frame::{SolveReport, Solver, SolverParams};
use glam::DVec3;
use std::ops::ControlFlow;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How to play the recording.
#[derive(Clone, Copy, Debug)]
pub struct OfflineOptions {
    /// The loop's rate, Hz; each tick's solve gets `1 / rate_hz` (the live budget).
    pub rate_hz: f64,
    /// Character metres per recording metre (a calibration's scale).
    pub marker_scale: f64,
    /// Whether each tick's solve stops at its live deadline (`1 / rate_hz` after it
    /// starts), as live; else it runs until it converges or its iteration cap (an
    /// export, which has no clock to keep).
    pub deadline: bool,
    /// Fit the skeleton's posture alone (a BVH export, which reads nothing
    /// else): the ticks' vertices are not written (zero), and the misfit is the
    /// skeleton's.
    pub posture_only: bool,
    /// Gate samples by the solved body, as an actor of a stage of several is
    /// ([`Pipeline::with_identity_gate`]).
    pub identity_gate: bool,
}

impl Default for OfflineOptions {
    fn default() -> Self {
        Self {
            rate_hz: 120.0,
            marker_scale: 1.0,
            deadline: true,
            posture_only: false,
            identity_gate: false,
        }
    }
}

/// What the replay did.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct OfflineReport {
    /// The recording's labels that feed a marker, and the markers no label feeds.
    pub labels_fed: usize,
    pub markers_unfed: usize,
    /// What the report says of other subjects' labels, ignored
    /// ([`crate::markers::index::LabelMap::others_text`]), when the take has any.
    pub other_subjects: Option<String>,
    pub frames: usize,
    /// Share of marker samples (markers fed by a label, over the ticks the recording
    /// covers) that were held (no measurement and no fill), 0 to 1.
    pub held_share: f64,
    /// Samples the identity gate dropped ([`OfflineOptions::identity_gate`]).
    pub identity_gated: u64,
    /// Misfit (distance from each marker to its bound point on the solved mesh) over
    /// the ticks with a marker in view: RMS over ticks of each tick's RMS, and the
    /// largest, character millimetres.
    pub residual_mm_rms: f64,
    pub residual_mm_max: f64,
    /// Largest mean relative bone-length error of a tick.
    pub bone_length_error_max: f64,
    /// Largest excess of the solved posture over a joint limit, degrees.
    pub joint_limit_violation_deg_max: f64,
    /// Most control tets inverted in one tick (ARAP only; 0 for the harmonic method).
    pub inverted_tets_max: usize,
    /// Ticks stopped by their deadline, and by the solver's iteration cap.
    pub deadline_stops: usize,
    pub iteration_cap_stops: usize,
    /// ARAP iterations per tick, mean and largest (0 for the harmonic method).
    pub iterations_mean: f64,
    pub iterations_max: usize,
    /// Whole tick (drain, buffer, solve, full mesh, publish), ms.
    pub frame_ms_p50: f64,
    pub frame_ms_p99: f64,
    pub frame_ms_max: f64,
    /// The solved mesh's lowest vertex above the take's floor (its `y = 0`, the capture
    /// volume's ground as optical systems set it), character metres, over the ticks with
    /// a marker in view: in the median tick (to the millimetre) and the lowest; `None`
    /// when the posture alone was fitted.
    pub lowest_vertex_m_median: Option<f64>,
    pub lowest_vertex_m_min: Option<f64>,
    /// The character's limbs (arms and legs, each an upper arm or upper leg joint by
    /// its name's role and the joints below it), and the share of ticks with a marker in
    /// view in which every limb had one measured or filled (not held); `None` without
    /// limbs.
    pub limbs: usize,
    pub all_limbs_driven_share: Option<f64>,
}

/// Plays `rec` through a pipeline over `rig` (its markers matched to the labels as the
/// replay input matches them) at `opts.rate_hz`, from the recording's first frame to its
/// last; `None` when no label feeds a marker.
pub fn replay_offline(
    rig: Arc<Rig>,
    params: SolverParams,
    rec: &Recording,
    opts: OfflineOptions,
) -> Result<Option<OfflineReport>, crate::solve::harmonic::HarmonicError> {
    replay_offline_with(rig, params, rec, opts, &mut |_| ControlFlow::Continue(()))
}

/// One tick of an offline replay, as [`replay_offline_with`] shows it.
pub struct OfflineTick<'a> {
    /// The tick (from 0) and the ticks in all.
    pub index: usize,
    pub of: usize,
    /// The full mesh after the tick (metres, the character's frame and vertex order).
    pub vertices: &'a [DVec3],
    /// The fitted posture after the tick: every joint's world rotation from rest and
    /// world position (metres).
    pub joint_rot: &'a [glam::DQuat],
    pub joint_pos: &'a [DVec3],
}

/// [`replay_offline`], showing `on_tick` every tick's mesh; a `Break` stops the replay
/// there (the report then covers the ticks played).
pub fn replay_offline_with(
    rig: Arc<Rig>,
    params: SolverParams,
    rec: &Recording,
    opts: OfflineOptions,
    on_tick: &mut dyn FnMut(OfflineTick<'_>) -> ControlFlow<()>,
) -> Result<Option<OfflineReport>, crate::solve::harmonic::HarmonicError> {
    let span = Span {
        warm_from: 0,
        from: 0,
        to: tick_count(rec, opts.rate_hz),
    };
    Ok(play(rig, params, rec, opts, span, on_tick)?.map(Tally::finish))
}

/// Ticks of `rec` at `rate_hz`: from its first frame's time to its last's.
fn tick_count(rec: &Recording, rate_hz: f64) -> usize {
    (rec.duration_secs() * rate_hz).floor() as usize + 1
}

/// The ticks a [`play`] goes through, in three runs: `..warm_from` only feed the marker
/// buffer (its gap filling and gating then stand as they would live); `warm_from..from`
/// are solved, neither shown nor counted (the solver's warm start settling); `from..to`
/// are solved, shown and counted.
#[derive(Clone, Copy, Debug)]
struct Span {
    warm_from: usize,
    from: usize,
    to: usize,
}

/// The running figures of a replay's counted ticks, which the parts of an export add up.
#[derive(Debug, Default)]
struct Tally {
    /// Maxima and counts so far (`frames` = ticks counted).
    rep: OfflineReport,
    held: usize,
    fed_samples: usize,
    sq_sum: f64,
    in_view: usize,
    times_ms: Vec<f64>,
    /// Limbs driven and the lowest vertex over the counted ticks with a marker in view
    /// (the pipeline's own tally).
    body: Option<BodyTally>,
}

impl Tally {
    /// Adds a later part's ticks.
    fn merge(&mut self, o: Tally) {
        let (r, q) = (&mut self.rep, &o.rep);
        r.frames += q.frames;
        r.residual_mm_max = r.residual_mm_max.max(q.residual_mm_max);
        r.bone_length_error_max = r.bone_length_error_max.max(q.bone_length_error_max);
        r.joint_limit_violation_deg_max = r
            .joint_limit_violation_deg_max
            .max(q.joint_limit_violation_deg_max);
        r.inverted_tets_max = r.inverted_tets_max.max(q.inverted_tets_max);
        r.deadline_stops += q.deadline_stops;
        r.identity_gated += q.identity_gated;
        r.iteration_cap_stops += q.iteration_cap_stops;
        r.iterations_mean += q.iterations_mean;
        r.iterations_max = r.iterations_max.max(q.iterations_max);
        self.held += o.held;
        self.fed_samples += o.fed_samples;
        self.sq_sum += o.sq_sum;
        self.in_view += o.in_view;
        self.times_ms.extend(o.times_ms);
        match (&mut self.body, o.body) {
            (Some(b), Some(o)) => b.merge(&o),
            (b @ None, o) => *b = o,
            (Some(_), None) => {}
        }
    }

    fn finish(mut self) -> OfflineReport {
        let mut rep = self.rep;
        rep.held_share = self.held as f64 / self.fed_samples.max(1) as f64;
        rep.iterations_mean /= rep.frames.max(1) as f64;
        rep.residual_mm_rms = (self.sq_sum / self.in_view.max(1) as f64).sqrt();
        self.times_ms.sort_by(f64::total_cmp);
        let t = &self.times_ms;
        let at = |q: f64| {
            t.get(((t.len().max(1) - 1) as f64 * q).round() as usize)
                .copied()
                .unwrap_or(0.0)
        };
        (rep.frame_ms_p50, rep.frame_ms_p99, rep.frame_ms_max) = (at(0.5), at(0.99), at(1.0));
        if let Some(b) = &self.body {
            (
                rep.lowest_vertex_m_median,
                rep.lowest_vertex_m_min,
                rep.limbs,
                rep.all_limbs_driven_share,
            ) = b.figures();
        }
        rep
    }
}

/// Plays the ticks of `span` ([`replay_offline_with`] for a part of the take); `None`
/// when no label feeds a marker.
fn play(
    rig: Arc<Rig>,
    params: SolverParams,
    rec: &Recording,
    opts: OfflineOptions,
    span: Span,
    on_tick: &mut dyn FnMut(OfflineTick<'_>) -> ControlFlow<()>,
) -> Result<Option<Tally>, crate::solve::harmonic::HarmonicError> {
    let map = LabelMap::new(&rec.labels, &MarkerIndex::fixed(&rig.marker_names));
    let fed: Vec<(usize, u32)> = map
        .marker_of_label
        .iter()
        .enumerate()
        .filter_map(|(l, m)| m.map(|m| (l, m)))
        .collect();
    if fed.is_empty() || rec.frames.is_empty() || opts.rate_hz.is_nan() || opts.rate_hz <= 0.0 {
        return Ok(None);
    }
    let solver = Solver::try_new(Arc::clone(&rig), params)?;
    let buffer = MarkerBuffer::new(BufferConfig::default(), &rig.marker_rest, &rig.marker_joint)
        .with_names(&rig.marker_names);
    // Room for every sample of one tick's frames (a recording faster than the loop sends
    // several frames per tick).
    let per_tick = (rec.rate_hz / opts.rate_hz).ceil().max(1.0) as usize + 1;
    let (tx, rx) = crossbeam_channel::bounded(fed.len() * per_tick);
    let mut pipeline =
        Pipeline::new(solver, buffer, rx, Vec::new()).with_marker_scale(opts.marker_scale);
    if opts.posture_only {
        pipeline = pipeline.posture_only();
    }
    if opts.identity_gate {
        pipeline = pipeline.with_identity_gate();
    }
    let fed_markers: Vec<usize> = {
        let mut m: Vec<usize> = fed.iter().map(|f| f.1 as usize).collect();
        m.sort_unstable();
        m.dedup();
        m
    };
    let period_s = 1.0 / opts.rate_hz;
    let ticks = tick_count(rec, opts.rate_hz).min(span.to);
    let mut tally = Tally {
        rep: OfflineReport {
            labels_fed: fed.len(),
            markers_unfed: map.unfed_markers.len(),
            other_subjects: map.others_text(),
            ..OfflineReport::default()
        },
        body: None,
        times_ms: Vec::with_capacity(ticks.saturating_sub(span.from)),
        ..Tally::default()
    };
    let mut next = 0;
    for tick in 0..ticks {
        let t_s = tick as f64 * period_s;
        while next < rec.frames.len() && next as f64 / rec.rate_hz <= t_s + 1e-9 {
            let source_time_s = next as f64 / rec.rate_hz;
            for &(l, m) in &fed {
                let p = rec.frames[next][l];
                let sample = MarkerSample {
                    marker: m,
                    time_s: source_time_s,
                    source_time_s,
                    position_m: p,
                    occluded: !p.is_finite(),
                };
                // Sized for a tick's frames, drained every tick: never full.
                if tx.try_send(sample).is_err() {
                    break;
                }
            }
            next += 1;
        }
        if tick < span.warm_from {
            pipeline.feed(t_s);
            continue;
        }
        // Without a deadline the solve stops on convergence or its iteration cap; the
        // hour is only an Instant far enough away.
        let budget = if opts.deadline {
            Duration::from_secs_f64(period_s)
        } else {
            Duration::from_secs(3600)
        };
        if tick == span.from {
            // The body's figures cover the counted ticks alone.
            pipeline.clear_body();
        }
        let r = pipeline.tick(t_s, Instant::now() + budget, &|| t_s);
        if tick < span.from {
            continue;
        }
        count(&mut tally, &pipeline, &fed_markers, &r);
        let (joint_rot, joint_pos) = pipeline.joint_world();
        let shown = OfflineTick {
            index: tick,
            of: ticks,
            vertices: pipeline.vertices(),
            joint_rot,
            joint_pos,
        };
        if on_tick(shown).is_break() {
            break;
        }
    }
    tally.body = Some(pipeline.body().clone());
    tally.rep.identity_gated = pipeline.buffer().counters().identity_gated;
    Ok(Some(tally))
}

/// Counts one tick into the tally.
fn count(tally: &mut Tally, pipeline: &Pipeline, fed_markers: &[usize], r: &TickReport) {
    let rep = &mut tally.rep;
    rep.frames += 1;
    tally.times_ms.push(r.frame_ms);
    let states = &pipeline.markers().states;
    tally.held += fed_markers
        .iter()
        .filter(|&&k| states[k] == FillState::Held)
        .count();
    tally.fed_samples += fed_markers.len();
    take(rep, &r.solve);
    if fed_markers.iter().any(|&k| states[k] != FillState::Held)
        && r.solve.marker_residual_rms_mm.is_finite()
    {
        tally.sq_sum += r.solve.marker_residual_rms_mm.powi(2);
        tally.in_view += 1;
        rep.residual_mm_max = rep.residual_mm_max.max(r.solve.marker_residual_max_mm);
    }
    if let Some(cp) = pipeline.control_positions() {
        let inverted = pipeline.rig().control.inverted_tets(cp);
        rep.inverted_tets_max = rep.inverted_tets_max.max(inverted);
    }
}

/// One tick's solver figures into the running maxima.
fn take(rep: &mut OfflineReport, s: &SolveReport) {
    rep.deadline_stops += (s.stop == StopReason::Deadline) as usize;
    rep.iteration_cap_stops += (s.stop == StopReason::IterationCap) as usize;
    // The sum until `Tally::finish` divides it.
    rep.iterations_mean += s.iterations as f64;
    rep.iterations_max = rep.iterations_max.max(s.iterations);
    rep.bone_length_error_max = rep.bone_length_error_max.max(s.bone_length_error);
    rep.joint_limit_violation_deg_max = rep
        .joint_limit_violation_deg_max
        .max(s.joint_limit_violation_deg);
}

/// Why a take could not be exported.
#[derive(Debug, thiserror::Error)]
pub enum OfflineExportError {
    #[error(transparent)]
    Solver(#[from] crate::solve::harmonic::HarmonicError),
    #[error(transparent)]
    Export(#[from] crate::output::export::ExportError),
    #[error("{take}: none of its labels is a marker of the character (calibrate the take onto it first)")]
    NoLabels { take: String },
    #[error("{path}: the format follows the extension: .pc2 (a point cache of the full mesh), .bvh (the fitted skeleton) or .glb (the mesh skinned to it, animated)")]
    Format { path: String },
}

/// What [`export_take`] wrote.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ExportSummary {
    /// Frames written (the take's), at `rate_hz`.
    pub frames: usize,
    pub rate_hz: f64,
    /// Vertices (a point cache) or joints (a BVH, a glTF) per frame.
    pub points: usize,
    /// Parts of the take solved at once ([`ExportOptions::threads`]).
    pub parts: usize,
    /// Whether only the skeleton's posture was fitted (a BVH export): then the
    /// replay's misfit is the fitted skeleton's, and no ARAP iteration is counted.
    pub posture_only: bool,
    /// The replay's figures over the take.
    pub replay: OfflineReport,
}

/// How [`export_take`] solves a take.
#[derive(Clone, Copy, Debug)]
pub struct ExportOptions {
    /// Character metres per recording metre (a calibration's scale).
    pub marker_scale: f64,
    /// Parts of the take solved at once, one thread each; 1 solves the take in one pass,
    /// frame after frame, exactly as the live loop would; 0 takes one per core.
    pub threads: usize,
}

impl Default for ExportOptions {
    fn default() -> Self {
        Self {
            marker_scale: 1.0,
            threads: 0,
        }
    }
}

/// Solved ticks before a part's first frame that warm its solver up, seconds of the
/// take: a part that starts mid-take starts from the rest pose, and its first frames
/// converge from there to where the one-pass solve's warm start was. The marker buffer
/// needs no such margin: a part feeds it every sample from the take's start.
/// `EXPORT_WARM_UP_SECS` is set by the measured seam error (docs/benchmarks.md, Export).
pub const EXPORT_WARM_UP_SECS: f64 = 0.25;

/// Solved frames a glTF's skin is fitted to, at most: spread evenly over the take (each
/// part takes its own and the fits add up), they cost well under a millisecond each.
const SKIN_FIT_FRAMES: usize = 240;

/// A part is at least this many times its warm-up long, else the take has fewer parts.
const MIN_PART_WARM_UPS: usize = 4;

/// The first frame of each of `parts` parts of a take of `frames` frames, then
/// `frames`: every part after the first also solves `warm` warm-up frames, so the first
/// is that much longer and all of them take the same time.
pub fn part_bounds(frames: usize, parts: usize, warm: usize) -> Vec<usize> {
    let parts = parts.max(1);
    // Each part's work, warm-ups included: `share` frames.
    let share = (frames + warm * (parts - 1)) / parts;
    let mut bounds: Vec<usize> = Vec::with_capacity(parts + 1);
    for i in 0..parts {
        let b = (i * share)
            .saturating_sub(i.saturating_sub(1) * warm)
            .min(frames);
        // Never before the previous bound (parts shorter than their warm-up).
        bounds.push(b.max(bounds.last().copied().unwrap_or(0)));
    }
    bounds.push(frames);
    bounds
}

/// Where a part of a take goes.
enum PartOut {
    Pc2(Pc2Writer),
    Bvh(BvhWriter),
    /// The glTF file, and the take frames between the solved meshes its skin is fitted
    /// to.
    Glb(Box<GlbWriter>, usize),
    /// A later part of a skeleton export, kept until the parts before it are written:
    /// each frame's joint rotations and positions, `joints` per frame; for a glTF, its
    /// share of the skin fit and the take frames between the meshes it takes.
    Posture {
        joints: usize,
        rot: Vec<glam::DQuat>,
        pos: Vec<DVec3>,
        skin: Option<(Box<SkinFit>, usize)>,
    },
}

impl PartOut {
    fn push(&mut self, t: &OfflineTick<'_>) -> Result<(), crate::output::export::ExportError> {
        match self {
            PartOut::Pc2(w) => w.push(t.vertices),
            PartOut::Bvh(w) => w.push(t.joint_rot, t.joint_pos),
            PartOut::Glb(w, every) => {
                w.push(t.joint_rot, t.joint_pos);
                if t.index.is_multiple_of(*every) {
                    w.fit_skin(t.joint_rot, t.joint_pos, t.vertices);
                }
                Ok(())
            }
            PartOut::Posture { rot, pos, skin, .. } => {
                rot.extend_from_slice(t.joint_rot);
                pos.extend_from_slice(t.joint_pos);
                if let Some((fit, every)) = skin {
                    if t.index.is_multiple_of(*every) {
                        fit.add(t.joint_rot, t.joint_pos, t.vertices);
                    }
                }
                Ok(())
            }
        }
    }
}

/// Solves every frame of `rec` at its own rate, without deadlines, and writes each to
/// `path` in the format of its extension ([`ExportFormat`]): the full mesh (PC2, in the
/// character's vertex order, metres, Y up) or the fitted skeleton's posture (BVH, in
/// centimetres; glTF, the mesh skinned to it); one sample per take frame. With
/// `opts.threads` above 1 the take is cut into parts solved at once, each warmed up over
/// the [`EXPORT_WARM_UP_SECS`] before it. `progress` hears frames done and in all.
pub fn export_take(
    rig: Arc<Rig>,
    params: SolverParams,
    rec: &Recording,
    opts: ExportOptions,
    path: &std::path::Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ExportSummary, OfflineExportError> {
    let format = ExportFormat::of(path).ok_or_else(|| OfflineExportError::Format {
        path: path.display().to_string(),
    })?;
    let frames = rec.frames.len();
    let map = LabelMap::new(&rec.labels, &MarkerIndex::fixed(&rig.marker_names));
    if frames == 0 || map.marker_of_label.iter().all(Option::is_none) {
        return Err(OfflineExportError::NoLabels {
            take: rec.name.clone(),
        });
    }
    let threads = match opts.threads {
        0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
        n => n,
    };
    let warm = (EXPORT_WARM_UP_SECS * rec.rate_hz).ceil() as usize;
    let parts = threads
        .min(frames / (warm * MIN_PART_WARM_UPS).max(1))
        .max(1);
    let bounds = part_bounds(frames, parts, warm);
    // Written beside `path` and renamed onto it when complete: a failed or killed
    // export leaves what was there.
    let staged = crate::output::export::StagedPath::new(path)?;
    let outs = create_outputs(
        &rig,
        format,
        staged.temp(),
        frames,
        1.0 / rec.rate_hz,
        &bounds,
    )?;
    let play_opts = OfflineOptions {
        rate_hz: rec.rate_hz,
        marker_scale: opts.marker_scale,
        deadline: false,
        // A BVH reads the posture alone, which the skeleton step fits before (and
        // without) the meshes; a glTF's skin is fitted to the solved meshes.
        posture_only: format == ExportFormat::Bvh,
        identity_gate: false,
    };
    let solved = solve_parts(&rig, params, rec, play_opts, &bounds, warm, outs, progress);
    let (tally, file) = solved?;
    finish_file(file)?;
    if parts > 1 {
        // The polling above may have missed the last parts' final frames.
        progress(frames, frames);
    }
    let Some(tally) = tally else {
        return Err(OfflineExportError::NoLabels {
            take: rec.name.clone(),
        });
    };
    staged.commit()?;
    Ok(ExportSummary {
        frames,
        rate_hz: rec.rate_hz,
        points: match format {
            ExportFormat::Pc2 => rig.mesh_rest.len(),
            ExportFormat::Bvh | ExportFormat::Glb => rig.skeleton.joints.len(),
        },
        parts,
        posture_only: play_opts.posture_only,
        replay: tally.finish(),
    })
}

/// Solves the parts `bounds` of `rec` at once, the first on this thread (showing
/// `progress`), each into its output; the figures of them all and the skeleton
/// formats' file, every part's postures written to it in take order.
#[allow(clippy::too_many_arguments)]
fn solve_parts(
    rig: &Arc<Rig>,
    params: SolverParams,
    rec: &Recording,
    play_opts: OfflineOptions,
    bounds: &[usize],
    warm: usize,
    outs: Vec<PartOut>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<(Option<Tally>, Option<PartOut>), OfflineExportError> {
    let (parts, frames) = (bounds.len() - 1, bounds[bounds.len() - 1]);
    let done = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    let span = |i: usize| Span {
        warm_from: if i == 0 {
            0
        } else {
            bounds[i].saturating_sub(warm)
        },
        from: bounds[i],
        to: bounds[i + 1],
    };
    let results: Vec<PartResult> = std::thread::scope(|scope| {
        let mut outs = outs.into_iter();
        let first = outs.next();
        let later: Vec<_> = outs
            .enumerate()
            .map(|(k, out)| {
                let (rig, span, done, stop) = (Arc::clone(rig), span(k + 1), &done, &stop);
                scope.spawn(move || {
                    run_part(
                        rig,
                        params,
                        rec,
                        play_opts,
                        span,
                        out,
                        done,
                        stop,
                        &mut |_| {},
                    )
                })
            })
            .collect();
        let mut all = Vec::with_capacity(parts);
        if let Some(out) = first {
            all.push(run_part(
                Arc::clone(rig),
                params,
                rec,
                play_opts,
                span(0),
                out,
                &done,
                &stop,
                &mut |d| progress(d, frames),
            ));
        }
        // The first part done, the others' progress still shows.
        while later.iter().any(|h| !h.is_finished()) {
            progress(done.load(Ordering::Relaxed), frames);
            std::thread::sleep(Duration::from_millis(50));
        }
        for h in later {
            all.push(h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)));
        }
        all
    });
    let mut tally: Option<Tally> = None;
    let mut file: Option<PartOut> = None;
    for r in results {
        let (t, out) = r?;
        match (&mut tally, t) {
            (Some(all), Some(t)) => all.merge(t),
            (None, t) => tally = t,
            (Some(_), None) => {}
        }
        finish_part(&mut file, out)?;
    }
    Ok((tally, file))
}

/// Flushes the skeleton formats' file (a PC2 part is finished with its part).
fn finish_file(file: Option<PartOut>) -> Result<(), OfflineExportError> {
    match file {
        Some(PartOut::Bvh(w)) => w.finish()?,
        Some(PartOut::Glb(w, _)) => w.finish()?,
        _ => {}
    }
    Ok(())
}

/// What a part of an export gives back: its figures and its output.
type PartResult = Result<(Option<Tally>, PartOut), OfflineExportError>;

/// The outputs of an export's parts (`bounds`, as [`Pc2Writer::create_parts`]): a PC2
/// writer per part; the skeleton formats' one file for the first part and a posture
/// store for each later one.
fn create_outputs(
    rig: &Rig,
    format: ExportFormat,
    path: &std::path::Path,
    frames: usize,
    frame_time_s: f64,
    bounds: &[usize],
) -> Result<Vec<PartOut>, crate::output::export::ExportError> {
    let sk = &rig.skeleton;
    let skin_every = frames.div_ceil(SKIN_FIT_FRAMES).max(1);
    let first = match format {
        ExportFormat::Pc2 => {
            let parts = Pc2Writer::create_parts(path, rig.mesh_rest.len(), frames, bounds)?;
            return Ok(parts.into_iter().map(PartOut::Pc2).collect());
        }
        ExportFormat::Bvh => {
            let names: Vec<String> = sk.joints.iter().map(|j| j.name.clone()).collect();
            let parents: Vec<Option<usize>> = sk.joints.iter().map(|j| j.parent).collect();
            let rest: Vec<DVec3> = sk.joints.iter().map(|j| j.rest).collect();
            let skeleton = BvhSkeleton {
                names: &names,
                parents: &parents,
                rest: &rest,
            };
            PartOut::Bvh(BvhWriter::create(path, &skeleton, frames, frame_time_s)?)
        }
        ExportFormat::Glb => PartOut::Glb(
            Box::new(GlbWriter::new(
                path,
                sk,
                &rig.mesh_rest,
                &rig.triangles,
                frame_time_s,
            )),
            skin_every,
        ),
    };
    let mut outs = vec![first];
    for w in bounds.windows(2).skip(1) {
        let n = (w[1] - w[0]) * sk.joints.len();
        let skin = (format == ExportFormat::Glb)
            .then(|| (Box::new(SkinFit::new(sk, &rig.mesh_rest)), skin_every));
        outs.push(PartOut::Posture {
            joints: sk.joints.len(),
            rot: Vec::with_capacity(n),
            pos: Vec::with_capacity(n),
            skin,
        });
    }
    Ok(outs)
}

/// Plays one part of an export into `out`, counting its frames into `done` (and showing
/// the count to `shown`); stops early when `stop` is raised, and raises it when its
/// output fails.
#[allow(clippy::too_many_arguments)]
fn run_part(
    rig: Arc<Rig>,
    params: SolverParams,
    rec: &Recording,
    opts: OfflineOptions,
    span: Span,
    mut out: PartOut,
    done: &AtomicUsize,
    stop: &AtomicBool,
    shown: &mut dyn FnMut(usize),
) -> PartResult {
    let mut failed = None;
    let tally = play(rig, params, rec, opts, span, &mut |t| {
        if stop.load(Ordering::Relaxed) {
            return ControlFlow::Break(());
        }
        if let Err(e) = out.push(&t) {
            failed = Some(e);
            stop.store(true, Ordering::Relaxed);
            return ControlFlow::Break(());
        }
        shown(done.fetch_add(1, Ordering::Relaxed) + 1);
        ControlFlow::Continue(())
    });
    if let Err(e) = tally {
        stop.store(true, Ordering::Relaxed);
        return Err(e.into());
    }
    if let Some(e) = failed {
        return Err(e.into());
    }
    Ok((tally?, out))
}

/// Completes a part's output in take order: a PC2 part is finished on its own; the
/// skeleton formats' file (the first part's) takes each later part's postures.
fn finish_part(
    file: &mut Option<PartOut>,
    out: PartOut,
) -> Result<(), crate::output::export::ExportError> {
    match (file.as_mut(), out) {
        (_, PartOut::Pc2(w)) => w.finish(),
        (
            Some(f),
            PartOut::Posture {
                joints,
                rot,
                pos,
                skin,
            },
        ) => {
            if let (PartOut::Glb(w, _), Some((fit, _))) = (&mut *f, &skin) {
                w.merge_skin(fit);
            }
            let joints = joints.max(1);
            for (r, p) in rot.chunks(joints).zip(pos.chunks(joints)) {
                match f {
                    PartOut::Bvh(w) => w.push(r, p)?,
                    PartOut::Glb(w, _) => w.push(r, p),
                    PartOut::Pc2(_) | PartOut::Posture { .. } => {}
                }
            }
            Ok(())
        }
        (_, first) => {
            *file = Some(first);
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::part_bounds;

    /// Parts cover the take once, in order, and each does the same work (its frames,
    /// and its warm-up after the first) to within a frame per part.
    #[test]
    fn parts_share_the_work() {
        for (frames, parts, warm) in [(1440, 2, 30), (1441, 3, 30), (500, 4, 30), (100, 1, 30)] {
            let b = part_bounds(frames, parts, warm);
            assert_eq!((b.len(), b[0], b[parts]), (parts + 1, 0, frames), "{b:?}");
            let work: Vec<usize> = (0..parts)
                .map(|i| b[i + 1] - b[i] + if i > 0 { warm } else { 0 })
                .collect();
            let (lo, hi) = (work.iter().min().unwrap(), work.iter().max().unwrap());
            assert!(
                hi - lo <= parts,
                "{frames} frames in {parts}: {b:?}, work {work:?}"
            );
        }
        // Two parts of the body walk: the first 15 frames longer than half.
        assert_eq!(part_bounds(1440, 2, 30), vec![0, 735, 1440]);
        // Parts shorter than their warm-up (which an export does not ask for): the
        // bounds still never go back.
        for (frames, parts) in [(28, 4), (10, 4), (0, 3), (50, 8)] {
            let b = part_bounds(frames, parts, 30);
            assert!(b.windows(2).all(|w| w[0] <= w[1]), "{b:?}");
            assert_eq!((b[0], b[parts]), (0, frames), "{b:?}");
        }
    }
}
