//! The `export` suite: how fast `rigless replay --solve --export` turns a take into a
//! file: the bundled hand finger play and body walk, solved off line at the take's rate
//! without deadlines, three runs each, written (to a temporary file) as a PC2 point cache
//! in one pass (one thread) and in a part per core, and as a BVH (the posture alone) in a
//! part per core.

use super::BenchError;
use crate::character::demo::{body_bind_params, demo_body, demo_hand, hand_bind_params};
use crate::daemon::offline::{export_take, ExportOptions, ExportSummary};
use crate::replay::bundled::bundled;
use crate::replay::recording::Recording;
use crate::rig::bind::Rig;
use crate::solve::frame::SolverParams;
use std::path::Path;
use std::sync::Arc;

/// Runs per case.
const RUNS: usize = 3;

/// The suite.
pub fn suite(json: bool, out: &mut dyn std::io::Write) -> Result<(), BenchError> {
    let cases = [
        ("hand", "hand_finger_play", demo_hand(), hand_bind_params()),
        ("body", "body_walk", demo_body(), body_bind_params()),
    ];
    let dir = std::env::temp_dir().join(format!("rigless-bench-export-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let result = (|| {
        for (character, take, ch, params) in cases {
            let bytes = bundled(take)
                .ok_or_else(|| BenchError::case(take, std::io::Error::other("not bundled")))?;
            let rec = Recording::from_c3d(take, bytes).map_err(|e| BenchError::case(take, e))?;
            let rig = Arc::new(Rig::bind(&ch, &params).map_err(|e| BenchError::case(take, e))?);
            // The point cache in one pass, then in a part per core; the skeleton.
            for (threads, format) in [(1, "pc2"), (0, "pc2"), (0, "bvh")] {
                let path = dir.join(format!("take.{format}"));
                let (s, fps) = runs(&rig, &rec, threads, &path, take)?;
                let (lo, median, hi) = (fps[0], fps[RUNS / 2], fps[RUNS - 1]);
                let bytes = std::fs::metadata(&path)?.len();
                if json {
                    super::json_line(
                        out,
                        &serde_json::json!({
                            "suite": "export", "character": character, "take": take,
                            "format": format, "parts": s.parts, "frames": s.frames, "points": s.points,
                            "rate_hz": s.rate_hz, "frames_per_second_median": median,
                            "frames_per_second_min": lo, "frames_per_second_max": hi,
                            "bytes": bytes, "misfit_mm_rms": s.replay.residual_mm_rms,
                        }),
                    )?;
                } else {
                    writeln!(
                        out,
                        "{character:<5} {take:<17} {format} {} part(s), {} frames of {} points: {median:.0} frames/s ({lo:.0}–{hi:.0}), {:.1} times real time; {:.1} MB; misfit {:.1} mm RMS",
                        s.parts,
                        s.frames,
                        s.points,
                        median / s.rate_hz,
                        bytes as f64 / 1e6,
                        s.replay.residual_mm_rms
                    )?;
                }
            }
        }
        Ok(())
    })();
    // The temporary file goes whatever happened; failing to remove it is only logged.
    if let Err(e) = std::fs::remove_dir_all(&dir) {
        tracing::debug!("removing {}: {e}", dir.display());
    }
    result
}

/// [`RUNS`] exports of `rec` onto `rig` with `threads`: the last summary and the frames
/// per second of each run, sorted.
fn runs(
    rig: &Arc<Rig>,
    rec: &Recording,
    threads: usize,
    path: &Path,
    take: &str,
) -> Result<(ExportSummary, Vec<f64>), BenchError> {
    let mut fps = Vec::with_capacity(RUNS);
    let mut last = None;
    for _ in 0..RUNS {
        let t0 = std::time::Instant::now();
        let opts = ExportOptions {
            marker_scale: 1.0,
            threads,
        };
        let s = export_take(
            Arc::clone(rig),
            SolverParams::default(),
            rec,
            opts,
            path,
            &mut |_, _| {},
        )
        .map_err(|e| BenchError::case(take, e))?;
        fps.push(s.frames as f64 / t0.elapsed().as_secs_f64());
        last = Some(s);
    }
    fps.sort_by(f64::total_cmp);
    let s = last.ok_or_else(|| BenchError::case(take, std::io::Error::other("no run")))?;
    Ok((s, fps))
}
