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

use glam::{DMat4, DQuat, DVec3};

/// Most joints (end sites included) a file may declare.
pub const MAX_JOINTS: usize = 1024;

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
}

struct Tokens<'a> {
    items: Vec<(usize, &'a str)>,
    at: usize,
}

impl<'a> Tokens<'a> {
    fn next(&mut self) -> Result<(usize, &'a str), BvhError> {
        let t = self.items.get(self.at).copied().ok_or(BvhError::Syntax {
            line: self.items.last().map_or(1, |t| t.0),
            what: "file ends early".into(),
        })?;
        self.at += 1;
        Ok(t)
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
    if joints.len() >= MAX_JOINTS || depth > 256 {
        return Err(BvhError::Syntax {
            line,
            what: format!("more than {MAX_JOINTS} joints or nesting deeper than 256"),
        });
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
                let n = tk.number()? as usize;
                if n > 6 {
                    return Err(BvhError::Syntax {
                        line,
                        what: format!("{n} channels (at most 6)"),
                    });
                }
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

/// Parses a BVH file's text; positions are scaled by `metres_per_unit`.
pub fn parse_bvh(text: &str, metres_per_unit: f64) -> Result<Bvh, BvhError> {
    let items: Vec<(usize, &str)> = text
        .lines()
        .enumerate()
        .flat_map(|(i, l)| l.split_whitespace().map(move |t| (i + 1, t)))
        .collect();
    let mut tk = Tokens { items, at: 0 };
    tk.expect("HIERARCHY")?;
    tk.expect("ROOT")?;
    let (_, root) = tk.next()?;
    let mut joints = Vec::new();
    parse_joint(&mut tk, root.to_owned(), None, &mut joints, 0)?;
    tk.expect("MOTION")?;
    tk.expect("Frames:")?;
    let frames = tk.number()?;
    tk.expect("Frame")?;
    tk.expect("Time:")?;
    let frame_time_s = tk.number()?;
    let nch: usize = joints.iter().map(|j| j.channels.len()).sum();
    let left = tk.items.len() - tk.at;
    if frames < 0.0 || frame_time_s <= 0.0 {
        return Err(BvhError::Syntax {
            line: tk.items.get(tk.at.saturating_sub(1)).map_or(1, |t| t.0),
            what: format!("{frames} frames of {frame_time_s} s"),
        });
    }
    // Keep the whole frames present (a cut file keeps what it has).
    let frames = (frames as usize).min(left.checked_div(nch).unwrap_or(frames as usize));
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
            world[j] = match joint.parent {
                Some(p) => world[p] * local,
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

#[cfg(test)]
mod tests {
    use super::*;
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
