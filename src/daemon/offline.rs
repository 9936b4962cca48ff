//! A recording through the live pipeline off line: the fixed-rate loop of a stage
//! (buffer, gap filling, solve, full mesh, publish) ticked on a manual clock at the
//! stage's rate, each tick given its live deadline, as fast as the solver goes. It tells
//! a user how well a marker layout carries a take (labels fed, samples held, misfit)
//! and what the character does (inverted tets, limits, bone lengths, frame time),
//! without waiting the take's length; `rigless calibrate --check` and the calibration
//! benchmark use it. Without deadlines it exports a take: every frame's full mesh to a
//! point cache, or the fitted skeleton to BVH ([`export_take`], `rigless replay
//! --export`).

use super::pipeline::Pipeline;
use crate::markers::buffer::{BufferConfig, MarkerBuffer};
use crate::markers::index::{LabelMap, MarkerIndex};
use crate::markers::{FillState, MarkerSample};
use crate::output::export::{BvhWriter, ExportFormat, GlbWriter, Pc2Writer};
use crate::replay::bvh::BvhSkeleton;
use crate::replay::recording::Recording;
use crate::rig::bind::Rig;
use crate::solve::arap::StopReason;
use crate::solve::frame::{SolveReport, Solver, SolverParams};
use glam::DVec3;
use std::ops::ControlFlow;
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
}

impl Default for OfflineOptions {
    fn default() -> Self {
        Self {
            rate_hz: 120.0,
            marker_scale: 1.0,
            deadline: true,
        }
    }
}

/// What the replay did.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct OfflineReport {
    /// The recording's labels that feed a marker, and the markers no label feeds.
    pub labels_fed: usize,
    pub markers_unfed: usize,
    pub frames: usize,
    /// Share of marker samples (markers fed by a label, over the ticks the recording
    /// covers) that were held (no measurement and no fill), 0 to 1.
    pub held_share: f64,
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
    /// Ticks stopped by their deadline.
    pub deadline_stops: usize,
    /// Whole tick (drain, buffer, solve, full mesh, publish), ms.
    pub frame_ms_p50: f64,
    pub frame_ms_p99: f64,
    pub frame_ms_max: f64,
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
    let fed_markers: Vec<usize> = {
        let mut m: Vec<usize> = fed.iter().map(|f| f.1 as usize).collect();
        m.sort_unstable();
        m.dedup();
        m
    };
    let period_s = 1.0 / opts.rate_hz;
    let ticks = (rec.duration_secs() * opts.rate_hz).floor() as usize + 1;
    let mut times_ms = Vec::with_capacity(ticks);
    let mut rep = OfflineReport {
        labels_fed: fed.len(),
        markers_unfed: map.unfed_markers.len(),
        frames: ticks,
        ..OfflineReport::default()
    };
    let (mut held, mut fed_samples) = (0usize, 0usize);
    let (mut sq_sum, mut in_view) = (0.0, 0usize);
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
        // Without a deadline the solve stops on convergence or its iteration cap; the
        // hour is only an Instant far enough away.
        let budget = if opts.deadline {
            Duration::from_secs_f64(period_s)
        } else {
            Duration::from_secs(3600)
        };
        let r = pipeline.tick(t_s, Instant::now() + budget, &|| t_s);
        times_ms.push(r.frame_ms);
        let states = &pipeline.markers().states;
        held += fed_markers
            .iter()
            .filter(|&&k| states[k] == FillState::Held)
            .count();
        fed_samples += fed_markers.len();
        take(&mut rep, &r.solve);
        if fed_markers.iter().any(|&k| states[k] != FillState::Held)
            && r.solve.marker_residual_rms_mm.is_finite()
        {
            sq_sum += r.solve.marker_residual_rms_mm.powi(2);
            in_view += 1;
            rep.residual_mm_max = rep.residual_mm_max.max(r.solve.marker_residual_max_mm);
        }
        if let Some(cp) = pipeline.control_positions() {
            rep.inverted_tets_max = rep.inverted_tets_max.max(rig.control.inverted_tets(cp));
        }
        let (joint_rot, joint_pos) = pipeline.joint_world();
        let shown = OfflineTick {
            index: tick,
            of: ticks,
            vertices: pipeline.vertices(),
            joint_rot,
            joint_pos,
        };
        if on_tick(shown).is_break() {
            rep.frames = tick + 1;
            break;
        }
    }
    rep.held_share = held as f64 / fed_samples.max(1) as f64;
    rep.residual_mm_rms = (sq_sum / in_view.max(1) as f64).sqrt();
    times_ms.sort_by(f64::total_cmp);
    let at = |q: f64| times_ms[((times_ms.len() - 1) as f64 * q).round() as usize];
    (rep.frame_ms_p50, rep.frame_ms_p99, rep.frame_ms_max) = (at(0.5), at(0.99), at(1.0));
    Ok(Some(rep))
}

/// One tick's solver figures into the running maxima.
fn take(rep: &mut OfflineReport, s: &SolveReport) {
    rep.deadline_stops += (s.stop == StopReason::Deadline) as usize;
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
    /// Vertices (a point cache) or joints (a BVH) per frame.
    pub points: usize,
    /// The replay's figures over the take.
    pub replay: OfflineReport,
}

/// The file a take is being written to.
enum TakeFile {
    Pc2(Pc2Writer),
    Bvh(BvhWriter),
    Glb(Box<GlbWriter>),
}

/// Solves every frame of `rec` at its own rate, without deadlines, and writes each to
/// `path` in the format of its extension ([`ExportFormat`]): the full mesh (PC2, in the
/// character's vertex order, metres, Y up) or the fitted skeleton's posture (BVH, in
/// centimetres); one sample per take frame. `progress` hears frames done and in all.
pub fn export_take(
    rig: Arc<Rig>,
    params: SolverParams,
    rec: &Recording,
    marker_scale: f64,
    path: &std::path::Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ExportSummary, OfflineExportError> {
    let format = ExportFormat::of(path).ok_or_else(|| OfflineExportError::Format {
        path: path.display().to_string(),
    })?;
    let frames = rec.frames.len();
    let sk = &rig.skeleton;
    let names: Vec<String> = sk.joints.iter().map(|j| j.name.clone()).collect();
    let parents: Vec<Option<usize>> = sk.joints.iter().map(|j| j.parent).collect();
    let rest: Vec<DVec3> = sk.joints.iter().map(|j| j.rest).collect();
    let points = match format {
        ExportFormat::Pc2 => rig.mesh_rest.len(),
        ExportFormat::Bvh | ExportFormat::Glb => names.len(),
    };
    let create = || -> Result<TakeFile, crate::output::export::ExportError> {
        Ok(match format {
            ExportFormat::Pc2 => TakeFile::Pc2(Pc2Writer::create(path, points, frames)?),
            ExportFormat::Bvh => {
                let skeleton = BvhSkeleton {
                    names: &names,
                    parents: &parents,
                    rest: &rest,
                };
                TakeFile::Bvh(BvhWriter::create(
                    path,
                    &skeleton,
                    frames,
                    1.0 / rec.rate_hz,
                )?)
            }
            ExportFormat::Glb => TakeFile::Glb(Box::new(GlbWriter::new(
                path,
                &rig.skeleton,
                &rig.mesh_rest,
                &rig.triangles,
                1.0 / rec.rate_hz,
            ))),
        })
    };
    // Created at the first frame: a take that feeds no marker leaves no file.
    let mut file: Option<TakeFile> = None;
    let mut failed = None;
    let opts = OfflineOptions {
        rate_hz: rec.rate_hz,
        marker_scale,
        deadline: false,
    };
    let report = replay_offline_with(Arc::clone(&rig), params, rec, opts, &mut |t| {
        let f = match file.as_mut() {
            Some(f) => Ok(f),
            None => create().map(|f| file.insert(f)),
        };
        let pushed = f.and_then(|f| match f {
            TakeFile::Pc2(w) => w.push(t.vertices),
            TakeFile::Bvh(w) => w.push(t.joint_rot, t.joint_pos),
            TakeFile::Glb(w) => {
                w.push(t.joint_rot, t.joint_pos);
                Ok(())
            }
        });
        if let Err(e) = pushed {
            failed = Some(e);
            return ControlFlow::Break(());
        }
        progress(t.index + 1, frames);
        // The take's frames, not the tick past its last one.
        if t.index + 1 >= frames {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    })?;
    if let Some(e) = failed {
        return Err(e.into());
    }
    let Some(replay) = report else {
        return Err(OfflineExportError::NoLabels {
            take: rec.name.clone(),
        });
    };
    match file {
        Some(TakeFile::Pc2(w)) => w.finish()?,
        Some(TakeFile::Bvh(w)) => w.finish()?,
        Some(TakeFile::Glb(w)) => w.finish()?,
        None => {}
    }
    Ok(ExportSummary {
        frames,
        rate_hz: rec.rate_hz,
        points,
        replay,
    })
}
