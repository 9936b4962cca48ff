//! Humanoid joint roles: which joint of a skeleton is the hips, a knee or a finger's
//! middle phalanx, recognised from the names of the common naming schemes (Mixamo
//! `mixamorig:LeftUpLeg`, VRM humanoid bones `leftUpperLeg`, Unreal `thigh_l`, MakeHuman
//! `upperleg01.L`, Blender Rigify `DEF-thigh.L`, 3ds Max Biped `Bip01 L Finger0`, WebXR
//! hand joints `index-finger-phalanx-proximal`) and from the joint tree ([`recognise`]);
//! and the default joint limits of each role ([`default_limits`]), whose bend axes come
//! from the character's own left, forward and palm directions so that a positive bend is
//! anatomical flexion whatever the file's joint axes are.
//!
//! Role names are VRM 1.0's humanoid bone names (`hips`, `leftUpperLeg`,
//! `rightIndexIntermediate`), plus `*Metacarpal` for the four fingers, and without the
//! side prefix when the side is unknown (a hand alone, as WebXR's hands are).

use super::skeleton::{Joint, JointLimits};
use glam::DVec3;

/// A body side.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Side {
    Left,
    Right,
}

/// A finger.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Digit {
    Thumb,
    Index,
    Middle,
    Ring,
    Little,
}

/// A bone of a finger, from the palm out.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Segment {
    Metacarpal,
    Proximal,
    Intermediate,
    Distal,
}

/// The body part whose segment leaves a joint (a knee joint's part is the lower leg).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Part {
    Hips,
    Spine,
    Neck,
    Head,
    /// The clavicle.
    Shoulder,
    UpperArm,
    LowerArm,
    Hand,
    UpperLeg,
    LowerLeg,
    Foot,
    Toes,
    Finger(Digit, Segment),
    /// The second joint of a limb bone split in two (MakeHuman's `upperleg02.L`, Rigify's
    /// `DEF-thigh.L.001`): it twists, it does not bend.
    LimbSegment,
}

/// A joint's humanoid role: a part, and its side when the part has one and it is known.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Role {
    pub part: Part,
    pub side: Option<Side>,
}

const DIGITS: [Digit; 5] = [
    Digit::Thumb,
    Digit::Index,
    Digit::Middle,
    Digit::Ring,
    Digit::Little,
];
const SEGMENTS: [Segment; 4] = [
    Segment::Metacarpal,
    Segment::Proximal,
    Segment::Intermediate,
    Segment::Distal,
];
const BODY_PARTS: [Part; 13] = [
    Part::Hips,
    Part::Spine,
    Part::Neck,
    Part::Head,
    Part::Shoulder,
    Part::UpperArm,
    Part::LowerArm,
    Part::Hand,
    Part::UpperLeg,
    Part::LowerLeg,
    Part::Foot,
    Part::Toes,
    Part::LimbSegment,
];

impl Part {
    /// The VRM name without the side, in lower camel case (`upperLeg`, `indexProximal`).
    fn vrm_name(self) -> String {
        let fixed = match self {
            Part::Hips => "hips",
            Part::Spine => "spine",
            Part::Neck => "neck",
            Part::Head => "head",
            Part::Shoulder => "shoulder",
            Part::UpperArm => "upperArm",
            Part::LowerArm => "lowerArm",
            Part::Hand => "hand",
            Part::UpperLeg => "upperLeg",
            Part::LowerLeg => "lowerLeg",
            Part::Foot => "foot",
            Part::Toes => "toes",
            Part::LimbSegment => "limbSegment",
            Part::Finger(d, s) => {
                let d = match d {
                    Digit::Thumb => "thumb",
                    Digit::Index => "index",
                    Digit::Middle => "middle",
                    Digit::Ring => "ring",
                    Digit::Little => "little",
                };
                let s = match s {
                    Segment::Metacarpal => "Metacarpal",
                    Segment::Proximal => "Proximal",
                    Segment::Intermediate => "Intermediate",
                    Segment::Distal => "Distal",
                };
                return format!("{d}{s}");
            }
        };
        fixed.to_string()
    }

    /// Whether the part comes in a left and a right.
    fn sided(self) -> bool {
        !matches!(self, Part::Hips | Part::Spine | Part::Neck | Part::Head)
    }

    /// Every part: the body's, then every finger's segments.
    fn all() -> impl Iterator<Item = Part> {
        BODY_PARTS.into_iter().chain(
            DIGITS
                .into_iter()
                .flat_map(|d| SEGMENTS.into_iter().map(move |s| Part::Finger(d, s))),
        )
    }
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let name = self.part.vrm_name();
        match self.side {
            None => write!(f, "{name}"),
            Some(side) => {
                let (first, rest) = name.split_at(1);
                let side = if side == Side::Left { "left" } else { "right" };
                write!(f, "{side}{}{rest}", first.to_uppercase())
            }
        }
    }
}

impl std::str::FromStr for Role {
    type Err = ();

    /// A VRM humanoid bone name (`leftUpperLeg`, `hips`, `thumbProximal`), in any case.
    fn from_str(s: &str) -> Result<Self, ()> {
        Part::all()
            .flat_map(|part| {
                let sides: &[Option<Side>] = if part.sided() {
                    &[None, Some(Side::Left), Some(Side::Right)]
                } else {
                    &[None]
                };
                sides.iter().map(move |&side| Role { part, side })
            })
            .find(|r| r.to_string().eq_ignore_ascii_case(s))
            .ok_or(())
    }
}

/// The words of a joint name, lower case: split at separators, at lower-to-upper case
/// changes (`LeftUpLeg`: left, up, leg), before the last capital of a capital run
/// followed by a lower-case letter (`LHip`: l, hip) and between letters and digits
/// (`spine01`: spine, 01). A namespace (`mixamorig:`) is dropped.
fn words(name: &str) -> Vec<String> {
    let name = name.rsplit(':').next().unwrap_or(name);
    let chars: Vec<char> = name.chars().collect();
    let mut out = Vec::new();
    let mut cur = String::new();
    for (i, &c) in chars.iter().enumerate() {
        if !c.is_alphanumeric() {
            if !cur.is_empty() {
                out.push(std::mem::take(&mut cur));
            }
            continue;
        }
        if let Some(&p) = cur.chars().last().as_ref() {
            let next_lower = chars.get(i + 1).is_some_and(|n| n.is_lowercase());
            let split = (p.is_lowercase() && c.is_uppercase())
                || (p.is_uppercase() && c.is_uppercase() && next_lower)
                || (p.is_ascii_digit() != c.is_ascii_digit());
            if split {
                out.push(std::mem::take(&mut cur));
            }
        }
        cur.push(c);
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out.into_iter().map(|w| w.to_lowercase()).collect()
}

/// What a joint's name says, before the tree is consulted.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Said {
    /// A part, with how sure the name is (a tie is settled by the tree).
    Part(Part, u8),
    /// A finger's bone whose place in the finger comes from the tree (`Index1`,
    /// `f_index.01`): its digit, if named (a metacarpal may name none).
    FingerBone(Option<Digit>, bool),
    /// A limb word alone (`leg_joint_L_2`, `LeftLeg`): the chain along the limb decides.
    Limb {
        leg: bool,
    },
    /// The end of a chain (`HeadTop_End`, `index-finger-tip`).
    End,
    Nothing,
}

fn side_of(w: &[String]) -> Option<Side> {
    w.iter().find_map(|x| match x.as_str() {
        "l" | "left" | "lft" => Some(Side::Left),
        "r" | "right" | "rt" | "rgt" => Some(Side::Right),
        _ => None,
    })
}

fn digit_word(x: &str) -> Option<Digit> {
    Some(match x {
        "thumb" | "pollex" => Digit::Thumb,
        "index" | "pointer" => Digit::Index,
        "middle" => Digit::Middle,
        "ring" => Digit::Ring,
        "little" | "pinky" | "pinkie" | "small" => Digit::Little,
        _ => return None,
    })
}

/// What the words of a name say.
fn read_words(w: &[String], zero_based_fingers: bool) -> Said {
    let has = |x: &str| w.iter().any(|y| y == x);
    let any = |xs: &[&str]| xs.iter().any(|x| has(x));
    if any(&[
        "twist", "roll", "helper", "ik", "pole", "target", "ctrl", "eye", "eyeball", "skirt",
        "hair", "bust", "breast", "sec", "cloth", "tail", "jaw", "tongue",
    ]) {
        return Said::Nothing;
    }
    if any(&["end", "tip", "nub", "top", "headtop", "null"]) {
        return Said::End;
    }
    // Feet first: DAZ's `lSmallToe1` and `left_foot_index` are not fingers.
    if any(&["toe", "toes", "toebase"]) {
        return Said::Part(Part::Toes, 2);
    }
    if any(&["foot", "ankle"]) && !any(&["finger"]) {
        return Said::Part(Part::Foot, 3);
    }
    // A finger: a digit word, or `finger` followed by its number (MakeHuman `finger2-1`
    // from 1 = thumb; Biped `Finger0` from 0 = thumb; the number's first figure).
    let numbered = w.iter().position(|x| x == "finger").and_then(|k| {
        let n = w.get(k + 1)?.chars().next()?.to_digit(10)? as usize;
        let n = if zero_based_fingers {
            n
        } else {
            n.checked_sub(1)?
        };
        DIGITS.get(n).copied()
    });
    let digit = w.iter().find_map(|x| digit_word(x)).or(numbered);
    let metacarpal = any(&["metacarpal", "metacarpals", "palm", "meta", "carpal"])
        || (has("finger") && has("base"));
    if let Some(d) = digit {
        let seg = if metacarpal {
            Some(Segment::Metacarpal)
        } else if has("proximal") {
            Some(Segment::Proximal)
        } else if any(&["intermediate", "medial"]) {
            Some(Segment::Intermediate)
        } else if has("distal") {
            Some(Segment::Distal)
        } else {
            None
        };
        return match seg {
            // A thumb's named bones are still counted along the chain: VRM 0's
            // `thumbProximal` is VRM 1's `thumbMetacarpal`.
            Some(s) if d != Digit::Thumb || s == Segment::Metacarpal => {
                Said::Part(Part::Finger(d, s), 3)
            }
            _ => Said::FingerBone(Some(d), false),
        };
    }
    if metacarpal {
        return Said::FingerBone(None, true);
    }
    let part = |p: Part, sure: u8| Said::Part(p, sure);
    let upper = any(&["upper", "up"]);
    let lower = any(&["lower", "low", "fore"]);
    let sided = side_of(w).is_some();
    if any(&["forearm", "lowerarm", "elbow", "radius", "ulna"]) || (lower && has("arm")) {
        return part(Part::LowerArm, 3);
    }
    if any(&["upperarm", "humerus", "bicep", "shldr"]) || (upper && has("arm")) {
        return part(Part::UpperArm, 3);
    }
    if any(&["clavicle", "collar", "shoulder", "collarbone"]) {
        return part(Part::Shoulder, 2);
    }
    if any(&["hand", "wrist"]) {
        return part(Part::Hand, 3);
    }
    if any(&["thigh", "upleg", "upperleg", "femur"]) || (upper && has("leg")) {
        return part(Part::UpperLeg, 3);
    }
    if any(&["shin", "calf", "knee", "lowerleg", "tibia", "crus"]) || (lower && has("leg")) {
        return part(Part::LowerLeg, 3);
    }
    if has("ball") {
        return part(Part::Toes, 2);
    }
    if has("leg") || has("arm") {
        return Said::Limb { leg: has("leg") };
    }
    if any(&["hip", "hips", "pelvis"]) {
        // CMU's `LHipJoint` is the bone from the root to the hip joint, parent of the
        // thigh (`LeftUpLeg`, or `LeftHip` in some of its BVH conversions): no part.
        if sided && has("joint") {
            return Said::Nothing;
        }
        // `LeftHip` is a thigh in some schemes; MakeHuman's `pelvis.L` sits between the
        // hips and the thigh: a weak claim.
        return if sided {
            part(Part::UpperLeg, 1)
        } else {
            part(Part::Hips, 3)
        };
    }
    if any(&[
        "spine",
        "chest",
        "torso",
        "abdomen",
        "waist",
        "back",
        "lowerback",
        "upperchest",
        "spine1",
        "abdomen2",
    ]) {
        return part(Part::Spine, 2);
    }
    if has("neck") {
        return part(Part::Neck, 3);
    }
    if has("head") {
        return part(Part::Head, 3);
    }
    Said::Nothing
}

/// The roles of a skeleton's joints (parents before children, as [`Joint::parent`]
/// promises), each `None` when no role was recognised. A user's assignments in
/// `overrides` (joint index, role or `None` for "no role") replace what was found.
///
/// Names give the part and side; the tree settles what names leave open: finger bones
/// take their place in the finger from their order along it (a thumb's first bone is its
/// metacarpal, another finger's first its proximal phalanx, unless named a metacarpal),
/// a metacarpal without a digit word takes its child's digit, limb words alone go by
/// their order along the limb (legs: upper leg, lower leg, foot, toes; arms of three:
/// upper arm, lower arm, hand, of four: the shoulder first; a lone `Leg` is a lower leg
/// and a lone `Arm` an upper arm, as in Mixamo, unless its child names the part after
/// another: `Left leg` over `Left knee` is an upper leg), a part claimed twice on one side keeps
/// the surer claim and then the joint nearer the root (a limb's second claim that is the
/// first's child is its split segment), and with no joint named the hips
/// a root with two children or more is the hips.
pub fn recognise(joints: &[Joint], overrides: &[(usize, Option<Role>)]) -> Vec<Option<Role>> {
    let n = joints.len();
    let words: Vec<Vec<String>> = joints.iter().map(|j| words(&j.name)).collect();
    let zero_based = words.iter().any(|w| {
        w.iter()
            .position(|x| x == "finger")
            .and_then(|k| w.get(k + 1))
            .is_some_and(|x| x.starts_with('0'))
    });
    let said: Vec<Said> = words.iter().map(|w| read_words(w, zero_based)).collect();
    let side: Vec<Option<Side>> = words.iter().map(|w| side_of(w)).collect();
    let mut children = vec![Vec::new(); n];
    let mut depth = vec![0usize; n];
    for (i, j) in joints.iter().enumerate() {
        if let Some(p) = j.parent.filter(|&p| p < i) {
            children[p].push(i);
            depth[i] = depth[p] + 1;
        }
    }
    let mut roles: Vec<Option<(Role, u8)>> = vec![None; n];
    for i in 0..n {
        if let Said::Part(part, sure) = said[i] {
            let side = if part.sided() { side[i] } else { None };
            roles[i] = Some((Role { part, side }, sure));
        }
    }
    chain_roles(joints, &said, &side, &children, &mut roles);
    keep_surest(joints, &depth, &mut roles);
    shoulder_as_upper_arm(&children, &mut roles);
    neck_top_as_head(joints, &said, &children, &mut roles);
    if !roles.iter().flatten().any(|(r, _)| r.part == Part::Hips) {
        if let Some(root) = (0..n).find(|&i| joints[i].parent.is_none()) {
            let weak = roles[root].is_none_or(|(r, _)| r.part == Part::Spine);
            if children[root].len() >= 2 && weak {
                roles[root] = Some((
                    Role {
                        part: Part::Hips,
                        side: None,
                    },
                    1,
                ));
            }
        }
    }
    let mut out: Vec<Option<Role>> = roles.into_iter().map(|r| r.map(|(r, _)| r)).collect();
    for &(j, role) in overrides {
        if let Some(slot) = out.get_mut(j) {
            *slot = role;
        }
    }
    out
}

/// Roles that come from a joint's place along a chain: finger bones and limb words.
fn chain_roles(
    joints: &[Joint],
    said: &[Said],
    side: &[Option<Side>],
    children: &[Vec<usize>],
    roles: &mut [Option<(Role, u8)>],
) {
    let n = joints.len();
    // A metacarpal without a digit word takes the digit of a child that names one.
    let digit_of = |i: usize| -> Option<Digit> {
        match said[i] {
            Said::FingerBone(Some(d), _) => Some(d),
            Said::Part(Part::Finger(d, _), _) => Some(d),
            Said::FingerBone(None, _) => children[i].iter().find_map(|&c| match said[c] {
                Said::FingerBone(Some(d), _) | Said::Part(Part::Finger(d, _), _) => Some(d),
                _ => None,
            }),
            _ => None,
        }
    };
    for i in 0..n {
        let Some(d) = digit_of(i) else { continue };
        if let Said::FingerBone(_, metacarpal) = said[i] {
            let seg = if metacarpal {
                Some(Segment::Metacarpal)
            } else {
                // Count the bones of this digit above this one (a thumb's metacarpal
                // is one of its three; another finger's is not counted).
                let mut above = 0;
                let mut p = joints[i].parent;
                while let Some(k) = p {
                    if digit_of(k) != Some(d) {
                        break;
                    }
                    let metacarpal = matches!(
                        said[k],
                        Said::FingerBone(_, true)
                            | Said::Part(Part::Finger(_, Segment::Metacarpal), _)
                    );
                    if d == Digit::Thumb || !metacarpal {
                        above += 1;
                    }
                    p = joints[k].parent;
                }
                let order: &[Segment] = if d == Digit::Thumb {
                    &[Segment::Metacarpal, Segment::Proximal, Segment::Distal]
                } else {
                    &[Segment::Proximal, Segment::Intermediate, Segment::Distal]
                };
                // Past the last bone: the chain's end (Mixamo's `Index4`).
                order.get(above).copied()
            };
            if let Some(seg) = seg {
                roles[i] = Some((
                    Role {
                        part: Part::Finger(d, seg),
                        side: side[i],
                    },
                    2,
                ));
            }
        }
    }
    // Limb words alone: the chain of joints saying the same word on the same side.
    for i in 0..n {
        let Said::Limb { leg } = said[i] else {
            continue;
        };
        let same = |k: usize| said[k] == Said::Limb { leg } && side[k] == side[i];
        if joints[i].parent.is_some_and(same) {
            continue; // not the chain's first joint
        }
        let mut chain = vec![i];
        while let Some(&next) = children[*chain.last().unwrap_or(&i)]
            .iter()
            .find(|&&c| same(c))
        {
            chain.push(next);
        }
        // A lone limb word is the part before the one its child names (`Left leg` over
        // `Left knee` is the thigh; Mixamo's `LeftLeg` over `LeftFoot` the shin).
        let next = children[i].iter().find_map(|&c| match said[c] {
            Said::Part(p, _) if side[c] == side[i] => Some(p),
            _ => None,
        });
        // A limb word on a joint with no child at all is the whole limb, hanging from
        // the trunk (Kenney's `leg-left`): its upper part.
        let whole = children[i].iter().all(|&c| said[c] == Said::End);
        let lone = match (leg, next) {
            (true, _) if whole => Part::UpperLeg,
            (true, Some(Part::LowerLeg)) => Part::UpperLeg,
            (true, _) => Part::LowerLeg,
            (false, Some(Part::Hand)) => Part::LowerArm,
            (false, Some(Part::UpperArm)) => Part::Shoulder,
            (false, _) => Part::UpperArm,
        };
        let parts: &[Part] = match (leg, chain.len()) {
            (_, 1) => std::slice::from_ref(&lone),
            (true, _) => &[Part::UpperLeg, Part::LowerLeg, Part::Foot, Part::Toes],
            (false, 4..) => &[Part::Shoulder, Part::UpperArm, Part::LowerArm, Part::Hand],
            (false, _) => &[Part::UpperArm, Part::LowerArm, Part::Hand],
        };
        for (&k, &part) in chain.iter().zip(parts) {
            roles[k] = Some((
                Role {
                    part,
                    side: side[k],
                },
                if chain.len() == 1 { 2 } else { 1 },
            ));
        }
    }
}

/// Where no joint is the head, the top of a neck chain of two or more joints (with no
/// child but end joints) is: a neck ends in a head (Khronos CesiumMan's
/// `Skeleton_neck_joint_1 → Skeleton_neck_joint_2`, the second carrying the head).
fn neck_top_as_head(
    joints: &[Joint],
    said: &[Said],
    children: &[Vec<usize>],
    roles: &mut [Option<(Role, u8)>],
) {
    if roles.iter().flatten().any(|(r, _)| r.part == Part::Head) {
        return;
    }
    let is_neck = |i: usize| roles[i].is_some_and(|(r, _)| r.part == Part::Neck);
    let tops: Vec<usize> = (0..joints.len())
        .filter(|&i| {
            is_neck(i)
                && joints[i].parent.is_some_and(is_neck)
                && children[i].iter().all(|&c| said[c] == Said::End)
        })
        .collect();
    if let [top] = tops[..] {
        roles[top] = Some((
            Role {
                part: Part::Head,
                side: None,
            },
            1,
        ));
    }
}

/// Where a side has no upper arm, a shoulder whose child is that side's lower arm is the
/// upper arm (SMPL's `L_Collar → L_Shoulder → L_Elbow`, Kinect's `ShoulderLeft →
/// ElbowLeft`: there "shoulder" names the shoulder joint, not the clavicle).
fn shoulder_as_upper_arm(children: &[Vec<usize>], roles: &mut [Option<(Role, u8)>]) {
    for side in [Some(Side::Left), Some(Side::Right), None] {
        let has = |roles: &[Option<(Role, u8)>], part| {
            roles
                .iter()
                .flatten()
                .any(|(r, _)| r.part == part && r.side == side)
        };
        if has(roles, Part::UpperArm) {
            continue;
        }
        let lower = Role {
            part: Part::LowerArm,
            side,
        };
        let shoulder = (0..roles.len()).find(|&i| {
            roles[i].is_some_and(|(r, _)| r.part == Part::Shoulder && r.side == side)
                && children[i]
                    .iter()
                    .any(|&c| roles[c].is_some_and(|(r, _)| r == lower))
        });
        if let Some(i) = shoulder {
            roles[i] = Some((
                Role {
                    part: Part::UpperArm,
                    side,
                },
                2,
            ));
        }
    }
}

/// Parts a side has once (the spine, neck, shoulder and toes may have several joints):
/// the surest claim keeps it, then the joint nearest the root. A limb bone's second claim
/// that is the first's child is its split segment ([`Part::LimbSegment`]).
fn keep_surest(joints: &[Joint], depth: &[usize], roles: &mut [Option<(Role, u8)>]) {
    let once = |p: Part| {
        !matches!(
            p,
            Part::Spine | Part::Neck | Part::Shoulder | Part::Toes | Part::Finger(..)
        )
    };
    for i in 0..roles.len() {
        let Some((r, sure)) = roles[i] else { continue };
        if !once(r.part) {
            continue;
        }
        let better = (0..roles.len()).any(|k| {
            k != i
                && roles[k].is_some_and(|(rk, sk)| {
                    rk == r && (sk > sure || (sk == sure && (depth[k], k) < (depth[i], i)))
                })
        });
        if better {
            let limb = matches!(
                r.part,
                Part::UpperArm | Part::LowerArm | Part::UpperLeg | Part::LowerLeg
            );
            let split = joints[i]
                .parent
                .filter(|&p| p < i)
                .is_some_and(|p| roles[p].is_some_and(|(rp, _)| rp == r));
            roles[i] = (limb && split).then_some((
                Role {
                    part: Part::LimbSegment,
                    side: r.side,
                },
                sure,
            ));
        }
    }
}

/// Which way a role's positive bend turns its segment.
#[derive(Clone, Copy, Debug)]
enum Flex {
    /// The segment's far end moves forward (hip and shoulder flexion, the elbow, the
    /// spine, the neck).
    Forward,
    /// The far end moves backward (the knee).
    Backward,
    /// The far end moves towards the palm (fingers, the wrist); symmetric when the palm
    /// is not known.
    Palm,
    /// About the character's left axis, with a symmetric range (feet, toes).
    Lateral,
}

/// A part's default limits: twist, bend and side ranges in degrees, and the bend's
/// direction.
type RoleLimits = ([f64; 2], [f64; 2], [f64; 2], Flex);

/// Default limits of a part. Ranges are from the anatomical neutral where
/// [`neutral_direction`] knows it (a straight knee, elbow or finger, a thigh hanging
/// down; hip extension 30° and toe extension 70° as the American Academy of Orthopaedic
/// Surgeons' normal ranges give them, Greene and Heckman 1994: a walk's trailing thigh and
/// toe-off reach past tighter ones); elsewhere from the rest pose, wide where rest poses
/// differ (T or A pose).
fn table(part: Part) -> Option<RoleLimits> {
    use Flex::*;
    Some(match part {
        Part::Hips => return None,
        Part::Spine => ([-25.0, 25.0], [-25.0, 40.0], [-25.0, 25.0], Forward),
        Part::Neck => ([-60.0, 60.0], [-40.0, 50.0], [-35.0, 35.0], Forward),
        Part::Head => ([-40.0, 40.0], [-35.0, 35.0], [-25.0, 25.0], Forward),
        Part::Shoulder => ([-15.0, 15.0], [-20.0, 20.0], [-25.0, 25.0], Forward),
        Part::UpperArm => ([-90.0, 90.0], [-45.0, 130.0], [-100.0, 100.0], Forward),
        Part::LowerArm => ([-80.0, 80.0], [-5.0, 150.0], [-5.0, 5.0], Forward),
        Part::Hand => ([-20.0, 20.0], [-70.0, 70.0], [-30.0, 30.0], Palm),
        Part::UpperLeg => ([-40.0, 40.0], [-30.0, 120.0], [-45.0, 45.0], Forward),
        Part::LowerLeg => ([-10.0, 10.0], [-5.0, 150.0], [-5.0, 5.0], Backward),
        Part::Foot => ([-20.0, 20.0], [-45.0, 45.0], [-30.0, 30.0], Lateral),
        Part::Toes => ([-5.0, 5.0], [-40.0, 70.0], [-10.0, 10.0], Lateral),
        Part::LimbSegment => ([-45.0, 45.0], [-3.0, 3.0], [-3.0, 3.0], Lateral),
        Part::Finger(Digit::Thumb, Segment::Metacarpal) => {
            ([-25.0, 25.0], [-40.0, 40.0], [-40.0, 40.0], Palm)
        }
        Part::Finger(_, Segment::Metacarpal) => ([-5.0, 5.0], [-5.0, 5.0], [-5.0, 5.0], Palm),
        Part::Finger(Digit::Thumb, Segment::Proximal) => {
            ([-10.0, 10.0], [-10.0, 60.0], [-10.0, 10.0], Palm)
        }
        Part::Finger(Digit::Thumb, _) => ([-10.0, 10.0], [-15.0, 80.0], [-5.0, 5.0], Palm),
        Part::Finger(_, Segment::Proximal) => ([-10.0, 10.0], [-15.0, 90.0], [-20.0, 20.0], Palm),
        Part::Finger(_, Segment::Intermediate) => ([-10.0, 10.0], [-5.0, 100.0], [-5.0, 5.0], Palm),
        Part::Finger(_, Segment::Distal) => ([-10.0, 10.0], [-5.0, 80.0], [-5.0, 5.0], Palm),
    })
}

/// The character's left direction (horizontal, unit): from right-side joints to their
/// left-side partners, or +X (glTF's convention: a character faces +Z, its left is +X)
/// when no pair is known.
fn left_direction(joints: &[Joint], roles: &[Option<Role>]) -> DVec3 {
    let mut sum = DVec3::ZERO;
    for (i, r) in roles.iter().enumerate() {
        let Some(Role {
            part,
            side: Some(Side::Left),
        }) = *r
        else {
            continue;
        };
        let partner = roles.iter().position(|o| {
            *o == Some(Role {
                part,
                side: Some(Side::Right),
            })
        });
        if let Some(k) = partner {
            sum += joints[i].rest - joints[k].rest;
        }
    }
    let horizontal = DVec3::new(sum.x, 0.0, sum.z);
    horizontal.try_normalize().unwrap_or(DVec3::X)
}

/// The palm normal of the hand at joint `hand` (unit; the side the fingers curl to), from
/// its fingers' bases (index and little, or the outermost fingers found) and either its
/// side or, for a hand of unknown side, the curl of its fingers at rest. `None` when
/// neither tells.
fn palm_normal(
    joints: &[Joint],
    roles: &[Option<Role>],
    children: &[Vec<usize>],
    hand: usize,
) -> Option<DVec3> {
    let under = |i: usize| {
        let mut p = joints[i].parent;
        while let Some(k) = p {
            if k == hand {
                return true;
            }
            p = joints[k].parent;
        }
        false
    };
    let base = |d: Digit| {
        (0..joints.len()).find(|&i| {
            roles[i].is_some_and(|r| r.part == Part::Finger(d, Segment::Proximal)) && under(i)
        })
    };
    let index = [Digit::Index, Digit::Middle].into_iter().find_map(base)?;
    let little = [Digit::Little, Digit::Ring].into_iter().find_map(base)?;
    let (wrist, a, b) = (joints[hand].rest, joints[index].rest, joints[little].rest);
    let along = 0.5 * (a + b) - wrist;
    let n0 = along.cross(b - a).try_normalize()?;
    match roles[hand].and_then(|r| r.side) {
        Some(Side::Right) => Some(n0),
        Some(Side::Left) => Some(-n0),
        None => {
            // Fingers at rest curl a little towards the palm: sum, over each finger
            // bone whose parent is a bone of the same finger, the turn between them.
            let mut curl = 0.0;
            for i in (0..joints.len()).filter(|&i| under(i)) {
                let (Some(p), Some(&c)) = (joints[i].parent, children[i].first()) else {
                    continue;
                };
                let is_finger = |k: usize| {
                    roles[k]
                        .is_some_and(|r| matches!(r.part, Part::Finger(d, _) if d != Digit::Thumb))
                };
                if !(is_finger(i) && is_finger(p)) {
                    continue;
                }
                let t0 = (joints[i].rest - joints[p].rest).normalize_or_zero();
                let t1 = (joints[c].rest - joints[i].rest).normalize_or_zero();
                curl += t0.cross(t1).dot(t0.cross(n0));
            }
            // Below a summed turn of about 3°, the rest pose says nothing.
            (curl.abs() > 0.05).then(|| n0 * curl.signum())
        }
    }
}

/// The rest direction of joint `j`'s segment at the anatomical neutral of its part
/// (world frame, unit), where one is known: a lower limb segment or a finger's middle or
/// end bone in line with the bone above it (a straight knee, elbow, finger), a thigh
/// hanging straight down. A rig's rest pose may bend those (a knee bent 25° at rest, an
/// elbow 20°): ranges from the rest would then forbid a straight leg. Not the hand: its
/// twist axis points at the mean of its fingers' bases, thumb included, which lies off
/// the forearm's line on a straight wrist (35° on MakeHuman's).
fn neutral_direction(joints: &[Joint], part: Part, j: usize) -> Option<DVec3> {
    match part {
        Part::UpperLeg => Some(-DVec3::Y),
        Part::LowerLeg
        | Part::LowerArm
        | Part::Finger(
            Digit::Index | Digit::Middle | Digit::Ring | Digit::Little,
            Segment::Intermediate | Segment::Distal,
        ) => {
            let p = joints[j].parent?;
            (joints[j].rest - joints[p].rest).try_normalize()
        }
        _ => None,
    }
}

/// The rest pose's own bend and side (radians) from the neutral direction `n` of a
/// segment whose rest direction is the twist axis `t`, about the bend axis `a` and the
/// side axis `t × a` (as [`crate::character::skeleton::decompose`] splits a swing): the
/// rotation vector taking `n` to `t`, on those axes.
fn rest_swing(n: DVec3, t: DVec3, a: DVec3) -> (f64, f64) {
    let angle = n.angle_between(t);
    let Some(axis) = n.cross(t).try_normalize() else {
        return (0.0, 0.0);
    };
    let r = axis * angle;
    (r.dot(a), r.dot(t.cross(a)))
}

/// Default limits and bend axes (world frame, rest pose) for joints with a role and
/// children, `None` elsewhere; a role's positive bend is flexion ([`table`]'s
/// directions), with the bend axis `a` chosen so that a bend turns the twist axis `t`
/// towards the flexion direction `f`: `a = t × f`. The limits are rotations from the
/// rest pose: a range from the anatomical neutral is moved by the rest pose's own swing
/// from it ([`neutral_direction`], [`rest_swing`]).
pub fn default_limits(
    joints: &[Joint],
    roles: &[Option<Role>],
) -> Vec<Option<(JointLimits, DVec3)>> {
    let n = joints.len();
    let mut children = vec![Vec::new(); n];
    for (i, j) in joints.iter().enumerate() {
        if let Some(p) = j.parent.filter(|&p| p < i) {
            children[p].push(i);
        }
    }
    let left = left_direction(joints, roles);
    let forward = left.cross(DVec3::Y);
    // The palm normal each joint's hand gives it.
    let mut palm: Vec<Option<DVec3>> = vec![None; n];
    for i in 0..n {
        palm[i] = match roles[i] {
            Some(Role {
                part: Part::Hand, ..
            }) => palm_normal(joints, roles, &children, i),
            _ => joints[i].parent.and_then(|p| palm[p]),
        };
    }
    (0..n)
        .map(|i| {
            let role = roles[i]?;
            let (twist, bend, side, flex) = table(role.part)?;
            if children[i].is_empty() {
                return None;
            }
            let mean = children[i].iter().map(|&c| joints[c].rest).sum::<DVec3>()
                / children[i].len() as f64;
            let t = (mean - joints[i].rest).try_normalize()?;
            let towards = match flex {
                Flex::Forward => Some(forward),
                Flex::Backward => Some(-forward),
                Flex::Palm => palm[i],
                Flex::Lateral => None,
            };
            let axis = towards
                .map(|f| t.cross(f))
                .filter(|a| a.length() > 0.3)
                .map(DVec3::normalize);
            let r = |v: [f64; 2]| (v[0].to_radians(), v[1].to_radians());
            let (bend, axis) = match axis {
                Some(a) => (r(bend), a),
                None => {
                    // No flexion direction: a symmetric range about the left axis.
                    let m = bend[0].abs().max(bend[1].abs()).to_radians();
                    let a = left - t * left.dot(t);
                    let a = a.try_normalize().unwrap_or(t.any_orthonormal_vector());
                    ((-m, m), a)
                }
            };
            let (rest_bend, rest_side) = neutral_direction(joints, role.part, i)
                .map_or((0.0, 0.0), |n| rest_swing(n, t, axis));
            // The rest pose stays inside its limits (the solve starts there): a rest
            // beyond the human range (a stylised rig) keeps the ranges from the rest.
            let from_rest = |(lo, hi): (f64, f64), rest: f64| {
                if lo - rest <= 0.0 && hi - rest >= 0.0 {
                    (lo - rest, hi - rest)
                } else {
                    (lo, hi)
                }
            };
            Some((
                JointLimits {
                    twist: r(twist),
                    bend: from_rest(bend, rest_bend),
                    side: from_rest(r(side), rest_side),
                },
                axis,
            ))
        })
        .collect()
}

/// A one-line account of the roles found: each role once (repeated ones counted), the
/// joints with children left without a role, and how many chain ends there are.
pub fn summary(joints: &[Joint], roles: &[Option<Role>]) -> RoleSummary {
    let mut found: Vec<(String, usize)> = Vec::new();
    for r in roles.iter().flatten() {
        let name = r.to_string();
        match found.iter_mut().find(|(n, _)| *n == name) {
            Some((_, c)) => *c += 1,
            None => found.push((name, 1)),
        }
    }
    let has_child: Vec<bool> = (0..joints.len())
        .map(|i| joints.iter().any(|j| j.parent == Some(i)))
        .collect();
    let without = (0..joints.len())
        .filter(|&i| roles[i].is_none() && has_child[i])
        .map(|i| joints[i].name.clone())
        .collect();
    RoleSummary {
        with_role: roles.iter().flatten().count(),
        found,
        without,
        ends_without: (0..joints.len())
            .filter(|&i| roles[i].is_none() && !has_child[i])
            .count(),
    }
}

/// What [`summary`] reports.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct RoleSummary {
    /// Joints with a role.
    pub with_role: usize,
    /// Each role found (VRM name) and how many joints have it, in skeleton order.
    pub found: Vec<(String, usize)>,
    /// Joints with children and no role (no default limits; free unless listed).
    pub without: Vec<String>,
    /// Chain ends (joints without children) with no role: they need none.
    pub ends_without: usize,
}

impl std::fmt::Display for RoleSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let found: Vec<String> = self
            .found
            .iter()
            .map(|(n, c)| {
                if *c > 1 {
                    format!("{n}×{c}")
                } else {
                    n.clone()
                }
            })
            .collect();
        write!(f, "{} joints have a role", self.with_role)?;
        if !found.is_empty() {
            write!(f, " ({})", found.join(", "))?;
        }
        if !self.without.is_empty() {
            write!(f, "; without one: {}", self.without.join(", "))?;
        }
        if self.ends_without > 0 {
            write!(f, "; {} chain ends", self.ends_without)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::character::skeleton::{compose, SwingTwist};
    use glam::DQuat;

    /// Joints from (name, parent name, rest position); parents listed first.
    fn tree(spec: &[(&str, Option<&str>, [f64; 3])]) -> Vec<Joint> {
        spec.iter()
            .map(|&(name, parent, p)| Joint {
                name: name.to_string(),
                parent: parent.map(|pn| {
                    spec.iter()
                        .position(|s| s.0 == pn)
                        .unwrap_or_else(|| panic!("{pn} not listed"))
                }),
                rest: DVec3::from_array(p),
                limits: None,
                bend_axis: DVec3::X,
            })
            .collect()
    }

    /// Joints of a chain-shaped tree (positions only need to differ).
    fn names_tree(spec: &[(&str, Option<&str>)]) -> Vec<Joint> {
        let with_pos: Vec<(&str, Option<&str>, [f64; 3])> = spec
            .iter()
            .enumerate()
            .map(|(i, &(n, p))| (n, p, [0.01 * i as f64, 1.0 - 0.01 * i as f64, 0.0]))
            .collect();
        tree(&with_pos)
    }

    /// How far the unit direction of joint `i`'s segment (towards its first child) moves
    /// when the joint bends by `bend_rad` about `axis`.
    fn bent(joints: &[Joint], i: usize, axis: DVec3, bend_rad: f64) -> DVec3 {
        let c = joints.iter().position(|j| j.parent == Some(i)).unwrap();
        let t = (joints[c].rest - joints[i].rest).normalize();
        let st = SwingTwist {
            twist: 0.0,
            bend: bend_rad,
            side: 0.0,
        };
        compose(st, t, axis) * t - t
    }

    fn role_of(joints: &[Joint], roles: &[Option<Role>], name: &str) -> String {
        let i = joints.iter().position(|j| j.name == name).unwrap();
        roles[i].map_or("-".to_string(), |r| r.to_string())
    }

    /// A Mixamo-named T pose facing +Z (its left at +X), palms down; metres.
    fn mixamo_t_pose() -> Vec<Joint> {
        let mut spec: Vec<(String, Option<String>, [f64; 3])> = vec![
            ("mixamorig:Hips".into(), None, [0.0, 1.0, 0.0]),
            ("mixamorig:Spine".into(), Some("Hips"), [0.0, 1.1, 0.0]),
            ("mixamorig:Spine1".into(), Some("Spine"), [0.0, 1.2, 0.0]),
            ("mixamorig:Spine2".into(), Some("Spine1"), [0.0, 1.3, 0.0]),
            ("mixamorig:Neck".into(), Some("Spine2"), [0.0, 1.5, 0.0]),
            ("mixamorig:Head".into(), Some("Neck"), [0.0, 1.6, 0.0]),
            (
                "mixamorig:HeadTop_End".into(),
                Some("Head"),
                [0.0, 1.8, 0.0],
            ),
        ]
        .into_iter()
        .map(|(n, p, x)| (n, p.map(|p: &str| format!("mixamorig:{p}")), x))
        .collect();
        for (side, s) in [("Left", 1.0), ("Right", -1.0)] {
            let j = |n: &str| format!("mixamorig:{side}{n}");
            let mut add = |n: &str, p: Option<String>, x: [f64; 3]| {
                spec.push((j(n), p, [s * x[0], x[1], x[2]]));
            };
            add(
                "Shoulder",
                Some("mixamorig:Spine2".into()),
                [0.05, 1.45, 0.0],
            );
            add("Arm", Some(j("Shoulder")), [0.15, 1.45, 0.0]);
            add("ForeArm", Some(j("Arm")), [0.45, 1.45, 0.0]);
            add("Hand", Some(j("ForeArm")), [0.7, 1.45, 0.0]);
            for (f, z) in [
                ("Index", 0.03),
                ("Middle", 0.01),
                ("Ring", -0.01),
                ("Pinky", -0.03),
            ] {
                let mut parent = j("Hand");
                for k in 1..=4 {
                    let name = format!("Hand{f}{k}");
                    add(&name, Some(parent), [0.78 + 0.03 * k as f64, 1.45, z]);
                    parent = j(&name);
                }
            }
            let mut parent = j("Hand");
            for k in 1..=4 {
                let name = format!("HandThumb{k}");
                add(
                    &name,
                    Some(parent),
                    [0.72 + 0.02 * k as f64, 1.44, 0.04 + 0.015 * k as f64],
                );
                parent = j(&name);
            }
            add("UpLeg", Some("mixamorig:Hips".into()), [0.1, 0.95, 0.0]);
            add("Leg", Some(j("UpLeg")), [0.1, 0.5, 0.0]);
            add("Foot", Some(j("Leg")), [0.1, 0.08, 0.0]);
            add("ToeBase", Some(j("Foot")), [0.1, 0.02, 0.12]);
            add("Toe_End", Some(j("ToeBase")), [0.1, 0.02, 0.18]);
        }
        let spec: Vec<(&str, Option<&str>, [f64; 3])> = spec
            .iter()
            .map(|(n, p, x)| (n.as_str(), p.as_deref(), *x))
            .collect();
        tree(&spec)
    }

    #[test]
    fn words_split_the_usual_spellings() {
        let w = |s: &str| words(s).join(" ");
        assert_eq!(w("mixamorig:LeftUpLeg"), "left up leg");
        assert_eq!(w("LHipJoint"), "l hip joint");
        assert_eq!(w("spine01"), "spine 01");
        assert_eq!(w("DEF-upper_arm.L.001"), "def upper arm l 001");
        assert_eq!(w("J_Bip_L_UpperArm"), "j bip l upper arm");
        assert_eq!(w("Bip01 L Finger01"), "bip 01 l finger 01");
        assert_eq!(
            w("index-finger-phalanx-proximal"),
            "index finger phalanx proximal"
        );
    }

    #[test]
    fn role_names_read_back() {
        for part in Part::all() {
            for side in [None, Some(Side::Left), Some(Side::Right)] {
                if side.is_some() && !part.sided() {
                    continue;
                }
                let r = Role { part, side };
                assert_eq!(r.to_string().parse::<Role>(), Ok(r), "{r}");
                assert_eq!(r.to_string().to_uppercase().parse::<Role>(), Ok(r), "{r}");
            }
        }
        assert_eq!("leftKnee".parse::<Role>(), Err(()));
        assert_eq!("leftHips".parse::<Role>(), Err(()), "the hips have no side");
    }

    #[test]
    fn mixamo_roles_and_flexion_directions() {
        let joints = mixamo_t_pose();
        let roles = recognise(&joints, &[]);
        let r = |n: &str| role_of(&joints, &roles, &format!("mixamorig:{n}"));
        for (name, want) in [
            ("Hips", "hips"),
            ("Spine1", "spine"),
            ("Neck", "neck"),
            ("Head", "head"),
            ("HeadTop_End", "-"),
            ("LeftShoulder", "leftShoulder"),
            ("LeftArm", "leftUpperArm"),
            ("LeftForeArm", "leftLowerArm"),
            ("RightHand", "rightHand"),
            ("LeftUpLeg", "leftUpperLeg"),
            ("LeftLeg", "leftLowerLeg"),
            ("RightFoot", "rightFoot"),
            ("RightToeBase", "rightToes"),
            ("LeftHandThumb1", "leftThumbMetacarpal"),
            ("LeftHandThumb2", "leftThumbProximal"),
            ("LeftHandThumb3", "leftThumbDistal"),
            ("LeftHandThumb4", "-"),
            ("RightHandIndex1", "rightIndexProximal"),
            ("RightHandIndex2", "rightIndexIntermediate"),
            ("RightHandPinky3", "rightLittleDistal"),
            ("RightHandPinky4", "-"),
        ] {
            assert_eq!(r(name), want, "{name}");
        }
        let s = summary(&joints, &roles);
        assert!(s.without.is_empty(), "{s}");
        // Per side: 4 ends of fingers, the thumb's and the toes'; and the head top.
        assert_eq!(s.ends_without, 2 * 6 + 1, "{s}");

        // A positive bend of 30° is flexion: where the segment's far end goes.
        let limits = default_limits(&joints, &roles);
        let moved = |n: &str| {
            let i = joints
                .iter()
                .position(|j| j.name == format!("mixamorig:{n}"))
                .unwrap();
            let (l, axis) = limits[i].unwrap_or_else(|| panic!("{n}: no limits"));
            assert!(l.bend.1 >= 30f64.to_radians(), "{n}: {l:?}");
            bent(&joints, i, axis, 30f64.to_radians())
        };
        // Forward is +Z, up +Y. Each movement is mostly along the expected direction (a
        // 30° turn moves a unit segment by 0.52, of which 0.5 across the segment).
        for side in ["Left", "Right"] {
            assert!(
                moved(&format!("{side}Leg")).z < -0.4,
                "{side} knee bends back"
            );
            assert!(
                moved(&format!("{side}UpLeg")).z > 0.4,
                "{side} hip flexes forward"
            );
            assert!(
                moved(&format!("{side}ForeArm")).z > 0.4,
                "{side} elbow bends forward"
            );
            for f in ["Index1", "Index2", "Middle3", "Pinky1"] {
                let d = moved(&format!("{side}Hand{f}"));
                assert!(d.y < -0.4, "{side} {f} curls to the palm (down): {d}");
            }
        }
        assert!(moved("Spine").z > 0.4, "the spine flexes forward");
        assert!(limits[0].is_none(), "the hips are free");
    }

    /// A rig whose rest pose bends the knee 25° and the hip 10° (as CesiumMan's does)
    /// gets ranges that still reach a straight knee and a thigh 30° behind the vertical:
    /// the table's ranges are from the anatomical neutral, and the rest's own bend is
    /// taken off them. The straight T pose gets the table's ranges unchanged.
    #[test]
    fn ranges_count_from_the_neutral_not_from_a_bent_rest() {
        let straight = mixamo_t_pose();
        let mut bent_rest = straight.clone();
        let index = |n: &str| {
            straight
                .iter()
                .position(|j| j.name == format!("mixamorig:Left{n}"))
                .unwrap()
        };
        let (hip, knee) = (index("UpLeg"), index("Leg"));
        let below = |root: usize, i: usize| {
            let mut p = Some(i);
            while let Some(k) = p {
                if k == root {
                    return true;
                }
                p = straight[k].parent;
            }
            false
        };
        // Flexion turns a leg segment's far end forward (+Z) at the hip, back at the knee.
        let turn = |joints: &mut [Joint], root: usize, deg: f64| {
            let q = DQuat::from_axis_angle(DVec3::X, deg.to_radians());
            let o = joints[root].rest;
            for (i, j) in joints.iter_mut().enumerate() {
                if i != root && below(root, i) {
                    j.rest = o + q * (j.rest - o);
                }
            }
        };
        turn(&mut bent_rest, knee, 25.0);
        turn(&mut bent_rest, hip, -10.0);
        let roles = recognise(&straight, &[]);
        let table_bend = |part| {
            let (_, [lo, hi], _, _) = table(part).unwrap();
            (lo.to_radians(), hi.to_radians())
        };
        let straight_limits = default_limits(&straight, &roles);
        assert_eq!(
            straight_limits[knee].unwrap().0.bend,
            table_bend(Part::LowerLeg)
        );
        assert_eq!(
            straight_limits[hip].unwrap().0.bend,
            table_bend(Part::UpperLeg)
        );
        let limits = default_limits(&bent_rest, &roles);
        // The rest pose turned in floating point: within a microradian (2e-9 measured).
        let close = |got: (f64, f64), want: (f64, f64)| {
            (got.0 - want.0).abs() < 1e-6 && (got.1 - want.1).abs() < 1e-6
        };
        let shift = |(lo, hi): (f64, f64), deg: f64| (lo - deg.to_radians(), hi - deg.to_radians());
        let (k, _) = limits[knee].unwrap();
        let (h, _) = limits[hip].unwrap();
        assert!(
            close(k.bend, shift(table_bend(Part::LowerLeg), 25.0)),
            "{k:?}"
        );
        assert!(
            close(h.bend, shift(table_bend(Part::UpperLeg), 10.0)),
            "{h:?}"
        );
    }

    #[test]
    fn a_mirrored_character_gets_mirrored_flexion() {
        // The same T pose turned to face −Z: left is now −X; the knee still bends back.
        let mut joints = mixamo_t_pose();
        for j in &mut joints {
            j.rest = DVec3::new(-j.rest.x, j.rest.y, -j.rest.z);
        }
        let roles = recognise(&joints, &[]);
        let limits = default_limits(&joints, &roles);
        let knee = joints
            .iter()
            .position(|j| j.name == "mixamorig:LeftLeg")
            .unwrap();
        let (_, axis) = limits[knee].unwrap();
        let d = bent(&joints, knee, axis, 1.0);
        assert!(d.z > 0.5, "backward is now +Z: {d}");
    }

    #[test]
    fn other_naming_schemes() {
        let check = |spec: &[(&str, Option<&str>)], want: &[(&str, &str)]| {
            let joints = names_tree(spec);
            let roles = recognise(&joints, &[]);
            for (name, role) in want {
                assert_eq!(&role_of(&joints, &roles, name), role, "{name}");
            }
        };
        // Unreal (UE4/UE5 mannequin).
        check(
            &[
                ("root", None),
                ("pelvis", Some("root")),
                ("spine_01", Some("pelvis")),
                ("clavicle_l", Some("spine_01")),
                ("upperarm_l", Some("clavicle_l")),
                ("upperarm_twist_01_l", Some("upperarm_l")),
                ("lowerarm_l", Some("upperarm_l")),
                ("hand_l", Some("lowerarm_l")),
                ("index_metacarpal_l", Some("hand_l")),
                ("index_01_l", Some("index_metacarpal_l")),
                ("index_02_l", Some("index_01_l")),
                ("thumb_01_l", Some("hand_l")),
                ("thumb_02_l", Some("thumb_01_l")),
                ("thigh_r", Some("pelvis")),
                ("calf_r", Some("thigh_r")),
                ("foot_r", Some("calf_r")),
                ("ball_r", Some("foot_r")),
            ],
            &[
                ("root", "-"),
                ("pelvis", "hips"),
                ("spine_01", "spine"),
                ("clavicle_l", "leftShoulder"),
                ("upperarm_l", "leftUpperArm"),
                ("upperarm_twist_01_l", "-"),
                ("lowerarm_l", "leftLowerArm"),
                ("index_metacarpal_l", "leftIndexMetacarpal"),
                ("index_01_l", "leftIndexProximal"),
                ("index_02_l", "leftIndexIntermediate"),
                ("thumb_01_l", "leftThumbMetacarpal"),
                ("thumb_02_l", "leftThumbProximal"),
                ("thigh_r", "rightUpperLeg"),
                ("calf_r", "rightLowerLeg"),
                ("ball_r", "rightToes"),
            ],
        );
        // VRM humanoid bone names and VRoid's node names.
        check(
            &[
                ("J_Bip_C_Hips", None),
                ("J_Bip_C_Spine", Some("J_Bip_C_Hips")),
                ("J_Bip_C_UpperChest", Some("J_Bip_C_Spine")),
                ("J_Bip_R_UpperArm", Some("J_Bip_C_UpperChest")),
                ("J_Bip_R_LowerArm", Some("J_Bip_R_UpperArm")),
                ("leftUpperLeg", Some("J_Bip_C_Hips")),
                ("leftLowerLeg", Some("leftUpperLeg")),
                ("leftThumbProximal", Some("leftLowerLeg")),
                ("leftThumbIntermediate", Some("leftThumbProximal")),
                ("leftMiddleIntermediate", Some("leftLowerLeg")),
            ],
            &[
                ("J_Bip_C_Hips", "hips"),
                ("J_Bip_C_UpperChest", "spine"),
                ("J_Bip_R_UpperArm", "rightUpperArm"),
                ("J_Bip_R_LowerArm", "rightLowerArm"),
                ("leftLowerLeg", "leftLowerLeg"),
                // VRM 0's thumb names, counted along the thumb.
                ("leftThumbProximal", "leftThumbMetacarpal"),
                ("leftThumbIntermediate", "leftThumbProximal"),
                ("leftMiddleIntermediate", "leftMiddleIntermediate"),
            ],
        );
        // MakeHuman's default skeleton.
        check(
            &[
                ("root", None),
                ("pelvis.L", Some("root")),
                ("upperleg01.L", Some("pelvis.L")),
                ("upperleg02.L", Some("upperleg01.L")),
                ("lowerleg01.L", Some("upperleg02.L")),
                ("spine05", Some("root")),
                ("clavicle.R", Some("spine05")),
                ("shoulder01.R", Some("clavicle.R")),
                ("upperarm01.R", Some("shoulder01.R")),
                ("lowerarm01.R", Some("upperarm01.R")),
                ("wrist.R", Some("lowerarm01.R")),
                ("metacarpal1.R", Some("wrist.R")),
                ("finger2-1.R", Some("metacarpal1.R")),
                ("finger2-2.R", Some("finger2-1.R")),
                ("finger1-1.R", Some("wrist.R")),
                ("jaw", Some("spine05")),
            ],
            &[
                ("root", "hips"),
                ("pelvis.L", "-"),
                ("upperleg01.L", "leftUpperLeg"),
                ("upperleg02.L", "leftLimbSegment"),
                ("lowerleg01.L", "leftLowerLeg"),
                ("spine05", "spine"),
                ("clavicle.R", "rightShoulder"),
                ("shoulder01.R", "rightShoulder"),
                ("upperarm01.R", "rightUpperArm"),
                ("wrist.R", "rightHand"),
                ("metacarpal1.R", "rightIndexMetacarpal"),
                ("finger2-1.R", "rightIndexProximal"),
                ("finger2-2.R", "rightIndexIntermediate"),
                ("finger1-1.R", "rightThumbMetacarpal"),
                ("jaw", "-"),
            ],
        );
        // Blender Rigify deform bones, 3ds Max Biped, CMU's BVH.
        check(
            &[
                ("DEF-spine", None),
                ("DEF-thigh.L", Some("DEF-spine")),
                ("DEF-thigh.L.001", Some("DEF-thigh.L")),
                ("DEF-shin.L", Some("DEF-thigh.L.001")),
                ("DEF-upper_arm.R", Some("DEF-spine")),
                ("DEF-forearm.R", Some("DEF-upper_arm.R")),
                ("DEF-hand.R", Some("DEF-forearm.R")),
                ("DEF-palm.01.R", Some("DEF-hand.R")),
                ("DEF-f_index.01.R", Some("DEF-palm.01.R")),
                ("DEF-thumb.01.R", Some("DEF-hand.R")),
                ("Bip01 L Finger0", Some("DEF-hand.R")),
                ("Bip01 L Finger01", Some("Bip01 L Finger0")),
                ("Bip01 L Finger1", Some("DEF-hand.R")),
            ],
            &[
                ("DEF-thigh.L", "leftUpperLeg"),
                ("DEF-thigh.L.001", "leftLimbSegment"),
                ("DEF-shin.L", "leftLowerLeg"),
                ("DEF-upper_arm.R", "rightUpperArm"),
                ("DEF-palm.01.R", "rightIndexMetacarpal"),
                ("DEF-f_index.01.R", "rightIndexProximal"),
                ("DEF-thumb.01.R", "rightThumbMetacarpal"),
                ("Bip01 L Finger0", "leftThumbMetacarpal"),
                ("Bip01 L Finger01", "leftThumbProximal"),
                ("Bip01 L Finger1", "leftIndexProximal"),
            ],
        );
        check(
            &[
                ("Hips", None),
                ("LHipJoint", Some("Hips")),
                ("LeftUpLeg", Some("LHipJoint")),
                ("LowerBack", Some("Hips")),
                ("LeftFingerBase", Some("LowerBack")),
                ("LeftHandIndex1", Some("LeftFingerBase")),
                ("LThumb", Some("LeftFingerBase")),
            ],
            &[
                ("LHipJoint", "-"),
                ("LeftUpLeg", "leftUpperLeg"),
                ("LowerBack", "spine"),
                ("LeftFingerBase", "leftIndexMetacarpal"),
                ("LeftHandIndex1", "leftIndexProximal"),
                ("LThumb", "leftThumbMetacarpal"),
            ],
        );
        // The CMU conversion of the shared data's 131_01.bvh: `LeftHip` is the thigh.
        check(
            &[
                ("Hips", None),
                ("LHipJoint", Some("Hips")),
                ("LeftHip", Some("LHipJoint")),
                ("LeftKnee", Some("LeftHip")),
                ("LeftAnkle", Some("LeftKnee")),
                ("LeftToe", Some("LeftAnkle")),
            ],
            &[
                ("LHipJoint", "-"),
                ("LeftHip", "leftUpperLeg"),
                ("LeftKnee", "leftLowerLeg"),
            ],
        );
        // Limb words alone, numbered along the limb (Khronos CesiumMan).
        check(
            &[
                ("Skeleton_torso_joint_1", None),
                ("leg_joint_L_1", Some("Skeleton_torso_joint_1")),
                ("leg_joint_L_2", Some("leg_joint_L_1")),
                ("leg_joint_L_3", Some("leg_joint_L_2")),
                ("leg_joint_L_5", Some("leg_joint_L_3")),
                ("Skeleton_arm_joint_R", Some("Skeleton_torso_joint_1")),
                ("Skeleton_arm_joint_R__2_", Some("Skeleton_arm_joint_R")),
                ("Skeleton_arm_joint_R__3_", Some("Skeleton_arm_joint_R__2_")),
            ],
            &[
                ("Skeleton_torso_joint_1", "hips"),
                ("leg_joint_L_1", "leftUpperLeg"),
                ("leg_joint_L_2", "leftLowerLeg"),
                ("leg_joint_L_3", "leftFoot"),
                ("leg_joint_L_5", "leftToes"),
                ("Skeleton_arm_joint_R", "rightUpperArm"),
                ("Skeleton_arm_joint_R__3_", "rightHand"),
            ],
        );
    }

    /// SMPL's shoulder is the shoulder joint; toes and eyes are not fingers or toes.
    #[test]
    fn schemes_where_words_mean_other_things() {
        let joints = names_tree(&[
            ("Pelvis", None),
            ("Spine3", Some("Pelvis")),
            ("L_Collar", Some("Spine3")),
            ("L_Shoulder", Some("L_Collar")),
            ("L_Elbow", Some("L_Shoulder")),
            ("L_Wrist", Some("L_Elbow")),
            ("lSmallToe1", Some("Pelvis")),
            ("left_foot_index", Some("Pelvis")),
            ("EyeBall_L", Some("Spine3")),
            ("J_Sec_L_SkirtBack0_01", Some("Pelvis")),
        ]);
        let roles = recognise(&joints, &[]);
        for (name, want) in [
            ("L_Collar", "leftShoulder"),
            ("L_Shoulder", "leftUpperArm"),
            ("L_Elbow", "leftLowerArm"),
            ("L_Wrist", "leftHand"),
            ("lSmallToe1", "leftToes"),
            ("left_foot_index", "leftFoot"),
            ("EyeBall_L", "-"),
            ("J_Sec_L_SkirtBack0_01", "-"),
        ] {
            assert_eq!(role_of(&joints, &roles, name), want, "{name}");
        }
    }

    /// Names written as words with spaces, dots and underscores: MMD-style English names
    /// (`Left leg` is the thigh, `Left knee` the shin, as VRM exports of MMD models
    /// name them) and the VRM add-on's Blender names (`upper_arm.L`, `lower_leg.R`).
    #[test]
    fn names_written_as_words_get_their_roles() {
        let joints = names_tree(&[
            ("Hips", None),
            ("Spine", Some("Hips")),
            ("Left leg", Some("Hips")),
            ("Left knee", Some("Left leg")),
            ("Left ankle", Some("Left knee")),
            ("Left toe", Some("Left ankle")),
            ("Right leg", Some("Hips")),
            ("Right knee", Some("Right leg")),
            ("Right ankle", Some("Right knee")),
            ("Left arm", Some("Spine")),
            ("Left elbow", Some("Left arm")),
            ("Left wrist", Some("Left elbow")),
            ("upper_arm.R", Some("Spine")),
            ("lower_arm.R", Some("upper_arm.R")),
            ("hand.R", Some("lower_arm.R")),
        ]);
        let roles = recognise(&joints, &[]);
        for (name, want) in [
            ("Left leg", "leftUpperLeg"),
            ("Left knee", "leftLowerLeg"),
            ("Left ankle", "leftFoot"),
            ("Left toe", "leftToes"),
            ("Right leg", "rightUpperLeg"),
            ("Right knee", "rightLowerLeg"),
            ("Left arm", "leftUpperArm"),
            ("Left elbow", "leftLowerArm"),
            ("Left wrist", "leftHand"),
            ("upper_arm.R", "rightUpperArm"),
            ("lower_arm.R", "rightLowerArm"),
            ("hand.R", "rightHand"),
        ] {
            assert_eq!(role_of(&joints, &roles, name), want, "{name}");
        }
    }

    #[test]
    fn the_top_of_a_neck_chain_without_a_head_is_the_head() {
        let joints = names_tree(&[
            ("Skeleton_torso_joint_1", None),
            ("Skeleton_torso_joint_2", Some("Skeleton_torso_joint_1")),
            ("Skeleton_neck_joint_1", Some("Skeleton_torso_joint_2")),
            ("Skeleton_neck_joint_2", Some("Skeleton_neck_joint_1")),
            ("Skeleton_neck_joint_2_end", Some("Skeleton_neck_joint_2")),
        ]);
        let roles = recognise(&joints, &[]);
        assert_eq!(role_of(&joints, &roles, "Skeleton_neck_joint_1"), "neck");
        assert_eq!(role_of(&joints, &roles, "Skeleton_neck_joint_2"), "head");
        // With a head named, the neck chain stays necks.
        let joints = names_tree(&[
            ("Hips", None),
            ("Neck", Some("Hips")),
            ("Neck1", Some("Neck")),
            ("Head", Some("Neck1")),
        ]);
        let roles = recognise(&joints, &[]);
        assert_eq!(role_of(&joints, &roles, "Neck1"), "neck");
    }

    #[test]
    fn a_limb_without_children_is_the_whole_limb() {
        // Kenney's mini characters: one joint per limb, nothing below it.
        let joints = names_tree(&[
            ("root", None),
            ("leg-left", Some("root")),
            ("leg-right", Some("root")),
            ("torso", Some("root")),
            ("arm-left", Some("torso")),
            ("head", Some("torso")),
        ]);
        let roles = recognise(&joints, &[]);
        for (name, want) in [
            ("leg-left", "leftUpperLeg"),
            ("leg-right", "rightUpperLeg"),
            ("arm-left", "leftUpperArm"),
        ] {
            assert_eq!(role_of(&joints, &roles, name), want, "{name}");
        }
    }

    #[test]
    fn overrides_replace_what_names_say() {
        let joints = names_tree(&[
            ("a", None),
            ("b", Some("a")),
            ("LeftLeg", Some("b")),
            ("LeftFoot", Some("LeftLeg")),
        ]);
        let knee = Role {
            part: Part::LowerLeg,
            side: Some(Side::Left),
        };
        let hips = Role {
            part: Part::Hips,
            side: None,
        };
        assert_eq!(recognise(&joints, &[])[2], Some(knee));
        let roles = recognise(&joints, &[(0, Some(hips)), (2, None)]);
        assert_eq!(roles[..3], [Some(hips), None, None]);
    }

    #[test]
    fn a_hand_of_unknown_side_flexes_the_way_its_fingers_curl() {
        // A hand alone (WebXR's joint names), pointing +X with the fingers curled a
        // little towards −Y at rest; mirrored in Y, it must curl towards +Y.
        for curl_y in [-1.0, 1.0] {
            let mut spec = vec![("wrist".to_string(), None, [0.0, 0.0, 0.0])];
            for (f, z) in [("index-finger", 0.02), ("little-finger", -0.02)] {
                let segs = [
                    "metacarpal",
                    "phalanx-proximal",
                    "phalanx-intermediate",
                    "phalanx-distal",
                    "tip",
                ];
                let mut parent = "wrist".to_string();
                for (k, s) in segs.iter().enumerate() {
                    let x = 0.03 * (k + 1) as f64;
                    let y = curl_y * 0.002 * (k * k) as f64;
                    let name = format!("{f}-{s}");
                    spec.push((name.clone(), Some(parent.clone()), [x, y, z]));
                    parent = name;
                }
            }
            let spec: Vec<(&str, Option<&str>, [f64; 3])> = spec
                .iter()
                .map(|(n, p, x)| (n.as_str(), p.as_deref(), *x))
                .collect();
            let joints = tree(&spec);
            let roles = recognise(&joints, &[]);
            assert_eq!(role_of(&joints, &roles, "wrist"), "hand");
            assert_eq!(
                role_of(&joints, &roles, "little-finger-phalanx-proximal"),
                "littleProximal"
            );
            let limits = default_limits(&joints, &roles);
            let i = joints
                .iter()
                .position(|j| j.name == "index-finger-phalanx-intermediate")
                .unwrap();
            let (l, axis) = limits[i].unwrap();
            assert!(l.bend.0 < 0.0 && l.bend.1 > 1.5, "{l:?}");
            let d = bent(&joints, i, axis, 1.0);
            assert!(d.y * curl_y > 0.5, "curl {curl_y}: {d}");
        }
    }
}
