//! The skeleton step's posture problem as a rig carries it ([`IkModel`]): the unknowns of
//! each joint, their bounds from the joint limits, the joints that move each marker, and
//! the elimination order of the normal equations. Built once at bind time; the
//! Levenberg–Marquardt posture fit on it is in `solve::ik`.
//!
//! Unknowns: per root joint a world rotation (as an increment ω, no prior) and a
//! position; per other joint with children its local rotation as swing-twist angles
//! `(twist, bend, side)` about its twist axis, bend axis and `twist × bend` (the
//! conventions of [`crate::character::skeleton`]), boxed by its limits (unbounded when
//! it has none). Leaf joints carry no unknowns.

use crate::character::skeleton::Skeleton;
use glam::DVec3;

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub(crate) enum Dofs {
    /// A leaf: no unknowns.
    None,
    /// A root: `[ω_x, ω_y, ω_z, t_x, t_y, t_z]` increments from `first`.
    Root { first: usize },
    /// `(twist, bend, side)` from `first`.
    Angles { first: usize },
}

impl Dofs {
    /// The indices of these unknowns.
    pub(crate) fn params(self) -> std::ops::Range<usize> {
        match self {
            Dofs::None => 0..0,
            Dofs::Root { first } => first..first + 6,
            Dofs::Angles { first } => first..first + 3,
        }
    }
}

/// The posture problem of one rig: immutable, shared. The fit on it (forward kinematics,
/// Levenberg–Marquardt) is in `solve::ik`.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct IkModel {
    pub(crate) parent: Vec<Option<usize>>,
    pub(crate) rest: Vec<DVec3>,
    /// Per joint `[twist, bend, side]` unit axes in the rest frame (orthonormal).
    pub(crate) axes: Vec<[DVec3; 3]>,
    pub(crate) dofs: Vec<Dofs>,
    pub(crate) n_params: usize,
    /// Bounds per parameter (infinite for roots and joints without limits).
    pub(crate) lo: Vec<f64>,
    pub(crate) hi: Vec<f64>,
    pub(crate) marker_joint: Vec<usize>,
    /// Marker rest position relative to its joint, `m_k^rest − r_J`.
    pub(crate) marker_offset: Vec<DVec3>,
    /// Per marker (CSR): the joints with unknowns that move it (its joint and ancestors).
    pub(crate) chain_start: Vec<usize>,
    pub(crate) chain: Vec<usize>,
    /// Elimination order of the normal equations: `order[i]` is the parameter in row `i`.
    /// The joints' parameters in post-order (every subtree's before its root's), so that
    /// the Cholesky factor of the tree-structured `JᵀJ` has no fill outside the rows'
    /// envelopes (fingers independent given the wrist; the root's rows last).
    pub(crate) order: Vec<usize>,
    /// Per row of that order, the first column any marker couples it with (its
    /// envelope starts there; everything left of it stays zero in the factor).
    pub(crate) envelope_first: Vec<usize>,
    /// Character height `h`, metres.
    pub(crate) height_m: f64,
}

impl IkModel {
    /// Builds the posture problem. `marker_joint[k]` is the joint whose segments carry
    /// marker `k`; `twist_axis[j]` the rest twist axis of joint `j`; `height_m` the
    /// character height (scales the priors).
    pub fn new(
        sk: &Skeleton,
        twist_axis: &[DVec3],
        marker_joint: &[usize],
        marker_rest: &[DVec3],
        height_m: f64,
    ) -> Self {
        let nj = sk.len();
        let mut has_child = vec![false; nj];
        for j in &sk.joints {
            if let Some(p) = j.parent {
                has_child[p] = true;
            }
        }
        let mut dofs = Vec::with_capacity(nj);
        let (mut lo, mut hi) = (Vec::new(), Vec::new());
        let mut axes = Vec::with_capacity(nj);
        for (j, joint) in sk.joints.iter().enumerate() {
            let a = twist_axis[j];
            let b0 = joint.bend_axis - a * joint.bend_axis.dot(a);
            let b = if b0.length() > 1e-6 {
                b0.normalize()
            } else {
                a.any_orthonormal_vector()
            };
            axes.push([a, b, a.cross(b)]);
            let first = lo.len();
            if joint.parent.is_none() {
                dofs.push(Dofs::Root { first });
                lo.extend([f64::NEG_INFINITY; 6]);
                hi.extend([f64::INFINITY; 6]);
            } else if has_child[j] {
                dofs.push(Dofs::Angles { first });
                match joint.limits {
                    Some(l) => {
                        lo.extend([l.twist.0, l.bend.0, l.side.0]);
                        hi.extend([l.twist.1, l.bend.1, l.side.1]);
                    }
                    None => {
                        lo.extend([f64::NEG_INFINITY; 3]);
                        hi.extend([f64::INFINITY; 3]);
                    }
                }
            } else {
                dofs.push(Dofs::None);
            }
        }
        let mut chain_start = vec![0];
        let mut chain = Vec::new();
        for &mj in marker_joint {
            let begin = chain.len();
            let mut j = Some(mj);
            while let Some(jj) = j {
                if dofs[jj] != Dofs::None {
                    chain.push(jj);
                }
                j = sk.joints[jj].parent;
            }
            chain[begin..].reverse();
            chain_start.push(chain.len());
        }
        let (order, envelope_first) = elimination_order(sk, &dofs, lo.len(), &chain_start, &chain);
        Self {
            parent: sk.joints.iter().map(|j| j.parent).collect(),
            rest: sk.joints.iter().map(|j| j.rest).collect(),
            axes,
            dofs,
            n_params: lo.len(),
            lo,
            hi,
            marker_joint: marker_joint.to_vec(),
            marker_offset: marker_joint
                .iter()
                .zip(marker_rest)
                .map(|(&j, &m)| m - sk.joints[j].rest)
                .collect(),
            chain_start,
            chain,
            order,
            envelope_first,
            height_m: height_m.abs().max(f64::MIN_POSITIVE),
        }
    }

    /// Number of unknowns.
    pub fn n_params(&self) -> usize {
        self.n_params
    }

    /// Each marker's rest position relative to its joint, `m_k^rest − r_J` (the joint's
    /// frame at rest is world-aligned).
    pub fn marker_offsets(&self) -> &[DVec3] {
        &self.marker_offset
    }

    /// The first of joint `j`'s three parameters `(twist, bend, side)`, radians; `None`
    /// for roots and leaves (no angles).
    pub fn angle_params(&self, j: usize) -> Option<usize> {
        match self.dofs.get(j)? {
            Dofs::Angles { first } => Some(*first),
            _ => None,
        }
    }
}

/// The elimination order of the posture's normal equations and each row's envelope (see
/// [`IkModel::order`]): joints with unknowns in post-order of the skeleton tree, each
/// joint's unknowns together; a row's envelope starts at the first row of any unknown a
/// marker's chain couples it with.
fn elimination_order(
    sk: &Skeleton,
    dofs: &[Dofs],
    n_params: usize,
    chain_start: &[usize],
    chain: &[usize],
) -> (Vec<usize>, Vec<usize>) {
    let nj = sk.len();
    let mut children = vec![Vec::new(); nj];
    let mut roots = Vec::new();
    for (j, joint) in sk.joints.iter().enumerate() {
        match joint.parent {
            Some(p) => children[p].push(j),
            None => roots.push(j),
        }
    }
    let params = |j: usize| dofs[j].params();
    // Iterative post-order: (joint, children visited).
    let mut order = Vec::with_capacity(n_params);
    let mut stack: Vec<(usize, bool)> = roots.iter().rev().map(|&r| (r, false)).collect();
    while let Some((j, expanded)) = stack.pop() {
        if expanded {
            order.extend(params(j));
        } else {
            stack.push((j, true));
            stack.extend(children[j].iter().rev().map(|&c| (c, false)));
        }
    }
    let mut row_of = vec![0; n_params];
    for (i, &p) in order.iter().enumerate() {
        row_of[p] = i;
    }
    let mut first: Vec<usize> = (0..n_params).collect();
    for k in 0..chain_start.len().saturating_sub(1) {
        let joints = &chain[chain_start[k]..chain_start[k + 1]];
        let lowest = joints
            .iter()
            .flat_map(|&j| params(j))
            .map(|p| row_of[p])
            .min();
        if let Some(lowest) = lowest {
            for p in joints.iter().flat_map(|&j| params(j)) {
                let r = row_of[p];
                first[r] = first[r].min(lowest);
            }
        }
    }
    (order, first)
}
