//! Character files end to end: the procedural hand and body written as OBJ + TOML load
//! back to the same characters, bake, cache, and track; bad files fail with errors that name
//! what is wrong.

use glam::DVec3;
use rigless::bench::characters::{demo_hand, hand_bind_params};
use rigless::character::bind_params::BindParams;
use rigless::character::demo::{body_bind_params, demo_body};
use rigless::character::file::{
    load_character, write_character_files, CharacterError, CharacterProblem, LoadedCharacter,
    MeshWarning, MAX_MARKERS,
};
use rigless::character::mesh::VertexAt;
use rigless::character::Character;
use rigless::markers::MarkerFrame;
use rigless::rig::bind::Rig;
use rigless::rig::cache;
use rigless::solve::frame::{Solver, SolverParams};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn write_hand(dir: &Path) -> std::path::PathBuf {
    write_character_files(&demo_hand(), Some(&hand_bind_params()), dir).expect("write hand")
}

/// Writes `written` with `bind` and checks that the file loads back as `ch`.
fn loads_back_as(written: &Character, ch: &Character, bind: &BindParams) -> LoadedCharacter {
    let dir = tempfile::tempdir().unwrap();
    let path = write_character_files(written, Some(bind), dir.path()).expect("write");
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    let back = &loaded.character;
    assert_eq!(back.vertices.len(), ch.vertices.len());
    assert_eq!(back.triangles, ch.triangles);
    // `{:?}` prints the shortest string that round-trips, so positions come back exactly.
    assert!(back.vertices.iter().zip(&ch.vertices).all(|(a, b)| a == b));
    assert_eq!(back.skeleton.len(), ch.skeleton.len());
    for (a, b) in back.skeleton.joints.iter().zip(&ch.skeleton.joints) {
        assert_eq!(
            (&a.name, a.parent, a.rest, a.limits),
            (&b.name, b.parent, b.rest, b.limits)
        );
        // Bend axes matter where there are limits (elsewhere they are only made
        // perpendicular to the bone on load).
        if a.limits.is_some() {
            assert!((a.bend_axis - b.bend_axis).length() < 1e-12, "{}", a.name);
        }
    }
    assert_eq!(back.markers.len(), ch.markers.len());
    for (a, b) in back.markers.iter().zip(&ch.markers) {
        assert_eq!((&a.name, a.joint), (&b.name, b.joint));
        assert!((a.rest - b.rest).length() < 1e-15);
    }
    assert_eq!(back.correspondences, ch.correspondences);
    assert_eq!(&loaded.bind, bind);
    loaded
}

/// One frame solved with rigs `a` and `b` of `ch`: every marker at rest moved by
/// `wiggle.0 · sin(wiggle.1 · y)`. Each side's iterations and mesh.
fn solve_both(
    ch: &Character,
    wiggle: (DVec3, f64),
    a: Rig,
    b: Rig,
) -> ((usize, Vec<DVec3>), (usize, Vec<DVec3>)) {
    let markers: Vec<DVec3> = ch
        .markers
        .iter()
        .map(|m| m.rest + wiggle.0 * (m.rest.y * wiggle.1).sin())
        .collect();
    let frame = MarkerFrame::all_present(0.0, markers);
    let far = Instant::now() + Duration::from_secs(60);
    let solve = |rig: Rig| {
        let mut out = vec![DVec3::ZERO; ch.vertices.len()];
        let r = Solver::new(Arc::new(rig), SolverParams::default()).solve(&frame, far, &mut out);
        (r.iterations, out)
    };
    (solve(a), solve(b))
}

#[test]
fn written_hand_loads_back_identically() {
    let hand = demo_hand();
    loads_back_as(&hand, &hand, &hand_bind_params());
}

/// `rigless export-character body` writes this: the file a studio's marker layout is
/// calibrated into. Loaded back, it binds to the procedural body's control mesh and
/// solves a frame to the same mesh (to rounding) as the procedural body does with its
/// bend axes made square to their bones, which loading a file does (the clavicles' and
/// hips' slant by up to 4°, and only theirs change).
#[test]
fn written_body_loads_back_and_solves_as_the_procedural_body() {
    let written = demo_body();
    let mut body = written.clone();
    assert!(body.skeleton.orthogonalize_bend_axes().is_empty());
    let squared: Vec<&str> = (body.skeleton.joints.iter().zip(&written.skeleton.joints))
        .filter(|(a, b)| (a.bend_axis - b.bend_axis).length() > 1e-12)
        .map(|(a, _)| a.name.as_str())
        .collect();
    assert_eq!(squared, ["clavicle_l", "hip_l", "clavicle_r", "hip_r"]);
    let loaded = loads_back_as(&written, &body, &body_bind_params());
    let a_rig = Rig::bind(&body, &body_bind_params()).unwrap();
    let b_rig = Rig::bind(&loaded.character, &loaded.bind).unwrap();
    assert_eq!(a_rig.control.positions, b_rig.control.positions);
    assert_eq!(a_rig.control.tets, b_rig.control.tets);
    let wiggle = (DVec3::new(0.01, -0.005, 0.008), 7.0);
    let ((ia, a), (ib, b)) = solve_both(&body, wiggle, a_rig, b_rig);
    // Markers are written as offsets from their bones and come back within 1e-15 m
    // (checked above), the squared axes within rounding; the solve, deterministic, carries
    // these through 4 iterations: 4e-16 m was measured, and 1e-12 m allows a thousand
    // times that while a real difference (a limit, an axis, a marker) moves the mesh by
    // far more.
    let worst = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (*x - *y).length())
        .fold(0.0, f64::max);
    assert_eq!(ia, ib);
    assert!(
        worst < 1e-12,
        "the written body solves differently: {worst:e} m"
    );
}

#[test]
fn bake_cache_round_trip_gives_the_same_solve() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_hand(dir.path());
    let loaded = load_character(&path).unwrap();
    assert!(matches!(
        cache::load(&path, loaded.inputs_hash),
        Err(cache::CacheMiss::Absent)
    ));
    let rig = Rig::bind(&loaded.character, &loaded.bind).unwrap();
    cache::store(&path, &rig, loaded.inputs_hash).unwrap();
    let (cached, source) = cache::load_or_bind(&path, &loaded, false, &mut |_, _| {})
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(matches!(source, cache::RigSource::Cache { .. }), "{source}");
    // A changed input invalidates the cache.
    assert!(matches!(
        cache::load(&path, loaded.inputs_hash ^ 1),
        Err(cache::CacheMiss::Stale)
    ));
    // Same solve, bit for bit, from the fresh and the cached rig.
    let wiggle = (DVec3::new(0.004, -0.002, 0.003), 20.0);
    let ((ia, a), (ib, b)) = solve_both(&loaded.character, wiggle, rig, cached);
    assert_eq!(ia, ib);
    assert_eq!(a, b, "cached rig solves differently");
}

#[test]
fn corrupt_cache_files_are_misses_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_hand(dir.path());
    let loaded = load_character(&path).unwrap();
    let rig = Rig::bind(&loaded.character, &loaded.bind).unwrap();
    let bytes = cache::encode(&rig, loaded.inputs_hash).unwrap();
    assert!(cache::decode(&bytes, loaded.inputs_hash).is_ok());
    for cut in [0, 11, 39, 40, bytes.len() / 2, bytes.len() - 1] {
        assert!(
            cache::decode(&bytes[..cut], loaded.inputs_hash).is_err(),
            "cut at {cut}"
        );
    }
    let mut flipped = bytes.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x40;
    assert!(matches!(
        cache::decode(&flipped, loaded.inputs_hash),
        Err(cache::CacheMiss::Corrupt)
    ));
    // A length field claiming more than the file holds is caught before decoding.
    let mut long = bytes.clone();
    long[24..32].copy_from_slice(&u64::MAX.to_le_bytes());
    assert!(cache::decode(&long, loaded.inputs_hash).is_err());
}

/// A cache file with a valid header, key and checksum but crafted contents (as anyone who
/// can write next to the character file could make) is a miss with its reason, never a
/// panic or a rig with out-of-range indices: the file only supplies coefficients, checked
/// against the control mesh rebuilt from the character.
#[test]
fn crafted_cache_contents_are_misses_with_their_reason() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_hand(dir.path());
    let loaded = load_character(&path).unwrap();
    let rig = Rig::bind(&loaded.character, &loaded.bind).unwrap();
    let good = rig.stored_green();
    let n = good.coefficients.phi.len();
    let mut other_key = good.clone();
    other_key.lattice_key ^= 1;
    let mut short = good.clone();
    short.coefficients.phi.truncate(n / 2);
    let mut nan = good.clone();
    nan.coefficients.psi[7][2] = f64::NAN;
    let mut long = good.clone();
    long.coefficients
        .psi
        .extend(std::iter::repeat_n([0.0; 4], 100_000));
    for (stored, want) in [
        (other_key, "another control mesh"),
        (
            short,
            &*format!("{} φ and {n} ψ rows for {n} vertices", n / 2),
        ),
        (nan, "vertex 7 are not finite"),
        (long, &*format!("{n} φ and {} ψ rows", n + 100_000)),
    ] {
        let bytes = cache::encode_stored(&stored, loaded.inputs_hash).unwrap();
        std::fs::write(cache::cache_path(&path), bytes).unwrap();
        let (fresh, source) = cache::load_or_bind(&path, &loaded, false, &mut |_, _| {}).unwrap();
        let said = source.to_string();
        assert!(said.contains(want), "{said}");
        assert_eq!(fresh.stats.mesh_vertices, n);
    }
}

/// Writes a variant of the hand's files with `edit` applied to the TOML text: the error.
fn broken(edit: impl Fn(&str) -> String, obj_edit: impl Fn(&str) -> String) -> String {
    outcome(edit, obj_edit).expect_err("the broken character loaded and bound")
}

/// Writes a variant of the hand's files with `edit` applied to the TOML text, loads and
/// binds it.
fn outcome(edit: impl Fn(&str) -> String, obj_edit: impl Fn(&str) -> String) -> Result<(), String> {
    let dir = tempfile::tempdir().unwrap();
    let path = write_hand(dir.path());
    let text = std::fs::read_to_string(&path).unwrap();
    std::fs::write(&path, edit(&text)).unwrap();
    let obj = path.with_extension("obj");
    let o = std::fs::read_to_string(&obj).unwrap();
    std::fs::write(&obj, obj_edit(&o)).unwrap();
    let loaded = load_character(&path).map_err(|e| e.to_string())?;
    Rig::bind(&loaded.character, &loaded.bind)
        .map(|_| ())
        .map_err(|e| e.to_string())
}

fn same(s: &str) -> String {
    s.to_string()
}

#[test]
fn bad_files_are_clear_errors() {
    // A NaN vertex names its line.
    let e = broken(same, |o| o.replacen("\nv ", "\nv NaN ", 1));
    assert!(e.contains("line 3") && e.contains("not finite"), "{e}");
    // A marker far from the mesh.
    let e = broken(
        |t| {
            t.replacen(
                "bone = \"thumb_3\"\noffset_m = [",
                "bone = \"thumb_3\"\noffset_m = [0.5, ",
                1,
            )
            .replacen("[0.5, ", "[0.5, 0.0, 0.0]\n#", 1)
        },
        same,
    );
    assert!(
        e.contains("marker \"thumb_nail\"") && e.contains("from the control mesh"),
        "{e}"
    );
    // Unknown parent, unknown bone, duplicate marker and an unknown key, all at once.
    let e = broken(
        |t| {
            t.replacen("parent = \"index_1\"", "parent = \"index_9\"", 1)
                .replacen("bone = \"middle_3\"", "bone = \"middle_7\"", 1)
                .replacen("name = \"ring_nail\"", "name = \"index_nail\"", 1)
        },
        same,
    );
    for want in [
        "parent \"index_9\" is not listed before it",
        "no joint is named \"middle_7\"",
        "marker name \"index_nail\" is used twice",
    ] {
        assert!(e.contains(want), "missing {want:?} in:\n{e}");
    }
    let e = broken(|t| t.replacen("[mesh]\n", "[mesh]\nscale = 0\n", 1), same);
    assert!(
        e.contains("mesh.scale must be 0.001 to 1000, got 0.0"),
        "{e}"
    );
    let e = broken(|t| t.replacen("[mesh]\n", "[mesh]\nscaling = 2\n", 1), same);
    assert!(
        e.contains("unknown field `scaling`") && e.contains("line"),
        "{e}"
    );
    // A joint with no bone: a skeleton of one joint.
    let e = broken(
        |t| {
            let keep: Vec<&str> = t.split("[[skeleton.joints]]").collect();
            let mut out = keep[0].to_string();
            out.push_str("[[skeleton.joints]]");
            out.push_str(keep[1]);
            out.push_str(
                &t[t.find("[[markers]]").unwrap()..]
                    .replace("bone = \"thumb_3\"", "bone = \"wrist\"")
                    .replace("bone = \"index_3\"", "bone = \"wrist\"")
                    .replace("bone = \"middle_3\"", "bone = \"wrist\"")
                    .replace("bone = \"ring_3\"", "bone = \"wrist\"")
                    .replace("bone = \"pinky_3\"", "bone = \"wrist\""),
            );
            out
        },
        same,
    );
    assert!(e.contains("has no bone"), "{e}");
}

/// `[[correspondences]]` give the harmonic method a joint's triangles: they load by joint
/// name, write back, and reach the solver's rig; a bad one names its joint and problem.
#[test]
fn correspondences_load_write_back_and_bad_ones_are_named() {
    use rigless::character::Correspondence;
    let dir = tempfile::tempdir().unwrap();
    let path = write_hand(dir.path());
    let mut text = std::fs::read_to_string(&path).unwrap();
    text.push_str("\n[[correspondences]]\njoint = \"index_1\"\ntriangles = [0, 1, 2]\n");
    std::fs::write(&path, &text).unwrap();
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    let ch = &loaded.character;
    let j = ch
        .skeleton
        .joints
        .iter()
        .position(|x| x.name == "index_1")
        .unwrap();
    let want = vec![Correspondence {
        joint: j,
        triangles: vec![0, 1, 2],
    }];
    assert_eq!(ch.correspondences, want);
    // Written out again, it reads back the same.
    let again = write_character_files(ch, Some(&loaded.bind), &dir.path().join("again")).unwrap();
    assert_eq!(
        load_character(&again).unwrap().character.correspondences,
        want
    );
    // Unknown joint, a triangle past the end and an empty list, all at once.
    let e = broken(
        |t| {
            format!(
                "{t}\n[[correspondences]]\njoint = \"index_9\"\ntriangles = [1]\n\n[[correspondences]]\njoint = \"wrist\"\ntriangles = [99999999]\n\n[[correspondences]]\njoint = \"thumb_1\"\ntriangles = []\n"
            )
        },
        same,
    );
    for want in [
        "correspondences[0] (joint \"index_9\"): no joint is named \"index_9\"",
        "correspondences[1] (joint \"wrist\"): triangle 99999999 is out of range",
        "correspondences[2] (joint \"thumb_1\"): no triangles",
    ] {
        assert!(e.contains(want), "missing {want:?} in:\n{e}");
    }
}

/// An open mesh (the last triangle dropped) is no longer refused: it loads with a
/// warning naming the hole and binds (the inside is the winding number's).
#[test]
fn an_open_mesh_binds_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_hand(dir.path());
    let obj = path.with_extension("obj");
    let o = std::fs::read_to_string(&obj).unwrap();
    let mut lines: Vec<&str> = o.lines().collect();
    lines.pop();
    std::fs::write(&obj, lines.join("\n")).unwrap();
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    let said: Vec<String> = loaded.warnings.iter().map(ToString::to_string).collect();
    assert_eq!(said.len(), 1, "{said:?}");
    assert!(
        said[0].starts_with("the mesh is open: 3 edges border a hole"),
        "{said:?}"
    );
    let rig = Rig::bind(&loaded.character, &loaded.bind).unwrap();
    assert_eq!(rig.stats.mesh_vertices, loaded.character.vertices.len());
}

/// Replaces the value of `key = ...` (one line) in `text`.
fn set_key(text: &str, key: &str, value: &str) -> String {
    let start = text.find(&format!("\n{key} = ")).expect(key) + 1;
    let end = start + text[start..].find('\n').unwrap();
    format!("{}{key} = {value}{}", &text[..start], &text[end..])
}

/// Settings and meshes that used to hang the bind or take the machine's memory are
/// refused, each with the setting or size at fault (each case returns in well under a
/// second; a regression shows as a hang or an abort).
#[test]
fn settings_and_meshes_that_would_hang_the_bind_are_refused() {
    // skeleton_step_m 1e-300: the skeleton's samples grew until memory ran out.
    let e = broken(|t| set_key(t, "skeleton_step_m", "1e-300"), same);
    assert!(
        e.contains("bind.skeleton_step_m 1e-300 is below 1/100 of the cell size"),
        "{e}"
    );
    // A weld tolerance that is no tolerance: NaN, negative, or the whole hand.
    for v in ["nan", "-1.0", "1e9"] {
        let e = broken(
            |t| {
                t.replacen(
                    "up = \"y\"\n",
                    &format!("up = \"y\"\nweld_tolerance_m = {v}\n"),
                    1,
                )
            },
            same,
        );
        assert!(e.contains("mesh.weld_tolerance_m"), "{v}: {e}");
        assert!(
            !e.contains("the mesh is"),
            "{v}: no misleading topology error: {e}"
        );
    }
    // A marker 5 m away with max_marker_distance_m 1e9: the search for its tet looped
    // over (2·1e9/cell)³ cells; now it is bounded by the grid.
    let r = outcome(
        |t| {
            set_key(t, "max_marker_distance_m", "1e9").replacen(
                "bone = \"thumb_3\"\noffset_m = [",
                "bone = \"thumb_3\"\noffset_m = [5.0, 0.0, 0.0]\n#",
                1,
            )
        },
        same,
    );
    // Within the limit the user set, the marker binds to the nearest tet of its bone.
    assert_eq!(r, Ok(()));
    // 1,100 more listed joints: refused at once (the checks on names and parents were
    // quadratic in their number).
    let e = broken(
        |t| {
            let mut t = t.to_string();
            for k in 0..1100 {
                t += &format!(
                    "\n[[skeleton.joints]]\nname = \"x{k}\"\nrest_m = [0.0, {k}.0, 0.0]\n"
                );
            }
            t
        },
        same,
    );
    assert!(e.contains("[[skeleton.joints]] (at most 1024)"), "{e}");
}

/// A closed box 1000 m by 1 cm by 1000 m used to get a default cell from its height (1 cm:
/// 3e14 cells, a hang and an abort); a 1000 m cube with the smallest cell the file
/// accepts (1/400 of its size) still asks for 6e7 cells: the bind refuses it before
/// allocating, with the size.
#[test]
fn a_lattice_too_large_to_build_is_refused_with_its_size() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_hand(dir.path());
    let obj = "v 0 0 0\nv 1000 0 0\nv 1000 1000 0\nv 0 1000 0\nv 0 0 1000\nv 1000 0 1000\n\
               v 1000 1000 1000\nv 0 1000 1000\nf 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\n\
               f 1 2 6\nf 1 6 5\nf 4 8 7\nf 4 7 3\nf 1 5 8\nf 1 8 4\nf 2 3 7\nf 2 7 6\n";
    std::fs::write(path.with_extension("obj"), obj).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    // Keep the character's own skeleton and markers; the smallest cell accepted.
    let text = set_key(&text, "cell_size_m", "2.5");
    let text = set_key(&text, "skeleton_step_m", "2.5");
    let text = set_key(&text, "max_marker_distance_m", "2000.0");
    std::fs::write(&path, text).unwrap();
    let e = match load_character(&path) {
        Ok(loaded) => Rig::bind(&loaded.character, &loaded.bind)
            .err()
            .expect("no lattice of 6e7 cells")
            .to_string(),
        Err(e) => e.to_string(),
    };
    assert!(e.contains("cells") && e.contains("cell_size_m"), "{e}");
}

/// A mesh path naming a device is refused before anything is read (`/dev/zero` used to be
/// read until memory ran out).
#[test]
fn a_mesh_path_that_is_not_a_regular_file_is_refused() {
    let e = broken(
        |t| t.replacen("path = \"", "path = \"/dev/zero\"\n# \"", 1),
        same,
    );
    assert!(
        e.contains("/dev/zero") && e.contains("not a regular file"),
        "{e}"
    );
}

/// A character declared with the wrong up axis lies down: the height (Y extent) is a
/// fraction of its length. The default cell no longer follows the height (which gave a
/// 370-vertex figure 74,110 control vertices): it follows the shortest marked bone
/// within a control-mesh window, the summary says so, and the posture is warned about.
#[test]
fn a_character_lying_down_gets_a_sensible_default_cell_and_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_hand(dir.path());
    let text = std::fs::read_to_string(&path).unwrap();
    let text: String = text
        .replacen("up = \"y\"", "up = \"z\"", 1)
        .lines()
        .filter(|l| {
            !l.starts_with("cell_size_m")
                && !l.starts_with("skeleton_step_m")
                && !l.starts_with("max_marker_distance_m")
        })
        // Offsets are in the world frame: put the markers on their joints, which turn
        // with the mesh.
        .map(|l| {
            if l.starts_with("offset_m") {
                "offset_m = [0.0, 0.0, 0.0]".to_string()
            } else if let Some(r) = l.strip_prefix("rest_m = [") {
                // Joint rests are in the world frame too: turn them as the mesh turns,
                // (x, y, z) → (x, z, −y).
                let v: Vec<f64> = r
                    .trim_end_matches(']')
                    .split(',')
                    .map(|x| x.trim().parse().unwrap())
                    .collect();
                format!("rest_m = [{:?}, {:?}, {:?}]", v[0], v[2], -v[1])
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    std::fs::write(&path, text).unwrap();
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    let said: Vec<String> = loaded.warnings.iter().map(ToString::to_string).collect();
    assert!(
        said.iter()
            .any(|w| w.contains("looks lying down for up = \"z\"")),
        "{said:?}"
    );
    let choice = loaded.cell_choice.as_ref().expect("a default cell");
    assert!(
        choice.reason.contains("shortest bone carrying a marker"),
        "{choice:?}"
    );
    let rig = Rig::bind(&loaded.character, &loaded.bind).unwrap();
    // The window's top (3,000) with the estimate's 30 % slack.
    let n = rig.stats.control_vertices;
    assert!(
        (300..=3900).contains(&n),
        "{n} control vertices with {choice:?}"
    );
    println!("{n} control vertices: {choice:?}");
}

/// The cache key covers what a glTF's external buffer holds, not only the `.gltf` text:
/// editing `mesh.bin` alone makes the cache stale (it used to be taken as current).
#[test]
fn editing_a_gltf_buffer_beside_it_changes_the_cache_key() {
    let dir = tempfile::tempdir().unwrap();
    // A tetrahedron: 4 float positions (48 bytes), then 12 u16 indices (24 bytes).
    let write_bin = |apex_y: f32| {
        let mut b = Vec::new();
        for p in [
            [0f32, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.3, apex_y, 0.3],
        ] {
            for c in p {
                b.extend(c.to_le_bytes());
            }
        }
        for i in [0u16, 2, 1, 0, 1, 3, 1, 2, 3, 0, 3, 2] {
            b.extend(i.to_le_bytes());
        }
        std::fs::write(dir.path().join("mesh.bin"), b).unwrap();
    };
    let gltf = r#"{"asset":{"version":"2.0"},"buffers":[{"uri":"mesh.bin","byteLength":72}],
"bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":48},{"buffer":0,"byteOffset":48,"byteLength":24}],
"accessors":[{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,1]},
{"bufferView":1,"componentType":5123,"count":12,"type":"SCALAR"}],
"meshes":[{"primitives":[{"attributes":{"POSITION":0},"indices":1}]}],
"nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}],"scene":0}"#;
    std::fs::write(dir.path().join("mesh.gltf"), gltf).unwrap();
    let toml = "[mesh]\npath = \"mesh.gltf\"\n\n[[skeleton.joints]]\nname = \"a\"\nrest_m = [0.3, 0.1, 0.3]\n\n\
                [[skeleton.joints]]\nname = \"b\"\nparent = \"a\"\nrest_m = [0.3, 0.4, 0.3]\n\n\
                [[markers]]\nname = \"m\"\nbone = \"a\"\n";
    let path = dir.path().join("tet.toml");
    std::fs::write(&path, toml).unwrap();
    write_bin(1.0);
    let first = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    write_bin(1.2);
    let second = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_ne!(
        first.character.vertices[3], second.character.vertices[3],
        "the edit reached the mesh"
    );
    assert_ne!(first.inputs_hash, second.inputs_hash);
}

/// A character binds with no marker layout; markers added later reuse the cached Green
/// coordinates (only the marker rows and the factorization are rebuilt), and a change
/// that moves the control mesh does not.
#[test]
fn markers_can_come_after_the_bake() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_hand(dir.path());
    let full = std::fs::read_to_string(&path).unwrap();
    let first_marker = full.find("[[markers]]").unwrap();
    let bind_at = full.find("[bind]").unwrap();
    // The same file without its markers (the [bind] section kept).
    let bare = if bind_at > first_marker {
        format!("{}{}", &full[..first_marker], &full[bind_at..])
    } else {
        full[..first_marker].to_string()
    };
    std::fs::write(&path, &bare).unwrap();
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    assert!(loaded.character.markers.is_empty());
    let (rig, source) = cache::load_or_bind(&path, &loaded, false, &mut |_, _| {}).unwrap();
    assert!(matches!(source, cache::RigSource::Bound { .. }), "{source}");
    assert_eq!(rig.n_markers, 0);
    // The markers come: the stored coordinates are used.
    std::fs::write(&path, &full).unwrap();
    let loaded = load_character(&path).unwrap();
    let (rig, source) = cache::load_or_bind(&path, &loaded, false, &mut |_, _| {}).unwrap();
    assert!(matches!(source, cache::RigSource::Cache { .. }), "{source}");
    assert_eq!(rig.n_markers, loaded.character.markers.len());
    // A different cell: another control mesh, so the coordinates are computed again.
    std::fs::write(&path, set_key(&full, "cell_size_m", "0.016")).unwrap();
    let loaded = load_character(&path).unwrap();
    let (_, source) = cache::load_or_bind(&path, &loaded, false, &mut |_, _| {}).unwrap();
    assert!(
        source.to_string().contains("another control mesh"),
        "{source}"
    );
}

/// A layout found for a file that sets no cell size binds with the cell `bake` would
/// choose for it once written: `bind_for` chooses the default cell again for the new
/// markers (it follows the shortest bone that carries one; without markers the file
/// gets another).
#[test]
fn a_new_layout_gets_the_cell_its_file_would_choose() {
    let dir = tempfile::tempdir().unwrap();
    let hand = demo_hand();
    // No bind settings: the default cell, chosen for the file's markers.
    let with = write_character_files(&hand, None, &dir.path().join("with")).unwrap();
    let bare = {
        let mut h = hand.clone();
        h.markers.clear();
        write_character_files(&h, None, &dir.path().join("bare")).unwrap()
    };
    let with = load_character(&with).unwrap_or_else(|e| panic!("{e}"));
    let bare = load_character(&bare).unwrap_or_else(|e| panic!("{e}"));
    assert!(bare.cell_choice.is_some() && with.cell_choice.is_some());
    let again = bare.bind_for(&with.character.markers);
    // The same computation on the same mesh, skeleton and markers: equal to round-off.
    assert!(
        (again.cell_size_m - with.bind.cell_size_m).abs() <= 1e-12,
        "{again:?} against {:?}",
        with.bind
    );
    assert!(
        (again.skeleton_step_m - with.bind.skeleton_step_m).abs() <= 1e-12,
        "{again:?}"
    );
    // Measured: 15.1 mm for the hand's layout, 9.5 mm without markers.
    assert!(
        (again.cell_size_m - bare.bind.cell_size_m).abs() > 1e-3,
        "the layout changes the cell: {} against {}",
        again.cell_size_m,
        bare.bind.cell_size_m
    );
}

/// The path from a studio's take to a character file for the body, through the binary:
/// `calibrate body TAKE --write` says how to get a file, `export-character body DIR`
/// writes one, and `calibrate DIR/body.toml TAKE --write` stores the layout in it (the
/// bundled range of motion: all 36 labels, the actor's scale 1 within 1 %, as the
/// calibration tests measure it on the procedural body).
#[test]
fn export_character_body_gives_calibrate_a_file_to_write() {
    let rigless = env!("CARGO_BIN_EXE_rigless");
    let take = concat!(env!("CARGO_MANIFEST_DIR"), "/replay/body_rom.c3d");
    let dir = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let out = std::process::Command::new(rigless)
            .args(args)
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout).into_owned()
            + &String::from_utf8_lossy(&out.stderr);
        (out.status.success(), text)
    };
    let (ok, text) = run(&["calibrate", "body", take, "--write"]);
    assert!(
        !ok && text.contains("rigless export-character body DIR"),
        "{text}"
    );
    let out = dir.path().join("mine");
    let (ok, text) = run(&["export-character", "body", out.to_str().unwrap()]);
    assert!(ok, "{text}");
    let file = out.join("body.toml");
    let (ok, text) = run(&["calibrate", file.to_str().unwrap(), take, "--write"]);
    assert!(ok, "{text}");
    let loaded = load_character(&file).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(loaded.character.markers.len(), 36);
    let scale = loaded.marker_scale;
    assert!((scale - 1.0).abs() < 0.01, "marker_scale {scale}");
    // `export-hand DIR` is `export-character hand DIR`.
    let (ok, text) = run(&["export-hand", out.to_str().unwrap()]);
    assert!(ok && out.join("hand.toml").is_file(), "{text}");
}

/// A mesh, a recording or any binary file given where a character file goes is named for
/// what it is, with the way to a character file, not reported as bad TOML or bad UTF-8.
#[test]
fn a_mesh_or_a_take_given_as_the_character_says_what_to_do() {
    let dir = tempfile::tempdir().unwrap();
    let glb = dir.path().join("CesiumMan.glb");
    // The glTF binary header: not UTF-8 from byte 8 on.
    std::fs::write(&glb, b"glTF\x02\x00\x00\x00\xa0\x86\x01\x00").unwrap();
    let take = dir.path().join("take.c3d");
    std::fs::write(&take, [2u8, 0x50, 0xff, 0xfe]).unwrap();
    let fbx = dir.path().join("rig.FBX");
    std::fs::write(&fbx, b"Kaydara FBX Binary  \x00").unwrap();
    let binary = dir.path().join("stage.toml");
    std::fs::write(&binary, b"name = \"x\"\n\xff\xfe").unwrap();
    let err = |p: &Path| load_character(p).expect_err("refused").to_string();
    let e = err(&glb);
    assert!(
        e.contains("a mesh, not a character file") && e.contains("path = \"CesiumMan.glb\""),
        "{e}"
    );
    let e = err(&take);
    assert!(e.contains("a recording, not a character file"), "{e}");
    let e = err(&fbx);
    assert!(e.contains("export it as glTF 2.0 (.glb) or OBJ"), "{e}");
    let e = err(&binary);
    assert!(e.contains("not UTF-8 text (byte 11 starts"), "{e}");
}

/// A tetrahedron's corners (1 m tall) and faces, outward.
const TET: [[f64; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0],
    [0.3, 1.0, 0.3],
];
const TET_FACES: [[u16; 3]; 4] = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]];

/// An OBJ of a tetrahedron with `corners`.
fn tet_obj(corners: [[f64; 3]; 4]) -> Vec<u8> {
    let mut o = String::new();
    for [x, y, z] in corners {
        o += &format!("v {x:?} {y:?} {z:?}\n");
    }
    for f in TET_FACES {
        o += &format!("f {} {} {}\n", f[0] + 1, f[1] + 1, f[2] + 1);
    }
    o.into_bytes()
}

/// A glTF of tetrahedra with `corners`, one mesh per node, each node with its `scale`
/// and name, their buffer `NAME.bin` in `dir` (NAME the first node's).
fn tet_gltf(dir: &Path, nodes: &[(&str, [[f64; 3]; 4], f64)]) -> Vec<u8> {
    let bin_name = format!("{}.bin", nodes[0].0);
    let mut bin = Vec::new();
    let (mut views, mut accessors, mut meshes, mut json_nodes) = (vec![], vec![], vec![], vec![]);
    for (k, (name, corners, scale)) in nodes.iter().enumerate() {
        let at = bin.len();
        for c in corners.iter().flatten() {
            bin.extend((*c as f32).to_le_bytes());
        }
        for i in TET_FACES.iter().flatten() {
            bin.extend(i.to_le_bytes());
        }
        views.push(format!(
            r#"{{"buffer":0,"byteOffset":{at},"byteLength":48}}"#
        ));
        views.push(format!(
            r#"{{"buffer":0,"byteOffset":{},"byteLength":24}}"#,
            at + 48
        ));
        accessors.push(format!(
            r#"{{"bufferView":{},"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,1]}}"#,
            2 * k
        ));
        accessors.push(format!(
            r#"{{"bufferView":{},"componentType":5123,"count":12,"type":"SCALAR"}}"#,
            2 * k + 1
        ));
        meshes.push(format!(
            r#"{{"primitives":[{{"attributes":{{"POSITION":{}}},"indices":{}}}]}}"#,
            2 * k,
            2 * k + 1
        ));
        json_nodes.push(format!(
            r#"{{"name":"{name}","mesh":{k},"scale":[{scale:?},{scale:?},{scale:?}]}}"#
        ));
    }
    std::fs::write(dir.join(&bin_name), &bin).unwrap();
    format!(
        r#"{{"asset":{{"version":"2.0"}},"buffers":[{{"uri":"{bin_name}","byteLength":{}}}],"bufferViews":[{}],"accessors":[{}],"meshes":[{}],"nodes":[{}]}}"#,
        bin.len(),
        views.join(","),
        accessors.join(","),
        meshes.join(","),
        json_nodes.join(",")
    )
    .into_bytes()
}

/// A character file in `dir` for the mesh `mesh_name` (written with `mesh`; the file is
/// named as the mesh, `.toml`): two listed joints up the tetrahedron, a marker on the
/// first bone, then `extra`.
fn tet_character(dir: &Path, mesh_name: &str, mesh: &[u8], extra: &str) -> PathBuf {
    std::fs::write(dir.join(mesh_name), mesh).unwrap();
    let toml = format!(
        "[mesh]\npath = \"{mesh_name}\"\n\n[[skeleton.joints]]\nname = \"a\"\nrest_m = [0.3, 0.1, 0.3]\n\n\
         [[skeleton.joints]]\nname = \"b\"\nparent = \"a\"\nrest_m = [0.3, 0.4, 0.3]\n\n\
         [[markers]]\nname = \"m\"\nbone = \"a\"\n\n{extra}"
    );
    let path = dir.join(mesh_name).with_extension("toml");
    std::fs::write(&path, toml).unwrap();
    path
}

/// The problems of a character file that loads with problems.
fn problems_of(path: &Path) -> Vec<CharacterProblem> {
    match load_character(path) {
        Err(CharacterError::Invalid { problems, .. }) => problems,
        other => panic!("{}: {other:?}", path.display()),
    }
}

/// A character whose size (largest extent after units, scale and node transforms) is
/// outside 1 mm to 1 km is refused, naming the size and the vertex farthest out with its
/// OBJ line or glTF node, and nothing else: these bound before (a tetrahedron
/// "300000000549775575777803994281145270272 m tall", Green rest error 9.7e24 m), and a
/// vertex at 1e300 was reported as `bind.cell_size_m = inf`, a key the file does not
/// set. A 1.5 mm and a 1 m tetrahedron, and one in millimetres 1.5 m tall, load.
#[test]
fn a_character_of_absurd_size_is_refused_naming_the_vertex_or_node() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let apex = |y: f64| {
        let mut c = TET;
        c[3][1] = y;
        c
    };
    let scaled = |k: f64| TET.map(|p| p.map(|x| x * k));
    let cases: Vec<(PathBuf, f64, usize, VertexAt)> = vec![
        (
            tet_character(d, "apex39.obj", &tet_obj(apex(1e39)), ""),
            1e39,
            3,
            VertexAt::ObjLine(4),
        ),
        (
            tet_character(d, "apex300.obj", &tet_obj(apex(1e300)), ""),
            1e300,
            3,
            VertexAt::ObjLine(4),
        ),
        (
            tet_character(d, "tiny.obj", &tet_obj(scaled(1e-4)), ""),
            1e-4,
            3,
            VertexAt::ObjLine(4),
        ),
        (
            tet_character(
                d,
                "huge.gltf",
                &tet_gltf(d, &[("huge", scaled(3e38), 1.0)]),
                "",
            ),
            f64::from(3e38f32),
            3,
            VertexAt::Node {
                node: 0,
                part: "huge".into(),
            },
        ),
        // A second node scaled by 1e30: its vertices are named, by its node.
        (
            tet_character(
                d,
                "scaled.gltf",
                &tet_gltf(d, &[("body", TET, 1.0), ("big", TET, 1e30)]),
                "",
            ),
            f64::from(1e30f32),
            7,
            VertexAt::Node {
                node: 1,
                part: "big".into(),
            },
        ),
    ];
    for (path, size, vertex, at) in cases {
        let problems = problems_of(&path);
        match &problems[..] {
            [CharacterProblem::ImplausibleSize {
                size_m,
                vertex: v,
                at: a,
                ..
            }] => {
                assert!((size_m / size - 1.0).abs() < 1e-9, "{size_m} for {size}");
                assert_eq!((*v, a), (vertex, &at), "{}", path.display());
            }
            other => panic!("{}: {other:?}", path.display()),
        }
        let said = problems[0].to_string();
        assert!(!said.contains("bind."), "{said}");
    }
    // Units and the mesh's own scale count: a tetrahedron 1.5 units tall in millimetres
    // is 1.5 mm and loads, as does the 1 m one; with mesh.scale 0.5 it is 0.75 mm and
    // refused.
    let in_mm = tet_character(d, "mm.obj", &tet_obj(scaled(1.5)), "");
    let text = std::fs::read_to_string(&in_mm).unwrap();
    std::fs::write(&in_mm, text.replacen("\n\n", "\nunits = \"mm\"\n\n", 1)).unwrap();
    let loaded = load_character(&in_mm).unwrap_or_else(|e| panic!("{e}"));
    let height = loaded.character.vertices[3].y;
    assert!((height - 0.0015).abs() < 1e-15, "{height}");
    let text = std::fs::read_to_string(&in_mm).unwrap();
    std::fs::write(
        &in_mm,
        text.replacen("units = \"mm\"", "units = \"mm\"\nscale = 0.5", 1),
    )
    .unwrap();
    assert!(matches!(
        problems_of(&in_mm)[..],
        [CharacterProblem::ImplausibleSize { vertex: 3, .. }]
    ));
    let ok = tet_character(d, "tet.obj", &tet_obj(TET), "");
    load_character(&ok).unwrap_or_else(|e| panic!("{e}"));
    // One stray vertex in a mesh of many is named by its OBJ line too.
    let hand = write_hand(&d.join("hand"));
    let obj = hand.with_extension("obj");
    let o = std::fs::read_to_string(&obj).unwrap();
    std::fs::write(&obj, o.replacen("\nv ", "\nv 1e39 0 0\n# ", 1)).unwrap();
    match &problems_of(&hand)[..] {
        [CharacterProblem::FarVertices {
            count: 1,
            vertex: 0,
            at: VertexAt::ObjLine(3),
            ..
        }] => {}
        other => panic!("{other:?}"),
    }
}

/// A cell size the file gives that is not finite, or more than half the character, is
/// refused naming `bind.cell_size_m` (9223372036854775807 bound the tetrahedron into a
/// single cell, with a rest error of 360 m); half the character loads.
#[test]
fn a_cell_size_huge_for_the_character_or_not_finite_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = tet_obj(TET);
    for (value, want) in [
        ("9223372036854775807", "large"),
        ("0.51", "large"),
        ("inf", "finite"),
        ("nan", "finite"),
        ("-0.1", "finite"),
    ] {
        let path = tet_character(
            dir.path(),
            "tet.obj",
            &mesh,
            &format!("[bind]\ncell_size_m = {value}\n"),
        );
        let problems = problems_of(&path);
        match (&problems[..], want) {
            (
                [CharacterProblem::CellTooLarge {
                    cell_size_m,
                    size_m,
                }],
                "large",
            ) => {
                assert_eq!(*cell_size_m, value.parse::<f64>().unwrap());
                assert_eq!(*size_m, 1.0);
            }
            (
                [CharacterProblem::NotPositive {
                    setting: "bind.cell_size_m",
                    value: v,
                }],
                "finite",
            ) => assert_eq!(v.to_string(), value.parse::<f64>().unwrap().to_string()),
            (other, _) => panic!("{value}: {other:?}"),
        }
    }
    let path = tet_character(dir.path(), "tet.obj", &mesh, "[bind]\ncell_size_m = 0.5\n");
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(loaded.bind.cell_size_m, 0.5);
}

/// A mesh whose every triangle has no area (its corners on a line) is said once, as the
/// only warning about its surface; `bake`, whose bind then fails on the marker, says it
/// before the error.
#[test]
fn a_mesh_of_only_zero_area_triangles_is_warned_about_once() {
    let dir = tempfile::tempdir().unwrap();
    let line = [
        [0.0, 0.0, 0.0],
        [0.0, 0.5, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.25, 0.0],
    ];
    let path = tet_character(dir.path(), "flat.obj", &tet_obj(line), "");
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(loaded.warnings, vec![MeshWarning::NoArea { triangles: 4 }]);
    // One triangle with an area: no such warning.
    let mut one = line;
    one[3] = [0.2, 0.25, 0.0];
    let path = tet_character(dir.path(), "flat.obj", &tet_obj(one), "");
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        !loaded
            .warnings
            .iter()
            .any(|w| matches!(w, MeshWarning::NoArea { .. })),
        "{:?}",
        loaded.warnings
    );
    let path = tet_character(dir.path(), "flat.obj", &tet_obj(line), "");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_rigless"))
        .args(["bake", path.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert_eq!(
        err.matches("all 4 triangles of the mesh have no area")
            .count(),
        1,
        "{err}"
    );
    let warned = err.find("have no area").unwrap();
    let failed = err.find("from the control mesh").expect("the bind's error");
    assert!(warned < failed, "{err}");
}

/// A file listing more markers than a capture stage has is refused with the count and
/// the cap; one at the cap loads with every marker placed on its bone. (The duplicate
/// check compared each marker with all before it: 100,000 markers took 17 s to load.)
#[test]
fn markers_are_capped_and_a_file_at_the_cap_loads() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_hand(dir.path());
    let text = std::fs::read_to_string(&path).unwrap();
    let own = load_character(&path).unwrap().character.markers.len();
    let with = |extra: usize| {
        let mut t = text.clone();
        for k in 0..extra {
            t += &format!(
                "\n[[markers]]\nname = \"extra{k}\"\nbone = \"wrist\"\noffset_m = [0.0, {:?}, 0.0]\n",
                k as f64 * 1e-6
            );
        }
        std::fs::write(&path, t).unwrap();
    };
    with(MAX_MARKERS - own);
    let loaded = load_character(&path).unwrap_or_else(|e| panic!("{e}"));
    let markers = &loaded.character.markers;
    assert_eq!(markers.len(), MAX_MARKERS);
    let wrist = loaded
        .character
        .skeleton
        .joints
        .iter()
        .position(|j| j.name == "wrist");
    let last = &markers[MAX_MARKERS - 1];
    assert_eq!(
        (last.name.as_str(), last.joint),
        (&*format!("extra{}", MAX_MARKERS - own - 1), wrist)
    );
    with(MAX_MARKERS - own + 1);
    assert_eq!(
        problems_of(&path),
        vec![CharacterProblem::TooManyMarkers {
            count: MAX_MARKERS + 1,
            max: 4096
        }]
    );
    let said = load_character(&path).unwrap_err().to_string();
    assert!(said.contains("4097 [[markers]] (at most 4096"), "{said}");
    // Written as an inline array (the file's own markers left out), they are counted
    // once parsed.
    let first = text.find("[[markers]]").unwrap();
    let after = text[first..]
        .find("\n[bind]")
        .map_or(text.len(), |b| first + b + 1);
    let bare = format!("{}{}", &text[..first], &text[after..]);
    let inline: Vec<String> = (0..=MAX_MARKERS)
        .map(|k| format!("{{ name = \"x{k}\", position_m = [0.0, 0.0, 0.0] }}"))
        .collect();
    std::fs::write(&path, format!("markers = [{}]\n{bare}", inline.join(", "))).unwrap();
    match &problems_of(&path)[..] {
        [CharacterProblem::TooManyMarkers { count, max: 4096 }] => {
            assert_eq!(*count, MAX_MARKERS + 1)
        }
        other => panic!("{other:?}"),
    }
}
