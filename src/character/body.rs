//! The procedural body, owned by the project: a 1.75 m adult in a relaxed A-pose (arms
//! 30° from the sides), 24 joints, 36 markers in a standard optical layout (4 on the
//! head, 12 on the trunk, 8 on each hand, 2 on each foot), and two motions, walking and
//! reaching, with known truth (the same mesh skinned by the same skeleton).
//!
//! The surface is an implicit smooth union of ellipsoids (pelvis, waist, chest, head)
//! and tapered capsules (neck, limbs, mitten hands, feet), meshed by marching
//! tetrahedra and simplified, as the hand is. Frame: metres, Y up, facing +Z, the
//! character's left towards +X.

use super::mesh::MeshPart;
use super::procedural::{on_skin, skin_by_distance, surface_of, Capsule, Pose, Shape};
use super::skeleton::{compose, Joint, JointLimits, Skeleton, SwingTwist};
use super::{Character, MarkerDef};
use glam::{DQuat, DVec3};

const DEG: f64 = std::f64::consts::PI / 180.0;

/// Procedural motions of the body.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BodyMotion {
    /// Walking forward at about 1.2 m/s (1.1 s gait cycle), arms swinging.
    Walk,
    /// Standing, reaching forward and up with the right arm while leaning in, and back.
    Reach,
    /// A calibration's range of motion: 1.5 s standing in the rest pose, then each group
    /// of joints bent and back in turn (arms, wrists and forearms, trunk, neck, each leg,
    /// a squat), 1.5 s each.
    RangeOfMotion,
}

impl BodyMotion {
    pub fn name(self) -> &'static str {
        match self {
            BodyMotion::Walk => "walk",
            BodyMotion::Reach => "reach",
            BodyMotion::RangeOfMotion => "rom",
        }
    }
}

/// Joint limits from degrees: twist `±twist`, bend and side `(min, max)`.
fn lim(twist: f64, bend: (f64, f64), side: (f64, f64)) -> Option<JointLimits> {
    Some(JointLimits {
        twist: (-twist * DEG, twist * DEG),
        bend: (bend.0 * DEG, bend.1 * DEG),
        side: (side.0 * DEG, side.1 * DEG),
    })
}

/// Builds the procedural body: meshed on a lattice of `mesh_cell_m` and simplified to
/// about `target_triangles` (20,000 gives about 10,000 vertices).
pub fn body(mesh_cell_m: f64, target_triangles: usize) -> Character {
    let skeleton = body_skeleton();
    let shapes = body_shapes(&skeleton);
    let sdf = |q: DVec3| body_sdf(&shapes, q);
    let (vertices, triangles) = surface_of(
        &sdf,
        DVec3::new(-0.62, -0.03, -0.2),
        DVec3::new(0.62, 1.81, 0.25),
        mesh_cell_m,
        target_triangles,
    );
    let skin = skin_by_distance(&vertices, &shapes, 0.03);
    let markers = body_markers(&skeleton, &sdf);
    Character {
        name: "body".into(),
        parts: vec![MeshPart::whole("body", vertices.len(), triangles.len())],
        vertices,
        triangles,
        skeleton,
        markers,
        skin: Some(skin),
        correspondences: Vec::new(),
    }
}

/// The body's 24 joints: trunk and head, then the left arm and leg, then the right.
fn body_skeleton() -> Skeleton {
    let mut joints: Vec<Joint> = Vec::new();
    let (pelvis, chest) = add_trunk(&mut joints);
    for side in [1.0, -1.0] {
        add_arm(&mut joints, chest, side);
        add_leg(&mut joints, pelvis, side);
    }
    Skeleton::new(joints).expect("procedural body skeleton is valid")
}

/// Appends a joint to `joints` and returns its index.
fn add_joint(
    joints: &mut Vec<Joint>,
    name: &str,
    parent: Option<usize>,
    rest: DVec3,
    limits: Option<JointLimits>,
    bend_axis: DVec3,
) -> usize {
    joints.push(Joint {
        name: name.into(),
        parent,
        rest,
        limits,
        bend_axis,
    });
    joints.len() - 1
}

/// `v` on the given side: mirrored across X = 0 for the right (`side` −1).
fn mirror(v: DVec3, side: f64) -> DVec3 {
    DVec3::new(v.x * side, v.y, v.z)
}

/// The joint-name suffix of a side: `"l"` for +1, `"r"` for −1.
fn side_suffix(side: f64) -> &'static str {
    if side > 0.0 {
        "l"
    } else {
        "r"
    }
}

/// Appends the trunk and head (pelvis to head_top); returns the pelvis and the chest.
fn add_trunk(joints: &mut Vec<Joint>) -> (usize, usize) {
    let x = DVec3::X;
    let pelvis = add_joint(joints, "pelvis", None, DVec3::new(0.0, 0.95, 0.0), None, x);
    let spine = add_joint(
        joints,
        "spine",
        Some(pelvis),
        DVec3::new(0.0, 1.10, -0.01),
        lim(30.0, (-25.0, 40.0), (-25.0, 25.0)),
        x,
    );
    let chest = add_joint(
        joints,
        "chest",
        Some(spine),
        DVec3::new(0.0, 1.30, -0.01),
        lim(25.0, (-20.0, 30.0), (-20.0, 20.0)),
        x,
    );
    let neck = add_joint(
        joints,
        "neck",
        Some(chest),
        DVec3::new(0.0, 1.50, -0.01),
        lim(50.0, (-40.0, 50.0), (-35.0, 35.0)),
        x,
    );
    let head = add_joint(
        joints,
        "head",
        Some(neck),
        DVec3::new(0.0, 1.59, 0.0),
        lim(30.0, (-30.0, 30.0), (-20.0, 20.0)),
        x,
    );
    add_joint(
        joints,
        "head_top",
        Some(head),
        DVec3::new(0.0, 1.75, 0.0),
        None,
        x,
    );
    (pelvis, chest)
}

/// Appends one side's arm (clavicle to hand_end), 30° from the side, on the chest.
fn add_arm(joints: &mut Vec<Joint>, chest: usize, side: f64) {
    let arm_l = DVec3::new(0.5, -(0.75f64).sqrt(), 0.0); // 30° from the side
    let s = |v: DVec3| mirror(v, side);
    let l = side_suffix(side);
    let d = DVec3::new(arm_l.x * side, arm_l.y, 0.0);
    // Flexion raises the arm forwards: about d × Z.
    let flex = d.cross(DVec3::Z).normalize();
    let clav = add_joint(
        joints,
        &format!("clavicle_{l}"),
        Some(chest),
        s(DVec3::new(0.03, 1.44, 0.0)),
        lim(10.0, (-10.0, 10.0), (-15.0, 15.0)),
        DVec3::Z,
    );
    let shoulder = s(DVec3::new(0.18, 1.43, -0.01));
    let elbow = shoulder + d * 0.28;
    let wrist = elbow + d * 0.26;
    let sh = add_joint(
        joints,
        &format!("shoulder_{l}"),
        Some(clav),
        shoulder,
        lim(80.0, (-60.0, 170.0), (-70.0, 70.0)),
        flex,
    );
    let el = add_joint(
        joints,
        &format!("elbow_{l}"),
        Some(sh),
        elbow,
        lim(80.0, (0.0, 145.0), (-5.0, 5.0)),
        flex,
    );
    let wr = add_joint(
        joints,
        &format!("wrist_{l}"),
        Some(el),
        wrist,
        lim(15.0, (-70.0, 80.0), (-30.0, 30.0)),
        flex,
    );
    add_joint(
        joints,
        &format!("hand_end_{l}"),
        Some(wr),
        wrist + d * 0.18,
        None,
        flex,
    );
}

/// Appends one side's leg (hip to toe) on the pelvis.
fn add_leg(joints: &mut Vec<Joint>, pelvis: usize, side: f64) {
    let x = DVec3::X;
    let s = |v: DVec3| mirror(v, side);
    let l = side_suffix(side);
    // Legs: hip flexion brings the thigh forwards (about −X), the knee bends back.
    let hip = add_joint(
        joints,
        &format!("hip_{l}"),
        Some(pelvis),
        s(DVec3::new(0.09, 0.90, 0.0)),
        lim(40.0, (-20.0, 120.0), (-30.0, 45.0)),
        -x,
    );
    let knee = add_joint(
        joints,
        &format!("knee_{l}"),
        Some(hip),
        s(DVec3::new(0.10, 0.50, 0.01)),
        lim(10.0, (0.0, 140.0), (-3.0, 3.0)),
        x,
    );
    let ankle = add_joint(
        joints,
        &format!("ankle_{l}"),
        Some(knee),
        s(DVec3::new(0.10, 0.09, -0.01)),
        lim(15.0, (-30.0, 40.0), (-20.0, 20.0)),
        x,
    );
    add_joint(
        joints,
        &format!("toe_{l}"),
        Some(ankle),
        s(DVec3::new(0.10, 0.03, 0.15)),
        None,
        x,
    );
}

/// Index of the body joint named `name`.
fn joint_index(sk: &Skeleton, name: &str) -> usize {
    sk.joints
        .iter()
        .position(|jt| jt.name == name)
        .expect("body joint")
}

/// Rest position of the body joint named `name`.
fn rest(sk: &Skeleton, name: &str) -> DVec3 {
    sk.joints[joint_index(sk, name)].rest
}

/// A tapered capsule shape from `a` (radius `ra`) to `b` (radius `rb`).
fn cap(a: DVec3, b: DVec3, ra: f64, rb: f64) -> Shape {
    Shape::Capsule(Capsule { a, b, ra, rb })
}

/// The flesh as (owner joint, shape): the five trunk and head pieces first (they blend
/// broadly in [`body_sdf`]), then each side's limbs, left first.
fn body_shapes(skeleton: &Skeleton) -> Vec<(usize, Shape)> {
    let j = |name: &str| joint_index(skeleton, name);
    let p = |name: &str| rest(skeleton, name);
    let mut shapes: Vec<(usize, Shape)> = vec![
        (
            j("pelvis"),
            Shape::Ellipsoid {
                c: DVec3::new(0.0, 0.94, -0.01),
                r: DVec3::new(0.165, 0.12, 0.11),
            },
        ),
        (
            j("spine"),
            Shape::Ellipsoid {
                c: DVec3::new(0.0, 1.12, -0.01),
                r: DVec3::new(0.135, 0.13, 0.095),
            },
        ),
        (
            j("chest"),
            Shape::Ellipsoid {
                c: DVec3::new(0.0, 1.33, -0.01),
                r: DVec3::new(0.17, 0.15, 0.11),
            },
        ),
        (
            j("neck"),
            cap(p("neck") - DVec3::Y * 0.04, p("head"), 0.055, 0.05),
        ),
        (
            j("head"),
            Shape::Ellipsoid {
                c: DVec3::new(0.0, 1.665, 0.01),
                r: DVec3::new(0.078, 0.105, 0.095),
            },
        ),
    ];
    for l in ["l", "r"] {
        shapes.extend(limb_shapes(skeleton, l));
    }
    shapes
}

/// One side's limb flesh (suffix `l`): upper arm to mitten hand, thigh to foot.
fn limb_shapes(skeleton: &Skeleton, l: &str) -> [(usize, Shape); 7] {
    let j = |name: &str| joint_index(skeleton, name);
    let p = |name: &str| rest(skeleton, name);
    let n = |b: &str| format!("{b}_{l}");
    [
        (
            j(&n("clavicle")),
            cap(p(&n("clavicle")), p(&n("shoulder")), 0.05, 0.055),
        ),
        (
            j(&n("shoulder")),
            cap(p(&n("shoulder")), p(&n("elbow")), 0.052, 0.04),
        ),
        (
            j(&n("elbow")),
            cap(p(&n("elbow")), p(&n("wrist")), 0.04, 0.028),
        ),
        (
            j(&n("wrist")),
            cap(
                p(&n("wrist")),
                p(&n("hand_end")) - (p(&n("hand_end")) - p(&n("wrist"))) * 0.15,
                0.03,
                0.026,
            ),
        ),
        (j(&n("hip")), cap(p(&n("hip")), p(&n("knee")), 0.085, 0.055)),
        (
            j(&n("knee")),
            cap(p(&n("knee")), p(&n("ankle")), 0.052, 0.035),
        ),
        (
            j(&n("ankle")),
            cap(
                p(&n("ankle")) - DVec3::new(0.0, 0.04, 0.06),
                p(&n("toe")),
                0.04,
                0.03,
            ),
        ),
    ]
}

/// The body's implicit surface at `q`: the smooth union of the shapes, the trunk pieces
/// (the first five) blended broadly, limbs narrowly.
fn body_sdf(shapes: &[(usize, Shape)], q: DVec3) -> f64 {
    let mut d = f64::INFINITY;
    for (k, (_, s)) in shapes.iter().enumerate() {
        let v = s.sdf(q);
        // Trunk pieces blend broadly, limbs narrowly.
        let blend = if k < 5 { 0.04 } else { 0.02 };
        d = if d.is_infinite() {
            v
        } else {
            super::procedural::smin(d, v, blend)
        };
    }
    d
}

/// Appends a marker carried by `joint`, on the skin where the ray from `from` along
/// `dir` leaves it: 14 mm balls, so their centres sit 8 mm off the skin.
fn mark(
    markers: &mut Vec<MarkerDef>,
    sdf: &dyn Fn(DVec3) -> f64,
    name: String,
    joint: usize,
    from: DVec3,
    dir: DVec3,
) {
    markers.push(MarkerDef {
        name,
        rest: on_skin(sdf, from, dir.normalize(), 0.4, 0.008),
        joint: Some(joint),
    });
}

/// The 36 markers: head, trunk, then each side's hand and foot.
fn body_markers(skeleton: &Skeleton, sdf: &dyn Fn(DVec3) -> f64) -> Vec<MarkerDef> {
    let mut markers = Vec::new();
    head_and_trunk_markers(&mut markers, skeleton, sdf);
    hand_and_foot_markers(&mut markers, skeleton, sdf);
    markers
}

/// Appends the 4 head markers and the 12 trunk markers (shoulders and pelvis included).
fn head_and_trunk_markers(
    markers: &mut Vec<MarkerDef>,
    skeleton: &Skeleton,
    sdf: &dyn Fn(DVec3) -> f64,
) {
    let j = |name: &str| joint_index(skeleton, name);
    let p = |name: &str| rest(skeleton, name);
    let hc = DVec3::new(0.0, 1.665, 0.01);
    for (name, dir) in [
        ("LFHD", DVec3::new(0.5, 0.3, 1.0)),
        ("RFHD", DVec3::new(-0.5, 0.3, 1.0)),
        ("LBHD", DVec3::new(0.5, 0.3, -1.0)),
        ("RBHD", DVec3::new(-0.5, 0.3, -1.0)),
    ] {
        mark(markers, sdf, name.into(), j("head"), hc, dir);
    }
    let trunk = [
        (
            "C7",
            "chest",
            DVec3::new(0.0, 1.47, -0.01),
            DVec3::new(0.0, 0.3, -1.0),
        ),
        ("T10", "spine", DVec3::new(0.0, 1.18, -0.01), -DVec3::Z),
        (
            "CLAV",
            "chest",
            DVec3::new(0.0, 1.43, 0.0),
            DVec3::new(0.0, 0.2, 1.0),
        ),
        ("STRN", "chest", DVec3::new(0.0, 1.28, 0.0), DVec3::Z),
        ("RBAK", "chest", DVec3::new(-0.08, 1.32, -0.01), -DVec3::Z),
        (
            "LSHO",
            "clavicle_l",
            p("shoulder_l"),
            DVec3::new(0.2, 1.0, 0.0),
        ),
        (
            "RSHO",
            "clavicle_r",
            p("shoulder_r"),
            DVec3::new(-0.2, 1.0, 0.0),
        ),
        (
            "LASI",
            "pelvis",
            DVec3::new(0.1, 0.98, 0.0),
            DVec3::new(0.3, 0.0, 1.0),
        ),
        (
            "RASI",
            "pelvis",
            DVec3::new(-0.1, 0.98, 0.0),
            DVec3::new(-0.3, 0.0, 1.0),
        ),
        (
            "LPSI",
            "pelvis",
            DVec3::new(0.05, 1.0, -0.01),
            DVec3::new(0.2, 0.0, -1.0),
        ),
        (
            "RPSI",
            "pelvis",
            DVec3::new(-0.05, 1.0, -0.01),
            DVec3::new(-0.2, 0.0, -1.0),
        ),
        ("SACR", "pelvis", DVec3::new(0.0, 0.95, -0.01), -DVec3::Z),
    ];
    for (name, joint, from, dir) in trunk {
        mark(markers, sdf, name.into(), j(joint), from, dir);
    }
}

/// Appends each side's 8 markers around the mitten hand and 2 on the foot, left first.
fn hand_and_foot_markers(
    markers: &mut Vec<MarkerDef>,
    skeleton: &Skeleton,
    sdf: &dyn Fn(DVec3) -> f64,
) {
    let j = |name: &str| joint_index(skeleton, name);
    let p = |name: &str| rest(skeleton, name);
    for (l, side) in [("l", 1.0), ("r", -1.0)] {
        let (w, e) = (p(&format!("wrist_{l}")), p(&format!("hand_end_{l}")));
        let axis = (e - w).normalize();
        let across = axis.cross(DVec3::Z).normalize();
        let up = L_OR_R_PREFIX[(side < 0.0) as usize];
        // Around the mitten: at 5, 40, 70 and 95 % of its length.
        for (k, (t, ang)) in [
            (0.05, 0.0),
            (0.05, 180.0),
            (0.4, 90.0),
            (0.4, 270.0),
            (0.7, 0.0),
            (0.7, 180.0),
            (0.95, 45.0),
            (0.95, 225.0),
        ]
        .into_iter()
        .enumerate()
        {
            let dir = DQuat::from_axis_angle(axis, ang * DEG) * across;
            mark(
                markers,
                sdf,
                format!("{up}HND{}", k + 1),
                j(&format!("wrist_{l}")),
                w + (e - w) * t,
                dir,
            );
        }
        let ankle = p(&format!("ankle_{l}"));
        mark(
            markers,
            sdf,
            format!("{up}HEE"),
            j(&format!("ankle_{l}")),
            ankle - DVec3::new(0.0, 0.04, 0.0),
            DVec3::new(0.0, -0.3, -1.0),
        );
        mark(
            markers,
            sdf,
            format!("{up}TOE"),
            j(&format!("ankle_{l}")),
            p(&format!("toe_{l}")),
            DVec3::new(0.0, 0.3, 1.0),
        );
    }
}

/// Vicon-style side prefixes, left then right.
const L_OR_R_PREFIX: [&str; 2] = ["L", "R"];

/// The body's pose at time `t_s` for a motion (all within the joint limits).
pub fn body_pose(sk: &Skeleton, motion: BodyMotion, t_s: f64) -> Pose {
    let mut local = vec![DQuat::IDENTITY; sk.len()];
    let j = |name: &str| {
        sk.joints
            .iter()
            .position(|jt| jt.name == name)
            .expect("body joint")
    };
    let set = |local: &mut Vec<DQuat>, name: &str, twist: f64, bend: f64, side: f64| {
        let k = j(name);
        local[k] = compose(
            SwingTwist {
                twist: twist * DEG,
                bend: bend * DEG,
                side: side * DEG,
            },
            sk.twist_axis(k),
            sk.joints[k].bend_axis,
        );
    };
    let tau = std::f64::consts::TAU;
    let root_offset = match motion {
        BodyMotion::Walk => {
            let ph = tau * t_s / 1.1;
            for (l, s) in [("l", 1.0), ("r", -1.0)] {
                let phase = ph + if s > 0.0 { 0.0 } else { std::f64::consts::PI };
                let hip = 12.0 + 22.0 * phase.sin();
                // The knee flexes most in swing, a little at loading.
                let knee = 8.0 + 30.0 * (0.5 + 0.5 * (phase - 1.9).sin()).powi(2) * 2.0;
                let ankle = 8.0 * (phase + 0.6).sin();
                set(&mut local, &format!("hip_{l}"), 0.0, hip, 2.0);
                set(&mut local, &format!("knee_{l}"), 0.0, knee, 0.0);
                set(&mut local, &format!("ankle_{l}"), 0.0, ankle, 0.0);
                // Arms swing against the legs.
                set(
                    &mut local,
                    &format!("shoulder_{l}"),
                    0.0,
                    -18.0 * phase.sin(),
                    -8.0 * s,
                );
                set(
                    &mut local,
                    &format!("elbow_{l}"),
                    0.0,
                    25.0 - 10.0 * phase.sin(),
                    0.0,
                );
            }
            set(&mut local, "spine", 6.0 * ph.sin(), 3.0, 0.0);
            set(&mut local, "chest", 4.0 * ph.sin(), 2.0, 0.0);
            set(&mut local, "neck", -5.0 * ph.sin(), 0.0, 0.0);
            local[j("pelvis")] = DQuat::from_rotation_y(-5.0 * DEG * ph.sin());
            DVec3::new(0.015 * ph.sin(), 0.02 * (2.0 * ph).cos(), 1.2 * t_s)
        }
        BodyMotion::Reach => {
            // 0 → 1 → 0 over a 3.2 s cycle, eased.
            let u = 0.5 - 0.5 * (tau * t_s / 3.2).cos();
            set(&mut local, "shoulder_r", -10.0 * u, 95.0 * u, 10.0 * u);
            set(&mut local, "elbow_r", 20.0 * u, 35.0 - 30.0 * u, 0.0);
            set(&mut local, "wrist_r", 0.0, 10.0 * u, 0.0);
            set(&mut local, "spine", -8.0 * u, 15.0 * u, -5.0 * u);
            set(&mut local, "chest", -5.0 * u, 10.0 * u, 0.0);
            set(&mut local, "neck", -15.0 * u, -10.0 * u, 0.0);
            set(&mut local, "shoulder_l", 0.0, -10.0 * u, 5.0);
            set(&mut local, "elbow_l", 0.0, 15.0 + 10.0 * u, 0.0);
            for l in ["l", "r"] {
                set(&mut local, &format!("hip_{l}"), 0.0, 12.0 * u, 0.0);
                set(&mut local, &format!("knee_{l}"), 0.0, 18.0 * u, 0.0);
                set(&mut local, &format!("ankle_{l}"), 0.0, 8.0 * u, 0.0);
            }
            DVec3::new(0.0, -0.03 * u, 0.02 * u)
        }
        BodyMotion::RangeOfMotion => range_of_motion(&mut local, &set, t_s),
    };
    Pose { local, root_offset }
}

/// Sets one joint's local rotation from swing-twist angles: `(local, joint, twist°,
/// bend°, side°)`.
type SetJoint<'a> = &'a dyn Fn(&mut Vec<DQuat>, &str, f64, f64, f64);

/// The range-of-motion take's pose at `t_s` (see [`BodyMotion::RangeOfMotion`]):
/// fills `local` through `set`, returns the root's offset.
fn range_of_motion(local: &mut Vec<DQuat>, set: SetJoint, t_s: f64) -> DVec3 {
    const REST_S: f64 = 1.5;
    const PHASE_S: f64 = 1.5;
    if t_s < REST_S {
        return DVec3::ZERO;
    }
    let phase = ((t_s - REST_S) / PHASE_S).floor();
    // 0 → 1 → 0 within the phase, eased.
    let u = 0.5 - 0.5 * (std::f64::consts::TAU * ((t_s - REST_S) / PHASE_S).fract()).cos();
    let both = |local: &mut Vec<DQuat>, name: &str, twist: f64, bend: f64, side: f64| {
        for l in ["l", "r"] {
            set(local, &format!("{name}_{l}"), twist, bend, side);
        }
    };
    match phase as i64 {
        0 => {
            both(local, "shoulder", 20.0 * u, 80.0 * u, 30.0 * u);
            both(local, "elbow", 0.0, 100.0 * u, 0.0);
        }
        1 => {
            both(local, "elbow", 60.0 * u, 45.0 * u, 0.0);
            both(local, "wrist", 10.0 * u, 50.0 * u, 20.0 * u);
            both(local, "clavicle", 0.0, 8.0 * u, 10.0 * u);
        }
        2 => {
            set(local, "spine", 20.0 * u, 30.0 * u, 15.0 * u);
            set(local, "chest", -15.0 * u, 20.0 * u, -10.0 * u);
        }
        3 => {
            set(local, "neck", 40.0 * u, 30.0 * u, 20.0 * u);
            set(local, "head", -20.0 * u, -20.0 * u, 10.0 * u);
        }
        4 | 5 => {
            let l = if phase as i64 == 4 { "l" } else { "r" };
            set(local, &format!("hip_{l}"), 20.0 * u, 70.0 * u, 20.0 * u);
            set(local, &format!("knee_{l}"), 0.0, 90.0 * u, 0.0);
            set(local, &format!("ankle_{l}"), 10.0 * u, 25.0 * u, 10.0 * u);
        }
        6 => {
            both(local, "hip", 0.0, 45.0 * u, 0.0);
            both(local, "knee", 0.0, 70.0 * u, 0.0);
            both(local, "ankle", 0.0, 25.0 * u, 0.0);
            set(local, "spine", 0.0, -20.0 * u, 0.0);
            return DVec3::new(0.0, -0.12 * u, 0.0);
        }
        _ => {}
    }
    DVec3::ZERO
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::character::mesh::{surface_issues, SurfaceIssues};
    use crate::character::procedural::mesh_volume;

    #[test]
    fn body_is_a_closed_body_sized_mesh_with_the_marker_layout() {
        let b = body(0.012, 20_000);
        let n = b.vertices.len();
        assert!((8_000..15_000).contains(&n), "{n} vertices");
        assert_eq!(surface_issues(&b.triangles), SurfaceIssues::default());
        let vol = mesh_volume(&b.vertices, &b.triangles);
        // An adult of 1.75 m: 50–90 litres.
        assert!((0.05..0.09).contains(&vol), "volume {} l", vol * 1e3);
        let (lo, hi) = b
            .vertices
            .iter()
            .fold((DVec3::MAX, DVec3::MIN), |(a, c), v| (a.min(*v), c.max(*v)));
        assert!(
            ((hi.y - lo.y) - 1.75).abs() < 0.03,
            "height {}",
            hi.y - lo.y
        );
        assert_eq!(b.markers.len(), 36);
        let count = |pre: &[&str]| {
            b.markers
                .iter()
                .filter(|m| pre.iter().any(|p| m.name.starts_with(p)))
                .count()
        };
        assert_eq!(count(&["LFHD", "RFHD", "LBHD", "RBHD"]), 4);
        assert_eq!(count(&["LHND", "RHND"]), 16);
        assert_eq!(count(&["LHEE", "RHEE", "LTOE", "RTOE"]), 4);
        // Every marker sits 8 mm off the skin (the mesh is within a few mm of the
        // implicit surface after simplification).
        for m in &b.markers {
            let d = b
                .vertices
                .iter()
                .map(|v| (*v - m.rest).length())
                .fold(f64::MAX, f64::min);
            assert!(
                (0.002..0.03).contains(&d),
                "marker {} is {d} m from the mesh",
                m.name
            );
        }
        assert_eq!(b.skeleton.len(), 24);
    }

    #[test]
    fn motions_stay_within_limits() {
        let b = body(0.02, 8_000);
        for motion in [
            BodyMotion::Walk,
            BodyMotion::Reach,
            BodyMotion::RangeOfMotion,
        ] {
            for k in 0..480 {
                let pose = body_pose(&b.skeleton, motion, k as f64 * 0.025);
                if let Some((j, excess)) = b.skeleton.worst_limit_excess(&pose.local) {
                    assert!(
                        excess < 1e-9,
                        "{motion:?}: joint {} exceeds its limits by {excess} rad",
                        b.skeleton.joints[j].name
                    );
                }
            }
        }
    }
}
