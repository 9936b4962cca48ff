//! Where a marker set's manual puts each marker, as a point on any humanoid character's
//! skin: the template a calibration starts a label at when no frame of the take shows
//! it on its bone's skin, and holds it loosely near (MoSh's marker placement: "latent
//! markers" start where the marker set puts them on the template body, Loper, Mahmood
//! and Black, SIGGRAPH Asia 2014, Section 4.1).
//!
//! A landmark is described against its segment's anatomical axes at rest, so one table
//! fits a T pose, an A pose and any proportions: the bone (from its joint to the mean of
//! its children), the front (the body's front, square to the bone; the body's up for a
//! bone that points forward, a foot) and the side (away from the body's midline, square
//! to both; for an arm held out level, whose bone runs along the midline's normal, the
//! front turned about the bone: up, the lateral side of an arm in a T pose with the
//! palms down). A ray from a point on the bone along the landmark's direction meets the
//! skin; the template is 8 mm out from there (a 14 mm marker on its base).
//!
//! The positions are those of the sets' manuals, roughly (Vicon, "Plug-in Gait Reference
//! Guide", marker placement; the CMU database's marker guide): a person places a marker
//! a few centimetres from where the manual says, and a character's skin is not a
//! person's; the fit moves each label to where the take puts it.

use super::marker_sets::{candidate_joints, normalise};
use crate::character::roles::{Part, Role, Side};
use crate::character::skeleton::Skeleton;
use crate::geom::ray::{leaves_volume, Reach};
use crate::geom::winding::WindingNumber;
use glam::DVec3;

/// Which joint of a part's chain carries a landmark.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pick {
    /// The first (parents first: the lowest spine joint).
    First,
    /// The middle one.
    Middle,
    /// The last (the top of the spine).
    Last,
}

/// One landmark: the label pattern (normalised, `{S}` for the side letter), the part
/// and which joint of it, how far along the bone the ray starts (0 at the joint, 1 at
/// its end), and the ray's direction in the segment's axes: front, side (away from the
/// midline on the label's side; for an unsided label, towards the body's left) and
/// along the bone.
pub type Landmark = (&'static str, Part, Pick, f64, [f64; 3]);

use Part::*;
use Pick::*;

/// Plug-in Gait (and its CMU and Motive variants): head, trunk, arms, pelvis and legs.
pub const PLUG_IN_GAIT: &[Landmark] = &[
    // Over the temples, and on the back of the head level with them.
    ("{S}FHD", Head, First, 0.5, [1.0, 0.6, 0.0]),
    ("{S}BHD", Head, First, 0.5, [-1.0, 0.6, 0.0]),
    // The seventh cervical vertebra and the jugular notch: the top of the trunk.
    ("C7", Spine, Last, 1.0, [-1.0, 0.0, 0.0]),
    ("CLAV", Spine, Last, 1.0, [1.0, 0.0, 0.0]),
    // The tenth thoracic vertebra and the xiphoid process: the middle of the trunk.
    ("T10", Spine, Middle, 0.5, [-1.0, 0.0, 0.0]),
    ("STRN", Spine, Middle, 1.0, [1.0, 0.0, 0.0]),
    // On the right scapula.
    ("RBAK", Spine, Last, 0.5, [-1.0, -0.6, 0.0]),
    // The acromio-clavicular joint: on top of the shoulder.
    ("{S}SHO", Shoulder, First, 1.0, [0.0, 1.0, 0.0]),
    // The lateral upper arm, the lateral epicondyle.
    ("{S}UPA", UpperArm, First, 0.5, [-0.3, 1.0, 0.0]),
    ("{S}ELB", UpperArm, First, 1.0, [-0.3, 1.0, 0.0]),
    // The forearm, the wrist bar's thumb and little-finger ends (the styloids).
    ("{S}FRM", LowerArm, First, 0.5, [0.0, 1.0, 0.0]),
    ("{S}WRA", LowerArm, First, 1.0, [1.0, 0.0, 0.0]),
    ("{S}WRB", LowerArm, First, 1.0, [-1.0, 0.0, 0.0]),
    // The back of the hand below the second metacarpal's head.
    ("{S}FIN", Hand, First, 0.5, [0.0, 1.0, 0.0]),
    // The anterior and posterior superior iliac spines, the sacrum: from the spines'
    // level ([`PELVIS`]).
    ("{S}ASI", Hips, First, 0.0, [0.0; 3]),
    ("{S}PSI", Hips, First, 0.0, [0.0; 3]),
    ("SACR", Hips, First, 0.0, [0.0; 3]),
    // The lateral thigh's lower third, the lateral femoral epicondyle.
    ("{S}THI", UpperLeg, First, 0.65, [0.0, 1.0, 0.0]),
    ("{S}KNE", UpperLeg, First, 1.0, [0.0, 1.0, 0.0]),
    // The lateral shank's lower third, the lateral malleolus.
    ("{S}TIB", LowerLeg, First, 0.65, [0.0, 1.0, 0.0]),
    ("{S}ANK", LowerLeg, First, 1.0, [0.0, 1.0, 0.0]),
    // The calcaneus, behind and below the ankle; the second metatarsal head, on top.
    ("{S}HEE", Foot, First, 0.0, [0.0; 3]),
    ("{S}TOE", Foot, First, 0.8, [1.0, 0.0, 0.0]),
    // CMU's variant: the top of the head, the waist, the front of the shin, the fifth
    // metatarsal head.
    ("ARIEL", Head, First, 0.0, [0.0, 0.0, 1.0]),
    ("RBAC", Spine, Last, 0.5, [-1.0, -0.6, 0.0]),
    ("{S}FWT", Hips, First, 0.0, [0.0; 3]),
    ("{S}BWT", Hips, First, 0.0, [0.0; 3]),
    ("{S}SHN", LowerLeg, First, 0.5, [1.0, 0.0, 0.0]),
    ("{S}MT5", Foot, First, 0.6, [0.0, 1.0, 0.0]),
];

/// The pelvis's landmarks ([`Templates::pelvis_ray`]): label pattern, distance from the
/// midline as a share of the inter-ASIS width, and whether on the back. The posterior
/// spines lie about 9 cm apart on an adult whose anterior ones lie 24 cm apart, the
/// sacrum marker between them; CMU's waist markers over the spines.
const PELVIS: &[(&str, f64, bool)] = &[
    ("{S}ASI", 0.5, false),
    ("{S}PSI", 0.19, true),
    ("SACR", 0.0, true),
    ("{S}FWT", 0.5, false),
    ("{S}BWT", 0.19, true),
];

/// The tables ([`super::marker_sets`]) whose labels [`PLUG_IN_GAIT`] places.
pub const SETS: &[&str] = &["plug-in-gait", "motive-conventional", "cmu-41"];

/// A marker's centre above the skin, metres (a 14 mm marker: 7 mm, plus its base).
const MARKER_OUT_M: f64 = 0.008;
/// Thickest layer of a character's surface (clothing over a body, armour over
/// clothing) as a share of its height (3 cm on a 1.75 m actor).
const LAYER_SHARE: f64 = 0.03 / 1.75;
/// How far past the skin a marker may sit on what covers it (a collar, a belt, a
/// glove's cuff: a character's armour is 4 to 8 cm thick over the Mixamo soldier's
/// neck, waist and wrists), as a multiple of [`LAYER_SHARE`] of the height.
pub const REACH_LAYERS: f64 = 4.0;
/// A joint without children: its bone's length as a share of the height (a head
/// without a top joint: the skull above its base).
fn leaf_bone_share(part: Part) -> f64 {
    match part {
        Head => 0.12,
        _ => 0.06,
    }
}

/// The body's axes at rest (front, up, left), from the hips, the head and the upper
/// legs' sides; `None` without them.
pub fn body_axes(sk: &Skeleton, roles: &[Option<Role>]) -> Option<(DVec3, DVec3, DVec3)> {
    let at = |part: Part, side: Option<Side>| {
        let j = candidate_joints(Role { part, side }, roles);
        j.first().map(|&j| sk.joints[j].rest)
    };
    let hips = at(Hips, None)?;
    let head = at(Head, None)?;
    let left = at(UpperLeg, Some(Side::Left))? - at(UpperLeg, Some(Side::Right))?;
    let up = (head - hips).normalize_or_zero();
    let left = (left - left.dot(up) * up).normalize_or_zero();
    let front = left.cross(up);
    (up != DVec3::ZERO && left != DVec3::ZERO).then_some((front, up, left))
}

/// The side letter's sign: `L` towards the body's left, `R` away from it.
fn side_sign(pattern: &str, label: &str) -> Option<f64> {
    match pattern.split_once("{S}") {
        None => (pattern == label).then_some(1.0),
        Some((before, after)) => match label.strip_prefix(before)?.strip_suffix(after)? {
            "L" => Some(1.0),
            "R" => Some(-1.0),
            _ => None,
        },
    }
}

/// The templates of a character: its skeleton, roles and rest skin.
pub struct Templates<'a> {
    sk: &'a Skeleton,
    roles: &'a [Option<Role>],
    vertices: &'a [DVec3],
    triangles: &'a [[u32; 3]],
    /// (front, up, left) at rest.
    axes: (DVec3, DVec3, DVec3),
    height: f64,
    /// What is inside the skin: the welded, outward-wound skin's winding number
    /// ([`crate::character::mesh::welded_outward`]), as the calibration's skin terms
    /// judge it.
    surface: &'a WindingNumber,
}

impl<'a> Templates<'a> {
    /// The templates of the skin `vertices`, `triangles` over `sk` at rest, `surface`
    /// its winding number welded and wound outward ([`crate::character::mesh::welded_outward`]);
    /// `None` for a character whose body axes cannot be told ([`body_axes`]: no hips,
    /// head or legs).
    pub fn new(
        sk: &'a Skeleton,
        roles: &'a [Option<Role>],
        vertices: &'a [DVec3],
        triangles: &'a [[u32; 3]],
        height: f64,
        surface: &'a WindingNumber,
    ) -> Option<Self> {
        Some(Self {
            sk,
            roles,
            vertices,
            triangles,
            axes: body_axes(sk, roles)?,
            height,
            surface,
        })
    }

    /// Where the manual of a set in [`PLUG_IN_GAIT`] puts `label` (any spelling) on this
    /// character's skin at rest, metres; `None` for a label the table lacks, a part the
    /// character lacks, or a ray that meets no skin.
    pub fn at(&self, label: &str) -> Option<DVec3> {
        let label = normalise(label);
        let (sign, &(pattern, part, pick, along, dir)) = PLUG_IN_GAIT
            .iter()
            .find_map(|l| Some((side_sign(l.0, &label)?, l)))?;
        let side =
            pattern
                .contains("{S}")
                .then_some(if sign > 0.0 { Side::Left } else { Side::Right });
        let chain = candidate_joints(Role { part, side }, self.roles);
        let &j = match pick {
            First => chain.first(),
            Middle => chain.get(chain.len() / 2),
            Last => chain.last(),
        }?;
        // A part the character lacks falls back to its parent's joints: no landmark
        // there.
        if self.roles.get(j).copied().flatten().map(|r| r.part) != Some(part) {
            return None;
        }
        let (origin, d) = match (part, pattern) {
            (Hips, _) => self.pelvis_ray(pattern, sign)?,
            (Foot, "{S}HEE") => self.heel_ray(j, sign)?,
            _ => {
                let (start, bone) = self.bone(j, part);
                let (front, side_axis) = segment_axes(self.axes, bone, sign);
                let axial = bone.normalize_or_zero();
                (
                    start + bone * along,
                    front * dir[0] + side_axis * dir[1] + axial * dir[2],
                )
            }
        };
        let d = d.normalize_or_zero();
        if d == DVec3::ZERO {
            return None;
        }
        let layer = LAYER_SHARE * self.height;
        let reach = Reach {
            layer_m: layer,
            out_m: MARKER_OUT_M,
            reach_m: REACH_LAYERS * layer,
        };
        let hit = leaves_volume(origin, d, self.vertices, self.triangles, reach, |p| {
            self.surface.at(p) > 0.5
        })?;
        Some(hit.point(self.vertices, MARKER_OUT_M))
    }

    /// A pelvis landmark's ray: from the level of the anterior superior iliac spines,
    /// at its share of the pelvis's width from the midline ([`PELVIS`]), straight to
    /// the front or the back. The spines are placed from the hip joints by inverting
    /// Bell, Pedersen and Brand's regression ("A comparison of the accuracy of several
    /// hip center location prediction methods", J. Biomech. 23(6), 1990), which puts each
    /// hip joint centre 30 % of the inter-ASIS width below, 19 % behind and 36 % lateral
    /// of the spines' midpoint: the width is the hips' distance apart over 0.72, and the
    /// spines lie 0.30 of it above the hip joints. `None` without both hip joints.
    fn pelvis_ray(&self, pattern: &str, sign: f64) -> Option<(DVec3, DVec3)> {
        let (front, up, left) = self.axes;
        let &(_, lateral, back) = PELVIS.iter().find(|p| p.0 == pattern)?;
        let hip = |side| {
            let chain = candidate_joints(
                Role {
                    part: UpperLeg,
                    side: Some(side),
                },
                self.roles,
            );
            chain.first().map(|&j| self.sk.joints[j].rest)
        };
        let (l, r) = (hip(Side::Left)?, hip(Side::Right)?);
        let width = (l - r).dot(left).abs() / 0.72;
        let mid = (l + r) / 2.0;
        let origin = mid + up * (0.30 * width) + left * (sign * lateral * width);
        Some((origin, if back { -front } else { front }))
    }

    /// The heel's ray: as the manual has it, on the calcaneus at the height of the toe
    /// marker above the sole, so from under the ankle joint `ankle` at the toe
    /// template's height, straight back. `None` without a toe template.
    fn heel_ray(&self, ankle: usize, sign: f64) -> Option<(DVec3, DVec3)> {
        let (front, up, _) = self.axes;
        let toe = self.at(if sign > 0.0 { "LTOE" } else { "RTOE" })?;
        let a = self.sk.joints[ankle].rest;
        Some((a + up * (toe - a).dot(up), -front))
    }

    /// Joint `j`'s rest position and bone (to the mean of its children; a leaf's along
    /// its parent's bone, [`leaf_bone_share`] of the height long).
    fn bone(&self, j: usize, part: Part) -> (DVec3, DVec3) {
        let sk = self.sk;
        let start = sk.joints[j].rest;
        let kids: Vec<DVec3> = sk.children(j).map(|c| sk.joints[c].rest).collect();
        if !kids.is_empty() && part != Hips {
            let end = kids.iter().sum::<DVec3>() / kids.len() as f64;
            return (start, end - start);
        }
        let share = leaf_bone_share(part);
        // The hips' children spread three ways (spine and legs): its bone is the body's
        // up, as for a leaf without a parent.
        let dir = match (sk.joints[j].parent, part) {
            (Some(p), p2) if p2 != Hips => (start - sk.joints[p].rest).normalize_or(self.axes.1),
            _ => self.axes.1,
        };
        (start, dir * share * self.height)
    }
}

/// A segment's front and side axes at rest, from the body's `axes` (front, up, left) and
/// the segment's `bone` (see the module doc); `sign` is `1` for the body's left side (or
/// an unsided label), `−1` for the right.
pub fn segment_axes(axes: (DVec3, DVec3, DVec3), bone: DVec3, sign: f64) -> (DVec3, DVec3) {
    let (front, up, left) = axes;
    let a = bone.normalize_or(up);
    let square = |v: DVec3| v - v.dot(a) * a;
    let f = square(front);
    let f = if f.length() >= 0.5 { f } else { square(up) }.normalize_or_zero();
    let s = square(square(left) - square(left).dot(f) * f);
    let s = if s.length() >= 0.3 {
        s.normalize() * sign
    } else {
        // An arm held out level: the front turned about the bone, up on both sides.
        f.cross(a).normalize_or_zero() * sign
    };
    (f, s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::character::demo::demo_body;
    use crate::character::roles::recognise;
    use crate::geom::winding::WindingNumber;

    /// Every Plug-in Gait label on the procedural body: 8 mm out of its skin, on the
    /// side of its bone the manual says, and the left and right ones mirror images.
    #[test]
    fn templates_sit_on_the_skin_where_the_manual_says() {
        let ch = demo_body();
        let sk = &ch.skeleton;
        let roles = recognise(&sk.joints, &[]);
        let (lo, hi) = crate::geom::shapes::bounds(&ch.vertices);
        let (unique, oriented, _) =
            crate::character::mesh::welded_outward(&ch.vertices, &ch.triangles);
        let surface = WindingNumber::new(&unique, &oriented);
        let height = hi.y - lo.y;
        let t = Templates::new(sk, &roles, &ch.vertices, &ch.triangles, height, &surface).unwrap();
        let (front, _, left) = t.axes;
        let labels: Vec<String> = PLUG_IN_GAIT
            .iter()
            .filter(|l| l.0 != "ARIEL" && !l.0.ends_with("WT") && l.0 != "RBAC")
            .flat_map(|l| {
                let p = l.0;
                if p.contains("{S}") {
                    vec![p.replace("{S}", "L"), p.replace("{S}", "R")]
                } else {
                    vec![p.to_string()]
                }
            })
            .collect();
        let at = |label: &str| {
            t.at(label)
                .unwrap_or_else(|| panic!("{label}: no template"))
        };
        for label in &labels {
            let x = at(label);
            // 8 mm out along the hit triangle's normal: the nearest skin is at most that
            // far, and not much nearer (7.7 mm at the closest, on the upper arm).
            let (_, d, _) = surface.signed_closest(x).unwrap();
            assert!(
                (0.0065..=0.0081).contains(&d),
                "{label}: {d} m off the skin"
            );
        }
        // The body is symmetric about its midline: each left template is its right one
        // mirrored, within the asymmetry of its marching-tets mesh (measured 2.2 mm at
        // most, on the forearm).
        let mirror = |p: DVec3| p - 2.0 * p.dot(left) * left;
        for label in labels.iter().filter(|l| l.starts_with('L')) {
            let right = format!("R{}", &label[1..]);
            let d = (at(label) - mirror(at(&right))).length();
            assert!(d < 0.004, "{label} and {right}: {d} m from mirror images");
        }
        // Sides: a knee and ankle marker outside the leg, an ASIS in front, C7 behind
        // CLAV, a thumb-side wrist marker in front of the little-finger side.
        let joint = |role: Part| {
            sk.joints[candidate_joints(
                Role {
                    part: role,
                    side: Some(Side::Left),
                },
                &roles,
            )[0]]
                .rest
        };
        assert!((at("LKNE") - joint(LowerLeg)).dot(left) > 0.03);
        assert!((at("LANK") - joint(Foot)).dot(left) > 0.02);
        assert!((at("LASI") - at("LPSI")).dot(front) > 0.1);
        assert!((at("CLAV") - at("C7")).dot(front) > 0.05);
        assert!((at("LWRA") - at("LWRB")).dot(front) > 0.02);
        // The heel at the toe marker's height, behind the ankle (the manual's calcaneus
        // marker); the spines of the pelvis by Bell's regression from the hip joints:
        // the anterior ones 0.30 of their width above the hips and as far apart as the
        // hips over 0.72, the posterior ones 0.38 of it apart, each give or take its
        // 8 mm out along a skin normal that leans outwards (measured below).
        let up = t.axes.1;
        for (heel, toe, ankle) in [("LHEE", "LTOE", Side::Left), ("RHEE", "RTOE", Side::Right)] {
            let a = sk.joints[candidate_joints(
                Role {
                    part: Foot,
                    side: Some(ankle),
                },
                &roles,
            )[0]]
                .rest;
            // Within the marker's 8 mm out from the skin, which the heel's slant tilts
            // (measured 4.7 mm higher).
            let dy = (at(heel) - at(toe)).dot(up);
            assert!(dy.abs() < 0.008, "{heel}: {dy}");
            assert!((at(heel) - a).dot(front) < -0.02, "{heel}");
        }
        let hip = |side| {
            sk.joints[candidate_joints(
                Role {
                    part: UpperLeg,
                    side: Some(side),
                },
                &roles,
            )[0]]
                .rest
        };
        let width = (hip(Side::Left) - hip(Side::Right)).dot(left) / 0.72;
        let apart = |a: &str, b: &str| (at(a) - at(b)).dot(left);
        // Measured: the anterior spines 9.5 mm wider apart than the width, the
        // posterior ones 3.7 mm, the anterior ones 3.4 mm higher.
        let asis = apart("LASI", "RASI") - width;
        assert!((0.0..0.016).contains(&asis), "{asis}");
        let psis = apart("LPSI", "RPSI") - 0.38 * width;
        assert!(psis.abs() < 0.008, "{psis}");
        let above = at("LASI").dot(up) - hip(Side::Left).dot(up) - 0.30 * width;
        assert!(above.abs() < 0.007, "{above}");
        assert!(t.at("XYZ").is_none());
    }
}
