//! The in-process frame: what the fixed-rate loop publishes to every sink, an
//! `Arc<DeformedFrame>` per tick. It holds what goes on the wire (a [`FrameView`] of it is
//! what the vertex stream encodes) and what only in-process sinks read (the fitted
//! skeleton, the convergence trace, the control mesh, the harmonic field).

use crate::markers::FillState;
use crate::protocol::vertex_stream::{FrameStatus, FrameView};
use glam::Vec3;

/// One solved frame.
#[derive(Clone, Debug, PartialEq)]
pub struct DeformedFrame {
    /// Frame number, counting solver ticks from 0.
    pub frame: u64,
    /// The actor solved: its index in the stage's config (0 on a stage of one).
    pub actor: u8,
    /// The markers' source time, seconds.
    pub source_time_s: f64,
    /// When the newest marker sample this frame used reached the daemon, seconds since
    /// the Unix epoch (0: none yet).
    pub received_time_s: f64,
    /// When the frame was published, seconds since the Unix epoch.
    pub publish_time_s: f64,
    pub status: FrameStatus,
    /// Fill state of each marker.
    pub marker_states: Vec<FillState>,
    /// Each marker's position as the solver used it, metres.
    pub markers_m: Vec<Vec3>,
    /// Full-resolution vertices, metres, world frame.
    pub vertices_m: Vec<Vec3>,
    /// The fitted skeleton's joint positions, metres.
    pub joints_m: Vec<Vec3>,
    /// The solver's convergence criterion after each iteration of this frame.
    pub convergence: Vec<f32>,
    /// Per joint, the excess over its limits on the solved mesh, degrees.
    pub joint_limit_excess_deg: Vec<f32>,
    /// The deformed control mesh's vertices, metres (empty unless the loop was asked for
    /// them).
    pub control_m: Vec<Vec3>,
    /// Harmonic method: per vertex, the rotation field's angle from the root segment,
    /// degrees (empty unless the loop was asked for it).
    pub field_deg: Vec<f32>,
    /// Volume projections the solver made to unfold control tets this frame (0 on most
    /// frames).
    pub untangle_projections: u32,
    /// The inputs' most recent rate windows, oldest first (at most a few per input: a
    /// sink that skips frames still finds every window in a later one).
    pub input_windows: Vec<InputWindowPoint>,
}

/// One input's packet rate and longest gap over a window of the stage's clock, measured
/// by the loop when the window closed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InputWindowPoint {
    /// The input's index in the stage's config.
    pub input: usize,
    /// The frame (solver tick) that closed the window.
    pub frame: u64,
    /// When the window closed, seconds since the Unix epoch (the stage's clock).
    pub unix_s: f64,
    /// Frames (packets) the input received per second over the window, Hz.
    pub rate_hz: f64,
    /// The longest time without a frame in the window, seconds: between two of the
    /// input's frames (its own clock), or since its last frame when it went quiet.
    pub gap_s: f64,
}

impl DeformedFrame {
    /// A frame with room for `markers` markers, `vertices` vertices (all zero) and
    /// `convergence` convergence values (so that filling it never allocates).
    pub fn with_sizes(markers: usize, vertices: usize, convergence: usize) -> Self {
        Self {
            frame: 0,
            actor: 0,
            source_time_s: 0.0,
            received_time_s: 0.0,
            publish_time_s: 0.0,
            status: FrameStatus::ZERO,
            marker_states: vec![FillState::Held; markers],
            markers_m: vec![Vec3::ZERO; markers],
            vertices_m: vec![Vec3::ZERO; vertices],
            joints_m: Vec::new(),
            convergence: Vec::with_capacity(convergence),
            joint_limit_excess_deg: Vec::new(),
            control_m: Vec::new(),
            field_deg: Vec::new(),
            untangle_projections: 0,
            input_windows: Vec::new(),
        }
    }

    /// What the vertex stream sends of this frame.
    pub fn wire(&self) -> FrameView<'_> {
        FrameView {
            frame: self.frame,
            actor: self.actor,
            source_time_s: self.source_time_s,
            publish_time_s: self.publish_time_s,
            status: self.status,
            marker_states: fill_codes(&self.marker_states),
            markers_m: &self.markers_m,
            vertices_m: &self.vertices_m,
            received_time_s: self.received_time_s,
            joints_m: &self.joints_m,
        }
    }
}

/// The wire codes of fill states, without copying.
fn fill_codes(states: &[FillState]) -> &[u8] {
    // SAFETY: `FillState` is a fieldless `#[repr(u8)]` enum, so a slice of it has the
    // layout of a slice of `u8` of the same length, and every value is a valid `u8`.
    unsafe { std::slice::from_raw_parts(states.as_ptr().cast::<u8>(), states.len()) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::vertex_stream::{decode, encode_frame, Message};

    #[test]
    fn fill_states_go_on_the_wire_as_their_codes() {
        let mut f = DeformedFrame::with_sizes(4, 1, 0);
        f.marker_states.copy_from_slice(&FillState::ALL);
        let mut b = Vec::new();
        encode_frame(&f.wire(), &mut b);
        let Ok((Message::Frame(w), _)) = decode(&b) else {
            panic!("a frame decodes");
        };
        assert_eq!(w.marker_states, vec![0, 1, 2, 3]);
        for (code, s) in w.marker_states.iter().zip(FillState::ALL) {
            assert_eq!(FillState::from_code(*code), Some(s));
        }
    }
}
