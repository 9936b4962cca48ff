//! Built-in marker-set tables: for each label of a common optical marker set, the
//! humanoid part whose bone carries it (a knee marker on the lateral femoral epicondyle
//! rides the thigh; an ankle marker on the malleolus rides the shank), so a take's labels
//! can be matched to any character's joints through their roles
//! ([`crate::character::roles`]). Tables: Vicon Plug-in Gait full body, the CMU 41-marker
//! variant, the ISB / Van Sint Jan anatomical landmarks (Qualisys, OptiTrack Biomech 57),
//! the Davis (Helen Hayes) gait set as BTS labels it, OptiTrack Motive's Baseline 37, and
//! the DFKI hand layout of the shared Qualisys hand recording.
//!
//! Labels are compared normalised ([`normalise`]): a `Subject:` prefix dropped, letters
//! upper-cased, everything but letters and digits removed (`L_IAS`, `l ias` and `LIAS`
//! are one label). In a table, `{S}` stands for the side letter, `L` or `R`.

use crate::character::roles::{Digit, Part, Role, Segment, Side};

/// What carries a marker of a set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Carrier {
    /// The bone of a humanoid part.
    Body(Part),
    /// Not the body: a prop or the room (the DFKI recording's pillow).
    Prop,
}

/// A marker-set table.
#[derive(Debug)]
pub struct MarkerSet {
    /// Short name, as `--marker-set` takes it.
    pub name: &'static str,
    /// What it is.
    pub about: &'static str,
    /// Normalised label patterns (`{S}` for the side letter) and their carriers, in
    /// groups (sets that share markers share a group).
    entries: &'static [&'static [(&'static str, Carrier)]],
}

use Carrier::{Body, Prop};
use Part::*;

const fn finger(d: Digit, s: Segment) -> Carrier {
    Body(Finger(d, s))
}

/// The head, torso and limb markers Plug-in Gait and its CMU variant share.
const PLUG_IN_GAIT_COMMON: &[(&str, Carrier)] = &[
    ("{S}FHD", Body(Head)),
    ("{S}BHD", Body(Head)),
    ("C7", Body(Spine)),
    ("T10", Body(Spine)),
    ("CLAV", Body(Spine)),
    ("STRN", Body(Spine)),
    ("{S}SHO", Body(Shoulder)),
    ("{S}UPA", Body(UpperArm)),
    ("{S}ELB", Body(UpperArm)),
    ("{S}FRM", Body(LowerArm)),
    ("{S}WRA", Body(LowerArm)),
    ("{S}WRB", Body(LowerArm)),
    ("{S}FIN", Body(Hand)),
    ("{S}THI", Body(UpperLeg)),
    ("{S}KNE", Body(UpperLeg)),
    ("{S}ANK", Body(LowerLeg)),
    ("{S}HEE", Body(Foot)),
    ("{S}TOE", Body(Foot)),
];

/// Plug-in Gait's markers beside the common ones: the back, the pelvis and the shins.
const PLUG_IN_GAIT_PELVIS: &[(&str, Carrier)] = &[
    ("RBAK", Body(Spine)),
    ("{S}ASI", Body(Hips)),
    ("{S}PSI", Body(Hips)),
    ("SACR", Body(Hips)),
    ("{S}TIB", Body(LowerLeg)),
];

/// Vicon Plug-in Gait, full body (39 markers).
pub const PLUG_IN_GAIT: MarkerSet = MarkerSet {
    name: "plug-in-gait",
    about: "Vicon Plug-in Gait full body",
    entries: &[PLUG_IN_GAIT_COMMON, PLUG_IN_GAIT_PELVIS],
};

/// OptiTrack Motive's Conventional full-body set (39 markers): Plug-in Gait's layout and
/// labels, as Motive names them (OptiTrack documentation, "Markersets: Conventional
/// (39)"), with the skeleton's `Name:` prefix Motive streams and exports.
pub const MOTIVE_CONVENTIONAL: MarkerSet = MarkerSet {
    name: "motive-conventional",
    about: "OptiTrack Motive Conventional full body (39 markers, Plug-in Gait labels)",
    entries: &[PLUG_IN_GAIT_COMMON, PLUG_IN_GAIT_PELVIS],
};

/// The CMU motion-capture database's 41-marker variant of Plug-in Gait (waist markers
/// instead of pelvis ones, `RBAC`, shins, fifth metatarsals).
pub const CMU_41: MarkerSet = MarkerSet {
    name: "cmu-41",
    about: "CMU 41-marker full body (LFWT/LBWT waist, RBAC)",
    entries: &[
        PLUG_IN_GAIT_COMMON,
        &[
            ("ARIEL", Body(Head)),
            ("RBAC", Body(Spine)),
            ("{S}FWT", Body(Hips)),
            ("{S}BWT", Body(Hips)),
            ("{S}SHN", Body(LowerLeg)),
            ("{S}MT5", Body(Foot)),
        ],
    ],
};

/// ISB anatomical landmarks in Van Sint Jan's abbreviations (Qualisys's labels, the
/// OptiTrack Biomech 57 set).
pub const ISB: MarkerSet = MarkerSet {
    name: "isb",
    about: "ISB / Van Sint Jan anatomical landmarks (Qualisys, OptiTrack Biomech 57)",
    entries: &[&[
        ("{S}HDF", Body(Head)),
        ("{S}HDB", Body(Head)),
        ("{S}AH", Body(Head)),
        ("{S}PH", Body(Head)),
        ("SJN", Body(Spine)),
        ("SNJ", Body(Spine)),
        ("SXS", Body(Spine)),
        ("CV7", Body(Spine)),
        ("TV2", Body(Spine)),
        ("TV7", Body(Spine)),
        ("TV8", Body(Spine)),
        ("{S}IAS", Body(Hips)),
        ("{S}IPS", Body(Hips)),
        ("{S}CAJ", Body(Shoulder)),
        ("{S}SAJ", Body(Shoulder)),
        ("{S}SCAP", Body(Shoulder)),
        ("{S}HGT", Body(UpperArm)),
        ("{S}UA", Body(UpperArm)),
        ("{S}HLE", Body(UpperArm)),
        ("{S}HME", Body(UpperArm)),
        ("{S}USP", Body(LowerArm)),
        ("{S}UHE", Body(LowerArm)),
        ("{S}RSP", Body(LowerArm)),
        ("{S}HM2", Body(Hand)),
        ("{S}HM5", Body(Hand)),
        ("{S}FTC", Body(UpperLeg)),
        ("{S}TH", Body(UpperLeg)),
        ("{S}SK", Body(UpperLeg)),
        ("{S}FLE", Body(UpperLeg)),
        ("{S}FME", Body(UpperLeg)),
        ("{S}TTC", Body(LowerLeg)),
        ("{S}FAX", Body(LowerLeg)),
        ("{S}FAL", Body(LowerLeg)),
        ("{S}TAM", Body(LowerLeg)),
        ("{S}FCC", Body(Foot)),
        ("{S}FM1", Body(Foot)),
        ("{S}FM2", Body(Foot)),
        ("{S}FM5", Body(Foot)),
    ]],
};

/// The Davis (Helen Hayes) gait protocol as BTS names it (`r asis`, `r bar 1`, ...).
pub const DAVIS: MarkerSet = MarkerSet {
    name: "davis",
    about: "Davis / Helen Hayes gait protocol, BTS labels",
    entries: &[&[
        ("C7", Body(Spine)),
        ("{S}SHOULD", Body(Shoulder)),
        ("SACRUM", Body(Hips)),
        ("{S}ASIS", Body(Hips)),
        ("{S}THIGH", Body(UpperLeg)),
        ("{S}BAR1", Body(UpperLeg)),
        ("{S}KNEE1", Body(UpperLeg)),
        ("{S}KNEE2", Body(UpperLeg)),
        ("{S}BAR2", Body(LowerLeg)),
        ("{S}MALL", Body(LowerLeg)),
        ("{S}HEEL", Body(Foot)),
        ("{S}MET", Body(Foot)),
    ]],
};

/// OptiTrack Motive's Baseline full-body set (37 markers).
pub const MOTIVE_BASELINE: MarkerSet = MarkerSet {
    name: "motive-baseline",
    about: "OptiTrack Motive Baseline full body (37 markers)",
    entries: &[&[
        ("HEADTOP", Body(Head)),
        ("HEADFRONT", Body(Head)),
        ("HEADSIDE", Body(Head)),
        ("BACKTOP", Body(Spine)),
        ("BACKLEFT", Body(Spine)),
        ("BACKRIGHT", Body(Spine)),
        ("CHEST", Body(Spine)),
        ("WAIST{S}FRONT", Body(Hips)),
        ("WAIST{S}BACK", Body(Hips)),
        ("{S}SHOULDERBACK", Body(Shoulder)),
        ("{S}SHOULDERTOP", Body(Shoulder)),
        ("{S}UARMHIGH", Body(UpperArm)),
        ("{S}ELBOWOUT", Body(UpperArm)),
        ("{S}WRISTOUT", Body(LowerArm)),
        ("{S}WRISTIN", Body(LowerArm)),
        ("{S}HANDOUT", Body(Hand)),
        ("{S}THIGH", Body(UpperLeg)),
        ("{S}KNEEOUT", Body(UpperLeg)),
        ("{S}SHIN", Body(LowerLeg)),
        ("{S}ANKLEOUT", Body(LowerLeg)),
        ("{S}TOEOUT", Body(Foot)),
        ("{S}TOEIN", Body(Foot)),
    ]],
};

/// The hand layout of the DFKI Qualisys recording in the shared data (`hand_top`,
/// `index_tip`, `index_middle`, ..., with elbow, shoulder and back markers of the right
/// arm, and a pillow). A finger's `middle` marker is on its proximal phalanx: in the
/// recording it stays 60 to 66 mm from the tip marker on the index, middle and ring
/// fingers, farther than the intermediate and distal phalanges reach (about 45 mm on
/// an adult hand), and 38 mm on the little finger, at its middle joint.
pub const DFKI_HAND: MarkerSet = MarkerSet {
    name: "dfki-hand",
    about: "DFKI hand recording: back of the hand, tip and middle of each finger",
    entries: &[&[
        ("HANDTOP", Body(Hand)),
        ("HANDLEFT", Body(Hand)),
        ("HANDRIGHT", Body(Hand)),
        ("THUMBTIP", finger(Digit::Thumb, Segment::Distal)),
        ("THUMBMIDDLE", finger(Digit::Thumb, Segment::Proximal)),
        ("INDEXTIP", finger(Digit::Index, Segment::Distal)),
        ("INDEXMIDDLE", finger(Digit::Index, Segment::Proximal)),
        ("MIDDLETIP", finger(Digit::Middle, Segment::Distal)),
        ("MIDDLEMIDDLE", finger(Digit::Middle, Segment::Proximal)),
        ("RINGTIP", finger(Digit::Ring, Segment::Distal)),
        ("RINGMIDDLE", finger(Digit::Ring, Segment::Proximal)),
        ("LITTLETIP", finger(Digit::Little, Segment::Distal)),
        ("LITTLEMIDDLE", finger(Digit::Little, Segment::Proximal)),
        ("RIGHTELBOW", Body(UpperArm)),
        ("RIGHTSHOULDER", Body(Shoulder)),
        ("BACKTOP", Body(Spine)),
        ("BACKLEFT", Body(Spine)),
        ("BACKRIGHT", Body(Spine)),
        ("PILLOWTOP", Prop),
        ("PILLOWLEFT", Prop),
        ("PILLOWRIGHT", Prop),
    ]],
};

/// The procedural body's 36 markers (`rigless demo`, the bundled body takes): Plug-in
/// Gait's head and trunk, heels and toes, and eight around each hand (`LHND1`...).
pub const RIGLESS_BODY: MarkerSet = MarkerSet {
    name: "rigless-body",
    about: "rigless procedural body: Plug-in Gait head and trunk, 8 per hand, heel and toe",
    entries: &[
        PLUG_IN_GAIT_COMMON,
        &[
            ("RBAK", Body(Spine)),
            ("{S}ASI", Body(Hips)),
            ("{S}PSI", Body(Hips)),
            ("SACR", Body(Hips)),
            ("{S}HND1", Body(Hand)),
            ("{S}HND2", Body(Hand)),
            ("{S}HND3", Body(Hand)),
            ("{S}HND4", Body(Hand)),
            ("{S}HND5", Body(Hand)),
            ("{S}HND6", Body(Hand)),
            ("{S}HND7", Body(Hand)),
            ("{S}HND8", Body(Hand)),
        ],
    ],
};

/// The procedural hand's 8 markers (`rigless demo`, the bundled hand take): a nail per
/// finger, three on the back of the hand.
pub const RIGLESS_HAND: MarkerSet = MarkerSet {
    name: "rigless-hand",
    about: "rigless procedural hand: a nail per finger, 3 on the back of the hand",
    entries: &[&[
        ("THUMBNAIL", finger(Digit::Thumb, Segment::Distal)),
        ("INDEXNAIL", finger(Digit::Index, Segment::Distal)),
        ("MIDDLENAIL", finger(Digit::Middle, Segment::Distal)),
        ("RINGNAIL", finger(Digit::Ring, Segment::Distal)),
        ("PINKYNAIL", finger(Digit::Little, Segment::Distal)),
        ("HANDINDEX", Body(Hand)),
        ("HANDPINKY", Body(Hand)),
        ("HANDWRIST", Body(Hand)),
    ]],
};

/// Every built-in table, in the order `--marker-set auto` prefers on a tie (the
/// procedural characters' own last).
pub const MARKER_SETS: [&MarkerSet; 9] = [
    &PLUG_IN_GAIT,
    &CMU_41,
    &ISB,
    &DAVIS,
    &MOTIVE_BASELINE,
    &MOTIVE_CONVENTIONAL,
    &DFKI_HAND,
    &RIGLESS_BODY,
    &RIGLESS_HAND,
];

/// A label as the tables compare it: the part after the last `:` (a `Subject:` prefix),
/// letters upper-cased, only letters and digits kept.
pub fn normalise(label: &str) -> String {
    let label = label.rsplit(':').next().unwrap_or(label);
    label
        .chars()
        .filter(char::is_ascii_alphanumeric)
        .map(|c| c.to_ascii_uppercase())
        .collect()
}

/// Whether `pattern` (with `{S}` for the side letter) matches the normalised `label`,
/// and with which side.
fn matches(pattern: &str, label: &str) -> Option<Option<Side>> {
    match pattern.split_once("{S}") {
        None => (pattern == label).then_some(None),
        Some((before, after)) => {
            let rest = label.strip_prefix(before)?.strip_suffix(after)?;
            match rest {
                "L" => Some(Some(Side::Left)),
                "R" => Some(Some(Side::Right)),
                _ => None,
            }
        }
    }
}

/// Where a label of a take sits, by a table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Placed {
    /// On the bone of this role.
    Body(Role),
    /// On a prop, not the body.
    Prop,
}

impl MarkerSet {
    /// What the table says of `label` (any spelling), or `None` when it does not know it.
    pub fn place(&self, label: &str) -> Option<Placed> {
        let label = normalise(label);
        self.entries
            .iter()
            .copied()
            .flatten()
            .find_map(|&(pattern, carrier)| {
                let side = matches(pattern, &label)?;
                Some(match carrier {
                    Body(part) => Placed::Body(Role { part, side }),
                    Prop => Placed::Prop,
                })
            })
    }

    /// How many of `labels` the table knows.
    pub fn known(&self, labels: &[String]) -> usize {
        labels.iter().filter(|l| self.place(l).is_some()).count()
    }
}

/// The table that knows most of `labels` (the first of [`MARKER_SETS`] on a tie), with
/// how many it knows; `None` when no table knows any.
pub fn best_set(labels: &[String]) -> Option<(&'static MarkerSet, usize)> {
    let mut best: Option<(&'static MarkerSet, usize)> = None;
    for set in MARKER_SETS {
        let n = set.known(labels);
        if n > 0 && best.is_none_or(|(_, b)| n > b) {
            best = Some((set, n));
        }
    }
    best
}

/// The table named `name` (`plug-in-gait`, `cmu-41`, `isb`, `davis`,
/// `motive-baseline`, `motive-conventional`, `dfki-hand`, `rigless-body`,
/// `rigless-hand`).
pub fn by_name(name: &str) -> Option<&'static MarkerSet> {
    MARKER_SETS.into_iter().find(|s| s.name == name)
}

/// The joints a label placed on role `role` may ride, given the skeleton's roles: the
/// joints with that role; failing that, for a part with a side, the same part without
/// a side (a hand asset of unknown side); for a finger bone, the finger's nearest bone
/// that has a role (a distal marker on a finger modelled with two bones); then the part
/// it hangs from (head to neck to spine, clavicle to spine, finger to hand to forearm,
/// toes to foot to shank).
pub fn candidate_joints(role: Role, roles: &[Option<Role>]) -> Vec<usize> {
    let with =
        |r: Role| -> Vec<usize> { (0..roles.len()).filter(|&j| roles[j] == Some(r)).collect() };
    let found = with(role);
    if !found.is_empty() {
        return found;
    }
    if role.side.is_some() {
        let unsided = with(Role { side: None, ..role });
        if !unsided.is_empty() {
            return unsided;
        }
    }
    if let Part::Finger(d, s) = role.part {
        let along = finger_fallback(d, s, role.side, &with);
        if !along.is_empty() {
            return along;
        }
    }
    // A part the character lacks rides the part it hangs from: a head marker on a neck
    // that ends the chain, an acromion marker on the chest of a character without
    // clavicles, a toe marker on a foot without toes.
    let parent = match role.part {
        Part::Head => Some(Part::Neck),
        Part::Neck | Part::Shoulder => Some(Part::Spine),
        Part::Hand => Some(Part::LowerArm),
        Part::Finger(..) => Some(Part::Hand),
        Part::Toes => Some(Part::Foot),
        Part::Foot => Some(Part::LowerLeg),
        _ => None,
    };
    match parent {
        Some(part) => {
            let side = if matches!(part, Part::Spine | Part::Neck) {
                None
            } else {
                role.side
            };
            candidate_joints(Role { part, side }, roles)
        }
        None => Vec::new(),
    }
}

/// A finger bone the character lacks: the finger's nearest bone that it has (a distal
/// marker on a finger modelled with two bones), with the side or without.
fn finger_fallback(
    d: Digit,
    s: Segment,
    side: Option<Side>,
    with: &dyn Fn(Role) -> Vec<usize>,
) -> Vec<usize> {
    let order = [
        Segment::Distal,
        Segment::Intermediate,
        Segment::Proximal,
        Segment::Metacarpal,
    ];
    let from = order.iter().position(|&x| x == s).unwrap_or(0);
    for &seg in &order[from..] {
        for side in [side, None] {
            let found = with(Role {
                part: Part::Finger(d, seg),
                side,
            });
            if !found.is_empty() {
                return found;
            }
        }
    }
    Vec::new()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn role(part: Part, side: Option<Side>) -> Option<Placed> {
        Some(Placed::Body(Role { part, side }))
    }

    #[test]
    fn spellings_and_sides() {
        let l = Some(Side::Left);
        let r = Some(Side::Right);
        assert_eq!(PLUG_IN_GAIT.place("LKNE"), role(UpperLeg, l));
        assert_eq!(PLUG_IN_GAIT.place("Subject01:RANK"), role(LowerLeg, r));
        assert_eq!(PLUG_IN_GAIT.place("C7"), role(Spine, None));
        assert_eq!(PLUG_IN_GAIT.place("XKNE"), None, "X is no side");
        assert_eq!(ISB.place("L_IAS"), role(Hips, l));
        assert_eq!(ISB.place("r_fle"), role(UpperLeg, r));
        assert_eq!(DAVIS.place("r bar 2"), role(LowerLeg, r));
        assert_eq!(DAVIS.place("sacrum"), role(Hips, None));
        assert_eq!(MOTIVE_BASELINE.place("WaistLFront"), role(Hips, l));
        assert_eq!(MOTIVE_BASELINE.place("RShin"), role(LowerLeg, r));
        assert_eq!(
            MOTIVE_CONVENTIONAL.place("Skeleton_001:LPSI"),
            role(Hips, l)
        );
        assert_eq!(MOTIVE_CONVENTIONAL.place("RTIB"), role(LowerLeg, r));
        assert_eq!(
            DFKI_HAND.place("index_middle"),
            role(Finger(Digit::Index, Segment::Proximal), None)
        );
        assert_eq!(DFKI_HAND.place("pillow_top"), Some(Placed::Prop));
        assert_eq!(normalise("Daphnee:CLAV_SC"), "CLAVSC");
    }

    #[test]
    fn every_table_name_is_found_and_patterns_are_well_formed() {
        for set in MARKER_SETS {
            assert_eq!(by_name(set.name).map(|s| s.name), Some(set.name));
            for (pattern, _) in set.entries.iter().copied().flatten() {
                assert_eq!(
                    &normalise(pattern.replace("{S}", "").as_str()),
                    &pattern.replace("{S}", "")
                );
                assert!(pattern.matches("{S}").count() <= 1, "{pattern}");
            }
        }
    }

    #[test]
    fn fingers_fall_back_along_the_finger_and_to_no_side() {
        let idx = |s| {
            Some(Role {
                part: Finger(Digit::Index, s),
                side: None,
            })
        };
        // A hand asset of unknown side whose index finger has no distal bone.
        let roles = vec![None, idx(Segment::Proximal), idx(Segment::Intermediate)];
        let want = Role {
            part: Finger(Digit::Index, Segment::Distal),
            side: Some(Side::Right),
        };
        assert_eq!(candidate_joints(want, &roles), vec![2]);
        let knee = Role {
            part: LowerLeg,
            side: Some(Side::Left),
        };
        assert!(candidate_joints(knee, &roles).is_empty());
    }

    #[test]
    fn a_missing_part_falls_back_to_the_part_it_hangs_from() {
        let r = |part, side| Some(Role { part, side });
        let l = Some(Side::Left);
        // CesiumMan-like: hips, spine, neck, no head, no clavicles, upper arm, forearm,
        // no hand.
        let roles = vec![
            r(Hips, None),
            r(Spine, None),
            r(Neck, None),
            r(UpperArm, l),
            r(LowerArm, l),
        ];
        let want = |part, side| candidate_joints(Role { part, side }, &roles);
        assert_eq!(want(Head, l), vec![2], "a head marker rides the neck");
        assert_eq!(
            want(Shoulder, l),
            vec![1],
            "an acromion marker rides the spine"
        );
        assert_eq!(want(Hand, l), vec![4], "a hand marker rides the forearm");
        assert_eq!(want(Finger(Digit::Index, Segment::Distal), l), vec![4]);
        assert!(want(Foot, l).is_empty(), "no leg at all");
    }
}
