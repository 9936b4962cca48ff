//! The range-of-motion exercise behind `rigless bake --exercise` and the real-asset rows
//! of `bench --suite characters`: binds a character, plays every joint with children to
//! its limits and back (bend, side and twist, alone and combined), then all joints
//! together, through the frame solver at the live frame budget, and reports what a user
//! needs to trust the character: the control mesh's size, the bind time, inverted tets,
//! vertices that never moved, joint-limit violations, the control mesh's volume change
//! and the frame time.
//!
//! Markers: the character's own layout, or (when it has none) one marker at the middle
//! of every bone, carried by the bone's joint, so any asset can be exercised before it
//! has a layout. Marker targets come from forward kinematics of the exercise pose.

use super::Spread;
use crate::character::bind_params::BindParams;
use crate::character::procedural::{flex_pose, Pose};
use crate::character::skeleton::{compose, JointLimits, Skeleton, SwingTwist};
use crate::character::{Character, MarkerDef};
use crate::markers::MarkerFrame;
use crate::rig::bind::{BindError, Rig};
use crate::solve::frame::{Solver, SolverParams};
use glam::{DQuat, DVec3};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How long the exercise plays.
#[derive(Clone, Copy, Debug)]
pub struct ExerciseOptions {
    /// Seconds for each joint's own range of motion (default 3: a knee to 150° and back
    /// peaks near 160°/s, an actor's calibration pace; at 2 s the sweeps' fastest frames,
    /// not the mesh, set the frame time's tail).
    pub seconds_per_joint: f64,
    /// Seconds of every joint moving together, at the end.
    pub combined_seconds: f64,
    /// Frame rate, Hz; each frame's solve gets `1 / rate_hz` (the live budget).
    pub rate_hz: f64,
}

impl Default for ExerciseOptions {
    fn default() -> Self {
        Self {
            seconds_per_joint: 3.0,
            combined_seconds: 4.0,
            rate_hz: 120.0,
        }
    }
}

/// What the exercise measured.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ExerciseReport {
    pub character: String,
    pub mesh_vertices: usize,
    pub control_vertices: usize,
    pub control_tets: usize,
    pub joints: usize,
    /// Joints with limits (from their role or the character file).
    pub limited_joints: usize,
    pub markers: usize,
    /// The character had no marker layout: one marker per bone was made for the exercise.
    pub markers_made_for_exercise: bool,
    /// Whole bind (lattice, Green coordinates, weights and factorization), seconds.
    pub bind_s: f64,
    /// Of which the Green coordinates, seconds.
    pub green_s: f64,
    pub frames: usize,
    /// Most control tets inverted in one frame.
    pub inverted_tets_max: usize,
    /// Mesh vertices that never moved by 1e-4 of the height on any frame, although
    /// every joint moved.
    pub unmoved_vertices: usize,
    /// Largest excess of the solved posture over any joint limit, degrees.
    pub joint_limit_violation_deg_max: f64,
    /// Largest relative change of the control mesh's volume.
    pub volume_error_max: f64,
    /// Largest mean relative bone-length error of a frame.
    pub bone_length_error_max: f64,
    pub marker_residual_mm_max: f64,
    /// Whole solve per frame (posture, ARAP, full-mesh update), ms.
    pub frame_ms_p50: f64,
    pub frame_ms_p99: f64,
    pub frame_ms_max: f64,
    /// The full-mesh update through the Green coordinates, median ms.
    pub green_ms_p50: f64,
}

/// Largest excess over a joint limit the exercise lets pass, degrees: the posture fit
/// clamps to the limits within half a degree, and a marker's pull may stretch a joint a
/// few degrees past them; more is a joint the solve does not hold.
pub const LIMIT_OVERSHOOT_DEG: f64 = 5.0;

impl ExerciseReport {
    /// What the exercise found wrong: control tets inverted in any frame (the mesh folds
    /// through itself there), and joints past their limits by more than
    /// [`LIMIT_OVERSHOOT_DEG`]. Empty when it went well.
    pub fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        if self.inverted_tets_max > 0 {
            out.push(format!(
                "{} control tets inverted in one frame: the mesh folds through itself there (a finer [bind] cell_size_m, or tighter limits on the joint)",
                self.inverted_tets_max
            ));
        }
        if self.joint_limit_violation_deg_max > LIMIT_OVERSHOOT_DEG {
            out.push(format!(
                "a joint went {:.1}° past its limit (over {LIMIT_OVERSHOOT_DEG}°): the solve does not hold it; check its [skeleton.limits] and bend axis",
                self.joint_limit_violation_deg_max
            ));
        }
        out
    }
}

/// Joints the exercise moves one at a time: those with children, the root apart (it
/// moves the whole character rigidly, in the combined part).
fn moving_joints(sk: &Skeleton) -> Vec<usize> {
    (0..sk.len())
        .filter(|&j| sk.joints[j].parent.is_some() && sk.children(j).next().is_some())
        .collect()
}

/// The exercise pose at time `t_s`: joint `moving[k]` alone during
/// `[k·d, (k+1)·d)` (`d = seconds_per_joint`), then [`flex_pose`].
///
/// A joint's own range: bend `sin 2πu`, side `sin 4πu` and twist `sin 6πu` over its slot
/// (`u` from 0 to 1), each scaled from the rest value (clamped into the range) to the
/// limit on its side of it, so the joint starts and ends at rest, reaches each limit, and
/// meets the combinations of bend with side and twist. A joint without limits swings
/// ±0.3 rad of bend and ±0.15 rad of side and twist.
pub fn exercise_pose(sk: &Skeleton, moving: &[usize], seconds_per_joint: f64, t_s: f64) -> Pose {
    let slot = (t_s / seconds_per_joint).floor();
    if slot >= moving.len() as f64 || slot < 0.0 {
        // Every joint together, eased in from rest over the first second (flex_pose
        // starts mid-swing).
        let t = t_s - moving.len() as f64 * seconds_per_joint;
        let mut pose = flex_pose(sk, t);
        let w = t.clamp(0.0, 1.0);
        for q in &mut pose.local {
            *q = DQuat::IDENTITY.slerp(*q, w);
        }
        pose.root_offset *= w;
        return pose;
    }
    let mut local = vec![DQuat::IDENTITY; sk.len()];
    let j = moving[slot as usize];
    let u = t_s / seconds_per_joint - slot;
    let l = sk.joints[j].limits.unwrap_or(JointLimits {
        twist: (-0.15, 0.15),
        bend: (-0.3, 0.3),
        side: (-0.15, 0.15),
    });
    let tau = std::f64::consts::TAU;
    let reach = |(lo, hi): (f64, f64), s: f64| {
        let rest = 0f64.clamp(lo, hi);
        if s >= 0.0 {
            rest + s * (hi - rest)
        } else {
            rest - s * (lo - rest)
        }
    };
    let st = SwingTwist {
        bend: reach(l.bend, (tau * u).sin()),
        side: reach(l.side, (2.0 * tau * u).sin()),
        twist: reach(l.twist, (3.0 * tau * u).sin()),
    };
    local[j] = compose(st, sk.twist_axis(j), sk.joints[j].bend_axis);
    Pose {
        local,
        root_offset: DVec3::ZERO,
    }
}

/// One marker at the middle of every bone, carried by the bone's joint (its parent).
fn bone_markers(sk: &Skeleton) -> Vec<MarkerDef> {
    sk.joints
        .iter()
        .filter_map(|j| {
            let p = j.parent?;
            Some(MarkerDef {
                name: format!("exercise_{}", j.name),
                rest: 0.5 * (j.rest + sk.joints[p].rest),
                joint: Some(p),
            })
        })
        .collect()
}

/// Binds `ch` and plays the exercise; `progress` gets the fraction done.
pub fn exercise(
    ch: &Character,
    bind: &BindParams,
    opts: ExerciseOptions,
    progress: &mut dyn FnMut(f64),
) -> Result<ExerciseReport, BindError> {
    // A rate or a slot too small to play would divide by zero below.
    let opts = ExerciseOptions {
        seconds_per_joint: opts.seconds_per_joint.max(0.01),
        combined_seconds: opts.combined_seconds.max(0.0),
        rate_hz: opts.rate_hz.max(1.0),
    };
    let made = ch.markers.is_empty();
    let with_markers;
    let ch = if made {
        with_markers = Character {
            markers: bone_markers(&ch.skeleton),
            ..ch.clone()
        };
        &with_markers
    } else {
        ch
    };
    let t0 = Instant::now();
    let rig = Arc::new(Rig::bind(ch, bind)?);
    let bind_s = t0.elapsed().as_secs_f64();
    let mut solver = Solver::new(Arc::clone(&rig), SolverParams::default());
    let sk = &ch.skeleton;
    let moving = moving_joints(sk);
    let seconds = moving.len() as f64 * opts.seconds_per_joint + opts.combined_seconds;
    let frames = (seconds * opts.rate_hz).round() as usize;
    let budget = Duration::from_secs_f64(1.0 / opts.rate_hz);
    let nv = ch.vertices.len();
    let mut out = vec![DVec3::ZERO; nv];
    let mut moved = vec![false; nv];
    let moved_m = 1e-4 * rig.height_m;
    let (mut rot, mut pos) = (vec![DQuat::IDENTITY; sk.len()], vec![DVec3::ZERO; sk.len()]);
    let mut targets = vec![DVec3::ZERO; ch.markers.len()];
    let rest_volume = rig.control.volume(&rig.control.positions);
    let (mut frame_t, mut green_t) = (Vec::with_capacity(frames), Vec::with_capacity(frames));
    let mut rep = ExerciseReport {
        character: ch.name.clone(),
        mesh_vertices: nv,
        control_vertices: rig.stats.control_vertices,
        control_tets: rig.stats.control_tets,
        joints: sk.len(),
        limited_joints: sk.joints.iter().filter(|j| j.limits.is_some()).count(),
        markers: ch.markers.len(),
        markers_made_for_exercise: made,
        bind_s,
        green_s: rig.stats.seconds_green,
        frames,
        inverted_tets_max: 0,
        unmoved_vertices: 0,
        joint_limit_violation_deg_max: 0.0,
        volume_error_max: 0.0,
        bone_length_error_max: 0.0,
        marker_residual_mm_max: 0.0,
        frame_ms_p50: 0.0,
        frame_ms_p99: 0.0,
        frame_ms_max: 0.0,
        green_ms_p50: 0.0,
    };
    for f in 0..frames {
        let t = f as f64 / opts.rate_hz;
        let pose = exercise_pose(sk, &moving, opts.seconds_per_joint, t);
        sk.forward(&pose.local, pose.root_offset, &mut rot, &mut pos);
        for (k, target) in targets.iter_mut().enumerate() {
            let j = rig.marker_joint[k];
            *target = pos[j] + rot[j] * (rig.marker_rest[k] - sk.joints[j].rest);
        }
        let frame = MarkerFrame::all_present(t, targets.clone());
        let start = Instant::now();
        let r = solver.solve(&frame, start + budget, &mut out);
        frame_t.push(start.elapsed());
        green_t.push(Duration::from_secs_f64(r.gc_ms / 1e3));
        let cp = solver.control_positions();
        rep.inverted_tets_max = rep.inverted_tets_max.max(rig.control.inverted_tets(cp));
        let vol = if rest_volume > 0.0 {
            (rig.control.volume(cp) - rest_volume).abs() / rest_volume
        } else {
            0.0
        };
        rep.volume_error_max = rep.volume_error_max.max(vol);
        rep.joint_limit_violation_deg_max = rep
            .joint_limit_violation_deg_max
            .max(r.joint_limit_violation_deg);
        rep.bone_length_error_max = rep.bone_length_error_max.max(r.bone_length_error);
        rep.marker_residual_mm_max = rep.marker_residual_mm_max.max(r.marker_residual_max_mm);
        for ((m, o), v) in moved.iter_mut().zip(&out).zip(&ch.vertices) {
            *m |= (*o - *v).length_squared() > moved_m * moved_m;
        }
        if f % 30 == 0 {
            progress(f as f64 / frames as f64);
        }
    }
    progress(1.0);
    rep.unmoved_vertices = moved.iter().filter(|m| !**m).count();
    let s = Spread::of(&frame_t);
    (rep.frame_ms_p50, rep.frame_ms_p99, rep.frame_ms_max) = (s.median_ms, s.p99_ms, s.max_ms);
    rep.green_ms_p50 = Spread::of(&green_t).median_ms;
    Ok(rep)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::character::demo::{demo_hand, hand_bind_params};
    use crate::character::skeleton::decompose;

    /// Each joint's slot starts and ends at rest and reaches both ends of its bend range.
    #[test]
    fn each_joint_reaches_its_limits_and_comes_back() {
        let ch = demo_hand();
        let sk = &ch.skeleton;
        let moving = moving_joints(sk);
        assert!(moving.len() > 10);
        let d = 2.0;
        for (k, &j) in moving.iter().enumerate() {
            let at = |u: f64| exercise_pose(sk, &moving, d, (k as f64 + u) * d).local[j];
            let st = |u: f64| decompose(at(u), sk.twist_axis(j), sk.joints[j].bend_axis);
            let l = sk.joints[j].limits.unwrap_or(JointLimits {
                twist: (-0.15, 0.15),
                bend: (-0.3, 0.3),
                side: (-0.15, 0.15),
            });
            // 1e-9 rad: the round trip through a quaternion.
            assert!(at(0.0).angle_between(DQuat::IDENTITY) < 1e-9, "{j}");
            // At u = 1/4 the bend is at its top and at 3/4 at its bottom, the side back
            // at rest (sin π, sin 3π) and the twist at one end of its range.
            let (top, bottom) = (st(0.25), st(0.75));
            assert!((top.bend - l.bend.1).abs() < 1e-9, "{j}: {top:?}");
            assert!((bottom.bend - l.bend.0).abs() < 1e-9, "{j}: {bottom:?}");
            assert!((top.twist - l.twist.0).abs() < 1e-9, "{j}: {top:?}");
            assert!((bottom.twist - l.twist.1).abs() < 1e-9, "{j}: {bottom:?}");
            // Every other joint stays at rest during this joint's slot.
            let pose = exercise_pose(sk, &moving, d, (k as f64 + 0.3) * d);
            for (i, q) in pose.local.iter().enumerate() {
                if i != j {
                    assert_eq!(*q, DQuat::IDENTITY, "{i} moved in {j}'s slot");
                }
            }
        }
    }

    /// The procedural hand through the whole exercise: no inverted tet, every vertex
    /// moved, the limits kept (0.5°: the posture fit's clamp tolerance, as in the
    /// solver's own tests).
    #[test]
    fn the_hand_survives_its_exercise() {
        let ch = demo_hand();
        let opts = ExerciseOptions {
            seconds_per_joint: 1.0,
            combined_seconds: 2.0,
            rate_hz: 120.0,
        };
        let mut last = 0.0;
        let r = exercise(&ch, &hand_bind_params(), opts, &mut |f| {
            assert!(f >= last, "progress goes forward");
            last = f;
        })
        .unwrap();
        assert_eq!(last, 1.0);
        let moving = moving_joints(&ch.skeleton).len();
        assert_eq!(r.frames, (moving as f64 * 120.0 + 240.0) as usize);
        assert!(!r.markers_made_for_exercise);
        assert_eq!(r.inverted_tets_max, 0, "{r:?}");
        assert_eq!(r.unmoved_vertices, 0, "{r:?}");
        assert!(r.joint_limit_violation_deg_max <= 0.5, "{r:?}");
        assert!(
            r.frame_ms_p50 > 0.0 && r.frame_ms_p99 >= r.frame_ms_p50,
            "{r:?}"
        );
        assert!(r.problems().is_empty(), "{:?}", r.problems());
        // What the summary calls a problem: one inverted tet, a joint 6° past its limit
        // (5° is let pass).
        let mut bad = r.clone();
        bad.inverted_tets_max = 1;
        assert_eq!(bad.problems().len(), 1);
        bad.joint_limit_violation_deg_max = 5.0;
        assert_eq!(bad.problems().len(), 1);
        bad.joint_limit_violation_deg_max = 6.0;
        assert_eq!(bad.problems().len(), 2, "{:?}", bad.problems());
    }

    /// A character without markers is exercised with one marker per bone.
    #[test]
    fn markers_are_made_when_there_are_none() {
        let mut ch = demo_hand();
        ch.markers.clear();
        let opts = ExerciseOptions {
            seconds_per_joint: 0.25,
            combined_seconds: 0.5,
            rate_hz: 120.0,
        };
        let r = exercise(&ch, &hand_bind_params(), opts, &mut |_| {}).unwrap();
        assert!(r.markers_made_for_exercise);
        assert_eq!(r.markers, ch.skeleton.len() - 1, "one per bone");
        assert_eq!(r.unmoved_vertices, 0, "{r:?}");
    }
}
