//! The `[calibration]` table of a stage config: calibrate the character's marker layout
//! from the first seconds of the live input before solving, with the section's own
//! checks ([`LiveCalibrationConfig::problems`]).

use super::marker_sets::{by_name, MARKER_SETS};
use super::DEFAULT_FRAMES;

/// Longest capture of live input to calibrate from, seconds.
pub const MAX_CAPTURE_SECS: f64 = 600.0;

/// `[calibration]`.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LiveCalibrationConfig {
    /// Seconds of live input to calibrate from when the stage starts (the actor stands
    /// in the character's rest pose, then moves every joint); unset: no calibration.
    pub first_secs: Option<f64>,
    /// Calibrate even when the character's layout already has every label that
    /// arrived (default: use the layout as it is).
    pub always: bool,
    /// Frames fitted, chosen over the capture to cover its range of motion.
    pub frames: usize,
    /// The marker-set table: `"auto"` (the one that knows most labels) or a name.
    pub marker_set: String,
    /// Write the layout and scale into the character file (the old file kept as
    /// FILE.bak), so the next start needs no calibration.
    pub write: bool,
}

impl Default for LiveCalibrationConfig {
    fn default() -> Self {
        Self {
            first_secs: None,
            always: false,
            frames: DEFAULT_FRAMES,
            marker_set: "auto".into(),
            write: false,
        }
    }
}

impl LiveCalibrationConfig {
    /// What is wrong, as `(key, message)` with keys relative to `[calibration]`.
    pub fn problems(&self) -> Vec<(String, String)> {
        let mut out = Vec::new();
        if let Some(s) = self.first_secs {
            if !(s.is_finite() && s > 0.0 && s <= MAX_CAPTURE_SECS) {
                out.push((
                    "first_secs".into(),
                    format!("must be more than 0 and at most {MAX_CAPTURE_SECS} s, got {s:?}"),
                ));
            }
        }
        if !(1..=1000).contains(&self.frames) {
            out.push((
                "frames".into(),
                format!("must be 1 to 1000, got {}", self.frames),
            ));
        }
        if self.marker_set != "auto" && by_name(&self.marker_set).is_none() {
            let names: Vec<&str> = MARKER_SETS.iter().map(|s| s.name).collect();
            out.push((
                "marker_set".into(),
                format!(
                    "no such table {:?} (auto, {})",
                    self.marker_set,
                    names.join(", ")
                ),
            ));
        }
        out
    }
}
