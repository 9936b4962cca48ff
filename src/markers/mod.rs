//! Marker frames: what the solver consumes each tick. (The marker buffer and its gap
//! filling policies come with the live daemon.)

use glam::DVec3;

/// One full frame of markers in the rig's layout order, metres, world frame.
#[derive(Clone, Debug)]
pub struct MarkerFrame {
    /// Source timestamp in seconds (device time when the protocol has one).
    pub source_time_s: f64,
    /// Position per marker.
    pub positions: Vec<DVec3>,
    /// `false` where the marker has no information this frame (held: the solver keeps
    /// its previous target, so the factorization never changes).
    pub present: Vec<bool>,
}

impl MarkerFrame {
    /// A frame where every marker is present.
    pub fn all_present(source_time_s: f64, positions: Vec<DVec3>) -> Self {
        let present = vec![true; positions.len()];
        Self {
            source_time_s,
            positions,
            present,
        }
    }
}
