//! The sessions bundled with rigless (`replay/*.c3d`, embedded in the binary): the
//! procedural characters playing their motions, sampled as an optical system would
//! deliver them (0.5 mm noise, 5 % of samples lost in occlusion gaps of 20 ms to 1 s).
//! `rigless make-sessions replay/` remakes them byte for byte from this spec.

use super::c3d::{write_c3d, C3dError, Processor};
use crate::character::body::BodyMotion;
use crate::character::demo::{demo_body, demo_hand, Motion};
use crate::character::session::{SyntheticParams, SyntheticSession};
use std::sync::Arc;

/// One bundled session.
#[derive(Clone, Copy, Debug)]
pub struct BundledSpec {
    /// File stem (`replay/NAME.c3d`).
    pub name: &'static str,
    /// `"hand"` or `"body"`.
    pub character: &'static str,
    pub motion: Motion,
    pub seconds: f64,
}

pub const SPECS: [BundledSpec; 4] = [
    BundledSpec {
        name: "hand_finger_play",
        character: "hand",
        motion: Motion::FingerPlay,
        seconds: 20.0,
    },
    BundledSpec {
        name: "body_walk",
        character: "body",
        motion: Motion::Body(BodyMotion::Walk),
        seconds: 12.0,
    },
    BundledSpec {
        name: "body_reach",
        character: "body",
        motion: Motion::Body(BodyMotion::Reach),
        seconds: 12.0,
    },
    BundledSpec {
        name: "body_rom",
        character: "body",
        motion: Motion::Body(BodyMotion::RangeOfMotion),
        seconds: 12.0,
    },
];

/// The sampling every bundled session uses.
pub fn params(seconds: f64) -> SyntheticParams {
    SyntheticParams {
        rate_hz: 120.0,
        duration_secs: seconds,
        noise_m: 0.0005,
        gap_fraction: 0.05,
        min_gap_secs: 0.02,
        max_gap_secs: 1.0,
        seed: 1,
    }
}

/// Makes a bundled session's C3D bytes.
pub fn generate(spec: &BundledSpec) -> Result<Vec<u8>, C3dError> {
    let ch = match spec.character {
        "body" => demo_body(),
        _ => demo_hand(),
    };
    let labels: Vec<String> = ch.markers.iter().map(|m| m.name.clone()).collect();
    let mut s = SyntheticSession::new(Arc::new(ch), spec.motion, params(spec.seconds));
    let mut frames = Vec::with_capacity(s.frames());
    let mut batch = Vec::new();
    for i in 0..s.frames() {
        batch.clear();
        s.frame(i, 0.0, &mut batch);
        frames.push(batch.iter().map(|m| m.position_m).collect());
    }
    write_c3d(&labels, s.params().rate_hz, &frames, Processor::Intel)
}

/// The bundled sessions' bytes, embedded at build time.
const EMBEDDED: [(&str, &[u8]); 4] = [
    (
        "hand_finger_play",
        include_bytes!("../../replay/hand_finger_play.c3d"),
    ),
    ("body_walk", include_bytes!("../../replay/body_walk.c3d")),
    ("body_reach", include_bytes!("../../replay/body_reach.c3d")),
    ("body_rom", include_bytes!("../../replay/body_rom.c3d")),
];

/// A bundled session's C3D bytes by name.
pub fn bundled(name: &str) -> Option<&'static [u8]> {
    EMBEDDED.iter().find(|(n, _)| *n == name).map(|(_, b)| *b)
}

/// The bundled sessions' names.
pub fn names() -> impl Iterator<Item = &'static str> {
    EMBEDDED.iter().map(|(n, _)| *n)
}

/// The bundled session's spec by name.
pub fn spec(name: &str) -> Option<&'static BundledSpec> {
    SPECS.iter().find(|s| s.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::replay::c3d::read_c3d;

    #[test]
    fn bundled_sessions_are_what_the_spec_makes() {
        // Compared by value (1 µm): the files must not drift from their generator.
        for spec in &SPECS {
            let made = read_c3d(&generate(spec).unwrap()).unwrap();
            let shipped = read_c3d(bundled(spec.name).unwrap()).unwrap();
            assert_eq!(made.labels, shipped.labels, "{}", spec.name);
            assert_eq!(made.rate_hz, shipped.rate_hz);
            assert_eq!(made.frames.len(), (spec.seconds * 120.0) as usize);
            assert_eq!(made.frames.len(), shipped.frames.len());
            let mut missing = 0usize;
            for (a, b) in made
                .frames
                .iter()
                .flatten()
                .zip(shipped.frames.iter().flatten())
            {
                assert_eq!(a.is_finite(), b.is_finite(), "{}", spec.name);
                if a.is_finite() {
                    assert!((*a - *b).length() < 1e-6, "{}: {a} vs {b}", spec.name);
                } else {
                    missing += 1;
                }
            }
            // About 5 % of samples are in gaps (a few hundred gaps: within 1.5 points).
            let share = missing as f64 / made.frames.iter().flatten().count() as f64;
            assert!((0.035..0.065).contains(&share), "{}: {share}", spec.name);
        }
    }
}
