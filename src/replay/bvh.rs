//! BVH motion files (Biovision hierarchy): the joint tree, the channels, and the motion,
//! turned into joint positions per frame by forward kinematics, so that a BVH plays like
//! a marker recording whose markers sit on the joints (a character whose markers are
//! placed at its joints, `bone` + zero offset, follows it: the paper's "positions of the
//! skeleton joints as control inputs").
//!
//! BVH has no units: positions are scaled by the caller's metres per unit (CMU's
//! conversions use about 0.0564). Y is up, as in the world frame. Rotation channels
//! compose in the order they are listed (`Zrotation Yrotation Xrotation` is
//! `Rz · Ry · Rx`), degrees. End sites become joints named `PARENT_end`.
//!
//! Hostile files: `Frames:` must be a whole number and `Frame Time:` a frame rate within
//! `recording`'s limits; the frames kept are those whose values the file holds (a frame
//! needs one value per channel, so a hierarchy without channels is refused), and the
//! positions they make (frames × joints) are held to `recording::position_budget` of the
//! text's length. The text is read token by token, without a token table.

use super::recording::{position_budget, MAX_RATE_HZ, MIN_RATE_HZ};
use glam::{DMat4, DQuat, DVec3};
use std::iter::Enumerate;
use std::str::{Lines, SplitWhitespace};

/// Most joints (end sites included) a file may declare.
pub const MAX_JOINTS: usize = 1024;
/// Deepest nesting of joints a file may declare.
pub const MAX_DEPTH: usize = 256;
/// Most channels a joint may declare (three positions, three rotations).
pub const MAX_CHANNELS: usize = 6;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Channel {
    Pos(usize),
    Rot(usize),
}

#[derive(Clone, Debug)]
struct Joint {
    name: String,
    parent: Option<usize>,
    offset: DVec3,
    channels: Vec<Channel>,
}

/// A parsed BVH file.
#[derive(Clone, Debug)]
pub struct Bvh {
    pub joint_names: Vec<String>,
    pub parents: Vec<Option<usize>>,
    pub frame_time_s: f64,
    /// `positions[f][j]`: joint `j`'s world position in frame `f`, metres.
    pub positions: Vec<Vec<DVec3>>,
}

/// Why a BVH file cannot be read, with its line (1-based).
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum BvhError {
    #[error("line {line}: {what}")]
    Syntax { line: usize, what: String },
    #[error("line {line}: CHANNELS {text:?} is not a channel count (0 to {MAX_CHANNELS})")]
    Channels { line: usize, text: String },
    #[error("line {line}: more than {MAX_JOINTS} joints")]
    Joints { line: usize },
    #[error("line {line}: joints nested deeper than {MAX_DEPTH}")]
    Depth { line: usize },
    #[error("line {line}: Frames: {text:?} is not a frame count (a whole number from 0)")]
    FrameCount { line: usize, text: String },
    #[error("line {line}: Frame Time: {value:?} s is outside 1/{MAX_RATE_HZ}..=1/{MIN_RATE_HZ} s")]
    FrameTime { line: usize, value: f64 },
    #[error("no joint has a channel, so the motion's {frames:?} frames hold no values")]
    NoChannels { frames: f64 },
    #[error(
        "{frames} frames × {joints} joints: more than the {budget} positions a \
         {text_len}-byte file may hold"
    )]
    TooLong {
        frames: usize,
        joints: usize,
        text_len: usize,
        budget: usize,
    },
}

/// The text's whitespace-separated tokens with their lines, read as they are asked for.
#[derive(Clone)]
struct Tokens<'a> {
    lines: Enumerate<Lines<'a>>,
    words: SplitWhitespace<'a>,
    /// The line of `words` (1-based).
    line: usize,
}

impl<'a> Tokens<'a> {
    fn new(text: &'a str) -> Self {
        Self {
            lines: text.lines().enumerate(),
            words: "".split_whitespace(),
            line: 1,
        }
    }

    fn try_next(&mut self) -> Option<(usize, &'a str)> {
        loop {
            if let Some(w) = self.words.next() {
                return Some((self.line, w));
            }
            let (i, l) = self.lines.next()?;
            self.line = i + 1;
            self.words = l.split_whitespace();
        }
    }

    fn next(&mut self) -> Result<(usize, &'a str), BvhError> {
        self.try_next().ok_or(BvhError::Syntax {
            line: self.line,
            what: "file ends early".into(),
        })
    }

    /// How many tokens are left (counted, not stored).
    fn remaining(&self) -> usize {
        let mut rest = self.clone();
        std::iter::from_fn(|| rest.try_next()).count()
    }

    fn expect(&mut self, want: &str) -> Result<usize, BvhError> {
        let (line, t) = self.next()?;
        if t.eq_ignore_ascii_case(want) {
            Ok(line)
        } else {
            Err(BvhError::Syntax {
                line,
                what: format!("expected {want:?}, found {t:?}"),
            })
        }
    }

    fn number(&mut self) -> Result<f64, BvhError> {
        let (line, t) = self.next()?;
        t.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or(BvhError::Syntax {
                line,
                what: format!("{t:?} is not a number"),
            })
    }
}

fn parse_joint(
    tk: &mut Tokens,
    name: String,
    parent: Option<usize>,
    joints: &mut Vec<Joint>,
    depth: usize,
) -> Result<(), BvhError> {
    let line = tk.expect("{")?;
    if joints.len() >= MAX_JOINTS {
        return Err(BvhError::Joints { line });
    }
    if depth > MAX_DEPTH {
        return Err(BvhError::Depth { line });
    }
    let me = joints.len();
    joints.push(Joint {
        name,
        parent,
        offset: DVec3::ZERO,
        channels: Vec::new(),
    });
    loop {
        let (line, t) = tk.next()?;
        match t.to_ascii_uppercase().as_str() {
            "OFFSET" => {
                joints[me].offset = DVec3::new(tk.number()?, tk.number()?, tk.number()?);
            }
            "CHANNELS" => {
                let (line, text) = tk.next()?;
                let n = text
                    .parse::<usize>()
                    .ok()
                    .filter(|n| *n <= MAX_CHANNELS)
                    .ok_or_else(|| BvhError::Channels {
                        line,
                        text: text.chars().take(32).collect(),
                    })?;
                for _ in 0..n {
                    let (line, c) = tk.next()?;
                    let ch = match c.to_ascii_lowercase().as_str() {
                        "xposition" => Channel::Pos(0),
                        "yposition" => Channel::Pos(1),
                        "zposition" => Channel::Pos(2),
                        "xrotation" => Channel::Rot(0),
                        "yrotation" => Channel::Rot(1),
                        "zrotation" => Channel::Rot(2),
                        _ => {
                            return Err(BvhError::Syntax {
                                line,
                                what: format!("unknown channel {c:?}"),
                            })
                        }
                    };
                    joints[me].channels.push(ch);
                }
            }
            "JOINT" => {
                let (_, n) = tk.next()?;
                parse_joint(tk, n.to_owned(), Some(me), joints, depth + 1)?;
            }
            "END" => {
                tk.expect("Site")?;
                let name = format!("{}_end", joints[me].name);
                parse_joint(tk, name, Some(me), joints, depth + 1)?;
            }
            "}" => return Ok(()),
            other => {
                return Err(BvhError::Syntax {
                    line,
                    what: format!("unexpected {other:?} in joint {:?}", joints[me].name),
                })
            }
        }
    }
}

/// The motion header: `Frames:` (a whole number from 0) and `Frame Time:` (seconds,
/// within the rate limits).
fn motion_header(tk: &mut Tokens) -> Result<(f64, f64), BvhError> {
    tk.expect("MOTION")?;
    tk.expect("Frames:")?;
    let (line, text) = tk.next()?;
    let frames = text
        .parse::<f64>()
        .ok()
        .filter(|f| *f >= 0.0 && f.fract() == 0.0)
        .ok_or_else(|| BvhError::FrameCount {
            line,
            text: text.chars().take(32).collect(),
        })?;
    tk.expect("Frame")?;
    let line = tk.expect("Time:")?;
    let frame_time_s = tk.number()?;
    if !(1.0 / MAX_RATE_HZ..=1.0 / MIN_RATE_HZ).contains(&frame_time_s) {
        return Err(BvhError::FrameTime {
            line,
            value: frame_time_s,
        });
    }
    Ok((frames, frame_time_s))
}

/// Parses a BVH file's text; positions are scaled by `metres_per_unit`.
pub fn parse_bvh(text: &str, metres_per_unit: f64) -> Result<Bvh, BvhError> {
    let mut tk = Tokens::new(text);
    tk.expect("HIERARCHY")?;
    tk.expect("ROOT")?;
    let (_, root) = tk.next()?;
    let mut joints = Vec::new();
    parse_joint(&mut tk, root.to_owned(), None, &mut joints, 0)?;
    let (declared, frame_time_s) = motion_header(&mut tk)?;
    let nch: usize = joints.iter().map(|j| j.channels.len()).sum();
    if nch == 0 {
        return Err(BvhError::NoChannels { frames: declared });
    }
    // Keep the whole frames present (a cut file keeps what it has): a frame needs `nch`
    // values, so the text's length bounds the count. `declared` is a whole number; the
    // cast saturates.
    let frames = (declared as usize).min(tk.remaining() / nch);
    let budget = position_budget(text.len());
    if frames.saturating_mul(joints.len()) > budget {
        return Err(BvhError::TooLong {
            frames,
            joints: joints.len(),
            text_len: text.len(),
            budget,
        });
    }
    let mut positions = Vec::with_capacity(frames);
    let mut world = vec![DMat4::IDENTITY; joints.len()];
    for _ in 0..frames {
        for (j, joint) in joints.iter().enumerate() {
            let mut t = joint.offset;
            let mut r = DQuat::IDENTITY;
            for c in &joint.channels {
                let v = tk.number()?;
                match c {
                    Channel::Pos(a) => t[*a] = v,
                    Channel::Rot(a) => {
                        let axis = [DVec3::X, DVec3::Y, DVec3::Z][*a];
                        r *= DQuat::from_axis_angle(axis, v.to_radians());
                    }
                }
            }
            // Position channels replace the offset (the root's usual case).
            let local = DMat4::from_rotation_translation(r, t);
            // A parent comes before its children, so `world[p]` is this frame's.
            let parent = joint.parent.and_then(|p| world.get(p)).copied();
            world[j] = match parent {
                Some(p) => p * local,
                None => local,
            };
        }
        positions.push(
            world
                .iter()
                .map(|m| m.w_axis.truncate() * metres_per_unit)
                .collect(),
        );
    }
    Ok(Bvh {
        joint_names: joints.iter().map(|j| j.name.clone()).collect(),
        parents: joints.iter().map(|j| j.parent).collect(),
        frame_time_s,
        positions,
    })
}

/// What [`encode_header`] writes of a skeleton: per joint its name, parent (listed
/// before it) and rest position (world, metres).
pub struct BvhSkeleton<'a> {
    pub names: &'a [String],
    pub parents: &'a [Option<usize>],
    pub rest: &'a [DVec3],
}

/// Units a written file uses: centimetres (read back with `--bvh-scale 0.01`, the
/// default).
pub const WRITTEN_METRES_PER_UNIT: f64 = 0.01;

/// Each joint's children, and the roots (a joint whose parent is not listed before it
/// counts as a root), in order.
fn tree(parents: &[Option<usize>]) -> (Vec<Vec<usize>>, Vec<usize>) {
    let mut children = vec![Vec::new(); parents.len()];
    let mut roots = Vec::new();
    for (j, p) in parents.iter().enumerate() {
        match p.filter(|&p| p < j) {
            Some(p) => children[p].push(j),
            None => roots.push(j),
        }
    }
    (children, roots)
}

/// A name as one BVH token (whitespace and braces become `_`; an empty name `joint`).
fn token(name: &str) -> String {
    let t: String = name
        .chars()
        .map(|c| {
            if c.is_whitespace() || c == '{' || c == '}' {
                '_'
            } else {
                c
            }
        })
        .collect();
    if t.is_empty() {
        "joint".into()
    } else {
        t
    }
}

/// The HIERARCHY section and the MOTION header of `frames` frames of `frame_time_s`.
/// Each joint's OFFSET is its rest position less its parent's (the root's is zero: its
/// position channels hold where it is); the root has six channels
/// (`Xposition Yposition Zposition Zrotation Xrotation Yrotation`), every other joint
/// three; a joint without children ends in an `End Site` on itself.
pub fn encode_header(sk: &BvhSkeleton<'_>, frames: usize, frame_time_s: f64) -> String {
    let (children, roots) = tree(sk.parents);
    let mut out = String::from("HIERARCHY\n");
    // Depth-first, iteratively: (joint, depth, entering).
    let mut stack: Vec<(usize, usize, bool)> =
        roots.into_iter().rev().map(|j| (j, 0, true)).collect();
    while let Some((j, depth, entering)) = stack.pop() {
        let pad = "  ".repeat(depth);
        if !entering {
            if children[j].is_empty() {
                out += &format!("{pad}  End Site\n{pad}  {{\n{pad}    OFFSET 0 0 0\n{pad}  }}\n");
            }
            out += &format!("{pad}}}\n");
            continue;
        }
        let root = sk.parents[j].is_none_or(|p| p >= j);
        let offset = match sk.parents[j].filter(|_| !root) {
            Some(p) => (sk.rest[j] - sk.rest[p]) / WRITTEN_METRES_PER_UNIT,
            None => DVec3::ZERO,
        };
        let (kind, channels) = if root {
            (
                "ROOT",
                "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",
            )
        } else {
            ("JOINT", "CHANNELS 3 Zrotation Xrotation Yrotation")
        };
        out += &format!(
            "{pad}{kind} {}\n{pad}{{\n{pad}  OFFSET {:.6} {:.6} {:.6}\n{pad}  {channels}\n",
            token(&sk.names[j]),
            offset.x,
            offset.y,
            offset.z
        );
        stack.push((j, depth, false));
        for &c in children[j].iter().rev() {
            stack.push((c, depth + 1, true));
        }
    }
    out += &format!("MOTION\nFrames: {frames}\nFrame Time: {frame_time_s:.12}\n");
    out
}

/// One MOTION line: every joint's channels in the hierarchy's order (depth-first, as
/// [`encode_header`] wrote it), from the posture's world rotations (each the rotation
/// from rest, world axes) and the roots' world positions (metres).
pub fn encode_frame(
    sk: &BvhSkeleton<'_>,
    world_rot: &[DQuat],
    world_pos: &[DVec3],
    out: &mut String,
) {
    let (children, roots) = tree(sk.parents);
    let mut stack: Vec<usize> = roots.into_iter().rev().collect();
    let mut first = true;
    let mut put = |out: &mut String, v: f64| {
        if !first {
            out.push(' ');
        }
        *out += &format!("{v:.6}");
        first = false;
    };
    while let Some(j) = stack.pop() {
        let parent = sk.parents[j].filter(|&p| p < j);
        let q = world_rot.get(j).copied().unwrap_or(DQuat::IDENTITY);
        let local = match parent {
            Some(p) => {
                world_rot
                    .get(p)
                    .copied()
                    .unwrap_or(DQuat::IDENTITY)
                    .inverse()
                    * q
            }
            None => {
                let x = world_pos.get(j).copied().unwrap_or(DVec3::ZERO) / WRITTEN_METRES_PER_UNIT;
                for c in x.to_array() {
                    put(out, c);
                }
                q
            }
        };
        // `Zrotation Xrotation Yrotation`: R = Rz · Rx · Ry, degrees.
        let (z, x, y) = local.normalize().to_euler(glam::EulerRot::ZXY);
        for a in [z, x, y] {
            put(out, a.to_degrees());
        }
        for &c in children[j].iter().rev() {
            stack.push(c);
        }
    }
    out.push('\n');
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A posture written and read back: every joint where forward kinematics of the
    /// posture puts it (to the 1e-6 cm the text keeps), the end sites on their joints.
    #[test]
    fn a_written_posture_reads_back_at_its_joints() {
        let names: Vec<String> = ["hips", "spine", "left arm", "hand", "leg"]
            .map(String::from)
            .to_vec();
        let parents = [None, Some(0), Some(1), Some(2), Some(0)];
        let rest = [
            DVec3::new(0.0, 1.0, 0.0),
            DVec3::new(0.0, 1.3, 0.02),
            DVec3::new(0.2, 1.4, 0.0),
            DVec3::new(0.45, 1.4, 0.01),
            DVec3::new(0.1, 0.5, 0.0),
        ];
        let sk = BvhSkeleton {
            names: &names,
            parents: &parents,
            rest: &rest,
        };
        // Local turns per joint over two frames, and the root's position.
        let turns = |f: f64| {
            [
                DQuat::from_euler(glam::EulerRot::YXZ, 0.3 * f, -0.2, 0.1),
                DQuat::from_rotation_x(0.4 + f),
                DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 1.2 - f),
                DQuat::from_rotation_z(-0.7),
                DQuat::from_rotation_y(2.9 * f),
            ]
        };
        let mut text = encode_header(&sk, 2, 1.0 / 120.0);
        let mut want = Vec::new();
        for f in 0..2 {
            let local = turns(f as f64);
            let (mut rot, mut pos) = (vec![DQuat::IDENTITY; 5], vec![DVec3::ZERO; 5]);
            for j in 0..5 {
                match parents[j] {
                    Some(p) => {
                        rot[j] = rot[p] * local[j];
                        pos[j] = pos[p] + rot[p] * (rest[j] - rest[p]);
                    }
                    None => {
                        rot[j] = local[j];
                        pos[j] = rest[j] + DVec3::new(0.5, 0.0, -0.25 * f as f64);
                    }
                }
            }
            encode_frame(&sk, &rot, &pos, &mut text);
            want.push(pos);
        }
        let bvh = parse_bvh(&text, WRITTEN_METRES_PER_UNIT).expect(&text);
        assert!((bvh.frame_time_s - 1.0 / 120.0).abs() < 1e-9);
        assert_eq!(bvh.positions.len(), 2);
        for (f, pos) in want.iter().enumerate() {
            for (j, name) in names.iter().enumerate() {
                let k = bvh
                    .joint_names
                    .iter()
                    .position(|n| *n == token(name))
                    .expect(name);
                let e = (bvh.positions[f][k] - pos[j]).length();
                assert!(e < 1e-6, "frame {f} {name}: {e} m off");
            }
            // The leaves' end sites sit on them.
            let hand = bvh.joint_names.iter().position(|n| n == "hand").unwrap();
            let end = bvh
                .joint_names
                .iter()
                .position(|n| n == "hand_end")
                .unwrap();
            assert!((bvh.positions[f][end] - bvh.positions[f][hand]).length() < 1e-9);
        }
    }
    use proptest::prelude::*;

    const ARM: &str = "HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Arm
  {
    OFFSET 10 0 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 5 0 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0083333
0 100 0 0 0 0 0 0 0
1 100 0 90 0 0 0 0 90
";

    #[test]
    fn forward_kinematics_of_a_two_bone_arm() {
        let b = parse_bvh(ARM, 0.01).unwrap();
        assert_eq!(b.joint_names, ["Hips", "Arm", "Arm_end"]);
        assert_eq!(b.parents, [None, Some(0), Some(1)]);
        assert_eq!(b.positions.len(), 2);
        let close = |a: DVec3, b: DVec3| (a - b).length() < 1e-12;
        // Frame 0: straight along X, 1 m up.
        assert!(close(b.positions[0][1], DVec3::new(0.10, 1.0, 0.0)));
        assert!(close(b.positions[0][2], DVec3::new(0.15, 1.0, 0.0)));
        // Frame 1: hips moved 1 cm along X and turned 90° about Z (X becomes Y); the arm
        // turned 90° about its own X, which leaves its X-pointing bone in place.
        assert!(close(b.positions[1][1], DVec3::new(0.01, 1.10, 0.0)));
        assert!(close(b.positions[1][2], DVec3::new(0.01, 1.15, 0.0)));
    }

    #[test]
    fn errors_name_the_line() {
        let bad = ARM.replace("OFFSET 10 0 0", "OFFSET 10 zero 0");
        assert_eq!(
            parse_bvh(&bad, 1.0).unwrap_err(),
            BvhError::Syntax {
                line: 8,
                what: "\"zero\" is not a number".into()
            }
        );
        let cut = &ARM[..ARM.len() - 10];
        // A cut file keeps its whole frames.
        assert_eq!(parse_bvh(cut, 1.0).unwrap().positions.len(), 1);
    }

    fn with_motion(hierarchy_channels: &str, frames: &str, frame_time: &str) -> String {
        format!(
            "HIERARCHY\nROOT Hips\n{{\n  OFFSET 0 0 0\n  CHANNELS {hierarchy_channels}\n}}\n\
             MOTION\nFrames: {frames}\nFrame Time: {frame_time}\n1 2 3\n"
        )
    }

    #[test]
    fn header_values_out_of_range_are_named() {
        let err = |t: String| parse_bvh(&t, 1.0).unwrap_err();
        // No channel: a frame needs no bytes, so no count of frames can be trusted.
        for frames in ["1e300", "1000000000", "1"] {
            assert!(matches!(
                err(with_motion("0", frames, "0.01")),
                BvhError::NoChannels { .. }
            ));
        }
        for frames in ["-1", "2.5", "inf", "NaN", "lots"] {
            assert_eq!(
                err(with_motion("1 Xposition", frames, "0.01")),
                BvhError::FrameCount {
                    line: 8,
                    text: frames.into()
                }
            );
        }
        for (text, value) in [
            ("0", 0.0),
            ("1e-300", 1e-300),
            ("-0.01", -0.01),
            ("11", 11.0),
        ] {
            assert_eq!(
                err(with_motion("1 Xposition", "1", text)),
                BvhError::FrameTime { line: 9, value }
            );
        }
        for channels in ["7", "-1", "1e300", "2.5"] {
            assert_eq!(
                err(with_motion(channels, "1", "0.01")),
                BvhError::Channels {
                    line: 5,
                    text: channels.into()
                }
            );
        }
        // The declared count is kept to the values present: 3 frames of 1 channel.
        let b = parse_bvh(&with_motion("1 Xposition", "1e300", "0.01"), 1.0).unwrap();
        assert_eq!(b.positions.len(), 3);
        assert_eq!(b.positions[2][0], DVec3::new(3.0, 0.0, 0.0));
    }

    #[test]
    fn joints_without_channels_are_held_to_the_position_budget() {
        // 1000 joints, one channel: every 2-byte value would make 1000 positions.
        let mut t = String::from("HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 1 Xposition\n");
        for i in 0..999 {
            t += &format!("JOINT j{i}\n{{\nOFFSET 0 0 0\n}}\n");
        }
        t += "}\nMOTION\nFrames: 3000\nFrame Time: 0.01\n";
        let head = t.len();
        t += &"1\n".repeat(3000);
        assert_eq!(
            parse_bvh(&t, 1.0).unwrap_err(),
            BvhError::TooLong {
                frames: 3000,
                joints: 1000,
                text_len: head + 6000,
                budget: position_budget(head + 6000),
            }
        );
        // A thousand frames fit the budget.
        let cut = &t[..head + 2000];
        assert_eq!(parse_bvh(cut, 1.0).unwrap().positions.len(), 1000);
    }

    proptest! {
        #[test]
        fn arbitrary_text_never_panics(s in "(?s).{0,300}") {
            let _ = parse_bvh(&s, 1.0);
        }

        #[test]
        fn arbitrary_motion_never_panics(m in "[-0-9. \n]{0,300}") {
            let text = ARM.split("MOTION").next().unwrap().to_owned() + "MOTION\nFrames: 5\nFrame Time: 0.01\n" + &m;
            let _ = parse_bvh(&text, 1.0);
        }
    }
}
