//! Markers between the inputs and the solver: [`MarkerSample`] (what an input sends, one
//! marker at one instant), [`MarkerFrame`] (what the solver consumes each tick, every
//! marker with a position and a [`FillState`]), and the [`buffer::MarkerBuffer`] that
//! turns the first into the second with gap filling; [`index::MarkerIndex`] finds a
//! marker by the name an input gives it.

pub mod buffer;
pub mod index;

use glam::DVec3;

/// How a marker's position in a [`MarkerFrame`] was obtained. The discriminants are the
/// vertex stream's wire codes (`protocols/vertex-stream.md`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
#[repr(u8)]
pub enum FillState {
    /// A sample from an input, recent enough to count as this frame's.
    Measured = 0,
    /// Short gap: extrapolated from the marker's own recent motion.
    Predicted = 1,
    /// Carried rigidly by three or more measured markers of the same body segment.
    RigidFilled = 2,
    /// No information: the solver keeps the marker's bound point where its bone takes it.
    Held = 3,
}

impl FillState {
    pub const ALL: [FillState; 4] = [
        FillState::Measured,
        FillState::Predicted,
        FillState::RigidFilled,
        FillState::Held,
    ];

    /// The snake_case name used in logs, JSON and the stream documentation.
    pub fn name(self) -> &'static str {
        match self {
            FillState::Measured => "measured",
            FillState::Predicted => "predicted",
            FillState::RigidFilled => "rigid_filled",
            FillState::Held => "held",
        }
    }

    /// The state for a wire code, if valid.
    pub fn from_code(code: u8) -> Option<Self> {
        Self::ALL.get(code as usize).copied()
    }
}

/// One marker observed at one instant, as an input adapter sends it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MarkerSample {
    /// Index in the character's marker layout (adapters map names once, at start).
    pub marker: u32,
    /// When the sample was taken, seconds on the daemon's clock (adapters map the
    /// source's clock onto it; replay uses the file's clock shifted to start now).
    pub time_s: f64,
    /// The source's own timestamp, seconds (device time when the protocol has one).
    pub source_time_s: f64,
    /// Position, metres, world frame (right-handed, Y up). Non-finite means occluded.
    pub position_m: DVec3,
    /// The source flags this marker occluded (its position is then ignored).
    pub occluded: bool,
}

/// One full frame of markers in the rig's layout order, metres, world frame.
#[derive(Clone, Debug)]
pub struct MarkerFrame {
    /// Source timestamp in seconds (device time when the protocol has one).
    pub source_time_s: f64,
    /// When the newest sample reached the daemon, seconds on the daemon's clock
    /// (−∞: none yet).
    pub received_at_s: f64,
    /// Position per marker (for `Held` markers: the last known one, for display only).
    pub positions: Vec<DVec3>,
    /// How each position was obtained.
    pub states: Vec<FillState>,
    /// How far each position is trusted, in `[0, 1]`: 1 measured or rigidly filled, the
    /// prediction's decay factor `exp(−gap/τ)` when predicted, 0 held.
    pub confidence: Vec<f64>,
}

impl MarkerFrame {
    /// A frame where every marker is measured.
    pub fn all_present(source_time_s: f64, positions: Vec<DVec3>) -> Self {
        let states = vec![FillState::Measured; positions.len()];
        let confidence = vec![1.0; positions.len()];
        Self {
            source_time_s,
            received_at_s: f64::NEG_INFINITY,
            positions,
            states,
            confidence,
        }
    }

    /// A frame of `n` held markers at the origin (a buffer to fill in place).
    pub fn empty(n: usize) -> Self {
        Self {
            source_time_s: 0.0,
            received_at_s: f64::NEG_INFINITY,
            positions: vec![DVec3::ZERO; n],
            states: vec![FillState::Held; n],
            confidence: vec![0.0; n],
        }
    }

    /// Whether marker `k` carries information for the solver (any state but `Held`, and a
    /// finite position).
    pub fn is_present(&self, k: usize) -> bool {
        self.states.get(k).is_some_and(|s| *s != FillState::Held)
            && self.positions.get(k).is_some_and(|p| p.is_finite())
    }
}
