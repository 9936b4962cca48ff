//! The procedural characters as the demo, the tests and the benchmarks use them: the hand
//! and the body at their standard resolutions, their binding parameters, and their
//! motions.

use super::bind_params::BindParams;
use super::body::{body, body_pose, BodyMotion};
use super::procedural::{hand, hand_pose, Character, HandMotion, Pose};
use super::skeleton::Skeleton;

/// Binding parameters for the procedural hand.
pub fn hand_bind_params() -> BindParams {
    BindParams {
        cell_size_m: 0.014,
        skeleton_step_m: 0.0126,
        w_shape: 1.0,
        w_marker: 30.0,
        w_skeleton: 1000.0,
        max_marker_distance_m: 0.03,
    }
}

/// The procedural hand used by the demo, tests and benchmarks (about 5,000 vertices).
pub fn demo_hand() -> Character {
    hand(0.0016, 10_000)
}

/// A procedural character's motion: its name and the pose at a time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Motion {
    FingerPlay,
    Body(BodyMotion),
}

impl Motion {
    pub fn name(self) -> &'static str {
        match self {
            Motion::FingerPlay => "finger_play",
            Motion::Body(m) => m.name(),
        }
    }

    /// The pose at `t_s` seconds.
    pub fn pose(self, sk: &Skeleton, t_s: f64) -> Pose {
        match self {
            Motion::FingerPlay => hand_pose(sk, HandMotion::FingerPlay, t_s),
            Motion::Body(m) => body_pose(sk, m, t_s),
        }
    }
}

/// Binding parameters for the procedural body (cells about 5 cm: the arms are two cells
/// across, the fingers are a mitten).
pub fn body_bind_params() -> BindParams {
    BindParams {
        cell_size_m: 0.05,
        skeleton_step_m: 0.045,
        w_shape: 1.0,
        w_marker: 30.0,
        w_skeleton: 1000.0,
        max_marker_distance_m: 0.15,
    }
}

/// The procedural body used by the benchmarks and tests (about 10,000 vertices).
pub fn demo_body() -> Character {
    body(0.01, 20_000)
}
