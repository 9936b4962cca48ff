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
//!   (relative change of the mesh's enclosed volume, computed on this thread); and
//!   `markers/*`: how many markers are in each fill state.
//! - `solver/convergence`: the convergence criterion after each iteration of a frame, on
//!   an `iteration` timeline as well, so a frame's convergence reads directly.
//!
//! World frame: metres, Y up (`ViewCoordinates::RIGHT_HAND_Y_UP` on `character`).

use crate::daemon::slot::LatestSlot;
use crate::markers::FillState;
use crate::protocol::vertex_stream::DeformedFrame;
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

/// What the sink logs.
#[derive(Clone, Debug, PartialEq)]
pub struct RerunOptions {
    pub target: RerunTarget,
    /// Log the mesh every this many frames (1: all).
    pub mesh_every: u64,
}

/// The parts of a character that do not change per frame.
#[derive(Clone, Debug)]
pub struct RerunScene {
    pub character: String,
    pub triangles: Vec<[u32; 3]>,
    pub marker_names: Vec<String>,
    /// Parent of each joint (`None`: root).
    pub joint_parents: Vec<Option<usize>>,
    /// Volume enclosed by the mesh at rest, m³ (for the volume error series; 0: not
    /// logged).
    pub rest_volume_m3: f64,
}

impl RerunScene {
    /// The scene of a bound character.
    pub fn of_rig(rig: &crate::rig::bind::Rig, character: &str) -> Self {
        Self {
            character: character.to_owned(),
            triangles: rig.triangles.clone(),
            marker_names: rig.marker_names.clone(),
            joint_parents: rig.skeleton.joints.iter().map(|j| j.parent).collect(),
            rest_volume_m3: crate::character::procedural::mesh_volume(
                &rig.mesh_rest,
                &rig.triangles,
            ),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RerunError {
    #[error("cannot start the Rerun recording: {0}")]
    Start(#[from] ::rerun::RecordingStreamError),
}

/// What the sink has done (the slot counts what it dropped).
#[derive(Debug, Default)]
pub struct RerunStats {
    pub frames_logged: AtomicU64,
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
fn open(target: &RerunTarget, character: &str) -> Result<::rerun::RecordingStream, RerunError> {
    // The application id must be static; the character names the recording.
    let b = ::rerun::RecordingStreamBuilder::new("rigless").recording_name(character);
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

/// Starts the sink thread: it takes frames from `slot` until `stop` is set, then logs
/// the last one and flushes. Returns `None` for [`RerunTarget::Off`].
pub fn start(
    opts: &RerunOptions,
    scene: RerunScene,
    slot: Arc<LatestSlot<DeformedFrame>>,
    stop: Arc<AtomicBool>,
    stats: Arc<RerunStats>,
) -> Result<Option<std::thread::JoinHandle<()>>, RerunError> {
    if opts.target == RerunTarget::Off {
        return Ok(None);
    }
    let rec = open(&opts.target, &scene.character)?;
    let mesh_every = opts.mesh_every.max(1);
    let handle = std::thread::Builder::new()
        .name("rerun".into())
        .spawn(move || {
            let mut logger = Logger::new(rec, scene, mesh_every);
            loop {
                let stopping = stop.load(Ordering::Relaxed);
                match slot.take() {
                    Some(f) => {
                        logger.log(&f);
                        stats.frames_logged.fetch_add(1, Ordering::Relaxed);
                    }
                    None if stopping => break,
                    None => std::thread::sleep(std::time::Duration::from_millis(1)),
                }
            }
            logger.finish();
        })
        .expect("spawning the rerun thread");
    Ok(Some(handle))
}

/// Turns frames into Rerun log calls. Logging errors are the SDK's to report (it logs
/// and drops); this side has nothing to recover.
struct Logger {
    rec: ::rerun::RecordingStream,
    scene: RerunScene,
    mesh_every: u64,
    first_time_s: Option<f64>,
    indices: Vec<::rerun::components::TriangleIndices>,
    strips: Vec<Vec<[f32; 3]>>,
    strip_colors: Vec<::rerun::Color>,
}

impl Logger {
    fn new(rec: ::rerun::RecordingStream, scene: RerunScene, mesh_every: u64) -> Self {
        let _ = rec.log_static("character", &::rerun::ViewCoordinates::RIGHT_HAND_Y_UP());
        let indices = scene
            .triangles
            .iter()
            .map(|t| ::rerun::components::TriangleIndices::from(*t))
            .collect();
        Self {
            rec,
            scene,
            mesh_every,
            first_time_s: None,
            indices,
            strips: Vec::new(),
            strip_colors: Vec::new(),
        }
    }

    fn log(&mut self, f: &DeformedFrame) {
        let rec = &self.rec;
        rec.set_time_sequence("frame", f.frame as i64);
        let t0 = *self.first_time_s.get_or_insert(f.publish_time_s);
        rec.set_duration_secs("time", (f.publish_time_s - t0).max(0.0));
        if f.frame.is_multiple_of(self.mesh_every) {
            let _ = rec.log(
                "character/mesh",
                &::rerun::Mesh3D::new(f.vertices_m.iter().map(|v| v.to_array()))
                    .with_triangle_indices(self.indices.iter().copied()),
            );
        }
        let present: Vec<usize> = (0..f.markers_m.len())
            .filter(|&k| f.markers_m[k].is_finite())
            .collect();
        let _ = rec.log(
            "character/markers",
            &::rerun::Points3D::new(present.iter().map(|&k| f.markers_m[k].to_array()))
                .with_colors(present.iter().map(|&k| {
                    let [r, g, b, a] = fill_color(f.marker_states[k]);
                    ::rerun::Color::from_unmultiplied_rgba(r, g, b, a)
                }))
                .with_labels(present.iter().map(|&k| self.scene.marker_names[k].clone()))
                .with_radii([0.006f32]),
        );
        if !f.joints_m.is_empty() {
            // One strip per bone, red where its parent joint exceeds its limits by more
            // than 0.5° (the quality target) on the solved mesh.
            self.strips.clear();
            self.strip_colors.clear();
            for (j, parent) in self.scene.joint_parents.iter().enumerate() {
                let Some(p) = *parent else { continue };
                if let (Some(a), Some(b)) = (f.joints_m.get(p), f.joints_m.get(j)) {
                    self.strips.push(vec![a.to_array(), b.to_array()]);
                    let over = f.joint_limit_excess_deg.get(p).is_some_and(|e| *e > 0.5);
                    self.strip_colors.push(if over {
                        ::rerun::Color::from_rgb(230, 60, 60)
                    } else {
                        ::rerun::Color::from_rgb(200, 200, 200)
                    });
                }
            }
            let _ = rec.log(
                "character/skeleton",
                &::rerun::LineStrips3D::new(self.strips.iter().cloned())
                    .with_colors(self.strip_colors.iter().copied()),
            );
        }
        if self.scene.rest_volume_m3 != 0.0 {
            // Relative change of the enclosed volume (signed tetrahedra from the origin).
            let v: f64 = self
                .scene
                .triangles
                .iter()
                .map(|t| {
                    let [a, b, c] = t.map(|i| f.vertices_m[i as usize].as_dvec3());
                    a.dot(b.cross(c)) / 6.0
                })
                .sum();
            let err = (v - self.scene.rest_volume_m3).abs() / self.scene.rest_volume_m3.abs();
            let _ = rec.log("solver/volume_error", &::rerun::Scalars::single(err));
        }
        let s = &f.status;
        for (name, v) in [
            ("solver/iterations", f64::from(s.iterations)),
            ("solver/solve_ms", f64::from(s.solve_ms)),
            ("solver/gc_ms", f64::from(s.gc_ms)),
            ("solver/rrms", f64::from(s.rrms)),
            ("solver/bone_length_error", f64::from(s.bone_length_error)),
            (
                "solver/joint_limit_violation_deg",
                f64::from(s.joint_limit_violation_deg),
            ),
            (
                "solver/marker_residual_rms_mm",
                f64::from(s.marker_residual_rms_mm),
            ),
        ] {
            let _ = rec.log(name, &::rerun::Scalars::single(v));
        }
        // The criterion per iteration of this frame, on the `iteration` timeline (with
        // the frame's own `frame` and `time`).
        for (i, c) in f.convergence.iter().enumerate() {
            rec.set_time_sequence("iteration", i as i64);
            let _ = rec.log(
                "solver/convergence",
                &::rerun::Scalars::single(f64::from(*c)),
            );
        }
        rec.disable_timeline("iteration");
        let mut counts = [0u32; 4];
        for st in &f.marker_states {
            counts[*st as usize] += 1;
        }
        for (state, n) in [
            FillState::Measured,
            FillState::Predicted,
            FillState::RigidFilled,
            FillState::Held,
        ]
        .iter()
        .zip(counts)
        {
            let _ = rec.log(
                format!("markers/{}", state.name()),
                &::rerun::Scalars::single(f64::from(n)),
            );
        }
    }

    fn finish(self) {
        if let Err(e) = self.rec.flush_blocking() {
            tracing::warn!("rerun: flushing the recording failed: {e}");
        }
    }
}
