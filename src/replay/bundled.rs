//! The sessions bundled with rigless (`replay/*.c3d`, embedded in the binary): the
//! procedural characters playing their motions, sampled as an optical system would
//! deliver them (0.5 mm noise, 5 % of samples lost in occlusion gaps of 20 ms to 1 s).
//! `rigless make-sessions replay/` remakes them byte for byte from this spec. A session
//! of several actors ([`BundledSpec::cast`]) has each one's labels behind its subject
//! (`Ann:LFHD`), each placed and turned on the floor, and entering when it says.

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
    /// Several actors playing the motion, each its own take (empty: one, with labels
    /// without a prefix, where the motion puts it).
    pub cast: &'static [CastMember],
}

/// One actor of a bundled session of several.
#[derive(Clone, Copy, Debug)]
pub struct CastMember {
    /// The subject prefixing its labels.
    pub subject: &'static str,
    /// Turned this much about the vertical (Y) axis, degrees, then moved by `offset_m`
    /// (metres, world frame).
    pub yaw_deg: f64,
    pub offset_m: [f64; 3],
    /// Its markers are absent (not yet in the volume) before this time, seconds.
    pub enters_s: f64,
}

/// The two-actor session: Ann walks along +Z; Bob walks the other way 0.4 m to her side,
/// entering the volume 1.5 s in, and passes her 4 s in (their hands about 0.1 m apart).
pub const TWO_ACTORS: [CastMember; 2] = [
    CastMember {
        subject: "Ann",
        yaw_deg: 0.0,
        offset_m: [0.0, 0.0, 0.0],
        enters_s: 0.0,
    },
    CastMember {
        subject: "Bob",
        yaw_deg: 180.0,
        offset_m: [0.4, 0.0, 9.6],
        enters_s: 1.5,
    },
];

pub const SPECS: [BundledSpec; 5] = [
    BundledSpec {
        name: "hand_finger_play",
        character: "hand",
        motion: Motion::FingerPlay,
        seconds: 20.0,
        cast: &[],
    },
    BundledSpec {
        name: "body_walk",
        character: "body",
        motion: Motion::Body(BodyMotion::Walk),
        seconds: 12.0,
        cast: &[],
    },
    BundledSpec {
        name: "body_reach",
        character: "body",
        motion: Motion::Body(BodyMotion::Reach),
        seconds: 12.0,
        cast: &[],
    },
    BundledSpec {
        name: "body_rom",
        character: "body",
        motion: Motion::Body(BodyMotion::RangeOfMotion),
        seconds: 12.0,
        cast: &[],
    },
    BundledSpec {
        name: "body_two_actors",
        character: "body",
        motion: Motion::Body(BodyMotion::Walk),
        seconds: 8.0,
        cast: &TWO_ACTORS,
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
    if spec.cast.is_empty() {
        let labels: Vec<String> = ch.markers.iter().map(|m| m.name.clone()).collect();
        let frames = take(Arc::new(ch), spec.motion, params(spec.seconds));
        return write_c3d(
            &labels,
            params(spec.seconds).rate_hz,
            &frames,
            Processor::Intel,
        );
    }
    let (labels, frames) = cast_take(Arc::new(ch), spec.motion, spec.seconds, spec.cast);
    write_c3d(
        &labels,
        params(spec.seconds).rate_hz,
        &frames,
        Processor::Intel,
    )
}

/// Every frame's marker positions of a synthetic take (NaN in gaps), metres.
fn take(
    ch: Arc<crate::character::procedural::Character>,
    motion: Motion,
    p: SyntheticParams,
) -> Vec<Vec<glam::DVec3>> {
    let mut s = SyntheticSession::new(ch, motion, p);
    let mut frames = Vec::with_capacity(s.frames());
    let mut batch = Vec::new();
    for i in 0..s.frames() {
        batch.clear();
        s.frame(i, 0.0, &mut batch);
        frames.push(batch.iter().map(|m| m.position_m).collect());
    }
    frames
}

/// A take of several actors playing `motion` on `ch`, as [`CastMember`]s say: the
/// labels (`Subject:Marker`, actor by actor) and every frame's positions. Each actor is
/// its own take (its own noise and gaps: seed 1 + its place in the cast).
pub fn cast_take(
    ch: Arc<crate::character::procedural::Character>,
    motion: Motion,
    seconds: f64,
    cast: &[CastMember],
) -> (Vec<String>, Vec<Vec<glam::DVec3>>) {
    use glam::{DQuat, DVec3};
    let labels = cast
        .iter()
        .flat_map(|c| {
            ch.markers
                .iter()
                .map(move |m| format!("{}:{}", c.subject, m.name))
        })
        .collect();
    let rate_hz = params(seconds).rate_hz;
    let mut frames: Vec<Vec<DVec3>> = Vec::new();
    for (k, c) in cast.iter().enumerate() {
        let p = SyntheticParams {
            seed: 1 + k as u64,
            ..params(seconds)
        };
        let world_from_walker = (
            DQuat::from_rotation_y(c.yaw_deg.to_radians()),
            DVec3::from_array(c.offset_m),
        );
        let own = take(Arc::clone(&ch), motion, p);
        frames.resize(own.len(), Vec::new());
        for (i, (f, o)) in frames.iter_mut().zip(own).enumerate() {
            let inside = i as f64 / rate_hz >= c.enters_s;
            f.extend(o.into_iter().map(|q| {
                if inside {
                    world_from_walker.0 * q + world_from_walker.1
                } else {
                    DVec3::NAN
                }
            }));
        }
    }
    (labels, frames)
}

/// The bundled sessions' bytes, embedded at build time.
const EMBEDDED: [(&str, &[u8]); 5] = [
    (
        "hand_finger_play",
        include_bytes!("../../replay/hand_finger_play.c3d"),
    ),
    ("body_walk", include_bytes!("../../replay/body_walk.c3d")),
    ("body_reach", include_bytes!("../../replay/body_reach.c3d")),
    ("body_rom", include_bytes!("../../replay/body_rom.c3d")),
    (
        "body_two_actors",
        include_bytes!("../../replay/body_two_actors.c3d"),
    ),
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
            // About 5 % of samples are in gaps (a few hundred gaps: within 1.5 points),
            // besides those of actors not yet in the volume.
            let absent = spec
                .cast
                .iter()
                .map(|c| c.enters_s.min(spec.seconds) / spec.seconds)
                .sum::<f64>()
                / spec.cast.len().max(1) as f64;
            let gaps = absent + (1.0 - absent) * 0.05;
            let share = missing as f64 / made.frames.iter().flatten().count() as f64;
            assert!(
                (share - gaps).abs() < 0.015,
                "{}: {share} vs {gaps}",
                spec.name
            );
        }
    }
}
