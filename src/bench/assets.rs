//! Real assets of the shared data folder as character files, for the benchmarks and the
//! golden tests: the MakeHuman base mesh with a skeleton taken from its own
//! `default.mhskel`, and the skinned glTF samples; and a big mesh made from one of them
//! by midpoint subdivision (Jacobson's and de Aguiar's largest test meshes are about
//! 170,000 vertices; the data folder has none that big).

use crate::character::file::{load_character, CharacterError, LoadedCharacter};
use crate::character::mesh::MeshPart;
use crate::geom::shapes::subdivide_midpoint;
use std::path::{Path, PathBuf};

/// `p` from the root (the character file is written elsewhere and reads its mesh path
/// from its own folder).
fn absolute(p: &Path) -> PathBuf {
    std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf())
}

/// Why an asset could not be prepared.
#[derive(Debug, thiserror::Error)]
pub enum AssetError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: {problem}")]
    Skeleton { path: String, problem: String },
    #[error(transparent)]
    Character(#[from] CharacterError),
}

/// The MakeHuman character file for the mesh groups `groups` (empty: every group),
/// written in `dir`: 28 joints placed as MakeHuman's own skeleton places them (means of
/// listed vertices of `default.mhskel`), hinge limits on the knees and elbows, a marker
/// on every bone but the hands', feet's and head's ends. `None` when the data folder has
/// no MakeHuman mesh.
pub fn makehuman_file(
    data: &Path,
    groups: &[&str],
    dir: &Path,
) -> Result<Option<PathBuf>, AssetError> {
    let (obj, skel) = (
        data.join("meshes/makehuman/base.obj"),
        data.join("meshes/makehuman/default.mhskel"),
    );
    if !(obj.is_file() && skel.is_file()) {
        return Ok(None);
    }
    let shown = skel.display().to_string();
    let text = std::fs::read_to_string(&skel).map_err(|source| AssetError::Io {
        path: shown.clone(),
        source,
    })?;
    let mh: serde_json::Value = serde_json::from_str(&text).map_err(|e| AssetError::Skeleton {
        path: shown.clone(),
        problem: e.to_string(),
    })?;
    let verts = |key: &str| -> Result<Vec<u64>, AssetError> {
        mh["joints"][key]
            .as_array()
            .and_then(|a| a.iter().map(serde_json::Value::as_u64).collect())
            .ok_or_else(|| AssetError::Skeleton {
                path: shown.clone(),
                problem: format!("no joint {key:?} with vertex indices"),
            })
    };
    // (our joint, its parent, MakeHuman joint whose vertices give the position)
    let mut joints: Vec<(String, Option<String>, String)> = [
        ("root", None, "root____head"),
        ("spine", Some("root"), "spine03____head"),
        ("chest", Some("spine"), "spine01____head"),
        ("neck", Some("chest"), "neck01____head"),
        ("head", Some("neck"), "head____head"),
        ("head_top", Some("head"), "head____tail"),
    ]
    .into_iter()
    .map(|(a, b, c)| (a.to_string(), b.map(str::to_string), c.to_string()))
    .collect();
    for s in ["L", "R"] {
        // (our joint, its parent, MakeHuman bone whose head is the joint)
        let limbs = [
            ("clavicle", "chest", "clavicle"),
            ("upperarm", "clavicle", "upperarm01"),
            ("forearm", "upperarm", "lowerarm01"),
            ("hand", "forearm", "wrist"),
            ("thigh", "root", "upperleg01"),
            ("shin", "thigh", "lowerleg01"),
            ("foot", "shin", "foot"),
        ];
        for (name, parent, mhb) in limbs {
            let parent = match parent {
                "chest" | "root" => parent.to_string(),
                p => format!("{p}.{s}"),
            };
            joints.push((
                format!("{name}.{s}"),
                Some(parent),
                format!("{mhb}.{s}____head"),
            ));
        }
        for (end, of, bone) in [("hand_end", "hand", "wrist"), ("toe", "foot", "foot")] {
            joints.push((
                format!("{end}.{s}"),
                Some(format!("{of}.{s}")),
                format!("{bone}.{s}____tail"),
            ));
        }
    }
    let groups: Vec<String> = groups.iter().map(|g| format!("{g:?}")).collect();
    let mut t = format!(
        "name = \"makehuman\"\n[mesh]\npath = {:?}\nunits = \"dm\"\ngroups = [{}]\n",
        absolute(&obj),
        groups.join(", ")
    );
    for (name, parent, key) in &joints {
        t.push_str(&format!("\n[[skeleton.joints]]\nname = {name:?}\n"));
        if let Some(p) = parent {
            t.push_str(&format!("parent = {p:?}\n"));
        }
        t.push_str(&format!("rest_vertices = {:?}\n", verts(key)?));
    }
    for s in ["L", "R"] {
        t.push_str(&format!("\n[skeleton.limits.\"shin.{s}\"]\ntwist_deg = [-5, 5]\nbend_deg = [0, 120]\nside_deg = [-3, 3]\nbend_axis = [-1, 0, 0]\n"
        ));
        t.push_str(&format!("\n[skeleton.limits.\"forearm.{s}\"]\ntwist_deg = [-60, 60]\nbend_deg = [0, 130]\nside_deg = [-3, 3]\nbend_axis = [0, 0, 1]\n"
        ));
    }
    for (name, _, _) in &joints {
        if !name.ends_with("_top") && !name.starts_with("hand_end") && !name.starts_with("toe") {
            t.push_str(&format!(
                "\n[[markers]]\nname = \"m_{name}\"\nbone = {name:?}\n"
            ));
        }
    }
    let path = dir.join("makehuman.toml");
    std::fs::write(&path, t).map_err(|source| AssetError::Io {
        path: path.display().to_string(),
        source,
    })?;
    Ok(Some(path))
}

/// The WebXR right hand's character file, written in `dir`: the skin's joints chained
/// per finger, a marker on each nail and three on the back of the hand, and (with
/// `limits`) hand-written limits; `None` when the data folder has no WebXR hand.
pub fn webxr_hand_file(
    data: &Path,
    dir: &Path,
    limits: bool,
) -> Result<Option<PathBuf>, AssetError> {
    let glb = data.join("meshes/webxr-generic-hand/right.glb");
    if !glb.is_file() {
        return Ok(None);
    }
    let mut t = format!(
        "name = \"webxr_right_hand\"\n[mesh]\npath = {:?}\n\n[skeleton.parents]\n",
        absolute(&glb)
    );
    let fingers = [
        "thumb",
        "index-finger",
        "middle-finger",
        "ring-finger",
        "pinky-finger",
    ];
    for f in fingers {
        let segs: &[&str] = if f == "thumb" {
            &["metacarpal", "phalanx-proximal", "phalanx-distal", "tip"]
        } else {
            &[
                "metacarpal",
                "phalanx-proximal",
                "phalanx-intermediate",
                "phalanx-distal",
                "tip",
            ]
        };
        let mut prev = "wrist".to_string();
        for s in segs {
            t += &format!("{f}-{s} = {prev:?}\n");
            prev = format!("{f}-{s}");
        }
    }
    for f in fingers.into_iter().filter(|_| limits) {
        let segs: &[&str] = if f == "thumb" {
            &["phalanx-proximal", "phalanx-distal"]
        } else {
            &["phalanx-proximal", "phalanx-intermediate", "phalanx-distal"]
        };
        for (k, s) in segs.iter().enumerate() {
            let side = if k == 0 { 20 } else { 5 };
            t += &format!("\n[skeleton.limits.{f}-{s}]\ntwist_deg = [-10, 10]\nbend_deg = [-10, 90]\nside_deg = [-{side}, {side}]\n"
            );
        }
        // The metacarpals barely move in a real hand (the thumb's a little more).
        let m = if f == "thumb" { 15 } else { 3 };
        t += &format!("\n[skeleton.limits.{f}-metacarpal]\ntwist_deg = [-{m}, {m}]\nbend_deg = [-{m}, {m}]\nside_deg = [-{m}, {m}]\n"
        );
    }
    for f in fingers {
        t += &format!("\n[[markers]]\nname = \"{f}_nail\"\nbone = \"{f}-phalanx-distal\"\n");
    }
    for b in [
        "index-finger-metacarpal",
        "pinky-finger-metacarpal",
        "wrist",
    ] {
        t += &format!("\n[[markers]]\nname = \"back_{b}\"\nbone = {b:?}\n");
    }
    let path = dir.join("webxr_right_hand.toml");
    std::fs::write(&path, t).map_err(|source| AssetError::Io {
        path: path.display().to_string(),
        source,
    })?;
    Ok(Some(path))
}

/// A character file with only the mesh (skeleton and roles from its skin), written in
/// `dir` for the glTF file `glb`.
pub fn gltf_file(glb: &Path, dir: &Path) -> Result<PathBuf, AssetError> {
    let path = dir.join(format!(
        "{}.toml",
        glb.file_stem()
            .map_or("asset".into(), |s| s.to_string_lossy())
    ));
    std::fs::write(&path, format!("[mesh]\npath = {:?}\n", absolute(glb))).map_err(|source| {
        AssetError::Io {
            path: path.display().to_string(),
            source,
        }
    })?;
    Ok(path)
}

/// Loads a character file and subdivides its mesh `levels` times (each triangle into
/// four at its edges' midpoints, so the shape is unchanged); the skeleton, limits and
/// markers are the file's.
pub fn load_subdivided(path: &Path, levels: usize) -> Result<LoadedCharacter, AssetError> {
    let mut loaded = load_character(path)?;
    for _ in 0..levels {
        let ch = &mut loaded.character;
        (ch.vertices, ch.triangles) = subdivide_midpoint(&ch.vertices, &ch.triangles);
        // Triangle indices of the harmonic method's correspondences, and the parts'
        // ranges, no longer apply.
        ch.correspondences.clear();
        ch.parts = vec![MeshPart::whole(
            &ch.name,
            ch.vertices.len(),
            ch.triangles.len(),
        )];
        ch.name = format!("{}-subdivided", ch.name.trim_end_matches("-subdivided"));
    }
    Ok(loaded)
}
