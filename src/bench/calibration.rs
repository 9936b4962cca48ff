//! The `calibration` suite: `rigless calibrate`'s time and accuracy. Known truth: the
//! bundled body takes onto the body with its layout removed (the range of motion at the
//! actor's size, 15 % smaller and larger, and five times over for a 60 s take; the reach;
//! the walk) and the hand's finger play onto the hand. Then real takes of the shared
//! data folder onto the body and the hand, and the body's range of motion onto the
//! folder's real assets: labels placed, misfit, flags.

use super::assets::{gltf_file, makehuman_file, webxr_hand_file};
use super::{json_line, BenchError};
use crate::calibrate::{calibrate, Calibration, CalibrationOptions, Verdict};
use crate::character::bind_params::BindParams;
use crate::character::demo::{body_bind_params, demo_body, demo_hand, hand_bind_params};
use crate::character::file::load_character;
use crate::character::roles::{recognise, Role};
use crate::character::Character;
use crate::daemon::offline::{replay_offline, OfflineOptions, OfflineReport};
use crate::replay::bundled::bundled;
use crate::replay::recording::Recording;
use crate::solve::frame::SolverParams;
use std::io::Write;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// Runs per case (the time's median and range).
const RUNS: usize = 3;

/// One case's figures.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CalibrationRecord {
    pub suite: &'static str,
    pub character: String,
    pub take: String,
    pub take_s: f64,
    pub labels: usize,
    pub placed: usize,
    pub left_out: usize,
    pub flagged: usize,
    /// Character metres per take metre.
    pub scale: f64,
    /// Known truth only: the scale's relative error, the offsets' distance from the
    /// truth (mm) and the labels on another joint than the truth's.
    pub scale_error: Option<f64>,
    pub offset_error_mm_mean: Option<f64>,
    pub offset_error_mm_max: Option<f64>,
    pub wrong_bones: Option<usize>,
    pub residual_mm_rms: f64,
    pub residual_mm_max: f64,
    /// The calibration's verdict and its concerns.
    pub verdict: Verdict,
    pub concerns: Vec<String>,
    pub seconds_median: f64,
    pub seconds_min: f64,
    pub seconds_max: f64,
    /// The take replayed through the live pipeline at 120 Hz with the calibrated layout
    /// and scale (each frame given its live budget).
    pub replay: Option<OfflineReport>,
}

/// A bundled take, its positions times `factor` (the actor that much the character's
/// size), repeated `times` over.
fn bundled_take(name: &str, factor: f64, times: usize) -> Result<Recording, BenchError> {
    let bytes = bundled(name)
        .ok_or_else(|| BenchError::case(name, std::io::Error::other("no such bundled take")))?;
    let mut rec = Recording::from_c3d(name, bytes).map_err(|e| BenchError::case(name, e))?;
    let one = rec.frames.clone();
    for _ in 1..times {
        rec.frames.extend(one.iter().cloned());
    }
    for p in rec.frames.iter_mut().flatten() {
        *p *= factor;
    }
    Ok(rec)
}

/// Calibrates `rec` onto `ch` [`RUNS`] times; the record, compared with `truth`'s
/// layout when given (the take `factor` times the character).
fn case(
    ch: &Character,
    roles: &[Option<Role>],
    rec: &Recording,
    truth: Option<(&Character, f64)>,
    bind: &BindParams,
) -> Result<CalibrationRecord, BenchError> {
    let mut times = Vec::with_capacity(RUNS);
    let mut cal: Option<Calibration> = None;
    let opts = CalibrationOptions {
        max_marker_distance_m: bind.max_marker_distance_m,
        ..CalibrationOptions::default()
    };
    for _ in 0..RUNS {
        let t0 = Instant::now();
        cal = Some(
            calibrate(ch, roles, rec.as_take(), &opts)
                .map_err(|e| BenchError::case(format!("{} onto {}", rec.name, ch.name), e))?,
        );
        times.push(t0.elapsed().as_secs_f64());
    }
    let Some(mut cal) = cal else {
        return Err(BenchError::case(&rec.name, std::io::Error::other("no run")));
    };
    times.sort_by(f64::total_cmp);
    let against = truth.map(|(t, factor)| {
        let errs: Vec<(bool, f64)> = cal
            .placed
            .iter()
            .filter_map(|p| {
                let m = t.markers.iter().find(|m| m.name == p.label)?;
                let rest = ch.skeleton.joints[p.joint].rest + p.offset_m;
                Some((m.joint == Some(p.joint), (rest - m.rest).length() * 1e3))
            })
            .collect();
        let n = errs.len().max(1) as f64;
        (
            (cal.scale * factor - 1.0).abs(),
            errs.iter().map(|e| e.1).sum::<f64>() / n,
            errs.iter().map(|e| e.1).fold(0.0, f64::max),
            errs.iter().filter(|e| !e.0).count(),
        )
    });
    let replay = replay_check(ch, bind, rec, &mut cal)?;
    Ok(CalibrationRecord {
        suite: "calibration",
        character: ch.name.clone(),
        take: rec.name.clone(),
        take_s: rec.frames.len() as f64 / rec.rate_hz,
        labels: rec.labels.len(),
        placed: cal.placed.len(),
        left_out: cal.left_out.len(),
        flagged: cal.placed.iter().filter(|p| p.flag.is_some()).count(),
        scale: cal.scale,
        scale_error: against.map(|a| a.0),
        offset_error_mm_mean: against.map(|a| a.1),
        offset_error_mm_max: against.map(|a| a.2),
        wrong_bones: against.map(|a| a.3),
        residual_mm_rms: cal.residual_mm_rms,
        residual_mm_max: cal.residual_mm_max,
        verdict: cal.verdict(),
        concerns: cal.concerns().iter().map(ToString::to_string).collect(),
        seconds_median: times[RUNS / 2],
        seconds_min: times[0],
        seconds_max: times[RUNS - 1],
        replay,
    })
}

/// `rec` replayed onto `ch` with the layout and scale of `cal` (labels the bind refuses
/// moved to the left-out ones).
fn replay_check(
    ch: &Character,
    bind: &BindParams,
    rec: &Recording,
    cal: &mut Calibration,
) -> Result<Option<OfflineReport>, BenchError> {
    let what = || format!("{} replayed onto {}", rec.name, ch.name);
    let rig = Arc::new(
        cal.bind(ch, bind, &mut |_, _| {})
            .map_err(|e| BenchError::case(what(), e))?,
    );
    let opts = OfflineOptions {
        marker_scale: cal.scale,
        ..OfflineOptions::default()
    };
    replay_offline(rig, SolverParams::default(), rec, opts).map_err(|e| BenchError::case(what(), e))
}

fn print(r: &CalibrationRecord, json: bool, out: &mut dyn Write) -> Result<(), BenchError> {
    if json {
        return json_line(out, r);
    }
    let known = match (r.scale_error, r.offset_error_mm_mean, r.offset_error_mm_max) {
        (Some(s), Some(mean), Some(max)) => format!(
            "scale error {:.2} %, offsets {mean:.1} mm mean {max:.1} max, {} wrong bones",
            100.0 * s,
            r.wrong_bones.unwrap_or(0)
        ),
        _ => String::new(),
    };
    writeln!(
        out,
        "{:<10} {:<22} {:>5.1} s  {:>2}/{:<2} placed {:>2} flagged  scale {:.4}  misfit {:.2} rms {:.2} max mm  {:.2} s ({:.2}–{:.2})  {}  {known}",
        r.character, r.take, r.take_s, r.placed, r.labels, r.flagged, r.scale,
        r.residual_mm_rms, r.residual_mm_max, r.seconds_median, r.seconds_min, r.seconds_max,
        r.verdict
    )?;
    for c in &r.concerns {
        writeln!(out, "{:<10} {c}", "")?;
    }
    if let Some(p) = &r.replay {
        writeln!(
            out,
            "{:<10} replayed at 120 Hz: {} labels fed, {:.1} % held, misfit {:.1} rms {:.1} max mm, bone length {:.2} %, limits +{:.2}°, inverted tets {}, frame p50 {:.2} p99 {:.2} max {:.2} ms, {} deadline stops in {}",
            "", p.labels_fed, 100.0 * p.held_share, p.residual_mm_rms, p.residual_mm_max,
            100.0 * p.bone_length_error_max, p.joint_limit_violation_deg_max, p.inverted_tets_max,
            p.frame_ms_p50, p.frame_ms_p99, p.frame_ms_max, p.deadline_stops, p.frames
        )?;
    }
    Ok(())
}

/// Runs the suite; the real cases only with `data` present.
pub fn suite(data: &Path, json: bool, out: &mut dyn Write) -> Result<(), BenchError> {
    let truth = demo_body();
    let mut bare = truth.clone();
    bare.markers.clear();
    let roles = recognise(&bare.skeleton.joints, &[]);
    for (take, factor, times) in [
        ("body_rom", 1.0, 1),
        ("body_rom", 0.85, 1),
        ("body_rom", 1.15, 1),
        ("body_rom", 1.0, 5),
        ("body_reach", 1.0, 1),
        ("body_walk", 1.0, 1),
    ] {
        let rec = bundled_take(take, factor, times)?;
        print(
            &case(
                &bare,
                &roles,
                &rec,
                Some((&truth, factor)),
                &body_bind_params(),
            )?,
            json,
            out,
        )?;
    }
    let hand = demo_hand();
    let mut bare_hand = hand.clone();
    bare_hand.markers.clear();
    let hand_roles = recognise(&hand.skeleton.joints, &[]);
    let rec = bundled_take("hand_finger_play", 1.0, 1)?;
    print(
        &case(
            &bare_hand,
            &hand_roles,
            &rec,
            Some((&hand, 1.0)),
            &hand_bind_params(),
        )?,
        json,
        out,
    )?;
    // Real takes onto the procedural characters.
    let (body_bind, hand_bind) = (body_bind_params(), hand_bind_params());
    for (file, onto, bind) in [
        ("c3d/Qualisys.c3d", &bare, &body_bind),
        ("c3d/BTS.c3d", &bare, &body_bind),
        ("c3d/FP_Type1.c3d", &bare, &body_bind),
        ("hand/dfki_hand_recording.tsv", &bare_hand, &hand_bind),
    ] {
        let path = data.join(file);
        if !path.is_file() {
            continue;
        }
        let rec = Recording::load(&path).map_err(|e| BenchError::case(file, e))?;
        let roles = recognise(&onto.skeleton.joints, &[]);
        print(&case(onto, &roles, &rec, None, bind)?, json, out)?;
    }
    // The body's range of motion and a real take onto real assets.
    let dir = std::env::temp_dir().join(format!("rigless-calibration-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let asset = |e| BenchError::case("assets", e);
    let mut files = Vec::new();
    if let Some(f) = makehuman_file(data, &["body"], &dir).map_err(asset)? {
        files.push(f);
    }
    let cesium = data.join("meshes/gltf-samples/CesiumMan.glb");
    if cesium.is_file() {
        files.push(gltf_file(&cesium, &dir).map_err(asset)?);
    }
    let rom = bundled_take("body_rom", 1.0, 1)?;
    let qualisys = Recording::load(&data.join("c3d/Qualisys.c3d")).ok();
    let takes: Vec<&Recording> = std::iter::once(&rom).chain(qualisys.as_ref()).collect();
    let mut cases: Vec<(std::path::PathBuf, Vec<&Recording>)> =
        files.into_iter().map(|f| (f, takes.clone())).collect();
    let dfki = Recording::load(&data.join("hand/dfki_hand_recording.tsv")).ok();
    if let (Some(f), Some(rec)) = (
        webxr_hand_file(data, &dir, true).map_err(asset)?,
        dfki.as_ref(),
    ) {
        cases.push((f, vec![rec]));
    }
    for (f, takes) in cases {
        let loaded =
            load_character(&f).map_err(|e| BenchError::case(f.display().to_string(), e))?;
        let mut ch = loaded.character;
        ch.markers.clear();
        for rec in takes {
            print(
                &case(&ch, &loaded.joint_roles, rec, None, &loaded.bind)?,
                json,
                out,
            )?;
        }
    }
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
