//! Skeletons: joints in a tree with rest positions, per-joint limits, forward kinematics,
//! and the swing-twist decomposition used to clamp joint rotations (Blow 2002,
//! "Inverse kinematics with quaternion joint limits").
//!
//! Conventions: a joint's local rotation `local_j` is relative to the rest pose and
//! rotates the segments leaving joint `j` (towards its children), expressed in the parent
//! joint's frame; world rotations compose as `Q_j = Q_parent(j) · local_j`, and a child
//! sits at `p_c = p_j + Q_j (rest_c − rest_j)`. Limits are about the joint's twist axis
//! (its rest direction towards its primary child) and two swing axes perpendicular to it
//! (`bend_axis`, and `twist × bend`).

use glam::{DQuat, DVec3};

/// Range limits of one joint's rotation, in radians.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct JointLimits {
    /// Twist about the joint's twist axis, `(min, max)`.
    pub twist: (f64, f64),
    /// Swing about the bend axis (flexion, positive curls the segment), `(min, max)`.
    pub bend: (f64, f64),
    /// Swing about the side axis `twist × bend` (abduction), `(min, max)`.
    pub side: (f64, f64),
}

/// One joint of a skeleton.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Joint {
    pub name: String,
    /// Parent joint index (always smaller than this joint's index), `None` for a root.
    pub parent: Option<usize>,
    /// Rest position in metres, world frame.
    pub rest: DVec3,
    /// Limits of the rotation of the segments leaving this joint; `None`: free.
    pub limits: Option<JointLimits>,
    /// Unit bend axis (flexion axis) in the rest frame; perpendicular to the twist axis.
    pub bend_axis: DVec3,
}

/// A joint tree in topological order (parents before children).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Skeleton {
    pub joints: Vec<Joint>,
}

/// Errors in a skeleton description.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SkeletonError {
    #[error("joint {joint:?} names parent {parent:?}, which is not listed before it")]
    UnknownParent { joint: String, parent: String },
    #[error("joint {joint:?} has a non-finite rest position")]
    NonFinite { joint: String },
    #[error("joint {joint:?} sits on its parent {parent:?}: zero-length bone")]
    ZeroLengthBone { joint: String, parent: String },
    #[error("joint {joint:?}: limit {which} has min {min_deg}° above max {max_deg}°")]
    BadLimits {
        joint: String,
        which: &'static str,
        min_deg: f64,
        max_deg: f64,
    },
    #[error("the skeleton has no joints")]
    Empty,
    #[error("joint name {0:?} is used twice")]
    DuplicateName(String),
}

impl Skeleton {
    /// Validates a skeleton (every error is a clear message naming the joint).
    pub fn new(joints: Vec<Joint>) -> Result<Self, Vec<SkeletonError>> {
        let mut errors = Vec::new();
        if joints.is_empty() {
            errors.push(SkeletonError::Empty);
        }
        let mut names = std::collections::HashSet::with_capacity(joints.len());
        for (i, j) in joints.iter().enumerate() {
            if !names.insert(j.name.as_str()) {
                errors.push(SkeletonError::DuplicateName(j.name.clone()));
            }
            if !j.rest.is_finite() {
                errors.push(SkeletonError::NonFinite {
                    joint: j.name.clone(),
                });
            }
            if let Some(p) = j.parent {
                if p >= i {
                    errors.push(SkeletonError::UnknownParent {
                        joint: j.name.clone(),
                        parent: format!("#{p}"),
                    });
                } else if (joints[p].rest - j.rest).length() < 1e-9 {
                    errors.push(SkeletonError::ZeroLengthBone {
                        joint: j.name.clone(),
                        parent: joints[p].name.clone(),
                    });
                }
            }
            if let Some(l) = j.limits {
                for (which, (lo, hi)) in [("twist", l.twist), ("bend", l.bend), ("side", l.side)] {
                    if lo > hi {
                        errors.push(SkeletonError::BadLimits {
                            joint: j.name.clone(),
                            which,
                            min_deg: lo.to_degrees(),
                            max_deg: hi.to_degrees(),
                        });
                    }
                }
            }
        }
        if errors.is_empty() {
            Ok(Self { joints })
        } else {
            Err(errors)
        }
    }

    pub fn len(&self) -> usize {
        self.joints.len()
    }
    pub fn is_empty(&self) -> bool {
        self.joints.is_empty()
    }

    /// Per joint, whether it is joint `j` or below it (one pass: parents come first).
    pub fn subtree(&self, j: usize) -> Vec<bool> {
        let mut inside = vec![false; self.len()];
        if let Some(x) = inside.get_mut(j) {
            *x = true;
        }
        for k in j + 1..self.len() {
            inside[k] = self.joints[k].parent.is_some_and(|p| inside[p]);
        }
        inside
    }

    /// Children of joint `j`.
    pub fn children(&self, j: usize) -> impl Iterator<Item = usize> + '_ {
        self.joints
            .iter()
            .enumerate()
            .filter(move |(_, c)| c.parent == Some(j))
            .map(|(i, _)| i)
    }

    /// Makes every bend axis a unit vector perpendicular to its joint's twist axis
    /// (Gram–Schmidt), as [`decompose`] and [`compose`] assume: with `side = twist ×
    /// bend` the three are an orthonormal frame and `compose` inverts `decompose`.
    /// Returns the joints whose axis lay along the bone (its part perpendicular to the
    /// bone under 1e-3), which were given an arbitrary perpendicular axis.
    pub fn orthogonalize_bend_axes(&mut self) -> Vec<usize> {
        let mut along = Vec::new();
        for j in 0..self.len() {
            let a = self.twist_axis(j);
            let b = self.joints[j].bend_axis;
            let p = b - a * b.dot(a);
            if p.length() < 1e-3 {
                along.push(j);
            }
            self.joints[j].bend_axis = p.normalize_or(a.any_orthonormal_vector());
        }
        along
    }

    /// Rest twist axis of joint `j`: unit direction towards the mean of its children
    /// (or away from its parent for a leaf).
    pub fn twist_axis(&self, j: usize) -> DVec3 {
        let kids: Vec<usize> = self.children(j).collect();
        let d = if kids.is_empty() {
            match self.joints[j].parent {
                Some(p) => self.joints[j].rest - self.joints[p].rest,
                None => DVec3::Y,
            }
        } else {
            kids.iter().map(|&c| self.joints[c].rest).sum::<DVec3>() / kids.len() as f64
                - self.joints[j].rest
        };
        d.normalize_or(DVec3::Y)
    }

    /// The joint whose local rotation in `local` (relative to rest, one per joint) exceeds
    /// its limits the most, and by how much (radians); `None` when all are inside.
    pub fn worst_limit_excess(&self, local: &[DQuat]) -> Option<(usize, f64)> {
        let mut worst: Option<(usize, f64)> = None;
        for (j, joint) in self.joints.iter().enumerate() {
            if let Some(l) = &joint.limits {
                let (_, excess) = clamp_to_limits(local[j], self.twist_axis(j), joint.bend_axis, l);
                if excess > 0.0 && worst.is_none_or(|(_, e)| excess > e) {
                    worst = Some((j, excess));
                }
            }
        }
        worst
    }

    /// Forward kinematics: world rotations and positions of every joint from local
    /// rotations (relative to rest) and a root translation (added to root rest positions).
    pub fn forward(
        &self,
        local: &[DQuat],
        root_offset: DVec3,
        world_rot: &mut [DQuat],
        world_pos: &mut [DVec3],
    ) {
        for (j, joint) in self.joints.iter().enumerate() {
            match joint.parent {
                None => {
                    world_rot[j] = local[j];
                    world_pos[j] = joint.rest + root_offset;
                }
                Some(p) => {
                    world_rot[j] = (world_rot[p] * local[j]).normalize();
                    world_pos[j] = world_pos[p] + world_rot[p] * (joint.rest - self.joints[p].rest);
                }
            }
        }
    }
}

/// Swing and twist angles of a local rotation about a joint's frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SwingTwist {
    pub twist: f64,
    pub bend: f64,
    pub side: f64,
}

/// Decomposes `q = swing · twist` with `twist` about `axis` and `swing` about an axis
/// perpendicular to it; the swing is expressed as a rotation vector split on `bend` and
/// `side = axis × bend`.
pub fn decompose(q: DQuat, axis: DVec3, bend: DVec3) -> SwingTwist {
    let q = if q.w < 0.0 { -q } else { q };
    let v = DVec3::new(q.x, q.y, q.z);
    let p = axis * v.dot(axis);
    let twist_q = DQuat::from_xyzw(p.x, p.y, p.z, q.w);
    let tl = twist_q.length();
    let (twist_q, twist) = if tl < 1e-12 {
        (DQuat::IDENTITY, 0.0)
    } else {
        let t = twist_q / tl;
        (t, 2.0 * DVec3::new(t.x, t.y, t.z).dot(axis).atan2(t.w))
    };
    let swing_q = q * twist_q.conjugate();
    let sv = swing_q.to_scaled_axis();
    let side = axis.cross(bend);
    SwingTwist {
        twist,
        bend: sv.dot(bend),
        side: sv.dot(side),
    }
}

/// Inverse of [`decompose`].
pub fn compose(st: SwingTwist, axis: DVec3, bend: DVec3) -> DQuat {
    let side = axis.cross(bend);
    let swing = DQuat::from_scaled_axis(bend * st.bend + side * st.side);
    swing * DQuat::from_axis_angle(axis, st.twist)
}

/// Clamps a local rotation to the limits; returns the clamped rotation and the largest
/// excess (radians) of the input over any limit (0 when within limits).
pub fn clamp_to_limits(q: DQuat, axis: DVec3, bend: DVec3, limits: &JointLimits) -> (DQuat, f64) {
    let st = decompose(q, axis, bend);
    let c = |v: f64, (lo, hi): (f64, f64)| (v.clamp(lo, hi), (lo - v).max(v - hi).max(0.0));
    let (twist, e1) = c(st.twist, limits.twist);
    let (b, e2) = c(st.bend, limits.bend);
    let (s, e3) = c(st.side, limits.side);
    let excess = e1.max(e2).max(e3);
    if excess == 0.0 {
        return (q, 0.0);
    }
    (
        compose(
            SwingTwist {
                twist,
                bend: b,
                side: s,
            },
            axis,
            bend,
        ),
        excess,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decompose_compose_round_trip() {
        let axis = DVec3::new(1.0, 0.2, 0.0).normalize();
        let bend = axis.cross(DVec3::Z).normalize();
        for (t, b, s) in [
            (0.3, 0.5, -0.2),
            (-1.0, 1.2, 0.4),
            (0.0, 0.0, 0.0),
            (0.1, -0.7, 0.9),
        ] {
            let st = SwingTwist {
                twist: t,
                bend: b,
                side: s,
            };
            let q = compose(st, axis, bend);
            let back = decompose(q, axis, bend);
            assert!(
                (back.twist - t).abs() < 1e-12
                    && (back.bend - b).abs() < 1e-12
                    && (back.side - s).abs() < 1e-12,
                "{back:?}"
            );
        }
    }

    #[test]
    fn an_axis_along_the_bone_is_reported_and_replaced() {
        let joint = |name: &str, parent, rest, bend_axis| Joint {
            name: String::from(name),
            parent,
            rest,
            limits: None,
            bend_axis,
        };
        let mut sk = Skeleton::new(vec![
            joint("a", None, DVec3::ZERO, DVec3::X),
            joint("b", Some(0), DVec3::Y, DVec3::new(1.0, 0.5, 0.0)),
            joint("c", Some(1), DVec3::Y * 2.0, DVec3::Y),
        ])
        .unwrap();
        // b's axis slants 27° off square to its bone: compose does not invert decompose.
        let q = DQuat::from_scaled_axis(DVec3::new(0.3, -0.5, 0.4));
        let round_trip = |sk: &Skeleton, j: usize| {
            let (axis, bend) = (sk.twist_axis(j), sk.joints[j].bend_axis);
            let back = compose(decompose(q, axis, bend), axis, bend);
            (back - q).length().min((back + q).length())
        };
        assert!(round_trip(&sk, 1) > 0.01);
        assert_eq!(sk.orthogonalize_bend_axes(), vec![2]);
        assert!((sk.joints[1].bend_axis - DVec3::X).length() < 1e-12);
        let c = sk.joints[2].bend_axis;
        assert!((c.length() - 1.0).abs() < 1e-12 && c.dot(DVec3::Y).abs() < 1e-12);
        for j in 0..3 {
            assert!(round_trip(&sk, j) < 1e-12, "joint {j}");
        }
    }

    #[test]
    fn clamp_reports_excess_and_respects_limits() {
        let axis = DVec3::X;
        let bend = DVec3::Z;
        let lim = JointLimits {
            twist: (-0.1, 0.1),
            bend: (0.0, 1.5),
            side: (-0.2, 0.2),
        };
        let q = compose(
            SwingTwist {
                twist: 0.05,
                bend: 2.0,
                side: -0.3,
            },
            axis,
            bend,
        );
        let (c, excess) = clamp_to_limits(q, axis, bend, &lim);
        assert!((excess - 0.5).abs() < 1e-12, "excess {excess}");
        let st = decompose(c, axis, bend);
        assert!(
            (st.bend - 1.5).abs() < 1e-12
                && (st.side + 0.2).abs() < 1e-12
                && (st.twist - 0.05).abs() < 1e-12
        );
        let inside = compose(
            SwingTwist {
                twist: 0.0,
                bend: 0.4,
                side: 0.1,
            },
            axis,
            bend,
        );
        assert_eq!(clamp_to_limits(inside, axis, bend, &lim), (inside, 0.0));
    }
}
