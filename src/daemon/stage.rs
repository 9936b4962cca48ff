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

use super::live_calibration::{calibrate_live, LiveCalibration, LiveCalibrationError, Target};
use super::pipeline::{run_loop, LoopParams, LoopStatus, Pipeline};
use crate::calibrate::labels::map_entries;
use crate::character::demo::{body_bind_params, demo_body, demo_hand, hand_bind_params};
use crate::character::file::{load_character, CharacterError};
use crate::character::procedural::Character;
use crate::character::roles::recognise;
use crate::config::StageConfig;
use crate::input::{ChannelSink, Input, InputError, OpenContext, PinTarget, SourceCounters};
use crate::markers::buffer::MarkerBuffer;
use crate::output::frame::DeformedFrame;
use crate::output::rerun_sink::{self, RerunOptions, RerunStats, RerunTarget};
use crate::output::scene::Scene;
use crate::output::stream::{StreamServer, StreamStats};
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
    /// The loop's final status.
    pub status: LoopStatus,
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
    status: Arc<LatestSlot<LoopStatus>>,
    solver: JoinHandle<LoopStatus>,
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
    slot: Arc<LatestSlot<DeformedFrame>>,
}

/// A bound character: the rig, its name, and the procedural character if it is one.
struct Bound {
    rig: Arc<Rig>,
    name: String,
    procedural: Option<Arc<Character>>,
    rig_source: Option<String>,
    /// Character metres per capture metre for incoming markers.
    marker_scale: f64,
}

fn bind_character(
    cfg: &StageConfig,
    base_dir: &Path,
    clock: &Arc<dyn Clock>,
    progress: &mut dyn FnMut(BindStage, f64),
) -> Result<(Bound, Option<LiveCalibration>), StageError> {
    // The live calibration, when the config asks for one, and its rig.
    let live = |target: Target<'_>, progress: &mut dyn FnMut(BindStage, f64)| {
        calibrate_live(
            &cfg.calibration,
            &cfg.inputs,
            base_dir,
            clock,
            target,
            progress,
        )
        .map(|found| found.map_or((None, None), |(l, r)| (Some(l), r)))
    };
    // The stage's marker_scale, else the live calibration's, else the file's.
    let scale = |live: &Option<LiveCalibration>, file: f64| {
        let found = live
            .as_ref()
            .and_then(|l| l.calibration.as_ref())
            .map(|c| c.scale);
        cfg.character.marker_scale.or(found).unwrap_or(file)
    };
    if let Some(p) = &cfg.character.procedural {
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
    let path = base_dir.join(cfg.character.path.as_ref().ok_or(StageError::NoCharacter)?);
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
        let (bound, calibration) = bind_character(
            cfg,
            base_dir,
            &clock,
            opts.progress.as_deref_mut().unwrap_or(&mut |_, _| {}),
        )?;
        let bind_s = t0.elapsed().as_secs_f64();
        let rig = Arc::clone(&bound.rig);
        let solver = Solver::try_new(Arc::clone(&rig), cfg.solver.params()).map_err(|source| {
            StageError::Solver {
                method: cfg.solver.method,
                character: bound.name.clone(),
                source,
            }
        })?;
        let scene =
            Scene::of_rig(&rig, &bound.name, cfg.solver.rate_hz).with_tied(solver.harmonic_tied());
        let sinks = Sinks::start(cfg, base_dir, &scene, opts.frames.take(), opts.rerun.take())?;
        let (tx, rx) = crossbeam_channel::bounded(cfg.solver.channel_capacity);
        let (mut pipeline, pins) = assemble(cfg, solver, rx, &sinks);
        pipeline = pipeline.with_marker_scale(bound.marker_scale);
        let recorder = match cfg.recorder.path_at(base_dir, clock.unix_s(0.0)) {
            Some(path) => {
                let (rec_tx, handle) = start_recorder(cfg, &path, &rig, &clock)?;
                pipeline = pipeline.with_recorder(rec_tx);
                Some((path, handle))
            }
            None => None,
        };

        let ctx = OpenContext {
            base_dir,
            markers: Some(&rig.marker_names),
            skeleton: Some(&rig.skeleton),
            procedural: bound.procedural.as_ref(),
            subject: &cfg.character.subject_filter(),
        };
        let opened = open_inputs(cfg, &ctx)?;
        let infos: Vec<InputInfo> = opened.iter().map(InputInfo::of).collect();
        let counters: Vec<Arc<SourceCounters>> = opened
            .iter()
            .map(|_| Arc::new(SourceCounters::default()))
            .collect();
        pipeline = pipeline.with_input_rates(&counters);
        let rerun = start_rerun(
            cfg,
            &sinks.rerun_target,
            scene,
            &infos,
            Arc::clone(&sinks.rerun_slot),
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
        // The loop's place on the clock is taken before any input starts; the inputs
        // stop when the stage is dropped before it is joined, or fails to start.
        let loop_place = Attached::new(&clock);
        let stop = Arc::new(AtomicBool::new(false));
        let stop_on_drop = StopOnDrop(Arc::clone(&stop));
        let sources = spawn_inputs(opened, &counters, &tx, &clock, start_s, &stop, &pins, &rig)?;
        drop(tx);
        let params = LoopParams {
            start_s: loop_start_s,
            rate_hz: cfg.solver.rate_hz,
            deadline_fraction: cfg.solver.deadline_fraction,
            end_s,
            status_interval_s: 1.0,
        };
        let status = Arc::new(LatestSlot::new());
        let solver = {
            let (clock2, stop, status) =
                (Arc::clone(&clock), Arc::clone(&stop), Arc::clone(&status));
            spawn_paced("solver", loop_place, move || {
                let last = run_loop(&mut pipeline, &*clock2, params, &stop, &status);
                // The inputs end with the loop (a paced input then sends nothing more).
                stop.store(true, Ordering::Relaxed);
                pipeline.flush_to_recorder();
                last
            })?
        };
        let server = sinks.server;
        let info = StageInfo {
            character: bound.name,
            mesh_vertices: rig.mesh_rest.len(),
            markers: rig.n_markers,
            control_vertices: rig.stats.control_vertices,
            bind_s,
            rig_source: bound.rig_source,
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
            calibration,
        };
        Ok(Self {
            info,
            stop,
            stop_requested: AtomicBool::new(false),
            status,
            solver,
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
        self.status.take()
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
        self.solver.is_finished()
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
        let status = self
            .solver
            .join()
            .map_err(|_| StageError::Panicked { thread: "solver" });
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
        // The pipeline and its recorder channel went with the solver thread.
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
                        frames_skipped: r.slot.dropped(),
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
        Ok(Summary {
            labels_fed: label_sum(|l| l.0),
            labels_ignored: label_sum(|l| l.1),
            status: status?,
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

/// Where frames go: the vertex stream's server, Rerun's slot (used when its target is
/// not off), an in-process reader's slot.
struct Sinks {
    server: Option<StreamServer>,
    slots: Vec<Arc<LatestSlot<DeformedFrame>>>,
    rerun_target: RerunTarget,
    rerun_note: Option<String>,
    rerun_slot: Arc<LatestSlot<DeformedFrame>>,
}

impl Sinks {
    /// Starts the stream server (when the config has an address) and decides the Rerun
    /// target.
    fn start(
        cfg: &StageConfig,
        base_dir: &Path,
        scene: &Scene,
        reader: Option<Arc<LatestSlot<DeformedFrame>>>,
        rerun: Option<RerunTarget>,
    ) -> Result<Self, StageError> {
        let stream_slot = Arc::new(LatestSlot::new());
        let (tcp, ws) = (cfg.outputs.stream.tcp, cfg.outputs.stream.websocket);
        let server = if tcp.is_some() || ws.is_some() {
            Some(
                StreamServer::start(
                    &cfg.outputs.stream,
                    &scene.topology(),
                    Arc::clone(&stream_slot),
                )
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
            base_dir.join(format!("rigless-{}.rrd", scene.character)),
        );
        let rerun_slot = Arc::new(LatestSlot::new());
        let mut slots = vec![stream_slot];
        if rerun_target != RerunTarget::Off {
            slots.push(Arc::clone(&rerun_slot));
        }
        slots.extend(reader);
        Ok(Self {
            server,
            slots,
            rerun_target,
            rerun_note,
            rerun_slot,
        })
    }
}

/// The loop's pipeline: the solver, the marker buffer, the channel's receiving end and
/// the sinks' slots, with what Rerun asked for; and the glove pin slot when the stage has
/// a glove.
fn assemble(
    cfg: &StageConfig,
    solver: Solver,
    rx: crossbeam_channel::Receiver<crate::markers::MarkerSample>,
    sinks: &Sinks,
) -> (Pipeline, Option<Arc<PinSlot>>) {
    let rig = Arc::clone(solver.rig());
    let buffer = MarkerBuffer::new(cfg.buffer.clone(), &rig.marker_rest, &rig.marker_joint)
        .with_names(&rig.marker_names);
    let mut pipeline = Pipeline::new(solver, buffer, rx, sinks.slots.clone());
    let rerun = &cfg.outputs.rerun;
    if sinks.rerun_target != RerunTarget::Off && rerun.control_mesh {
        pipeline = pipeline.with_control_mesh();
    }
    if sinks.rerun_target != RerunTarget::Off && rerun.harmonic_field {
        pipeline = pipeline.with_harmonic_field();
    }
    let pins = cfg
        .inputs
        .iter()
        .any(crate::input::config::InputConfig::poses_joints)
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
    tx: &crossbeam_channel::Sender<crate::markers::MarkerSample>,
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
        let mut sink = ChannelSink::new(tx.clone(), Arc::clone(c), pins)
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
    rig: &Rig,
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
        marker_names: rig.marker_names.clone(),
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
    scene: Scene,
    infos: &[InputInfo],
    slot: Arc<LatestSlot<DeformedFrame>>,
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
        scene,
        series,
        Arc::clone(&slot),
        Arc::clone(&stop),
        Arc::clone(&stats),
    )?;
    Ok(thread.map(|thread| RunningRerun {
        thread,
        stop,
        stats,
        slot,
    }))
}
