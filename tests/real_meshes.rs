//! Golden tests on real meshes from `../shared/data/meshes` (skipped, with the reason
//! printed, when the shared data folder is absent): the WebXR generic hand (glTF, 25-joint
//! skin) and the MakeHuman body (OBJ, body group, decimetres, a skeleton listed from its
//! own `default.mhskel`). Each bakes and tracks a motion inside its joint limits without
//! inverted tets.

mod common;

use glam::DVec3;
use rigless::bench::assets::webxr_hand_file;
use rigless::bench::exercise::{exercise, ExerciseOptions};
use rigless::character::file::load_character;
use rigless::character::procedural::{flex_pose, skin_pose};
use rigless::character::roles::{recognise, summary};
use rigless::character::skeleton::Joint;
use rigless::markers::MarkerFrame;
use rigless::rig::bind::Rig;
use rigless::solve::frame::{Solver, SolverParams};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn shared(rel: &str) -> Option<PathBuf> {
    common::shared_path(rel).map(|p| p.canonicalize().unwrap())
}

/// What [`track`] measured over a motion.
#[derive(Debug)]
struct Tracked {
    /// Most inverted tets in one frame, and the smallest signed-to-rest volume ratio of
    /// any tet, on the first frame (a cold start from rest to a far pose) ...
    cold_inverted_tets: usize,
    cold_min_volume_ratio: f64,
    /// ... and over every later frame (tracking, warm-started).
    inverted_tets: usize,
    min_volume_ratio: f64,
    joint_limit_violation_deg: f64,
    bone_length_error_mean: f64,
    marker_residual_mm_rms: f64,
    /// Vertices exactly at rest (within 1e-12 m) on the last frame, a posed one: a vertex
    /// no part of the control mesh carries.
    unmoved_vertices: usize,
}

/// Binds a character file and plays `seconds` of [`flex_pose`] through the solver.
fn track(toml_path: &Path, seconds: f64) -> Tracked {
    let loaded = load_character(toml_path).unwrap_or_else(|e| panic!("{e}"));
    let ch = &loaded.character;
    eprintln!("{}: cell {:?}", toml_path.display(), loaded.cell_choice);
    let t0 = Instant::now();
    let rig = Arc::new(Rig::bind(ch, &loaded.bind).unwrap_or_else(|e| panic!("{e}")));
    let s = &rig.stats;
    eprintln!(
        "{}: {} mesh vertices, {} control vertices, {} free parts, bound in {:.2} s",
        toml_path.display(),
        s.mesh_vertices,
        s.control_vertices,
        s.free_parts,
        t0.elapsed().as_secs_f64()
    );
    assert_eq!(s.mesh_vertices_inside, s.mesh_vertices, "{s:?}");
    assert!(s.green_max_rest_error_m < 1e-9 * rig.height_m, "{s:?}");
    let mut solver = Solver::new(Arc::clone(&rig), SolverParams::default());
    let mut out = vec![DVec3::ZERO; ch.vertices.len()];
    let mut markers = vec![DVec3::ZERO; ch.markers.len()];
    // No real asset here carries a skin rigless reads (MakeHuman's weights are not in
    // its files; the glTF samples' skins are not kept), so there is no skinned truth to
    // compare the mesh with: the truth is the markers, placed on the bones exactly, and
    // the residual is the measure. `skin_pose` poses the markers only.
    let mut skinned = Vec::new();
    let (mut inv, mut jlv, mut ble, mut res2) = (0usize, 0.0f64, 0.0, 0.0);
    let (mut min_ratio, mut cold) = (f64::INFINITY, (0, 0.0));
    let frames = (seconds * 120.0) as usize;
    for f in 0..frames {
        let t = f as f64 / 120.0;
        skin_pose(ch, &flex_pose(&ch.skeleton, t), &mut skinned, &mut markers);
        let frame = MarkerFrame::all_present(t, markers.clone());
        let r = solver.solve(&frame, Instant::now() + Duration::from_secs(10), &mut out);
        let (n_inv, ratio) = (
            rig.control.inverted_tets(solver.control_positions()),
            rig.control.min_volume_ratio(solver.control_positions()),
        );
        if f == 0 {
            cold = (n_inv, ratio);
        } else {
            inv = inv.max(n_inv);
            min_ratio = min_ratio.min(ratio);
        }
        jlv = jlv.max(r.joint_limit_violation_deg);
        ble += r.bone_length_error / frames as f64;
        res2 += r.marker_residual_rms_mm.powi(2) / frames as f64;
        assert!(
            out.iter().all(|v| v.is_finite()),
            "frame {f}: non-finite vertex"
        );
    }
    let unmoved_vertices = out
        .iter()
        .zip(&ch.vertices)
        .filter(|(a, b)| (**a - **b).length() < 1e-12)
        .count();
    let t = Tracked {
        unmoved_vertices,
        cold_inverted_tets: cold.0,
        cold_min_volume_ratio: cold.1,
        inverted_tets: inv,
        min_volume_ratio: min_ratio,
        joint_limit_violation_deg: jlv,
        bone_length_error_mean: ble,
        marker_residual_mm_rms: res2.sqrt(),
    };
    eprintln!("{}: {t:?}", toml_path.display());
    t
}

/// The checks both real meshes must pass. Inverted tets: none. Per-vertex ARAP alone
/// folds two tets of the WebXR hand at the index knuckle under flexion with sideways
/// swing (down to −0.34 of their rest volume); the solver's untangling pushes every tet
/// back to at least 2 % of its rest volume (`UNTANGLE_MIN_RATIO`), less the
/// second-order remainder of its linearised projection (1e-6; 3e-8 measured on the
/// MakeHuman body flexed through its role limits).
fn assert_tracked(t: &Tracked, residual_limit_mm: f64) {
    assert!(
        t.cold_inverted_tets == 0 && t.cold_min_volume_ratio > 0.0,
        "{t:?}"
    );
    assert!(
        t.inverted_tets == 0 && t.min_volume_ratio > 0.02 - 1e-6,
        "{t:?}"
    );
    assert!(t.joint_limit_violation_deg <= 0.5, "{t:?}");
    assert!(t.bone_length_error_mean <= 0.005, "{t:?}");
    assert!(t.marker_residual_mm_rms <= residual_limit_mm, "{t:?}");
    assert_eq!(t.unmoved_vertices, 0, "{t:?}");
}

/// The WebXR right hand's character file (`bench::assets::webxr_hand_file`), written in
/// `dir`; `None` (skipped, with the reason printed) when the shared data is absent.
fn webxr_file(dir: &Path, limits: bool) -> Option<PathBuf> {
    let glb = shared("meshes/webxr-generic-hand/right.glb")?;
    let data = glb.ancestors().nth(3).expect("data folder");
    webxr_hand_file(data, dir, limits).expect("WebXR hand file")
}

#[test]
fn webxr_hand_bakes_and_tracks() {
    let dir = tempfile::tempdir().unwrap();
    let Some(path) = webxr_file(dir.path(), true) else {
        return;
    };
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    // Sizes from ../shared/data/README.md: the file's own vertex count is kept.
    assert_eq!(loaded.character.vertices.len(), 1_360);
    assert_eq!(loaded.character.triangles.len(), 2_314);
    assert_eq!(loaded.character.skeleton.len(), 25);
    assert_tracked(&track(&path, 2.0), 2.0);
}

/// With no hand-written limit, the WebXR hand's joints get their roles from WebXR's
/// names (the side unknown: the palm is found from the fingers' curl at rest) and the
/// roles' default limits, and it tracks as well as with the hand-written ones.
#[test]
fn webxr_hand_binds_with_the_limits_of_its_roles() {
    let dir = tempfile::tempdir().unwrap();
    let Some(path) = webxr_file(dir.path(), false) else {
        return;
    };
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    let r = &loaded.roles;
    eprintln!("roles: {r}");
    // The wrist, 5 metacarpals, 14 phalanges; the 5 tips need none.
    assert_eq!(r.with_role, 20, "{r}");
    assert!(r.without.is_empty(), "{r}");
    assert_eq!(r.ends_without, 5, "{r}");
    let sk = &loaded.character.skeleton;
    let limited = sk.joints.iter().filter(|j| j.limits.is_some()).count();
    assert_eq!(
        limited, 20,
        "every joint with a role and children is limited"
    );
    assert_tracked(&track(&path, 2.0), 2.0);
}

/// The roles of MakeHuman's own 163-bone skeleton (`default.mhskel`, by its bone names
/// and parents): every limb and finger bone of both sides, and the face's, tongue's and
/// helper bones left without one.
#[test]
fn makehuman_skeleton_roles() {
    let Some(skel) = shared("meshes/makehuman/default.mhskel") else {
        return;
    };
    let mh: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(skel).unwrap()).unwrap();
    let bones = mh["bones"].as_object().unwrap();
    // Parents first: repeat passes over the bones until each is placed.
    let mut order: Vec<String> = Vec::new();
    while order.len() < bones.len() {
        for (name, b) in bones {
            let placed = |n: &str| order.iter().any(|o| o == n);
            let parent_placed = b["parent"].as_str().is_none_or(placed);
            if !placed(name) && parent_placed {
                order.push(name.clone());
            }
        }
    }
    let joints: Vec<Joint> = order
        .iter()
        .enumerate()
        .map(|(i, name)| Joint {
            name: name.clone(),
            parent: bones[name]["parent"]
                .as_str()
                .map(|p| order.iter().position(|o| o == p).unwrap()),
            rest: DVec3::new(0.0, i as f64, 0.0),
            limits: None,
            bend_axis: DVec3::X,
        })
        .collect();
    assert_eq!(joints.len(), 163);
    let roles = recognise(&joints, &[]);
    let s = summary(&joints, &roles);
    eprintln!("{s}");
    let has = |role: &str| s.found.iter().any(|(n, _)| n == role);
    for side in ["left", "right"] {
        for part in [
            "Shoulder",
            "UpperArm",
            "LowerArm",
            "Hand",
            "UpperLeg",
            "LowerLeg",
            "Foot",
            "Toes",
            "ThumbMetacarpal",
            "ThumbProximal",
            "ThumbDistal",
        ] {
            assert!(has(&format!("{side}{part}")), "{side}{part}: {s}");
        }
        for digit in ["Index", "Middle", "Ring", "Little"] {
            for seg in ["Metacarpal", "Proximal", "Intermediate", "Distal"] {
                assert!(
                    has(&format!("{side}{digit}{seg}")),
                    "{side}{digit}{seg}: {s}"
                );
            }
        }
    }
    for role in ["hips", "spine", "neck", "head"] {
        assert!(has(role), "{role}: {s}");
    }
    for free in ["jaw", "eye.L", "tongue01", "breast.R", "levator03.L"] {
        let i = joints.iter().position(|j| j.name == free).unwrap();
        assert_eq!(roles[i], None, "{free}");
    }
}

/// Checks a character's parts against its mesh: their triangle ranges follow each other
/// and cover every triangle once, and each part's triangles use only vertices of its
/// vertex range. Returns the names.
fn check_parts(ch: &rigless::character::Character) -> Vec<&str> {
    let mut next = 0;
    for p in &ch.parts {
        assert_eq!(p.first_triangle, next, "{p:?}");
        next += p.triangle_count;
        let vertices = p.first_vertex..p.first_vertex + p.vertex_count;
        let tris = &ch.triangles[p.first_triangle as usize..next as usize];
        assert!(tris.iter().flatten().all(|v| vertices.contains(v)), "{p:?}");
    }
    assert_eq!(next as usize, ch.triangles.len());
    ch.parts.iter().map(|p| p.name.as_str()).collect()
}

/// The MakeHuman character file for the mesh groups `groups` (empty: every group) in
/// `dir` ([`rigless::bench::assets::makehuman_file`]); `None` (the reason printed) when
/// the shared data is absent.
fn makehuman_file(dir: &Path, groups: &[&str]) -> Option<PathBuf> {
    shared("meshes/makehuman/default.mhskel")?;
    let data = shared("")?;
    Some(
        rigless::bench::assets::makehuman_file(&data, groups, dir)
            .unwrap_or_else(|e| panic!("{e}"))
            .expect("MakeHuman files present"),
    )
}

/// The MakeHuman body's marker residual bound, mm RMS: measured 0.08 (the body group)
/// and 0.12 (every part); the solve has no deadline here, so it is the same on every
/// machine up to libm's rounding, and twice the larger figure leaves room for that. A
/// marker bound to the wrong bone, or a solve stopped early, leaves millimetres.
const MAKEHUMAN_RESIDUAL_MM: f64 = 0.25;

#[test]
fn makehuman_body_bakes_and_tracks() {
    let dir = tempfile::tempdir().unwrap();
    let Some(path) = makehuman_file(dir.path(), &["body"]) else {
        return;
    };
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    // The body group alone: 13,380 vertices and 13,378 quads (README).
    assert_eq!(loaded.character.vertices.len(), 13_380);
    assert_eq!(loaded.character.triangles.len(), 2 * 13_378);
    let h = loaded
        .character
        .vertices
        .iter()
        .map(|v| v.y)
        .fold(f64::MIN, f64::max)
        - loaded
            .character
            .vertices
            .iter()
            .map(|v| v.y)
            .fold(f64::MAX, f64::min);
    assert!(
        (1.5..1.8).contains(&h),
        "height {h} m after the decimetre conversion"
    );
    let t = track(&path, 1.0);
    assert_tracked(&t, MAKEHUMAN_RESIDUAL_MM);
    assert_eq!(t.inverted_tets, 0, "{t:?}");
}

/// The MakeHuman mesh with every group: the body, the open `helper-tights` shell over
/// it, eyes, teeth, tongue, hair, skirt and the joint helpers inside (19,158 vertices in
/// all, open and overlapping parts) binds with warnings, not errors, moves every vertex,
/// and tracks within the body's limits.
#[test]
fn makehuman_with_all_its_parts_bakes_and_tracks() {
    let dir = tempfile::tempdir().unwrap();
    let Some(path) = makehuman_file(dir.path(), &[]) else {
        return;
    };
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    let said: Vec<String> = loaded.warnings.iter().map(ToString::to_string).collect();
    eprintln!(
        "{} vertices, warnings: {said:?}",
        loaded.character.vertices.len()
    );
    assert!(loaded.character.vertices.len() > 13_380);
    assert!(
        said.iter().any(|w| w.starts_with("the mesh is open")),
        "{said:?}"
    );
    let names: Vec<&str> = check_parts(&loaded.character);
    eprintln!("parts: {names:?}");
    for group in [
        "body",
        "helper-tights",
        "helper-l-eye",
        "helper-upper-teeth",
    ] {
        assert!(names.contains(&group), "{group}: {names:?}");
    }
    let t = track(&path, 1.0);
    assert_tracked(&t, MAKEHUMAN_RESIDUAL_MM);
}

/// A character file for a skinned glTF with one marker on every skin joint and no limits
/// ([`flex_pose`] then swings every joint with children by up to ±0.3 rad of bend).
fn marked_gltf(dir: &Path, glb: &Path) -> PathBuf {
    let bytes = std::fs::read(glb).unwrap();
    let mesh = rigless::character::mesh::parse_gltf(&bytes, glb.parent()).unwrap();
    let mut t = format!("[mesh]\npath = {glb:?}\n");
    for j in &mesh.skin_joints {
        let _ = writeln!(
            t,
            "\n[[markers]]\nname = \"m_{}\"\nbone = {:?}",
            j.name, j.name
        );
    }
    let path = dir.join("character.toml");
    std::fs::write(&path, t).unwrap();
    path
}

/// The Khronos samples CesiumMan (19 joints, 3,273 vertices) and RiggedSimple (4 joints)
/// bind with their defaults and track a motion of their skeletons with no inverted tet
/// and no vertex left unmoved.
#[test]
fn khronos_samples_bake_and_track() {
    for (rel, vertices) in [
        ("meshes/gltf-samples/CesiumMan.glb", 3_273),
        ("meshes/gltf-samples/RiggedSimple.glb", 960),
    ] {
        let Some(glb) = shared(rel) else {
            return;
        };
        let dir = tempfile::tempdir().unwrap();
        let path = marked_gltf(dir.path(), &glb);
        let loaded = load_character(&path).unwrap_or_else(|e| panic!("{rel}: {e}"));
        assert_eq!(loaded.character.vertices.len(), vertices, "{rel}");
        eprintln!("{rel}: roles {}", loaded.roles);
        let parts = check_parts(&loaded.character);
        eprintln!("{rel}: parts {parts:?}");
        assert_eq!(parts.len(), 1, "one skinned primitive: {parts:?}");
        if rel.contains("CesiumMan") {
            // Its limbs are named by a limb word and a number along the limb.
            let r = &loaded.roles;
            for role in [
                "hips",
                "leftUpperLeg",
                "rightLowerLeg",
                "leftFoot",
                "rightToes",
                "leftUpperArm",
                "rightLowerArm",
                "leftHand",
            ] {
                assert!(r.found.iter().any(|(n, _)| n == role), "{role}: {r}");
            }
            assert!(r.without.is_empty(), "{r}");
        }
        let t = track(&path, 1.0);
        assert!(
            t.inverted_tets == 0 && t.cold_inverted_tets == 0,
            "{rel}: {t:?}"
        );
        assert_eq!(t.unmoved_vertices, 0, "{rel}: {t:?}");
        assert!(t.bone_length_error_mean <= 0.005, "{rel}: {t:?}");
    }
}

/// `rigless bake --exercise` on the real assets: every joint to the limits of its role
/// and back, then all together. No inverted tet, every vertex moved, the limits kept
/// (0.5°, as in [`assert_tracked`]). Without the untangler's over-relaxation, the
/// MakeHuman mesh kept 3 tets folded where a thigh is pressed into the belly.
#[test]
fn real_assets_survive_the_exercise() {
    let dir = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    for rel in [
        "meshes/gltf-samples/CesiumMan.glb",
        "meshes/gltf-samples/RiggedSimple.glb",
    ] {
        let Some(glb) = shared(rel) else {
            return;
        };
        files.push(rigless::bench::assets::gltf_file(&glb, dir.path()).unwrap());
    }
    let Some(mh) = makehuman_file(dir.path(), &[]) else {
        return;
    };
    files.push(mh);
    for path in files {
        let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
        let r = exercise(
            &loaded.character,
            &loaded.bind,
            ExerciseOptions::default(),
            &mut |_| {},
        )
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        eprintln!("{}: {r:?}", path.display());
        assert_eq!(r.inverted_tets_max, 0, "{r:?}");
        assert_eq!(r.unmoved_vertices, 0, "{r:?}");
        assert!(r.joint_limit_violation_deg_max <= 0.5, "{r:?}");
    }
}

/// A limb of one joint gets an end joint where its skin ends: Kenney's mini character
/// (7 joints; each leg one joint from the hips down, the head one joint) reads with an
/// end under each of its five leaves, the legs as upper legs and the head as a head.
#[test]
fn one_joint_limbs_get_end_joints_where_their_skin_ends() {
    let Some(glb) = shared("meshes/real/kenney_mini_character_female_a.glb") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let path = rigless::bench::assets::gltf_file(&glb, dir.path()).unwrap();
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    let sk = &loaded.character.skeleton;
    let names: Vec<&str> = sk.joints.iter().map(|j| j.name.as_str()).collect();
    for leaf in ["leg-left", "leg-right", "arm-left", "arm-right", "head"] {
        let end = format!("{leaf}_end");
        let e = names
            .iter()
            .position(|n| *n == end)
            .unwrap_or_else(|| panic!("{end} in {names:?}"));
        let j = names.iter().position(|n| *n == leaf).unwrap();
        assert_eq!(sk.joints[e].parent, Some(j), "{end}");
    }
    // The legs' ends are at the soles (measured y = -0.016 m, the skin's lowest along
    // the leg), far below the hip joints (0.18 m).
    let foot = sk.joints[names.iter().position(|n| *n == "leg-left_end").unwrap()].rest;
    assert!(foot.y < 0.05, "{foot}");
    let role = |n: &str| loaded.joint_roles[names.iter().position(|x| *x == n).unwrap()];
    use rigless::character::roles::{Part, Side};
    assert_eq!(
        role("leg-left").map(|r| (r.part, r.side)),
        Some((Part::UpperLeg, Some(Side::Left)))
    );
    assert_eq!(role("head").map(|r| r.part), Some(Part::Head));
    assert_eq!(role("leg-left_end"), None);
}
