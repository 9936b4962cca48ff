//! The procedural body follows its walk and reach within the quality targets.

use rigless::bench::characters::{
    body_bind_params, demo_body, run_character, CharacterRun, Motion,
};
use rigless::character::body::BodyMotion;
use rigless::solve::frame::{SolveReport, SolverParams};

/// 1.8 s of `motion` (a full gait cycle of 1.1 s, and most of the reach: 3.2 s cycle, its
/// farthest point at 1.6 s) through a solver with `params`; `on_frame` sees each report.
fn play(
    motion: BodyMotion,
    params: SolverParams,
    on_frame: impl FnMut(usize, &SolveReport),
) -> rigless::bench::characters::CharacterRecord {
    run_character(
        &demo_body(),
        &body_bind_params(),
        params,
        Motion::Body(motion),
        CharacterRun {
            seconds: 1.8,
            rate_hz: 120.0,
            noise_m: 0.0,
            // Quality must not depend on this machine's speed: no deadline stops.
            frame_budget_s: 10.0,
        },
        on_frame,
    )
    .expect("body binds")
}

#[test]
fn the_body_walks_and_reaches_within_the_quality_targets() {
    for motion in [BodyMotion::Walk, BodyMotion::Reach] {
        let mut worst_limit_deg = 0.0f64;
        let rec = play(motion, SolverParams::default(), |_, r| {
            worst_limit_deg = worst_limit_deg.max(r.joint_limit_violation_deg)
        });
        // The targets (DESIGN.md's quality table).
        assert!(
            worst_limit_deg <= 0.5,
            "{motion:?}: limits exceeded by {worst_limit_deg}°"
        );
        assert!(rec.bone_length_error_mean <= 0.005, "{rec:?}");
        assert!(rec.marker_residual_mm_rms <= 2.0, "{rec:?}");
        assert!(rec.volume_error_mean <= 0.02, "{rec:?}");
        assert_eq!(rec.inverted_tets_max, 0, "{rec:?}");
        assert!(rec.gt_vertex_error_mean <= 0.02, "{rec:?}");
    }
}

/// The second method (harmonic rotation fields, de Aguiar et al.) on the same motions:
/// the same ground-truth and volume targets (the skeleton figures are the posture fit's,
/// rigid by construction).
#[test]
fn the_harmonic_method_follows_the_body_within_the_quality_targets() {
    use rigless::solve::frame::Method;
    for motion in [BodyMotion::Walk, BodyMotion::Reach] {
        let rec = play(
            motion,
            SolverParams {
                method: Method::Harmonic,
                ..SolverParams::default()
            },
            |_, _| {},
        );
        assert_eq!(rec.method, "harmonic");
        assert!(rec.marker_residual_mm_rms <= 2.0, "{rec:?}");
        assert!(rec.volume_error_mean <= 0.02, "{rec:?}");
        assert!(rec.gt_vertex_error_mean <= 0.02, "{rec:?}");
    }
}
