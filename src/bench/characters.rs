//! The `characters` suite: procedural characters (the hand and the body) playing their
//! motions at 120 Hz through
//! the frame solver (warm-started, solved to convergence), compared against the known
//! truth every frame.

use super::assets::{gltf_file, load_subdivided, makehuman_file};
use super::exercise::{exercise, ExerciseOptions, ExerciseReport};
use super::Spread;
use crate::character::bind_params::BindParams;
pub use crate::character::demo::{
    body_bind_params, demo_body, demo_hand, hand_bind_params, Motion,
};
use crate::character::procedural::{mesh_volume, skin_pose, Character};
use crate::markers::MarkerFrame;
use crate::rig::bind::{BindError, Rig};
use crate::solve::frame::{Method, SolveReport, Solver, SolverParams};
use crate::solve::harmonic::HarmonicError;

/// Why a character could not be run.
#[derive(Debug, thiserror::Error)]
pub enum CharacterRunError {
    #[error(transparent)]
    Bind(#[from] BindError),
    #[error(transparent)]
    Harmonic(#[from] HarmonicError),
}
use glam::DVec3;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// One character's run.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CharacterRecord {
    pub suite: &'static str,
    /// `"arap"` or `"harmonic"`.
    pub method: &'static str,
    pub character: String,
    pub motion: String,
    pub frames: usize,
    pub rate_hz: f64,
    pub mesh_vertices: usize,
    pub n: usize,
    pub control_tets: usize,
    pub factor_s: f64,
    pub bind_s: f64,
    pub frame_ms_p50: f64,
    pub frame_ms_p99: f64,
    pub frame_ms_max: f64,
    pub solve_ms_p50: f64,
    pub gc_ms_p50: f64,
    pub ik_ms_p50: f64,
    pub iterations_mean: f64,
    pub iterations_max: usize,
    pub converged_fraction: f64,
    pub rrms_mean: f64,
    pub bone_length_error_mean: f64,
    pub bone_length_error_max: f64,
    pub joint_limit_violation_deg_max: f64,
    pub marker_residual_mm_rms: f64,
    pub marker_residual_mm_max: f64,
    pub volume_error_mean: f64,
    pub volume_error_max: f64,
    pub inverted_tets_max: usize,
    pub gt_vertex_error_mean: f64,
    pub gt_vertex_error_max: f64,
}

/// How to play a motion through the solver.
#[derive(Clone, Copy, Debug)]
pub struct CharacterRun {
    /// Seconds of motion.
    pub seconds: f64,
    /// Frame rate, Hz.
    pub rate_hz: f64,
    /// Uniform marker noise amplitude, metres (0 for none).
    pub noise_m: f64,
    /// Each frame's deadline after its start, seconds (`1 / rate_hz` live; longer in tests
    /// that check quality independently of the machine's speed).
    pub frame_budget_s: f64,
}

/// Plays a procedural character's motion through a solver, comparing every frame with
/// the skinned truth.
pub fn run_character(
    ch: &Character,
    bind: &BindParams,
    solver_params: SolverParams,
    motion: Motion,
    run: CharacterRun,
    mut on_frame: impl FnMut(usize, &SolveReport),
) -> Result<CharacterRecord, CharacterRunError> {
    let CharacterRun {
        seconds,
        rate_hz,
        noise_m,
        frame_budget_s,
    } = run;
    let t0 = Instant::now();
    let rig = Arc::new(Rig::bind(ch, bind)?);
    let bind_s = t0.elapsed().as_secs_f64();
    let mut solver = Solver::try_new(Arc::clone(&rig), solver_params)?;
    let frames = (seconds * rate_hz).round() as usize;
    let nv = ch.vertices.len();
    let mut truth = vec![DVec3::ZERO; nv];
    let mut markers = vec![DVec3::ZERO; ch.markers.len()];
    let mut out = vec![DVec3::ZERO; nv];
    let rest_volume = mesh_volume(&ch.vertices, &ch.triangles);
    let mut frame_t = Vec::with_capacity(frames);
    let mut solve_t = Vec::with_capacity(frames);
    let mut gc_t = Vec::with_capacity(frames);
    let mut ik_t = Vec::with_capacity(frames);
    let mut rec = CharacterRecord {
        suite: "characters",
        method: solver_params.method.name(),
        character: ch.name.clone(),
        motion: motion.name().into(),
        frames,
        rate_hz,
        mesh_vertices: nv,
        n: rig.stats.control_vertices,
        control_tets: rig.stats.control_tets,
        factor_s: rig.stats.seconds_weights_factor,
        bind_s,
        frame_ms_p50: 0.0,
        frame_ms_p99: 0.0,
        frame_ms_max: 0.0,
        solve_ms_p50: 0.0,
        gc_ms_p50: 0.0,
        ik_ms_p50: 0.0,
        iterations_mean: 0.0,
        iterations_max: 0,
        converged_fraction: 0.0,
        rrms_mean: 0.0,
        bone_length_error_mean: 0.0,
        bone_length_error_max: 0.0,
        joint_limit_violation_deg_max: 0.0,
        marker_residual_mm_rms: 0.0,
        marker_residual_mm_max: 0.0,
        volume_error_mean: 0.0,
        volume_error_max: 0.0,
        inverted_tets_max: 0,
        gt_vertex_error_mean: 0.0,
        gt_vertex_error_max: 0.0,
    };
    let mut rng = 0x9E3779B97F4A7C15u64;
    let mut uniform = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let mut res2 = 0.0;
    for f in 0..frames {
        let t = f as f64 / rate_hz;
        let pose = motion.pose(&ch.skeleton, t);
        skin_pose(ch, &pose, &mut truth, &mut markers);
        let noisy: Vec<DVec3> = markers
            .iter()
            .map(|m| *m + DVec3::new(uniform(), uniform(), uniform()) * noise_m)
            .collect();
        let frame = MarkerFrame::all_present(t, noisy);
        let start = Instant::now();
        let rep = solver.solve(
            &frame,
            start + Duration::from_secs_f64(frame_budget_s),
            &mut out,
        );
        frame_t.push(start.elapsed());
        solve_t.push(Duration::from_secs_f64(rep.solve_ms / 1e3));
        gc_t.push(Duration::from_secs_f64(rep.gc_ms / 1e3));
        ik_t.push(Duration::from_secs_f64(rep.ik_ms / 1e3));
        on_frame(f, &rep);
        let vol_err = (mesh_volume(&out, &ch.triangles) - rest_volume).abs() / rest_volume;
        let (mut sum, mut max) = (0.0f64, 0.0f64);
        for (a, b) in out.iter().zip(&truth) {
            let d = (*a - *b).length();
            sum += d;
            max = max.max(d);
        }
        rec.gt_vertex_error_mean += sum / nv as f64 / rig.height_m;
        rec.gt_vertex_error_max = rec.gt_vertex_error_max.max(max / rig.height_m);
        rec.volume_error_mean += vol_err;
        rec.volume_error_max = rec.volume_error_max.max(vol_err);
        rec.inverted_tets_max = rec
            .inverted_tets_max
            .max(rig.control.inverted_tets(solver.control_positions()));
        rec.iterations_mean += rep.iterations as f64;
        rec.iterations_max = rec.iterations_max.max(rep.iterations);
        rec.converged_fraction +=
            (rep.stop == crate::solve::arap::StopReason::Converged) as u8 as f64;
        rec.rrms_mean += rep.rrms;
        rec.bone_length_error_mean += rep.bone_length_error;
        rec.bone_length_error_max = rec.bone_length_error_max.max(rep.bone_length_error);
        rec.joint_limit_violation_deg_max = rec
            .joint_limit_violation_deg_max
            .max(rep.joint_limit_violation_deg);
        res2 += rep.marker_residual_rms_mm * rep.marker_residual_rms_mm;
        rec.marker_residual_mm_max = rec.marker_residual_mm_max.max(rep.marker_residual_max_mm);
    }
    let nf = frames.max(1) as f64;
    for v in [
        &mut rec.gt_vertex_error_mean,
        &mut rec.volume_error_mean,
        &mut rec.iterations_mean,
        &mut rec.converged_fraction,
        &mut rec.rrms_mean,
        &mut rec.bone_length_error_mean,
    ] {
        *v /= nf;
    }
    rec.marker_residual_mm_rms = (res2 / nf).sqrt();
    let s = Spread::of(&frame_t);
    rec.frame_ms_p50 = s.median_ms;
    rec.frame_ms_p99 = s.p99_ms;
    rec.frame_ms_max = s.max_ms;
    rec.solve_ms_p50 = Spread::of(&solve_t).median_ms;
    rec.gc_ms_p50 = Spread::of(&gc_t).median_ms;
    rec.ik_ms_p50 = Spread::of(&ik_t).median_ms;
    Ok(rec)
}
/// The suite: the hand's finger play, the body's walk and reach, and the body at 50,000
/// triangles, 10 s at 120 Hz each, through both methods; one line per run; then the real
/// assets of the data folder `data` through the range-of-motion exercise
/// ([`asset_rows`]).
pub fn suite(
    data: &std::path::Path,
    json: bool,
    out: &mut dyn std::io::Write,
) -> Result<(), super::BenchError> {
    procedural_rows(json, out)?;
    asset_rows(data, json, out)
}

/// One real asset's exercise, as a JSON line.
#[derive(serde::Serialize)]
struct AssetRecord<'a> {
    suite: &'static str,
    asset: &'a str,
    /// Midpoint subdivisions applied to the file's mesh.
    subdivisions: usize,
    #[serde(flatten)]
    exercise: &'a ExerciseReport,
}

/// The real assets of the data folder through [`exercise`]: CesiumMan as its file has
/// it and subdivided three times (157,070 vertices: the size of the largest meshes of
/// the published methods; targets: bind under 10 s, frame p99 under 6 ms), and the
/// MakeHuman mesh with all its parts. Skipped, with the reason printed, when the data
/// folder lacks them.
fn asset_rows(
    data: &std::path::Path,
    json: bool,
    out: &mut dyn std::io::Write,
) -> Result<(), super::BenchError> {
    let dir = std::env::temp_dir().join(format!("rigless-bench-assets-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let result = (|| {
        let cesium = data.join("meshes/gltf-samples/CesiumMan.glb");
        let mut cases: Vec<(&str, Option<std::path::PathBuf>, usize, &str)> = Vec::new();
        let cesium_file = cesium
            .is_file()
            .then(|| gltf_file(&cesium, &dir))
            .transpose()
            .map_err(|e| super::BenchError::case("CesiumMan", e))?;
        cases.push(("CesiumMan", cesium_file.clone(), 0, "-"));
        cases.push(("CesiumMan", cesium_file, 3, "bind<10s p99≤6"));
        let mh =
            makehuman_file(data, &[], &dir).map_err(|e| super::BenchError::case("MakeHuman", e))?;
        cases.push(("MakeHuman all parts", mh, 0, "-"));
        if !json {
            writeln!(
                out,
                "\n{:<22} {:>7} {:>5} {:>6} {:>7} {:>8} {:>6} {:>8} {:>8} {:>7} {:>4} {:>7} {:>7} {:>6} {:>14}",
                "asset (exercise)", "verts", "n", "tets", "bind s", "green s", "frames", "p50 ms",
                "p99 ms", "gc ms", "inv", "unmoved", "limit°", "vol %", "target"
            )?;
        }
        for (name, file, levels, target) in cases {
            let Some(file) = file else {
                writeln!(out, "skipped: {name} is not in {}", data.display())?;
                continue;
            };
            let loaded =
                load_subdivided(&file, levels).map_err(|e| super::BenchError::case(name, e))?;
            let r = exercise(
                &loaded.character,
                &loaded.bind,
                ExerciseOptions::default(),
                &mut |_| {},
            )
            .map_err(|e| super::BenchError::case(name, e))?;
            if json {
                super::json_line(
                    out,
                    &AssetRecord {
                        suite: "characters",
                        asset: name,
                        subdivisions: levels,
                        exercise: &r,
                    },
                )?;
                continue;
            }
            let shown = if levels > 0 {
                format!("{name} ×{levels} subdiv")
            } else {
                name.to_string()
            };
            writeln!(
                out,
                "{:<22} {:>7} {:>5} {:>6} {:>7.2} {:>8.2} {:>6} {:>8.3} {:>8.3} {:>7.3} {:>4} {:>7} {:>7.2} {:>6.2} {:>14}",
                shown, r.mesh_vertices, r.control_vertices, r.control_tets, r.bind_s, r.green_s,
                r.frames, r.frame_ms_p50, r.frame_ms_p99, r.green_ms_p50, r.inverted_tets_max,
                r.unmoved_vertices, r.joint_limit_violation_deg_max, 100.0 * r.volume_error_max, target
            )?;
        }
        Ok(())
    })();
    // The character files were only needed to load the assets.
    if let Err(e) = std::fs::remove_dir_all(&dir) {
        tracing::warn!(dir = %dir.display(), error = %e, "could not remove the bench's temporary folder");
    }
    result
}

/// The procedural characters through both methods.
fn procedural_rows(json: bool, out: &mut dyn std::io::Write) -> Result<(), super::BenchError> {
    use crate::character::body::BodyMotion;
    let run = CharacterRun {
        seconds: 10.0,
        rate_hz: 120.0,
        noise_m: 0.0,
        frame_budget_s: 1.0 / 120.0,
    };
    let hand = demo_hand();
    let body = demo_body();
    // The body at about 50,000 triangles (25,000 vertices): the harmonic method's second
    // target.
    let body50k = crate::character::body::body(0.006, 50_000);
    // Frame p99 targets (ms) of the two methods; the harmonic method's is the body's.
    let walk = Motion::Body(BodyMotion::Walk);
    let cases = [
        (
            &hand,
            hand_bind_params(),
            Motion::FingerPlay,
            Some(1.0),
            None,
        ),
        (&body, body_bind_params(), walk, Some(4.0), Some(3.0)),
        (
            &body,
            body_bind_params(),
            Motion::Body(BodyMotion::Reach),
            Some(4.0),
            Some(3.0),
        ),
        (&body50k, body_bind_params(), walk, None, Some(15.0)),
    ];
    if !json {
        writeln!(
            out,
            "{:<9} {:<6} {:<12} {:>6} {:>5} {:>9} {:>9} {:>6} {:>8} {:>8} {:>8} {:>7} {:>7} {:>5} {:>8}",
            "method", "char", "motion", "verts", "n", "p50 ms", "p99 ms", "iters", "bone_err",
            "limit°", "res mm", "vol", "gt %", "inv", "target"
        )?;
    }
    for (ch, bind, motion, arap_target_ms, harmonic_target_ms) in cases {
        for (method, target_ms) in [
            (Method::Arap, arap_target_ms),
            (Method::Harmonic, harmonic_target_ms),
        ] {
            let params = SolverParams {
                method,
                ..SolverParams::default()
            };
            let rec = run_character(ch, &bind, params, motion, run, |_, _| {})
                .map_err(|e| super::BenchError::case(format!("the procedural {}", ch.name), e))?;
            if json {
                super::json_line(out, &rec)?;
                continue;
            }
            // The harmonic method has no control mesh: no iterations, no sampled bones
            // (the posture's are rigid), no tets.
            let arap = rec.method == "arap";
            let na = |v: String| if arap { v } else { "-".into() };
            writeln!(
                out,
                "{:<9} {:<6} {:<12} {:>6} {:>5} {:>9.3} {:>9.3} {:>6} {:>8} {:>8.3} {:>8.2} {:>7.3} {:>7.2} {:>5} {:>8}",
                rec.method,
                rec.character,
                rec.motion,
                rec.mesh_vertices,
                na(rec.n.to_string()),
                rec.frame_ms_p50,
                rec.frame_ms_p99,
                na(format!("{:.2}", rec.iterations_mean)),
                na(format!("{:.4}", rec.bone_length_error_mean)),
                rec.joint_limit_violation_deg_max,
                rec.marker_residual_mm_rms,
                rec.volume_error_mean,
                rec.gt_vertex_error_mean * 100.0,
                na(rec.inverted_tets_max.to_string()),
                target_ms.map_or("-".into(), |t| format!("p99≤{t}"))
            )?;
        }
    }
    Ok(())
}
