//! The Rerun sink: logs what the solver publishes to a Rerun viewer or `.rrd` file, on
//! its own thread behind a latest-value slot (a frame it cannot keep up with is replaced
//! in the slot and counted there, so logging never slows the solver).
//!
//! Entities, on the `frame` (solver tick) and `time` (seconds since the first frame)
//! timelines:
//! - `character/mesh`: the full-resolution mesh (`Mesh3D`; every `mesh_every`-th frame,
//!   every frame by default), triangles as in the character file.
//! - `character/markers`: the markers as the solver used them (`Points3D`), named, and
//!   coloured by fill state: measured green, predicted yellow, rigid-filled blue, held
//!   red.
//! - `character/skeleton`: the fitted skeleton, one line strip per bone (`LineStrips3D`),
//!   red where the bone's joint exceeds its limits by more than 0.5° on the solved mesh.
//! - `solver/*`: time series (`Scalars`): iterations, solve_ms, gc_ms, rrms,
//!   bone_length_error, joint_limit_violation_deg, marker_residual_rms_mm, volume_error
//!   (relative change of the mesh's enclosed volume, computed on this thread),
//!   untangle_projections (volume projections that unfolded control tets after the
//!   frame's iterations); and
//!   `markers/*`: how many markers are in each fill state.
//! - `solver/convergence`: the convergence criterion after each iteration of a frame, on
//!   an `iteration` timeline as well, so a frame's convergence reads directly.
//! - `character/control_mesh`: the deformed control mesh's tet edges (`LineStrips3D`), on
//!   the mesh's frames, when asked for (off by default; the ARAP method only).
//! - The harmonic method's rotation field, when asked for, on the mesh's frames: the
//!   mesh's vertices coloured by their field angle from the root segment (blue 0°, green
//!   45°, red 90° and more), and `character/correspondences`, the tied vertices as
//!   points coloured by their joint.
//! - `inputs/K_KIND/packet_rate_hz` and `inputs/K_KIND/gap_ms` for each input (`K` its
//!   place in the stage, `KIND` its scheme), every quarter second: frames per second, and
//!   the longest wait for a frame (between two frames, or since the last one), as the loop
//!   measured them ([`crate::daemon::input_rates`] fills the frames'
//!   [`InputWindowPoint`]s); each point at the frame that closed its window, so frames the
//!   sink skips lose none.
//!
//! A stage of several actors logs each under its own paths: `character/NAME/mesh`,
//! `character/NAME/markers`, ..., `solver/NAME/*` and `markers/NAME/*` (`NAME` the
//! actor's name, any character outside `A-Z a-z 0-9 _ -` as `_`); the inputs' series
//! stay as they are.
//!
//! A default blueprint lays out the 3D view beside the plots (see [`blueprint`]).
//!
//! World frame: metres, Y up (`ViewCoordinates::RIGHT_HAND_Y_UP` on `character`).

use super::frame::{DeformedFrame, InputWindowPoint};
use super::scene::Scene;
use crate::markers::FillState;
use crate::runtime::slot::LatestSlot;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

/// Where the recording goes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RerunTarget {
    Off,
    /// Start a viewer (`rerun` on PATH) and stream to it.
    Spawn,
    /// Stream to a running viewer: `HOST:PORT` (its gRPC port, 9876 by default) or a full
    /// `rerun+http://...` URL.
    Connect(String),
    /// Write a `.rrd` file.
    Save(PathBuf),
}

impl std::str::FromStr for RerunTarget {
    type Err = String;

    /// `off`, `spawn`, `connect=ADDR` or `save=PATH`.
    fn from_str(s: &str) -> Result<Self, String> {
        match s.split_once('=') {
            None if s == "off" => Ok(Self::Off),
            None if s == "spawn" => Ok(Self::Spawn),
            Some(("connect", a)) if !a.is_empty() => Ok(Self::Connect(a.to_owned())),
            Some(("save", p)) if !p.is_empty() => Ok(Self::Save(p.into())),
            _ => Err(format!(
                "{s:?}: expected off, spawn, connect=HOST:PORT or save=PATH.rrd"
            )),
        }
    }
}

impl std::fmt::Display for RerunTarget {
    /// The form [`str::parse`] reads back: `off`, `spawn`, `connect=ADDR`, `save=PATH`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Off => f.write_str("off"),
            Self::Spawn => f.write_str("spawn"),
            Self::Connect(a) => write!(f, "connect={a}"),
            Self::Save(p) => write!(f, "save={}", p.display()),
        }
    }
}

/// What the sink logs.
#[derive(Clone, Debug, PartialEq)]
pub struct RerunOptions {
    pub target: RerunTarget,
    /// Log the mesh every this many frames (1: all).
    pub mesh_every: u64,
    /// Log the control mesh as a wireframe (on the mesh's frames).
    pub control_mesh: bool,
    /// Log the harmonic rotation field and correspondences (on the mesh's frames).
    pub harmonic_field: bool,
}

/// Colour of a rotation-field angle: blue at 0°, green at 45°, red from 90°.
fn field_color(angle_deg: f32) -> ::rerun::Color {
    let t = (angle_deg / 90.0).clamp(0.0, 1.0);
    let (r, g, b) = if t < 0.5 {
        let u = t * 2.0;
        (0.0, u, 1.0 - u)
    } else {
        let u = (t - 0.5) * 2.0;
        (u, 1.0 - u, 0.0)
    };
    let c = |x: f32| (40.0 + 200.0 * x) as u8;
    ::rerun::Color::from_rgb(c(r), c(g), c(b))
}

/// A distinct colour per joint (golden-angle hues).
fn joint_color(j: u32) -> ::rerun::Color {
    let h = (j as f32 * 0.618_034).fract() * 6.0;
    let x = 1.0 - (h % 2.0 - 1.0).abs();
    let (r, g, b) = match h as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        4 => (x, 0.0, 1.0),
        _ => (1.0, 0.0, x),
    };
    let c = |v: f32| (50.0 + 200.0 * v) as u8;
    ::rerun::Color::from_rgb(c(r), c(g), c(b))
}

/// The default layout: the 3D view (mesh, markers, skeleton) on the left; on the right,
/// tabs of plots: the solver's figures, the convergence of each frame (on the
/// `iteration` timeline), markers by fill state, and the inputs. `solvers` are the
/// actors' solver series bases (`solver`, or `solver/NAME` each on a stage of several).
pub fn blueprint(solvers: &[String]) -> ::rerun::blueprint::Blueprint {
    use ::rerun::blueprint::{
        Blueprint, Horizontal, Spatial3DView, Tabs, TimeSeriesView, Vertical,
    };
    let plots = |name: &str, origin: &str| TimeSeriesView::new(name).with_origin(origin).into();
    let of = |names: &[&str]| -> Vec<String> {
        solvers
            .iter()
            .flat_map(|b| names.iter().map(move |n| format!("{b}/{n}")))
            .collect()
    };
    Blueprint::new(Horizontal::new([
        Spatial3DView::new("character")
            .with_origin("character")
            .into(),
        Vertical::new([
            Tabs::new([
                TimeSeriesView::new("timing")
                    .with_origin("solver")
                    .with_contents(of(&["solve_ms", "gc_ms", "iterations"]))
                    .into(),
                TimeSeriesView::new("quality")
                    .with_origin("solver")
                    .with_contents(of(&[
                        "rrms",
                        "bone_length_error",
                        "joint_limit_violation_deg",
                        "marker_residual_rms_mm",
                        "volume_error",
                        "untangle_projections",
                    ]))
                    .into(),
            ])
            .into(),
            Tabs::new([
                plots("convergence", "solver/convergence"),
                plots("markers", "markers"),
                plots("inputs", "inputs"),
            ])
            .into(),
        ])
        .into(),
    ]))
}

#[derive(Debug, thiserror::Error)]
pub enum RerunError {
    #[error("cannot start the Rerun recording: {0}")]
    Start(#[from] ::rerun::RecordingStreamError),
    #[error("the Rerun thread ended before opening the recording")]
    ThreadEnded,
    #[error("starting the Rerun thread: {0}")]
    Thread(std::io::Error),
}

/// What the sink has done (the slot counts what it dropped).
#[derive(Debug, Default)]
pub struct RerunStats {
    pub frames_logged: AtomicU64,
    /// Log calls the SDK refused (the first is logged as a warning, the rest counted).
    pub log_errors: AtomicU64,
}

impl RerunStats {
    /// Counts a refused log call; the first one is logged.
    fn check(&self, result: ::rerun::RecordingStreamResult<()>) {
        if let Err(e) = result {
            if self.log_errors.fetch_add(1, Ordering::Relaxed) == 0 {
                tracing::warn!("rerun: a log call failed (later failures are only counted): {e}");
            }
        }
    }
}

fn fill_color(s: FillState) -> [u8; 4] {
    match s {
        FillState::Measured => [60, 200, 90, 255],
        FillState::Predicted => [235, 200, 40, 255],
        FillState::RigidFilled => [70, 140, 240, 255],
        FillState::Held => [230, 60, 60, 255],
    }
}

/// Opens the recording for `target` (not [`RerunTarget::Off`]).
fn open(
    target: &RerunTarget,
    character: &str,
    solvers: &[String],
) -> Result<::rerun::RecordingStream, RerunError> {
    // The application id must be static; the character names the recording. The
    // blueprint is the default: a layout the user changed in the viewer stays.
    let b = ::rerun::RecordingStreamBuilder::new("rigless")
        .recording_name(character)
        .with_default_blueprint(blueprint(solvers));
    Ok(match target {
        RerunTarget::Off | RerunTarget::Spawn => b.spawn()?,
        RerunTarget::Connect(a) => {
            let url = if a.contains("://") {
                a.clone()
            } else {
                format!("rerun+http://{a}/proxy")
            };
            b.connect_grpc_opts(url)?
        }
        RerunTarget::Save(p) => b.save(p)?,
    })
}

/// Starts the sink thread: it takes each actor's frames from its `slots[i]` (one per
/// scene of `scenes`, in the stage's order) until `stop` is set, then logs the last ones
/// and flushes. Returns `None` for [`RerunTarget::Off`].
pub fn start(
    opts: &RerunOptions,
    scenes: Vec<Scene>,
    inputs: Vec<String>,
    slots: Vec<Arc<LatestSlot<DeformedFrame>>>,
    stop: Arc<AtomicBool>,
    stats: Arc<RerunStats>,
) -> Result<Option<std::thread::JoinHandle<()>>, RerunError> {
    assert_eq!(scenes.len(), slots.len(), "a slot per actor");
    if opts.target == RerunTarget::Off {
        return Ok(None);
    }
    let opts = RerunOptions {
        mesh_every: opts.mesh_every.max(1),
        ..opts.clone()
    };
    // The recording is opened on the sink's thread, after it has lowered its priority,
    // so the SDK's own threads (batcher, file or network sink) inherit the lower
    // priority too; the open's outcome comes back here.
    let (opened_tx, opened_rx) = std::sync::mpsc::sync_channel(1);
    let handle = std::thread::Builder::new()
        .name("rerun".into())
        .spawn(move || {
            lower_thread_priority();
            // `start` waits for this answer, so its receiver is there to take it.
            let actors: Vec<ActorLog> = scenes.into_iter().map(ActorLog::new).collect();
            let solvers: Vec<String> = actors.iter().map(|a| a.solver.clone()).collect();
            let rec = match open(&opts.target, &actors[0].scene.character, &solvers) {
                Ok(rec) => {
                    opened_tx.send(Ok(())).expect("start waits for the answer");
                    rec
                }
                Err(e) => {
                    opened_tx.send(Err(e)).expect("start waits for the answer");
                    return;
                }
            };
            let mut logger = Logger::new(rec, actors, &opts, inputs, Arc::clone(&stats));
            loop {
                let stopping = stop.load(Ordering::Relaxed);
                let mut logged = false;
                for slot in &slots {
                    if let Some(f) = slot.take() {
                        logger.log(&f);
                        stats.frames_logged.fetch_add(1, Ordering::Relaxed);
                        logged = true;
                    }
                }
                match logged {
                    true => {}
                    false if stopping => break,
                    false => std::thread::sleep(std::time::Duration::from_millis(1)),
                }
            }
            logger.finish();
        })
        .map_err(RerunError::Thread)?;
    match opened_rx.recv() {
        Ok(Ok(())) => Ok(Some(handle)),
        Ok(Err(e)) => Err(e),
        Err(_) => Err(RerunError::ThreadEnded),
    }
}

/// Nice value of the sink's threads: below the solver's (0), so that on a machine with
/// few cores the scheduler lets the solver run first when both are ready.
const SINK_NICE: i32 = 10;

/// Lowers the calling thread's scheduling priority to [`SINK_NICE`] (Linux: the nice
/// value is per thread and new threads inherit it). Elsewhere, or if refused, nothing
/// changes; logging still works.
fn lower_thread_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: setpriority on the calling thread's id has no memory effects.
    unsafe {
        let tid = libc::gettid();
        if libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, SINK_NICE) != 0 {
            tracing::debug!("rerun: the sink's priority stays as it was (setpriority refused)");
        }
    }
}

/// Turns frames into Rerun log calls. A refused call is counted in [`RerunStats`] (the
/// first one logged); there is nothing to recover.
struct Logger {
    rec: ::rerun::RecordingStream,
    stats: Arc<RerunStats>,
    /// Each actor's paths and state, by its index on the stage.
    actors: Vec<ActorLog>,
    mesh_every: u64,
    control_mesh: bool,
    harmonic_field: bool,
    inputs: Vec<InputSeries>,
    first_time_s: Option<f64>,
}

/// The solver's series, under each actor's `solver` base.
const SOLVER_SERIES: [&str; 8] = [
    "iterations",
    "solve_ms",
    "gc_ms",
    "rrms",
    "bone_length_error",
    "joint_limit_violation_deg",
    "marker_residual_rms_mm",
    "untangle_projections",
];

/// One actor's entity paths (built once) and what its frames are drawn with.
struct ActorLog {
    scene: Scene,
    /// `solver` or `solver/NAME`.
    solver: String,
    mesh: String,
    markers: String,
    skeleton: String,
    control_mesh: String,
    correspondences: String,
    volume_error: String,
    convergence: String,
    /// [`SOLVER_SERIES`] under `solver`.
    series: Vec<String>,
    /// `markers/STATE` (or `markers/NAME/STATE`) for each fill state.
    states: Vec<String>,
    /// The markers' names as Rerun text (shared buffers: a clone does not copy).
    labels: Vec<::rerun::components::Text>,
    strips: Vec<Vec<[f32; 3]>>,
    strip_colors: Vec<::rerun::Color>,
}

/// An actor's name as one entity path part: `A-Z a-z 0-9 _ -` kept, anything else `_`.
fn path_part(name: &str) -> String {
    name.chars()
        .map(|c| match c {
            'A'..='Z' | 'a'..='z' | '0'..='9' | '_' | '-' => c,
            _ => '_',
        })
        .collect()
}

impl ActorLog {
    fn new(scene: Scene) -> Self {
        let (base, solver, markers_base) = if scene.actor_count > 1 {
            let n = path_part(&scene.actor);
            (
                format!("character/{n}"),
                format!("solver/{n}"),
                format!("markers/{n}"),
            )
        } else {
            ("character".into(), "solver".into(), "markers".into())
        };
        let labels = scene
            .marker_names
            .iter()
            .map(|n| ::rerun::components::Text::from(n.as_str()))
            .collect();
        Self {
            mesh: format!("{base}/mesh"),
            markers: format!("{base}/markers"),
            skeleton: format!("{base}/skeleton"),
            control_mesh: format!("{base}/control_mesh"),
            correspondences: format!("{base}/correspondences"),
            volume_error: format!("{solver}/volume_error"),
            convergence: format!("{solver}/convergence"),
            series: SOLVER_SERIES
                .iter()
                .map(|n| format!("{solver}/{n}"))
                .collect(),
            states: FillState::ALL
                .iter()
                .map(|st| format!("{markers_base}/{}", st.name()))
                .collect(),
            labels,
            strips: Vec::new(),
            strip_colors: Vec::new(),
            scene,
            solver,
        }
    }
}

/// An input's plotted series: its entity path and the last window logged.
struct InputSeries {
    /// `inputs/K_KIND`.
    base: String,
    /// The frame that closed the last window logged.
    logged_through: Option<u64>,
}

impl InputSeries {
    /// Logs `p` (a window of this input) unless it was logged already, at the frame that
    /// closed it; `t0_unix_s` is the `time` timeline's zero.
    fn log(
        &mut self,
        rec: &::rerun::RecordingStream,
        stats: &RerunStats,
        p: &InputWindowPoint,
        t0_unix_s: f64,
    ) {
        if self.logged_through.is_some_and(|f| p.frame <= f) {
            return;
        }
        self.logged_through = Some(p.frame);
        rec.set_time_sequence("frame", p.frame as i64);
        rec.set_duration_secs("time", (p.unix_s - t0_unix_s).max(0.0));
        let base = &self.base;
        stats.check(rec.log(
            format!("{base}/packet_rate_hz"),
            &::rerun::Scalars::single(p.rate_hz),
        ));
        stats.check(rec.log(
            format!("{base}/gap_ms"),
            &::rerun::Scalars::single(p.gap_s * 1e3),
        ));
    }
}

/// Logs actor `a`'s mesh of frame `f`, with the harmonic field as its colours and the
/// control mesh when `(harmonic_field, control_mesh)` ask for them and the frame has them.
fn log_mesh(
    rec: &::rerun::RecordingStream,
    stats: &RerunStats,
    a: &ActorLog,
    f: &DeformedFrame,
    (harmonic_field, control_mesh): (bool, bool),
) {
    let mut mesh = ::rerun::Mesh3D::update_fields()
        .with_vertex_positions(f.vertices_m.iter().map(|v| v.to_array()));
    // The harmonic method's field as the vertices' colours.
    let field =
        harmonic_field && !a.scene.tied.is_empty() && f.field_deg.len() == f.vertices_m.len();
    if field {
        mesh = mesh.with_vertex_colors(f.field_deg.iter().map(|a| field_color(*a)));
    }
    stats.check(rec.log(a.mesh.as_str(), &mesh));
    if field {
        stats.check(
            rec.log(
                a.correspondences.as_str(),
                &::rerun::Points3D::update_fields().with_positions(
                    a.scene
                        .tied
                        .iter()
                        .filter_map(|&(v, _)| f.vertices_m.get(v as usize))
                        .map(|p| p.to_array()),
                ),
            ),
        );
    }
    if control_mesh && !f.control_m.is_empty() {
        let p = &f.control_m;
        stats.check(
            rec.log(
                a.control_mesh.as_str(),
                &::rerun::LineStrips3D::new(
                    a.scene
                        .control_edges
                        .iter()
                        .map(|&[i, j]| [p[i as usize].to_array(), p[j as usize].to_array()]),
                )
                .with_radii([::rerun::Radius::new_ui_points(0.5)])
                .with_colors([::rerun::Color::from_unmultiplied_rgba(120, 160, 220, 90)]),
            ),
        );
    }
}

/// Logs actor `a`'s fitted skeleton of frame `f`: one strip per bone, red where its
/// parent joint exceeds its limits by more than 0.5° (the quality target) on the solved
/// mesh.
fn log_skeleton(
    rec: &::rerun::RecordingStream,
    stats: &RerunStats,
    a: &mut ActorLog,
    f: &DeformedFrame,
) {
    a.strips.clear();
    a.strip_colors.clear();
    for (j, parent) in a.scene.joint_parents.iter().enumerate() {
        let Some(p) = *parent else { continue };
        if let (Some(x), Some(y)) = (f.joints_m.get(p), f.joints_m.get(j)) {
            a.strips.push(vec![x.to_array(), y.to_array()]);
            let over = f.joint_limit_excess_deg.get(p).is_some_and(|e| *e > 0.5);
            a.strip_colors.push(if over {
                ::rerun::Color::from_rgb(230, 60, 60)
            } else {
                ::rerun::Color::from_rgb(200, 200, 200)
            });
        }
    }
    stats.check(
        rec.log(
            a.skeleton.as_str(),
            &::rerun::LineStrips3D::new(a.strips.iter().cloned())
                .with_colors(a.strip_colors.iter().copied()),
        ),
    );
}

impl Logger {
    fn new(
        rec: ::rerun::RecordingStream,
        actors: Vec<ActorLog>,
        opts: &RerunOptions,
        inputs: Vec<String>,
        stats: Arc<RerunStats>,
    ) -> Self {
        stats.check(rec.log_static("character", &::rerun::ViewCoordinates::RIGHT_HAND_Y_UP()));
        for a in &actors {
            let scene = &a.scene;
            // The triangles never change: logged once, static; frames carry positions.
            stats.check(
                rec.log_static(
                    a.mesh.as_str(),
                    &::rerun::Mesh3D::update_fields().with_triangle_indices(
                        scene
                            .triangles
                            .iter()
                            .map(|t| ::rerun::components::TriangleIndices::from(*t)),
                    ),
                ),
            );
            if opts.harmonic_field && !scene.tied.is_empty() {
                stats.check(
                    rec.log_static(
                        a.correspondences.as_str(),
                        &::rerun::Points3D::update_fields()
                            .with_colors(scene.tied.iter().map(|&(_, j)| joint_color(j)))
                            .with_radii([::rerun::Radius::new_ui_points(2.0)]),
                    ),
                );
            }
        }
        Self {
            rec,
            stats,
            actors,
            mesh_every: opts.mesh_every,
            control_mesh: opts.control_mesh,
            harmonic_field: opts.harmonic_field,
            inputs: inputs
                .into_iter()
                .map(|name| InputSeries {
                    base: format!("inputs/{name}"),
                    logged_through: None,
                })
                .collect(),
            first_time_s: None,
        }
    }

    fn log(&mut self, f: &DeformedFrame) {
        let rec = &self.rec;
        let stats = &*self.stats;
        let Some(a) = self.actors.get_mut(usize::from(f.actor)) else {
            return;
        };
        rec.set_time_sequence("frame", f.frame as i64);
        let t0 = *self.first_time_s.get_or_insert(f.publish_time_s);
        rec.set_duration_secs("time", (f.publish_time_s - t0).max(0.0));
        if f.frame.is_multiple_of(self.mesh_every) {
            let opts = (self.harmonic_field, self.control_mesh);
            log_mesh(rec, stats, a, f, opts);
        }
        let present: Vec<usize> = (0..f.markers_m.len())
            .filter(|&k| f.markers_m[k].is_finite())
            .collect();
        stats.check(
            rec.log(
                a.markers.as_str(),
                &::rerun::Points3D::new(present.iter().map(|&k| f.markers_m[k].to_array()))
                    .with_colors(present.iter().map(|&k| {
                        let [r, g, b, a] = fill_color(f.marker_states[k]);
                        ::rerun::Color::from_unmultiplied_rgba(r, g, b, a)
                    }))
                    .with_labels(present.iter().filter_map(|&k| a.labels.get(k).cloned()))
                    .with_radii([0.006f32]),
            ),
        );
        if !f.joints_m.is_empty() {
            log_skeleton(rec, stats, a, f);
        }
        if a.scene.rest_volume_m3 != 0.0 {
            // Relative change of the enclosed volume.
            let v = crate::character::procedural::mesh_volume_of(&a.scene.triangles, |i| {
                f.vertices_m[i as usize].as_dvec3()
            });
            let err = (v - a.scene.rest_volume_m3).abs() / a.scene.rest_volume_m3.abs();
            stats.check(rec.log(a.volume_error.as_str(), &::rerun::Scalars::single(err)));
        }
        let s = &f.status;
        let values = [
            f64::from(s.iterations),
            f64::from(s.solve_ms),
            f64::from(s.gc_ms),
            f64::from(s.rrms),
            f64::from(s.bone_length_error),
            f64::from(s.joint_limit_violation_deg),
            f64::from(s.marker_residual_rms_mm),
            f64::from(f.untangle_projections),
        ];
        for (name, v) in a.series.iter().zip(values) {
            stats.check(rec.log(name.as_str(), &::rerun::Scalars::single(v)));
        }
        // The criterion per iteration of this frame, on the `iteration` timeline (with
        // the frame's own `frame` and `time`).
        for (i, c) in f.convergence.iter().enumerate() {
            rec.set_time_sequence("iteration", i as i64);
            stats.check(rec.log(
                a.convergence.as_str(),
                &::rerun::Scalars::single(f64::from(*c)),
            ));
        }
        rec.disable_timeline("iteration");
        let mut counts = [0u32; 4];
        for st in &f.marker_states {
            counts[*st as usize] += 1;
        }
        for (path, n) in a.states.iter().zip(counts) {
            stats.check(rec.log(path.as_str(), &::rerun::Scalars::single(f64::from(n))));
        }
        // Last: each window moves the timelines to the frame that closed it.
        for p in &f.input_windows {
            if let Some(series) = self.inputs.get_mut(p.input) {
                series.log(rec, stats, p, t0);
            }
        }
    }

    fn finish(self) {
        if let Err(e) = self.rec.flush_blocking() {
            tracing::warn!("rerun: flushing the recording failed: {e}");
        }
    }
}
