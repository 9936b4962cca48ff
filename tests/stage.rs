//! Whole stages in-process on a manual clock: the bundled hand session replayed into the
//! procedural hand, the loop, the recorder and the stream all started by
//! `Stage::start`, run as fast as they compute with no sleeps, and deterministic.

use rigless::character::demo::{demo_hand, Motion};
use rigless::character::procedural::skin_pose;
use rigless::config::parse_stage;
use rigless::daemon::stage::{Stage, StartOptions, StopCause, Summary};
use rigless::output::frame::DeformedFrame;
use rigless::runtime::clock::ManualClock;
use rigless::runtime::slot::LatestSlot;
use std::sync::Arc;

/// The hand fed by the bundled finger-play session (120 Hz), stream on a free port.
const HAND_STAGE: &str = r#"
[character]
procedural = "hand"

[[inputs]]
type = "replay"
session = "hand_finger_play"

[outputs.stream]
tcp = "127.0.0.1:0"
"#;

/// Runs `text` on a manual clock for `seconds`; returns the summary and the last frame.
fn run_manual(text: &str, seconds: f64, dir: &std::path::Path) -> (Summary, Arc<DeformedFrame>) {
    let cfg = parse_stage(text, "test stage").unwrap();
    let frames = Arc::new(LatestSlot::new());
    let stage = Stage::start_with(
        &cfg,
        dir,
        Arc::new(ManualClock::new(0.0)),
        StartOptions {
            stop_after_secs: Some(seconds),
            frames: Some(Arc::clone(&frames)),
            ..StartOptions::default()
        },
    )
    .unwrap();
    let summary = stage.join().unwrap();
    (summary, frames.take().expect("a frame was published"))
}

#[test]
fn a_whole_stage_runs_on_a_manual_clock_exactly_and_deterministically() {
    let dir = tempfile::tempdir().unwrap();
    let (summary, last) = run_manual(HAND_STAGE, 2.0, dir.path());
    let st = &summary.status;
    // Ticks at loop_start + k/120 for k = 0..=240; the source's frames at start + n/120
    // for n = 0..=240 (it stops with the loop); 8 labels each, occluded ones included.
    assert_eq!(st.frames, 241);
    assert_eq!((st.overruns, st.deadline_stops), (0, 0));
    assert_eq!(summary.stopped, StopCause::TimeLimit);
    assert_eq!(summary.source_samples, 241 * 8);
    assert_eq!(summary.source_dropped, 0);
    assert_eq!(st.samples, 241 * 8, "the loop drained every sample");
    assert_eq!(last.frame, 240);
    // The last frame is the session's frame 240 (2 s): the solved mesh follows the
    // skinned truth. 3 % of the height: the characters benchmark measures 1.33 % mean
    // and 8.9 % max over the whole finger play (one nail marker per finger leaves the
    // distal joints under-bent); a single frame's mean stays well under 3 %.
    let hand = demo_hand();
    let pose = Motion::FingerPlay.pose(&hand.skeleton, 2.0);
    let mut truth = vec![glam::DVec3::ZERO; hand.vertices.len()];
    skin_pose(
        &hand,
        &pose,
        &mut truth,
        &mut vec![glam::DVec3::ZERO; hand.markers.len()],
    );
    let ys = hand.vertices.iter().map(|v| v.y);
    let height = ys.clone().fold(f64::MIN, f64::max) - ys.fold(f64::MAX, f64::min);
    let mean_err = last
        .vertices_m
        .iter()
        .zip(&truth)
        .map(|(v, t)| (v.as_dvec3() - *t).length())
        .sum::<f64>()
        / truth.len() as f64;
    assert!(
        mean_err < 0.03 * height,
        "mean vertex error {:.2} % of the height",
        100.0 * mean_err / height
    );
    // The same stage again: the same frames, bit for bit.
    let (again, last2) = run_manual(HAND_STAGE, 2.0, dir.path());
    assert_eq!(again.status.frames, 241);
    assert!(
        last2.vertices_m == last.vertices_m,
        "a manual clock is deterministic"
    );
}

#[test]
fn the_recorder_keeps_every_sample_a_manual_stage_received() {
    let dir = tempfile::tempdir().unwrap();
    let text = format!("{HAND_STAGE}\n[recorder]\npath = \"take.rlsession\"\n");
    let (summary, _) = run_manual(&text, 1.0, dir.path());
    let (path, written) = summary.recorded.expect("a recording");
    assert_eq!(path, dir.path().join("take.rlsession"));
    // 121 frames of 8 samples, every one written.
    assert_eq!(summary.source_dropped, 0);
    assert_eq!(written, 121 * 8);
    let rec = rigless::replay::recording::Recording::load_with(&path, 1.0).unwrap();
    assert_eq!(rec.labels.len(), 8);
}
