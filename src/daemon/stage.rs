//! The stage: a whole live rigless, in-process, built from a [`StageConfig`]. It binds
//! the character (or loads its bake cache), serves the vertex stream, opens the inputs,
//! starts the session recorder and the Rerun sink, and runs the solver thread at its
//! rate on the clock it is given; [`Stage::stop`] and [`Stage::join`] shut it down in
//! order (loop, inputs, recorder, stream clients told goodbye, Rerun flushed).
//!
//! `rigless run`, `demo` and `replay --solve`, the live benchmark and the tests all start
//! stages through [`Stage::start`] or [`Stage::start_with`]; none builds the wiring
//! itself. On a
//! [`ManualClock`](crate::runtime::clock::ManualClock) a stage runs as fast as it
//! computes and deterministically: inputs that pace themselves and the loop take turns
//! in time order.

use super::live_calibration::{
    calibrate_captured, calibrate_live, capture_for_calibration, LiveCalibration,
    LiveCalibrationError, Target,
};
use super::pipeline::{run_loop_many, ActorBoard, LoopParams, LoopStatus, Pipeline};
use crate::calibrate::labels::map_entries;
use crate::character::demo::{body_bind_params, demo_body, demo_hand, hand_bind_params};
use crate::character::file::{load_character, CharacterError};
use crate::character::procedural::Character;
use crate::character::roles::recognise;
use crate::config::StageConfig;
use crate::input::{ChannelSink, Input, InputError, OpenContext, PinTarget, SourceCounters};
use crate::markers::buffer::MarkerBuffer;
use crate::markers::index::{ActorLabels, Claim};
use crate::output::frame::DeformedFrame;
use crate::output::rerun_sink::{self, RerunOptions, RerunStats, RerunTarget};
use crate::output::scene::Scene;
use crate::output::stream::{StreamServer, StreamStats};
use crate::replay::recording::Recording;
use crate::replay::session::{run_recorder, RecorderOutcome, SessionHeader, SessionWriter};
use crate::rig::bind::{BindError, BindStage, Rig};
use crate::rig::cache::{load_or_bind, LoadOrBindError};
use crate::runtime::clock::{Attached, Clock};
use crate::runtime::slot::{LatestSlot, PinSlot};
use crate::solve::frame::Solver;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

/// Inputs that pace themselves send their first frame this long after the stage has
/// started everything else (the character bound, the stream, Rerun and the inputs
/// opened), seconds on the stage's clock; the threads start in the meantime.
pub const START_DELAY_S: f64 = 0.05;
/// The loop's first tick comes this long after the paced inputs' first frame, seconds: at
/// equal rates every tick then comes just after a frame was sent, so that its samples
/// are in the channel when the tick drains it.
pub const LOOP_PHASE_S: f64 = 0.0002;

/// How a stage is started, besides its config.
#[derive(Default)]
pub struct StartOptions<'a> {
    /// Stop this many seconds after the first tick (default: when every input has
    /// ended, or on [`Stage::stop`]).
    pub stop_after_secs: Option<f64>,
    /// Hears the progress of binding a character file (stage, fraction done).
    pub progress: Option<&'a mut dyn FnMut(BindStage, f64)>,
    /// Also publish every frame here (an in-process reader: it gets the newest frame).
    pub frames: Option<Arc<LatestSlot<DeformedFrame>>>,
    /// Where the Rerun recording goes, instead of the config's `[outputs.rerun] target`
    /// (a relative save path is taken as it is, not from the stage's folder).
    pub rerun: Option<RerunTarget>,
    /// Also publish each actor's frames here, `actor_frames[i]` for the `i`-th actor
    /// (in-process readers of a stage of several).
    pub actor_frames: Vec<Arc<LatestSlot<DeformedFrame>>>,
    /// Also send each actor's every frame here, `frame_logs[i]` for the `i`-th actor,
    /// without blocking (a reader that must see every frame: tests, benchmarks).
    pub frame_logs: Vec<crossbeam_channel::Sender<Arc<DeformedFrame>>>,
}

/// Why a stage could not start, or ended badly.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    #[error("binding the procedural {name}: {source}")]
    Procedural { name: String, source: BindError },
    #[error("the stage names no character")]
    NoCharacter,
    #[error("{path}: the character has no markers ([[markers]]): nothing could drive it")]
    NoMarkers { path: String },
    #[error(transparent)]
    Character(#[from] CharacterError),
    #[error(transparent)]
    Rig(#[from] LoadOrBindError),
    #[error("starting the vertex stream on {addresses}: {source}")]
    Stream {
        addresses: String,
        source: std::io::Error,
    },
    #[error("setting up the {} solver for {character}: {source}", .method.name())]
    Solver {
        method: crate::solve::frame::Method,
        character: String,
        source: crate::solve::harmonic::HarmonicError,
    },
    #[error("input {index} ({kind}): {source}")]
    Input {
        index: usize,
        kind: &'static str,
        source: Box<InputError>,
    },
    #[error("the session file {path}: {source}")]
    Recorder {
        path: String,
        source: std::io::Error,
    },
    #[error("starting the Rerun recording: {0}")]
    Rerun(#[from] rerun_sink::RerunError),
    #[error("starting the {name} thread: {source}")]
    Thread {
        name: &'static str,
        source: std::io::Error,
    },
    #[error("the {thread} thread panicked")]
    Panicked { thread: &'static str },
    #[error(transparent)]
    LiveCalibration(#[from] LiveCalibrationError),
}

/// What a started stage is, for the user (the CLI prints it).
#[derive(Clone, Debug)]
pub struct StageInfo {
    /// The character's name.
    pub character: String,
    pub mesh_vertices: usize,
    pub markers: usize,
    pub control_vertices: usize,
    /// Seconds from the start to a bound character.
    pub bind_s: f64,
    /// For a character file: its path and where its rig came from (cache or bound).
    pub rig_source: Option<String>,
    /// Where the vertex stream listens.
    pub stream_tcp: Option<SocketAddr>,
    pub stream_ws: Option<SocketAddr>,
    /// Each input: its kind, what was opened, and its warnings.
    pub inputs: Vec<InputInfo>,
    /// The session file being recorded, and its flush interval, seconds.
    pub recording: Option<(PathBuf, f64)>,
    /// Where the Rerun recording goes (off when none).
    pub rerun: RerunTarget,
    /// Why the Rerun target differs from the one asked for, if it does.
    pub rerun_note: Option<String>,
    /// When paced inputs start and when the loop first ticks, seconds on the clock.
    pub start_s: f64,
    pub loop_start_s: f64,
    /// What the calibration from the first seconds of live input did, when the config
    /// asked for one.
    pub calibration: Option<LiveCalibration>,
    /// Every actor, in the config's order (one for a `[character]` stage; the fields
    /// above describe the first).
    pub actors: Vec<ActorInfo>,
    /// Threads the actors are solved on.
    pub solver_threads: usize,
}

/// One actor of a started stage.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ActorInfo {
    /// The actor's name (its character's for a `[character]` stage).
    pub name: String,
    pub character: String,
    pub mesh_vertices: usize,
    pub markers: usize,
    /// How it claims its labels (`subject "Ann"`); `None` for a `[character]` stage.
    pub claim: Option<String>,
    /// Its first marker's stage index (markers are numbered across actors in inputs and
    /// session files).
    pub first_marker: u32,
    /// What the live calibration of its first seconds did, in a line (a stage of
    /// several actors with `[calibration] first_secs`; `None` otherwise).
    pub calibration: Option<String>,
}

/// One input of a started stage.
#[derive(Clone, Debug)]
pub struct InputInfo {
    pub kind: &'static str,
    /// What was opened (`osc input listening on udp://...`).
    pub opened: String,
    pub warnings: Vec<String>,
    pub local_addr: Option<SocketAddr>,
    /// A recording's labels that feed a marker, and those ignored (replay inputs).
    pub label_counts: Option<(usize, usize)>,
}

/// Why a stage stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopCause {
    /// [`Stage::stop`] (Ctrl-C in the CLI).
    Stopped,
    /// `stop_after_secs` passed.
    TimeLimit,
    /// Every input ended.
    InputsEnded,
}

impl StopCause {
    /// What clients are told in the stream's goodbye.
    pub fn reason(self) -> &'static str {
        match self {
            StopCause::Stopped => "shutting down",
            StopCause::TimeLimit => "time limit reached",
            StopCause::InputsEnded => "session ended",
        }
    }
}

/// What a stage did, once joined.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Summary {
    /// The loop's final status (the first actor's).
    pub status: LoopStatus,
    /// Every actor's name and final status, in the config's order.
    pub actors: Vec<ActorSummary>,
    pub stopped: StopCause,
    /// Samples the inputs sent into the channel, and dropped at a full channel.
    pub source_samples: u64,
    pub source_dropped: u64,
    /// Per input (the config's order): times its source clock jumped, and packets whose
    /// source time was not trusted (their samples carry one from the receive clock).
    pub source_clock_jumps: Vec<u64>,
    pub source_clock_untrusted: Vec<u64>,
    /// Each input's closing line (what it received), or its error.
    pub inputs: Vec<String>,
    /// The replayed recordings' labels that fed a marker, and those ignored (no such
    /// marker, or another subject's); `None` without a replay input.
    pub labels_fed: Option<usize>,
    pub labels_ignored: Option<usize>,
    pub stream: StreamSummary,
    /// The session file and the samples written to it.
    pub recorded: Option<(PathBuf, u64)>,
    /// Why the recording stopped part way (a full disk, say), and the samples that were
    /// not written: the stage went on solving without it.
    pub recording_failed: Option<String>,
    pub rerun: Option<RerunSummary>,
}

/// One actor's part of a [`Summary`].
#[derive(Clone, Debug, serde::Serialize)]
pub struct ActorSummary {
    pub name: String,
    pub status: LoopStatus,
}

/// What the vertex stream did.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct StreamSummary {
    pub connections: u64,
    pub frames_sent: u64,
    pub frames_skipped: u64,
    pub write_errors: u64,
    /// Connections refused because `max_clients` were connected.
    pub refused: u64,
    /// Accepts that failed (out of file descriptors, ...).
    pub accept_errors: u64,
}

/// What the Rerun sink did.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct RerunSummary {
    pub frames_logged: u64,
    /// Frames the sink fell behind on (replaced in its slot before it took them).
    pub frames_skipped: u64,
    /// Log calls the SDK refused.
    pub log_errors: u64,
}

/// A running stage.
pub struct Stage {
    info: StageInfo,
    stop: Arc<AtomicBool>,
    stop_requested: AtomicBool,
    /// Each actor's status slot, in the config's order.
    status: Vec<Arc<LatestSlot<LoopStatus>>>,
    solvers: Solvers,
    sources: Vec<JoinHandle<Result<String, InputError>>>,
    counters: Vec<Arc<SourceCounters>>,
    recorder: Option<(PathBuf, JoinHandle<RecorderOutcome>)>,
    server: Option<StreamServer>,
    stream_stats: Arc<StreamStats>,
    rerun: Option<RunningRerun>,
    time_limited: bool,
    /// Sets `stop` when the stage is dropped without [`Stage::join`].
    _stop_on_drop: StopOnDrop,
}

/// Sets a stop flag when dropped: a stage that is dropped, or fails half-way through
/// starting, stops the threads it started.
struct StopOnDrop(Arc<AtomicBool>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

struct RunningRerun {
    thread: JoinHandle<()>,
    stop: Arc<AtomicBool>,
    stats: Arc<RerunStats>,
    /// Each actor's slot.
    slots: Vec<Arc<LatestSlot<DeformedFrame>>>,
}

/// A bound character: the rig, its name, and the procedural character if it is one.
#[derive(Clone)]
struct Bound {
    rig: Arc<Rig>,
    name: String,
    procedural: Option<Arc<Character>>,
    rig_source: Option<String>,
    /// Character metres per capture metre for incoming markers.
    marker_scale: f64,
}

/// Binds `character`, calibrated live when the config asks for it: on the seconds
/// `captured` already (an actor's labels of them, on a stage of several), else on a
/// capture of its own.
fn bind_character(
    cfg: &StageConfig,
    character: &crate::character::config::CharacterConfig,
    base_dir: &Path,
    clock: &Arc<dyn Clock>,
    progress: &mut dyn FnMut(BindStage, f64),
    captured: Option<(f64, &Recording)>,
) -> Result<(Bound, Option<LiveCalibration>), StageError> {
    // The live calibration, when the config asks for one, and its rig.
    let live = |target: Target<'_>, progress: &mut dyn FnMut(BindStage, f64)| match captured {
        Some((seconds, rec)) => {
            calibrate_captured(&cfg.calibration, seconds, rec, target, progress)
                .map(|(l, r)| (Some(l), r))
        }
        None => calibrate_live(
            &cfg.calibration,
            &cfg.inputs,
            base_dir,
            clock,
            target,
            progress,
        )
        .map(|found| found.map_or((None, None), |(l, r)| (Some(l), r))),
    };
    // The stage's marker_scale, else the live calibration's, else the file's.
    let scale = |live: &Option<LiveCalibration>, file: f64| {
        let found = live
            .as_ref()
            .and_then(|l| l.calibration.as_ref())
            .map(|c| c.scale);
        character.marker_scale.or(found).unwrap_or(file)
    };
    if let Some(p) = &character.procedural {
        let (mut ch, bind) = match p.as_str() {
            "body" => (demo_body(), body_bind_params()),
            _ => (demo_hand(), hand_bind_params()),
        };
        let roles = recognise(&ch.skeleton.joints, &[]);
        let (calibrated, rig) = live(
            Target {
                character: &ch,
                bind: &bind,
                bind_for: &|_| bind.clone(),
                roles: &roles,
                map: Vec::new(),
                file: None,
            },
            progress,
        )?;
        if let Some(c) = calibrated.as_ref().and_then(|l| l.calibration.as_ref()) {
            ch.markers = c.layout(&ch);
        }
        let rig = match rig {
            Some(rig) => rig,
            None => Rig::bind(&ch, &bind).map_err(|source| StageError::Procedural {
                name: p.clone(),
                source,
            })?,
        };
        let marker_scale = scale(&calibrated, 1.0);
        let bound = Bound {
            rig: Arc::new(rig),
            name: ch.name.clone(),
            procedural: Some(Arc::new(ch)),
            rig_source: None,
            marker_scale,
        };
        return Ok((bound, calibrated));
    }
    let path = base_dir.join(character.path.as_ref().ok_or(StageError::NoCharacter)?);
    let mut loaded = load_character(&path)?;
    let (calibrated, live_rig) = live(
        Target {
            character: &loaded.character,
            bind: &loaded.bind,
            bind_for: &|m| loaded.bind_for(m),
            roles: &loaded.joint_roles,
            map: map_entries(&loaded.calibration_map),
            file: Some(&path),
        },
        progress,
    )?;
    let written = calibrated.as_ref().is_some_and(|l| l.written.is_some());
    if written {
        // The file now holds the layout: bind (and cache) it as any file.
        loaded = load_character(&path)?;
    } else if let Some(c) = calibrated.as_ref().and_then(|l| l.calibration.as_ref()) {
        loaded.character.markers = c.layout(&loaded.character);
    }
    if loaded.character.markers.is_empty() {
        return Err(StageError::NoMarkers {
            path: path.display().to_string(),
        });
    }
    for w in &loaded.warnings {
        tracing::warn!("{}: {w} (bound anyway)", path.display());
    }
    let (rig, source) = match live_rig.filter(|_| !written) {
        // A layout the file does not hold: bound with it, not cached under the file.
        Some(rig) => (rig, "bound with the live calibration's layout".to_string()),
        None => {
            let (rig, source) = load_or_bind(&path, &loaded, false, progress)?;
            (rig, source.to_string())
        }
    };
    let marker_scale = scale(&calibrated, loaded.marker_scale);
    let bound = Bound {
        rig: Arc::new(rig),
        name: loaded.character.name.clone(),
        procedural: None,
        rig_source: Some(format!("{}: {source}", path.display())),
        marker_scale,
    };
    Ok((bound, calibrated))
}

/// A stage's actors, bound, with what inputs need to route their labels.
struct Actors {
    bound: Vec<Bound>,
    solvers: Vec<Solver>,
    infos: Vec<ActorInfo>,
    /// Each actor's first marker's stage index.
    starts: Vec<u32>,
    /// Every marker's stage name (each with its subject for a stage of several).
    stage_names: Vec<String>,
    /// Each actor's labels, for a stage of several (`None`: one `[character]`).
    labels: Option<Vec<ActorLabels>>,
    calibration: Option<LiveCalibration>,
}

impl Actors {
    /// What every sink knows of each actor before the first frame.
    fn scenes(&self, rate_hz: f64) -> Vec<Scene> {
        let count = self.bound.len() as u8;
        (self.bound.iter().zip(&self.solvers).zip(&self.infos))
            .enumerate()
            .map(|(i, ((b, solver), info))| {
                Scene::of_rig(&b.rig, &b.name, rate_hz)
                    .with_tied(solver.harmonic_tied())
                    .for_actor(&info.name, i as u8, count)
            })
            .collect()
    }
}

/// Binds every actor of the stage and sets up its solver.
fn bind_actors(
    cfg: &StageConfig,
    base_dir: &Path,
    clock: &Arc<dyn Clock>,
    progress: &mut dyn FnMut(BindStage, f64),
) -> Result<Actors, StageError> {
    let specs = cfg.actor_specs();
    let several = specs.iter().any(|s| s.claim.is_some());
    let mut out = Actors {
        bound: Vec::new(),
        solvers: Vec::new(),
        infos: Vec::new(),
        starts: Vec::new(),
        stage_names: Vec::new(),
        labels: several.then(Vec::new),
        calibration: None,
    };
    // A stage of several calibrating live captures the first seconds once; each actor
    // is calibrated on its own labels of them.
    let captured = match several {
        true => capture_for_calibration(&cfg.calibration, &cfg.inputs, base_dir, clock)?,
        false => None,
    };
    for (i, spec) in specs.iter().enumerate() {
        // Actors of the same character share its rig (bound once), unless each is
        // calibrated to its own performer.
        let same = specs[..i]
            .iter()
            .position(|s| s.character == spec.character)
            .filter(|_| captured.is_none());
        let mut calibrated = None;
        let bound = match same {
            Some(j) => out.bound[j].clone(),
            None => {
                let mine = captured.as_ref().map(|(seconds, rec)| {
                    let mut rec = rec.clone();
                    if let Some(claim) = &spec.claim {
                        rec.keep_claimed(claim);
                    }
                    (*seconds, rec)
                });
                let (bound, calibration) = bind_character(
                    cfg,
                    &spec.character,
                    base_dir,
                    clock,
                    progress,
                    mine.as_ref().map(|(s, r)| (*s, r)),
                )?;
                calibrated = calibration.as_ref().map(LiveCalibration::describe);
                out.calibration = out.calibration.or(calibration);
                bound
            }
        };
        let rig = &bound.rig;
        let params = crate::solve::frame::SolverParams {
            method: spec.method,
            ..cfg.solver.params()
        };
        let solver =
            Solver::try_new(Arc::clone(rig), params).map_err(|source| StageError::Solver {
                method: spec.method,
                character: bound.name.clone(),
                source,
            })?;
        let start = out.stage_names.len() as u32;
        let name = spec.name.clone().unwrap_or_else(|| bound.name.clone());
        match (&spec.claim, &mut out.labels) {
            (Some(claim), Some(labels)) => {
                // A session file keeps each label with its subject (the actor's name for
                // an actor that claims by pattern).
                let prefix = match claim {
                    Claim::Subject(s) => format!("{s}:"),
                    Claim::Patterns(_) => format!("{name}:"),
                    Claim::Unprefixed => String::new(),
                };
                let names: Vec<String> = rig
                    .marker_names
                    .iter()
                    .map(|m| format!("{prefix}{m}"))
                    .collect();
                out.stage_names.extend(names.iter().cloned());
                labels.push(ActorLabels {
                    names,
                    markers: rig.marker_names.clone(),
                    claim: claim.clone(),
                });
            }
            _ => out.stage_names.extend(rig.marker_names.iter().cloned()),
        }
        out.infos.push(ActorInfo {
            name,
            character: bound.name.clone(),
            mesh_vertices: rig.mesh_rest.len(),
            markers: rig.n_markers,
            claim: spec.claim.as_ref().map(Claim::describe),
            first_marker: start,
            calibration: calibrated.filter(|_| several),
        });
        out.starts.push(start);
        out.solvers.push(solver);
        out.bound.push(bound);
    }
    Ok(out)
}

/// What [`actor_pipelines`] makes: each actor's channel's sending end, its pipeline,
/// and the glove's pin slot.
type ActorWiring = (
    Vec<crossbeam_channel::Sender<crate::markers::MarkerSample>>,
    Vec<Pipeline>,
    Option<Arc<PinSlot>>,
);

/// Each actor's pipeline and the sending end of its channel; the glove's pin slot (the
/// first actor's). The stream and Rerun carry every actor; the in-process reader of
/// `opts.frames` the first, those of `opts.actor_frames` any. On a stage of several actors each gates samples by identity, sharing
/// its fitted markers with the others on a board.
fn actor_pipelines(
    cfg: &StageConfig,
    solvers: Vec<Solver>,
    actors: &Actors,
    sinks: &Sinks,
    opts: &StartOptions<'_>,
) -> ActorWiring {
    let mut txs = Vec::new();
    let mut pipelines = Vec::new();
    let mut pins = None;
    let markers: Vec<usize> = actors.infos.iter().map(|a| a.markers).collect();
    let board = Arc::new(ActorBoard::new(&markers));
    for (i, solver) in solvers.into_iter().enumerate() {
        let (tx, rx) = crossbeam_channel::bounded(cfg.solver.channel_capacity);
        let mut slots = sinks.slots[i].clone();
        slots.extend(opts.actor_frames.get(i).cloned());
        let rerun_on = sinks.rerun_target != RerunTarget::Off;
        let (pipeline, p) = assemble(cfg, solver, rx, slots, rerun_on, i == 0);
        pins = pins.or(p);
        txs.push(tx);
        let mut pipeline = pipeline
            .with_marker_scale(actors.bound[i].marker_scale)
            .as_actor(i as u8);
        if let Some(tx) = opts.frame_logs.get(i) {
            pipeline = pipeline.with_frame_log(tx.clone());
        }
        if actors.labels.is_some() {
            pipeline = pipeline
                .with_identity_gate()
                .with_board(Arc::clone(&board), i);
        }
        pipelines.push(pipeline);
    }
    (txs, pipelines, pins)
}

/// Where inputs send samples: each actor's channel, by stage index.
struct Route {
    tx: Vec<crossbeam_channel::Sender<crate::markers::MarkerSample>>,
    starts: Vec<u32>,
}

/// What a solver thread gives back: its actors' pipelines and final statuses.
type SolverOutcome = (Vec<Pipeline>, Vec<LoopStatus>);

/// The solver threads, each with the actors (indices in the config's order) it solves.
struct Solvers {
    threads: Vec<(Vec<usize>, JoinHandle<SolverOutcome>)>,
}

/// Counts a solver thread out when it ends (a panic too); the last one out stops the
/// stage's inputs, as a stage of one's loop does when it ends.
struct SolverDone {
    running: Arc<std::sync::atomic::AtomicUsize>,
    stop: Arc<AtomicBool>,
}

impl Drop for SolverDone {
    fn drop(&mut self) {
        if self.running.fetch_sub(1, Ordering::AcqRel) == 1 {
            self.stop.store(true, Ordering::Relaxed);
        }
    }
}

/// Spreads the actors over `places.len()` solver threads (actor `i` on thread
/// `i mod threads`), each running [`run_loop_many`] over its actors on the clock.
fn spawn_solvers(
    pipelines: Vec<Pipeline>,
    places: Vec<Attached>,
    status: &[Arc<LatestSlot<LoopStatus>>],
    clock: &Arc<dyn Clock>,
    params: LoopParams,
    stop: &Arc<AtomicBool>,
) -> Result<Solvers, StageError> {
    let n = places.len();
    let mut groups: Vec<(Vec<usize>, Vec<Pipeline>)> =
        (0..n).map(|_| (Vec::new(), Vec::new())).collect();
    for (i, p) in pipelines.into_iter().enumerate() {
        groups[i % n].0.push(i);
        groups[i % n].1.push(p);
    }
    let running = Arc::new(std::sync::atomic::AtomicUsize::new(n));
    let mut threads = Vec::new();
    for ((members, mut ps), place) in groups.into_iter().zip(places) {
        let slots: Vec<Arc<LatestSlot<LoopStatus>>> =
            members.iter().map(|&i| Arc::clone(&status[i])).collect();
        let (clock, stop) = (Arc::clone(clock), Arc::clone(stop));
        let done = SolverDone {
            running: Arc::clone(&running),
            stop: Arc::clone(&stop),
        };
        let handle = spawn_paced("solver", place, move || {
            let _done = done;
            let refs: Vec<&LatestSlot<LoopStatus>> = slots.iter().map(|s| &**s).collect();
            let last = run_loop_many(&mut ps, &*clock, params, &stop, &refs);
            (ps, last)
        })?;
        threads.push((members, handle));
    }
    Ok(Solvers { threads })
}

/// A Rerun target that can be honoured here: `spawn` needs the `rerun` viewer on PATH;
/// without it the recording is saved to `fallback` (and the note says so).
fn usable_rerun_target(t: RerunTarget, fallback: PathBuf) -> (RerunTarget, Option<String>) {
    let on_path = std::env::var_os("PATH")
        .is_some_and(|paths| std::env::split_paths(&paths).any(|d| d.join("rerun").is_file()));
    match t {
        RerunTarget::Spawn if !on_path => {
            let note = format!(
                "no Rerun viewer on PATH: saving to {0} instead; open it with: rerun {0}",
                fallback.display()
            );
            (RerunTarget::Save(fallback), Some(note))
        }
        t => (t, None),
    }
}

/// Spawns a named thread that paces itself on the clock `place` was taken on.
fn spawn_paced<T: Send + 'static>(
    name: &'static str,
    place: Attached,
    f: impl FnOnce() -> T + Send + 'static,
) -> Result<JoinHandle<T>, StageError> {
    std::thread::Builder::new()
        .name(name.into())
        .spawn(move || {
            let _detach_on_exit = place;
            f()
        })
        .map_err(|source| StageError::Thread { name, source })
}

fn spawn<T: Send + 'static>(
    name: &'static str,
    f: impl FnOnce() -> T + Send + 'static,
) -> Result<JoinHandle<T>, StageError> {
    std::thread::Builder::new()
        .name(name.into())
        .spawn(f)
        .map_err(|source| StageError::Thread { name, source })
}

impl Stage {
    /// Starts the stage `cfg` describes on `clock`; relative paths in it are taken from
    /// `base_dir`.
    pub fn start(
        cfg: &StageConfig,
        base_dir: &Path,
        clock: Arc<dyn Clock>,
    ) -> Result<Self, StageError> {
        Self::start_with(cfg, base_dir, clock, StartOptions::default())
    }

    /// [`Self::start`] with options.
    pub fn start_with(
        cfg: &StageConfig,
        base_dir: &Path,
        clock: Arc<dyn Clock>,
        mut opts: StartOptions<'_>,
    ) -> Result<Self, StageError> {
        let t0 = std::time::Instant::now();
        let mut actors = bind_actors(
            cfg,
            base_dir,
            &clock,
            opts.progress.as_deref_mut().unwrap_or(&mut |_, _| {}),
        )?;
        let bind_s = t0.elapsed().as_secs_f64();
        let scenes = actors.scenes(cfg.solver.rate_hz);
        let sinks = Sinks::start(
            cfg,
            base_dir,
            &scenes,
            opts.frames.take(),
            opts.rerun.take(),
        )?;
        let solvers = std::mem::take(&mut actors.solvers);
        let (txs, mut pipelines, pins) = actor_pipelines(cfg, solvers, &actors, &sinks, &opts);
        let recorder = match cfg.recorder.path_at(base_dir, clock.unix_s(0.0)) {
            Some(path) => {
                let (rec_tx, handle) = start_recorder(cfg, &path, &actors.stage_names, &clock)?;
                pipelines = pipelines
                    .into_iter()
                    .zip(&actors.starts)
                    .map(|(p, &start)| p.with_recorder_at(rec_tx.clone(), start))
                    .collect();
                Some((path, handle))
            }
            None => None,
        };
        let first_rig = Arc::clone(&actors.bound[0].rig);
        let ctx = OpenContext {
            base_dir,
            markers: Some(&actors.stage_names),
            skeleton: Some(&first_rig.skeleton),
            procedural: actors.bound[0].procedural.as_ref(),
            subject: &cfg.character.subject_filter(),
            actors: actors.labels.as_deref(),
        };
        let opened = open_inputs(cfg, &ctx)?;
        let infos: Vec<InputInfo> = opened.iter().map(InputInfo::of).collect();
        let counters: Vec<Arc<SourceCounters>> = opened
            .iter()
            .map(|_| Arc::new(SourceCounters::default()))
            .collect();
        // The first actor's frames carry the inputs' rate windows (the stream's and
        // Rerun's).
        let first_pipeline = pipelines.remove(0).with_input_rates(&counters);
        pipelines.insert(0, first_pipeline);
        let rerun = start_rerun(
            cfg,
            &sinks.rerun_target,
            scenes,
            &infos,
            sinks.rerun_slots.clone(),
        )?;
        // Everything is open: the clock starts the inputs and the loop a moment from now.
        let start_s = clock.now_s() + START_DELAY_S;
        let loop_start_s = start_s + LOOP_PHASE_S;
        let end_s = match opts.stop_after_secs {
            Some(s) => Some(loop_start_s + s),
            None => opened.iter().try_fold(start_s, |end, i| {
                i.duration_s().map(|d| end.max(start_s + d))
            }),
        };
        let threads = cfg.solver.threads_for(pipelines.len());
        // The loops' places on the clock are taken before any input starts; the inputs
        // stop when the stage is dropped before it is joined, or fails to start.
        let places: Vec<Attached> = (0..threads).map(|_| Attached::new(&clock)).collect();
        let stop = Arc::new(AtomicBool::new(false));
        let stop_on_drop = StopOnDrop(Arc::clone(&stop));
        let route = Route {
            tx: txs,
            starts: actors.starts.clone(),
        };
        let sources = spawn_inputs(
            opened, &counters, &route, &clock, start_s, &stop, &pins, &first_rig,
        )?;
        drop(route);
        let params = LoopParams {
            start_s: loop_start_s,
            rate_hz: cfg.solver.rate_hz,
            deadline_fraction: cfg.solver.deadline_fraction,
            end_s,
            status_interval_s: 1.0,
        };
        let status: Vec<Arc<LatestSlot<LoopStatus>>> = pipelines
            .iter()
            .map(|_| Arc::new(LatestSlot::new()))
            .collect();
        let solvers = spawn_solvers(pipelines, places, &status, &clock, params, &stop)?;
        let server = sinks.server;
        let rig = &first_rig;
        let info = StageInfo {
            character: actors.bound[0].name.clone(),
            mesh_vertices: rig.mesh_rest.len(),
            markers: rig.n_markers,
            control_vertices: rig.stats.control_vertices,
            bind_s,
            rig_source: actors.bound[0].rig_source.clone(),
            stream_tcp: server.as_ref().and_then(StreamServer::local_addr),
            stream_ws: server.as_ref().and_then(StreamServer::ws_addr),
            inputs: infos,
            recording: recorder
                .as_ref()
                .map(|(p, _)| (p.clone(), cfg.recorder.flush_interval_secs)),
            rerun: sinks.rerun_target,
            rerun_note: sinks.rerun_note,
            start_s,
            loop_start_s,
            calibration: actors.calibration,
            actors: actors.infos,
            solver_threads: threads,
        };
        Ok(Self {
            info,
            stop,
            stop_requested: AtomicBool::new(false),
            status,
            solvers,
            sources,
            counters,
            _stop_on_drop: stop_on_drop,
            recorder,
            stream_stats: server.as_ref().map_or_else(
                || Arc::new(StreamStats::default()),
                |s| Arc::clone(s.stats()),
            ),
            server,
            rerun,
            time_limited: opts.stop_after_secs.is_some(),
        })
    }

    /// What was started.
    pub fn info(&self) -> &StageInfo {
        &self.info
    }

    /// The newest status of the loop (about once a second), if one came since the last
    /// call.
    pub fn status(&self) -> Option<Arc<LoopStatus>> {
        self.status[0].take()
    }

    /// Each actor's newest status, if one came since the last call (the config's
    /// order; for a stage of one, the same as [`Self::status`]).
    pub fn actor_statuses(&self) -> Vec<Option<Arc<LoopStatus>>> {
        self.status.iter().map(|s| s.take()).collect()
    }

    /// Stream clients connected now.
    pub fn stream_clients(&self) -> u64 {
        self.stream_stats.clients.load(Ordering::Relaxed)
    }

    /// The stream server's counters.
    pub fn stream_stats(&self) -> &Arc<StreamStats> {
        &self.stream_stats
    }

    /// Each input's counters, in the config's order.
    pub fn input_counters(&self) -> &[Arc<SourceCounters>] {
        &self.counters
    }

    /// Whether the loop has ended (by itself, or after [`Self::stop`]).
    pub fn is_finished(&self) -> bool {
        self.solvers.threads.iter().all(|(_, t)| t.is_finished())
    }

    /// Asks the loop and the inputs to stop; [`Self::join`] then shuts down.
    pub fn stop(&self) {
        self.stop_requested.store(true, Ordering::Relaxed);
        self.stop.store(true, Ordering::Relaxed);
    }

    /// Waits for the loop to end, then shuts the rest down in order: the inputs, the
    /// recorder (every sample that arrived is written), the stream (clients are told
    /// why), Rerun (flushed).
    pub fn join(self) -> Result<Summary, StageError> {
        // A panicked loop still shuts everything else down before its error is returned.
        let n_actors = self.info.actors.len();
        let mut statuses: Vec<Option<LoopStatus>> = vec![None; n_actors];
        let mut pipelines = Vec::new();
        let mut panicked = false;
        for (members, t) in self.solvers.threads {
            match t.join() {
                Ok((ps, last)) => {
                    for (&i, st) in members.iter().zip(last) {
                        statuses[i] = Some(st);
                    }
                    pipelines.extend(ps);
                }
                Err(_) => panicked = true,
            }
        }
        self.stop.store(true, Ordering::Relaxed);
        let stopped = if self.stop_requested.load(Ordering::Relaxed) {
            StopCause::Stopped
        } else if self.time_limited {
            StopCause::TimeLimit
        } else {
            StopCause::InputsEnded
        };
        let mut inputs = Vec::new();
        for ((s, info), c) in self
            .sources
            .into_iter()
            .zip(&self.info.inputs)
            .zip(&self.counters)
        {
            let mut line = match s.join() {
                Ok(Ok(line)) => format!("{}: {line}", info.kind),
                Ok(Err(e)) => format!("{}: {e}", info.kind),
                Err(_) => format!("{}: the input's thread panicked", info.kind),
            };
            let jumps = c.clock_jumps.load(Ordering::Relaxed);
            if jumps > 0 {
                line.push_str(&format!(
                    "; its source clock jumped {jumps} time{} ({} packets stamped from the receive clock)",
                    if jumps == 1 { "" } else { "s" },
                    c.clock_untrusted.load(Ordering::Relaxed)
                ));
            }
            inputs.push(line);
        }
        // Every sample that arrived before the inputs ended goes to the recorder; the
        // pipelines then let go of its channel, and it ends.
        for p in &mut pipelines {
            p.flush_to_recorder();
        }
        drop(pipelines);
        let (recorded, recording_failed) = match self.recorder {
            Some((path, handle)) => match handle.join() {
                Ok(out) => {
                    let failed = out.failed.map(|(e, lost)| {
                        format!(
                            "{e}, after {} samples; {lost} samples not written",
                            out.written
                        )
                    });
                    (Ok(Some((path, out.written))), failed)
                }
                Err(_) => (Err(StageError::Panicked { thread: "recorder" }), None),
            },
            None => (Ok(None), None),
        };
        if let Some(s) = self.server {
            s.shutdown(stopped.reason());
        }
        let rerun = match self.rerun {
            Some(r) => {
                r.stop.store(true, Ordering::Relaxed);
                match r.thread.join() {
                    Ok(()) => Ok(Some(RerunSummary {
                        frames_logged: r.stats.frames_logged.load(Ordering::Relaxed),
                        frames_skipped: r.slots.iter().map(|s| s.dropped()).sum(),
                        log_errors: r.stats.log_errors.load(Ordering::Relaxed),
                    })),
                    Err(_) => Err(StageError::Panicked { thread: "rerun" }),
                }
            }
            None => Ok(None),
        };
        let sum = |f: fn(&SourceCounters) -> u64| self.counters.iter().map(|c| f(c)).sum();
        let each = |f: fn(&SourceCounters) -> u64| self.counters.iter().map(|c| f(c)).collect();
        let s = &self.stream_stats;
        let labels: Vec<(usize, usize)> = self
            .info
            .inputs
            .iter()
            .filter_map(|i| i.label_counts)
            .collect();
        let label_sum = |f: fn(&(usize, usize)) -> usize| {
            (!labels.is_empty()).then(|| labels.iter().map(f).sum())
        };
        if panicked {
            return Err(StageError::Panicked { thread: "solver" });
        }
        let actors: Vec<ActorSummary> = self
            .info
            .actors
            .iter()
            .zip(statuses)
            .map(|(a, st)| ActorSummary {
                name: a.name.clone(),
                status: st.unwrap_or_default(),
            })
            .collect();
        Ok(Summary {
            labels_fed: label_sum(|l| l.0),
            labels_ignored: label_sum(|l| l.1),
            status: actors[0].status.clone(),
            actors,
            stopped,
            source_samples: sum(|c| c.samples.load(Ordering::Relaxed)),
            source_dropped: sum(|c| c.dropped.load(Ordering::Relaxed)),
            source_clock_jumps: each(|c| c.clock_jumps.load(Ordering::Relaxed)),
            source_clock_untrusted: each(|c| c.clock_untrusted.load(Ordering::Relaxed)),
            inputs,
            stream: StreamSummary {
                connections: s.connections.load(Ordering::Relaxed),
                frames_sent: s.frames_sent.load(Ordering::Relaxed),
                frames_skipped: s.frames_skipped.load(Ordering::Relaxed),
                write_errors: s.write_errors.load(Ordering::Relaxed),
                refused: s.refused.load(Ordering::Relaxed),
                accept_errors: s.accept_errors.load(Ordering::Relaxed),
            },
            recorded: recorded?,
            recording_failed,
            rerun: rerun?,
        })
    }
}

impl InputInfo {
    fn of(i: &Input) -> Self {
        Self {
            kind: i.kind(),
            opened: i.opened(),
            warnings: i.warnings(),
            local_addr: i.local_addr(),
            label_counts: i.label_counts(),
        }
    }
}

/// Where frames go: the vertex stream's server, Rerun's slots (used when its target is
/// not off), an in-process reader's slot; each actor's in `slots`.
struct Sinks {
    server: Option<StreamServer>,
    /// Each actor's slots: the stream's, Rerun's, and the reader's (the first actor's).
    slots: Vec<Vec<Arc<LatestSlot<DeformedFrame>>>>,
    rerun_target: RerunTarget,
    rerun_note: Option<String>,
    /// Each actor's slot for Rerun.
    rerun_slots: Vec<Arc<LatestSlot<DeformedFrame>>>,
}

impl Sinks {
    /// Starts the stream server (when the config has an address) with every actor of
    /// `scenes`, and decides the Rerun target.
    fn start(
        cfg: &StageConfig,
        base_dir: &Path,
        scenes: &[Scene],
        reader: Option<Arc<LatestSlot<DeformedFrame>>>,
        rerun: Option<RerunTarget>,
    ) -> Result<Self, StageError> {
        let fresh = || -> Vec<Arc<LatestSlot<DeformedFrame>>> {
            scenes.iter().map(|_| Arc::new(LatestSlot::new())).collect()
        };
        let stream_slots = fresh();
        let (tcp, ws) = (cfg.outputs.stream.tcp, cfg.outputs.stream.websocket);
        let server = if tcp.is_some() || ws.is_some() {
            let topologies: Vec<_> = scenes.iter().map(Scene::topology).collect();
            Some(
                StreamServer::start(&cfg.outputs.stream, &topologies, stream_slots.clone())
                    .map_err(|source| StageError::Stream {
                        addresses: [tcp, ws]
                            .iter()
                            .flatten()
                            .map(ToString::to_string)
                            .collect::<Vec<_>>()
                            .join(" and "),
                        source,
                    })?,
            )
        } else {
            None
        };
        let (rerun_target, rerun_note) = usable_rerun_target(
            rerun.unwrap_or_else(|| cfg.outputs.rerun.target(base_dir)),
            base_dir.join(format!("rigless-{}.rrd", scenes[0].character)),
        );
        let rerun_slots = fresh();
        let mut slots: Vec<Vec<_>> = stream_slots.into_iter().map(|s| vec![s]).collect();
        if rerun_target != RerunTarget::Off {
            for (s, r) in slots.iter_mut().zip(&rerun_slots) {
                s.push(Arc::clone(r));
            }
        }
        slots[0].extend(reader);
        Ok(Self {
            server,
            slots,
            rerun_target,
            rerun_note,
            rerun_slots,
        })
    }
}

/// An actor's pipeline: the solver, the marker buffer, its channel's receiving end and
/// the sinks' `slots`, with what Rerun asked for when `rerun_on`; and the glove pin slot
/// when the stage has a glove and `pinned` (the first actor).
fn assemble(
    cfg: &StageConfig,
    solver: Solver,
    rx: crossbeam_channel::Receiver<crate::markers::MarkerSample>,
    slots: Vec<Arc<LatestSlot<DeformedFrame>>>,
    rerun_on: bool,
    pinned: bool,
) -> (Pipeline, Option<Arc<PinSlot>>) {
    let rig = Arc::clone(solver.rig());
    let buffer = MarkerBuffer::new(cfg.buffer.clone(), &rig.marker_rest, &rig.marker_joint)
        .with_names(&rig.marker_names);
    let mut pipeline = Pipeline::new(solver, buffer, rx, slots);
    let rerun = &cfg.outputs.rerun;
    if rerun_on && rerun.control_mesh {
        pipeline = pipeline.with_control_mesh();
    }
    if rerun_on && rerun.harmonic_field {
        pipeline = pipeline.with_harmonic_field();
    }
    let pins = (pinned
        && cfg
            .inputs
            .iter()
            .any(crate::input::config::InputConfig::poses_joints))
    .then(|| Arc::new(PinSlot::new(rig.ik.n_params())));
    if let Some(p) = &pins {
        pipeline = pipeline.with_pins(Arc::clone(p));
    }
    (pipeline, pins)
}

/// Starts a thread per input, each with its sink into the channel (counting into its
/// `counters`, and writing the pin slot); paced inputs take their places on the clock
/// before any starts.
#[allow(clippy::too_many_arguments)]
fn spawn_inputs(
    opened: Vec<Input>,
    counters: &[Arc<SourceCounters>],
    route: &Route,
    clock: &Arc<dyn Clock>,
    start_s: f64,
    stop: &Arc<AtomicBool>,
    pins: &Option<Arc<PinSlot>>,
    rig: &Arc<Rig>,
) -> Result<Vec<JoinHandle<Result<String, InputError>>>, StageError> {
    let places: Vec<Option<Attached>> = opened
        .iter()
        .map(|i| i.is_paced().then(|| Attached::new(clock)))
        .collect();
    let mut threads = Vec::new();
    for (index, ((input, place), c)) in opened.into_iter().zip(places).zip(counters).enumerate() {
        let pins = pins.as_ref().map(|slot| PinTarget {
            slot: Arc::clone(slot),
            rig: Arc::clone(rig),
        });
        let kind = input.kind();
        let mut sink = ChannelSink::new(route.tx[0].clone(), Arc::clone(c), pins)
            .routed(route.tx.clone(), route.starts.clone())
            .named(format!("input {index} ({kind})"));
        let (clock, stop) = (Arc::clone(clock), Arc::clone(stop));
        let run = move || input.run(&*clock, start_s, &stop, &mut sink);
        threads.push(match place {
            Some(place) => spawn_paced(kind, place, run)?,
            None => spawn(kind, run)?,
        });
    }
    Ok(threads)
}

fn open_inputs(cfg: &StageConfig, ctx: &OpenContext<'_>) -> Result<Vec<Input>, StageError> {
    cfg.inputs
        .iter()
        .enumerate()
        .map(|(index, c)| {
            Input::open(c, ctx).map_err(|source| StageError::Input {
                index,
                kind: c.kind(),
                source: Box::new(source),
            })
        })
        .collect()
}

/// Creates the session file and starts the recorder thread; returns the channel the
/// loop copies samples into.
fn start_recorder(
    cfg: &StageConfig,
    path: &Path,
    marker_names: &[String],
    clock: &Arc<dyn Clock>,
) -> Result<
    (
        crossbeam_channel::Sender<crate::markers::MarkerSample>,
        JoinHandle<RecorderOutcome>,
    ),
    StageError,
> {
    let io = |source| StageError::Recorder {
        path: path.display().to_string(),
        source,
    };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(io)?;
    }
    let file = std::fs::File::create(path).map_err(io)?;
    let header = SessionHeader {
        marker_names: marker_names.to_vec(),
        rate_hz: cfg.solver.rate_hz,
        started_unix_s: clock.unix_s(0.0),
        inputs: cfg.inputs.iter().map(|i| i.describe()).collect(),
    };
    let writer =
        SessionWriter::new(file, &header, cfg.recorder.flush_interval_secs, 0.0).map_err(io)?;
    let (tx, rx) = crossbeam_channel::bounded(cfg.solver.channel_capacity * 4);
    let clock = Arc::clone(clock);
    let shown = path.display().to_string();
    let handle = spawn("recorder", move || {
        run_recorder(writer, &rx, &|| clock.now_s(), &shown)
    })?;
    Ok((tx, handle))
}

/// Starts the Rerun sink when its target is not off.
fn start_rerun(
    cfg: &StageConfig,
    target: &RerunTarget,
    scenes: Vec<Scene>,
    infos: &[InputInfo],
    slots: Vec<Arc<LatestSlot<DeformedFrame>>>,
) -> Result<Option<RunningRerun>, StageError> {
    let stop = Arc::new(AtomicBool::new(false));
    let stats = Arc::new(RerunStats::default());
    let series = infos
        .iter()
        .enumerate()
        .map(|(k, i)| format!("{k}_{}", i.kind))
        .collect();
    let r = &cfg.outputs.rerun;
    let thread = rerun_sink::start(
        &RerunOptions {
            target: target.clone(),
            mesh_every: r.mesh_every,
            control_mesh: r.control_mesh,
            harmonic_field: r.harmonic_field,
        },
        scenes,
        series,
        slots.clone(),
        Arc::clone(&stop),
        Arc::clone(&stats),
    )?;
    Ok(thread.map(|thread| RunningRerun {
        thread,
        stop,
        stats,
        slots,
    }))
}
