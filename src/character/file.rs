//! Character files: a TOML description of what the user brings (the mesh file with its
//! units and up axis, the skeleton from the glTF skin or listed, joint limits, the
//! marker layout, binding settings), validated with every problem reported at once, and
//! loaded into a [`Character`] in the world frame (metres, Y up).
//!
//! ```toml
//! [mesh]
//! path = "right.glb"          # .glb, .gltf, .vrm or .obj, relative to this file
//! units = "m"                 # m, dm, cm, mm or in
//! up = "y"                    # y or z
//!
//! [skeleton.parents]          # skin joints that are not nested in the file
//! thumb-metacarpal = "wrist"
//!
//! [skeleton.roles]             # humanoid roles are recognised from the joint names
//! "hand_root" = "rightHand"     # (Mixamo, VRM, Unreal, MakeHuman, Rigify...); this
//!                               # sets or corrects one ("none" removes it)
//!
//! [skeleton.limits.index-finger-phalanx-proximal]   # replaces the role's limits
//! twist_deg = [-5, 5]
//! bend_deg = [0, 100]
//! side_deg = [-5, 5]
//!
//! [[markers]]
//! name = "index_nail"
//! bone = "index-finger-phalanx-distal"
//! offset_m = [0.0, -0.012, -0.008]
//!
//! [[correspondences]]         # harmonic method only; optional
//! joint = "wrist"             # these triangles follow the wrist's segment
//! triangles = [120, 121, 122] # indices in the mesh file's face order, from 0
//! ```
//!
//! Output vertex order: the mesh file's own (glTF: primitives in document order; OBJ:
//! the `v` lines used by the kept faces, in file order), so an engine can apply the
//! stream to the asset it already has. Seams are welded only for the checks and the
//! lattice; every file vertex gets its own Green coordinates.

use super::bind_params::BindParams;
use super::cell_size::{default_cell_size, CellChoice, Figure};
use super::mesh::{
    parse_gltf_file, parse_obj, surface_issues, weld, MeshData, MeshError, VertexAt,
    MAX_SKIN_JOINTS,
};
use super::roles::{default_limits, recognise, summary as roles_summary, Role, RoleSummary};
use super::skeleton::{Joint, JointLimits, Skeleton, SkeletonError};
use super::{Character, Correspondence, MarkerDef};
use crate::geom::axes::y_up_from_z_up;
use crate::geom::shapes::bounds;
use crate::runtime::files::{read_bounded, read_text_bounded, MAX_DATA_BYTES, MAX_TEXT_BYTES};
use glam::{DMat4, DVec3};
use serde::Deserialize;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

/// Most `[[markers]]` a character file may list. A capture stage labels tens to a few
/// hundred markers (a full body with fingers and a face about 200; `rigless calibrate`
/// keeps at most 512 labels of a take), and every marker is a row of the solver's
/// system each frame: 4,096 is ample room, and a file listing more is refused before any
/// is placed.
pub const MAX_MARKERS: usize = 4096;

/// Smallest `calibration.marker_scale`: a character a tenth of its actor's size.
pub const MIN_MARKER_SCALE: f64 = 0.1;
/// Largest: ten times.
pub const MAX_MARKER_SCALE: f64 = 10.0;

/// The whole character file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CharacterFile {
    /// Display name (default: the file's stem).
    pub name: Option<String>,
    /// The mesh file and how to read it.
    pub mesh: MeshSpec,
    /// Where the skeleton comes from, and its joint limits.
    #[serde(default)]
    pub skeleton: SkeletonSpec,
    /// The marker layout, in the order the solver reports them.
    #[serde(default)]
    pub markers: Vec<MarkerSpec>,
    /// Binding settings (defaults scale with the character's height).
    #[serde(default)]
    pub bind: BindSpec,
    /// The harmonic method's correspondences for some joints (the others are chosen
    /// automatically along their bones).
    #[serde(default)]
    pub correspondences: Vec<CorrespondenceSpec>,
    /// What `rigless calibrate` needs and finds: the label map and the actor's scale.
    #[serde(default)]
    pub calibration: CalibrationSpec,
}

/// `[calibration]`.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationSpec {
    /// Character metres per take metre, applied to incoming markers (written by
    /// `rigless calibrate --write`; default 1).
    pub marker_scale: Option<f64>,
    /// Labels to bones for `rigless calibrate`, before the built-in tables: globs over
    /// labels (`*`, `?`) to a joint name or a role (`"L*WR*" = "leftHand"`).
    #[serde(default)]
    pub bones: BTreeMap<String, String>,
}

/// `[[correspondences]]`: triangles that follow one joint's segment rigidly in the
/// harmonic method (`solver.method = "harmonic"`), instead of the ones picked along its
/// bone.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CorrespondenceSpec {
    /// The joint whose segment the triangles follow.
    pub joint: String,
    /// Triangle indices in the mesh file's order (its faces as read, from 0; OBJ polygons
    /// count as one triangle per fan triangle).
    pub triangles: Vec<usize>,
}

/// Length unit of a mesh file.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq)]
#[serde(rename_all = "lowercase")]
pub enum Units {
    #[default]
    M,
    Dm,
    Cm,
    Mm,
    In,
}

impl Units {
    /// Metres per file unit.
    pub fn metres(self) -> f64 {
        match self {
            Units::M => 1.0,
            Units::Dm => 0.1,
            Units::Cm => 0.01,
            Units::Mm => 0.001,
            Units::In => 0.0254,
        }
    }

    /// As the file writes it.
    pub fn name(self) -> &'static str {
        match self {
            Units::M => "m",
            Units::Dm => "dm",
            Units::Cm => "cm",
            Units::Mm => "mm",
            Units::In => "in",
        }
    }
}

/// Smallest and largest `mesh.scale`.
pub const MIN_MESH_SCALE: f64 = 1e-3;
pub const MAX_MESH_SCALE: f64 = 1e3;

/// Smallest and largest size of a character, metres: its largest extent in the world
/// frame, after `mesh.units`, `mesh.scale` and the file's node transforms. A hand is
/// about 0.2 m, a body 1.8 m; a millimetre is a mesh in the wrong units twice over, a
/// kilometre one in millimetres read as metres (or a node scaled by 1e30). Outside this
/// range the lattice, the weld tolerance and every default setting would follow a size
/// that no capture stage holds.
pub const MIN_CHARACTER_SIZE_M: f64 = 1e-3;
pub const MAX_CHARACTER_SIZE_M: f64 = 1e3;

/// Largest `bind.cell_size_m` as a share of the character's size: a coarser lattice is
/// one or two cells across and follows no limb.
pub const MAX_CELL_SHARE: f64 = 0.5;

fn unit_scale() -> f64 {
    1.0
}

/// Up axis of a mesh file.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    /// Y up (glTF's convention): kept.
    #[default]
    Y,
    /// Z up (most capture and CAD tools): turned to Y up, `(x, y, z) → (x, z, −y)`.
    Z,
}

impl std::fmt::Display for UpAxis {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            UpAxis::Y => "y",
            UpAxis::Z => "z",
        })
    }
}

/// `[mesh]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshSpec {
    /// Mesh file relative to the character file: `.glb`, `.gltf` or `.obj`.
    pub path: PathBuf,
    /// Length unit of the mesh file.
    #[serde(default)]
    pub units: Units,
    /// Multiplies the mesh (and its skeleton) after its units: a character modelled at
    /// another size than it is meant to have (a person exported 0.2 m tall: 8.5), from
    /// [`MIN_MESH_SCALE`] to [`MAX_MESH_SCALE`].
    #[serde(default = "unit_scale")]
    pub scale: f64,
    /// Up axis of the mesh file.
    #[serde(default)]
    pub up: UpAxis,
    /// OBJ only: keep the faces of these `g`/`o` groups (all when empty).
    #[serde(default)]
    pub groups: Vec<String>,
    /// Positions closer than this are welded for the mesh checks (the lattice welds its
    /// own copy at 1e-9 of the size, only to orient the parts), metres
    /// (default 1e-6 of the character's size, its longest extent).
    pub weld_tolerance_m: Option<f64>,
}

/// `[skeleton]`.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkeletonSpec {
    /// Take the joints from the glTF skin (default: yes when the mesh has one).
    pub from_skin: Option<bool>,
    /// Parent of each skin joint by name, for skins whose joints are not nested.
    #[serde(default)]
    pub parents: BTreeMap<String, String>,
    /// Joints listed by hand, parents first (when there is no skin).
    #[serde(default)]
    pub joints: Vec<JointSpec>,
    /// Limits per joint name; they replace the default limits of the joint's role.
    #[serde(default)]
    pub limits: BTreeMap<String, LimitSpec>,
    /// Humanoid role per joint name, as VRM names it (`leftUpperLeg`, `hips`,
    /// `rightIndexProximal`), or `"none"`; replaces the role recognised from the name.
    #[serde(default)]
    pub roles: BTreeMap<String, String>,
    /// Give each joint with a humanoid role the default limits of its role (default
    /// true; joints with neither a role nor `limits` are free).
    pub role_limits: Option<bool>,
}

/// `[[skeleton.joints]]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointSpec {
    /// Joint name, unique.
    pub name: String,
    /// Parent joint name (listed before this one); none for the root.
    pub parent: Option<String>,
    /// Rest position, metres, world frame (Y up).
    pub rest_m: Option<[f64; 3]>,
    /// Or: rest position as the mean of these vertices of the mesh file, 0-based in file
    /// order (OBJ: counting every `v` line, in any group, as MakeHuman's skeleton files
    /// do; glTF: the vertices of all primitives in document order).
    pub rest_vertices: Option<Vec<usize>>,
}

/// `[skeleton.limits.NAME]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimitSpec {
    /// Twist about the joint's twist axis (towards its children), `[min, max]` degrees.
    pub twist_deg: [f64; 2],
    /// Flexion about the bend axis, `[min, max]` degrees (positive curls the segment).
    pub bend_deg: [f64; 2],
    /// Abduction about `twist × bend`, `[min, max]` degrees.
    pub side_deg: [f64; 2],
    /// Bend axis at rest, world frame; made perpendicular to the twist axis (default: a
    /// skin joint's bind-pose X axis; required for listed joints).
    pub bend_axis: Option<[f64; 3]>,
}

/// `[[markers]]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MarkerSpec {
    /// Marker name, as the capture system labels it.
    pub name: String,
    /// Rest position, metres, world frame.
    pub position_m: Option<[f64; 3]>,
    /// Or: the joint whose bone carries it (a leaf joint means its parent's bone) ...
    pub bone: Option<String>,
    /// ... and its offset from that joint at rest, metres, world axes (default zero).
    pub offset_m: Option<[f64; 3]>,
}

/// `[bind]`.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BindSpec {
    /// Lattice cell edge, metres (default: the shortest bone carrying a marker, kept to a control mesh of 500 to 3,000 vertices; `rigless bake` says how it was chosen).
    pub cell_size_m: Option<f64>,
    /// Spacing of skeleton samples along each bone, metres (default 0.9 cell).
    pub skeleton_step_m: Option<f64>,
    /// Shape weight `w_l` (default 1).
    pub w_shape: Option<f64>,
    /// Marker row weight `w_u` (default 30).
    pub w_marker: Option<f64>,
    /// Skeleton sample row weight `w_d` (default 1000).
    pub w_skeleton: Option<f64>,
    /// A marker farther than this from the control mesh is an error, metres (default 10 %
    /// of the character's size, its longest extent).
    pub max_marker_distance_m: Option<f64>,
}

/// What is unusual about a mesh but does not stop the bind: the lattice's inside is
/// decided by the generalized winding number, which needs no closed, manifold or
/// consistently oriented surface. Shown as warnings in `rigless bake`'s summary.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshWarning {
    /// Edges used by one triangle only, with an example edge (file vertices).
    #[error("the mesh is open: {edges} edges border a hole or an open part{}", example_edge(.example))]
    Open {
        edges: usize,
        example: Option<(usize, usize)>,
    },
    /// Edges used by more than two triangles, with an example edge (file vertices).
    #[error("the mesh is not manifold: {edges} edges are shared by more than two triangles{}", example_edge(.example))]
    NonManifold {
        edges: usize,
        example: Option<(usize, usize)>,
    },
    /// Edges whose two triangles run them in the same direction.
    #[error("the mesh is not consistently oriented: {edges} edges join flipped triangles")]
    InconsistentOrientation { edges: usize },
    /// The mesh is less tall (along the declared up axis) than half its longest extent.
    #[error("the mesh is {height_m:.3} m tall but {longest_m:.3} m long: it looks lying down for up = \"{up}\"; check [mesh] up")]
    LyingDown {
        height_m: f64,
        longest_m: f64,
        up: UpAxis,
    },
    /// Skin joints no vertex is weighted to and below which none is (IK poles, controls,
    /// sockets), dropped from the skeleton.
    #[error("{} joint{} of the skin carr{} no skin weight and {} no weighted joint below {}, so {} dropped (IK poles, controls, sockets): {}", .dropped.len(), if .dropped.len() == 1 { "" } else { "s" }, if .dropped.len() == 1 { "ies" } else { "y" }, if .dropped.len() == 1 { "has" } else { "have" }, if .dropped.len() == 1 { "it" } else { "them" }, if .dropped.len() == 1 { "it was" } else { "they were" }, .dropped.join(", "))]
    UnweightedJoints { dropped: Vec<String> },
    /// Skin joints that sat on their parents, merged into them (name, parent).
    #[error("{} joint{} of the skin sat on {} parent{} (bones of no length) and {} merged into {}: {}", .merged.len(), if .merged.len() == 1 { "" } else { "s" }, if .merged.len() == 1 { "its" } else { "their" }, if .merged.len() == 1 { "" } else { "s" }, if .merged.len() == 1 { "was" } else { "were" }, if .merged.len() == 1 { "it" } else { "them" }, .merged.iter().map(|(j, p)| format!("{j} into {p}")).collect::<Vec<_>>().join(", "))]
    ZeroLengthBones { merged: Vec<(String, String)> },
    /// Every triangle has no area (its corners coincide or lie on a line, to a
    /// millionth of the character's size): the mesh encloses nothing, and the lattice
    /// follows the skeleton alone.
    #[error("all {triangles} triangles of the mesh have no area (their corners coincide or lie on a line): it encloses nothing for the lattice to follow; check the file's faces")]
    NoArea { triangles: usize },
    /// The skeleton's hips-to-head line leans far from the declared up axis.
    #[error("the skeleton's hips-to-head line leans {lean_deg:.0}° from up: it looks lying down for up = \"{up}\"; check [mesh] up")]
    TrunkLyingDown { lean_deg: f64, up: UpAxis },
}

/// How far a skeleton's trunk (hips to head, or to the neck) leans from up, degrees;
/// `None` without joints of those roles.
fn trunk_lean_deg(sk: &Skeleton, roles: &[Option<Role>]) -> Option<f64> {
    use super::roles::Part;
    let find = |part: Part| {
        (0..sk.len()).find(|&j| {
            roles
                .get(j)
                .copied()
                .flatten()
                .is_some_and(|r| r.part == part)
        })
    };
    let hips = find(Part::Hips)?;
    let top = find(Part::Head).or_else(|| find(Part::Neck))?;
    let v = sk.joints[top].rest - sk.joints[hips].rest;
    let len = v.length();
    (len > 0.0).then(|| (v.y / len).clamp(-1.0, 1.0).acos().to_degrees())
}

/// The lying-down warning: by the skeleton's trunk when it has one (leaning over 60°
/// from up; a half-body avatar with wide arms is wider than tall and stands all the
/// same), else by the mesh's height against its longest extent.
fn lying_down(
    lean_deg: Option<f64>,
    height_m: f64,
    longest_m: f64,
    up: UpAxis,
) -> Option<MeshWarning> {
    match lean_deg {
        Some(lean_deg) => (lean_deg > 60.0).then_some(MeshWarning::TrunkLyingDown { lean_deg, up }),
        None => (height_m > 0.0 && height_m < 0.5 * longest_m).then_some(MeshWarning::LyingDown {
            height_m,
            longest_m,
            up,
        }),
    }
}

/// Errors loading a character file.
#[derive(Debug, thiserror::Error)]
pub enum CharacterError {
    #[error("{path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: {} problem{}:\n  - {}", .problems.len(), if .problems.len() == 1 { "" } else { "s" }, .problems.join("\n  - "))]
    Toml { path: String, problems: Vec<String> },
    #[error("{path}: {source}")]
    Mesh { path: String, source: MeshError },
    /// A mesh or a recording given where a character file goes.
    #[error("{path}: {what}")]
    NotACharacterFile { path: String, what: String },
    #[error("{path}: {} problem{}:\n  - {}", .problems.len(), if .problems.len() == 1 { "" } else { "s" }, join_problems(.problems))]
    Invalid {
        path: String,
        problems: Vec<CharacterProblem>,
    },
}

/// The problems' texts, one per line after the first, as [`CharacterError::Invalid`]
/// lists them.
fn join_problems(problems: &[CharacterProblem]) -> String {
    problems
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join("\n  - ")
}

/// One problem found in a character file (with its mesh); [`build`] reports every one
/// it finds at once. Joint and marker names are as the file spells them; vertex and
/// triangle numbers are 0-based in the mesh file's order.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum CharacterProblem {
    /// `mesh.scale` is out of range.
    #[error("mesh.scale must be {MIN_MESH_SCALE} to {MAX_MESH_SCALE}, got {value:?}")]
    MeshScale { value: f64 },
    /// `calibration.marker_scale` is out of range.
    #[error("calibration.marker_scale must be {MIN_MARKER_SCALE} to {MAX_MARKER_SCALE} (character metres per take metre), got {value:?}")]
    MarkerScale { value: f64 },
    /// `mesh.path` has an extension that is not a mesh format.
    #[error(
        "mesh.path {path:?}: unknown mesh format {extension:?} (use .glb, .gltf, .vrm or .obj)"
    )]
    UnknownMeshFormat { path: PathBuf, extension: String },
    /// A vertex is NaN or infinite (in the world frame); `position` as the file gives it.
    #[error("mesh vertex {vertex} is not finite: {position:?}")]
    NonFiniteVertex { vertex: usize, position: DVec3 },
    /// Every vertex has the same height.
    #[error("the mesh has no height (all vertices at one Y)")]
    NoHeight,
    /// Vertices far outside the box that holds the rest of the mesh (a stray vertex in
    /// the file), with the first of them.
    #[error("{count} mesh vertices lie far from the rest of the mesh, e.g. vertex {vertex} (from 0, {at}) at {position:?} in the file's units, while the rest fit in a box {extent_m:.3} m across")]
    FarVertices {
        count: usize,
        vertex: usize,
        at: VertexAt,
        position: DVec3,
        extent_m: f64,
    },
    /// The character's size is outside [`MIN_CHARACTER_SIZE_M`] to
    /// [`MAX_CHARACTER_SIZE_M`]; with the vertex farthest from the middle of the mesh
    /// (0-based among the mesh's vertices), where the file gives it and its position in
    /// the file's units.
    #[error("the character is {size_m:e} m across (its largest extent after mesh.units = {units:?}, mesh.scale = {scale:?} and the file's node transforms), outside the {MIN_CHARACTER_SIZE_M} to {MAX_CHARACTER_SIZE_M} m a character may be; the farthest out is vertex {vertex} (from 0, {at}) at {position:?} in the file's units")]
    ImplausibleSize {
        size_m: f64,
        units: &'static str,
        scale: f64,
        vertex: usize,
        at: VertexAt,
        position: DVec3,
    },
    /// `skeleton.from_skin = true` for a mesh without a skin.
    #[error("skeleton.from_skin is true but the mesh has no skin")]
    NoSkin,
    /// `skeleton.joints` listed while the skin gives the joints.
    #[error(
        "skeleton.joints cannot be listed when the skin is used (set skeleton.from_skin = false)"
    )]
    JointsWithSkin,
    /// `skeleton.parents` names a joint the skin does not have.
    #[error("skeleton.parents: no skin joint is named {name:?}")]
    UnknownSkinJoint { name: String },
    /// `skeleton.parents` makes a joint its own ancestor.
    #[error("skeleton.parents makes a cycle")]
    ParentCycle,
    /// `skeleton.parents` given without a skin.
    #[error("skeleton.parents applies to skin joints only")]
    ParentsWithoutSkin,
    /// A listed joint's parent is not listed before it.
    #[error("joint {joint:?}: parent {parent:?} is not listed before it")]
    ParentNotListedBefore { joint: String, parent: String },
    /// A listed joint's `rest_vertices` names a vertex past the file's last.
    #[error("joint {joint:?}: rest_vertices names vertex {vertex}, but the mesh file has {vertex_count}")]
    RestVertexOutOfRange {
        joint: String,
        vertex: usize,
        vertex_count: usize,
    },
    /// A listed joint has both or neither of `rest_m` and (non-empty) `rest_vertices`.
    #[error("joint {joint:?}: give exactly one of rest_m and rest_vertices (non-empty)")]
    RestPosition { joint: String },
    /// Neither a skin nor listed joints.
    #[error("the character has no skeleton: list skeleton.joints or use a glTF file with a skin")]
    NoSkeleton,
    /// More than one joint without a parent.
    #[error("the skeleton has {} roots ({}): give every joint but one a parent", .roots.len(), .roots.join(", "))]
    SeveralRoots { roots: Vec<String> },
    /// A skeleton of a single joint.
    #[error("joint {joint:?} has no bone: a skeleton needs at least two joints")]
    NoBone { joint: String },
    /// `skeleton.limits` names a joint the skeleton does not have.
    #[error("skeleton.limits: no joint is named {joint:?}")]
    LimitsUnknownJoint { joint: String },
    /// `skeleton.roles` names a joint the skeleton does not have.
    #[error("skeleton.roles: no joint is named {joint:?}")]
    RolesUnknownJoint { joint: String },
    /// `skeleton.roles` gives a role that is not a VRM humanoid bone name.
    #[error("skeleton.roles.{joint}: {role:?} is not a role (VRM humanoid names such as \"hips\", \"leftUpperLeg\", \"rightIndexProximal\", or \"none\")")]
    UnknownRole { joint: String, role: String },
    /// A limit (`twist_deg`, `bend_deg` or `side_deg`) is not a finite `[min, max]`.
    #[error("skeleton.limits.{joint}.{which}: [{min}, {max}] is not a range (min ≤ max, finite)")]
    BadLimitRange {
        joint: String,
        which: &'static str,
        min: f64,
        max: f64,
    },
    /// Limits without a usable bend axis (none given, none from the skin, or zero).
    #[error(
        "skeleton.limits.{joint}: bend_axis is required (a non-zero vector) for a listed joint"
    )]
    BendAxisRequired { joint: String },
    /// The skeleton itself is invalid.
    #[error(transparent)]
    Skeleton(#[from] SkeletonError),
    /// A limited joint's bend axis runs along its bone.
    #[error("joint {joint:?}: bend_axis {axis} is parallel to the bone; give an axis across it")]
    BendAxisAlongBone { joint: String, axis: DVec3 },
    /// Two markers share a name.
    #[error("marker name {marker:?} is used twice")]
    DuplicateMarker { marker: String },
    /// More `[[markers]]` than a character may have.
    #[error("{count} [[markers]] (at most {max}: a capture stage has tens to a few hundred)")]
    TooManyMarkers { count: usize, max: usize },
    /// A marker's `bone` names a joint the skeleton does not have.
    #[error("marker {marker:?}: no joint is named {bone:?}")]
    MarkerUnknownBone { marker: String, bone: String },
    /// A marker has both or neither of `position_m` and `bone`.
    #[error("marker {marker:?}: give exactly one of position_m and bone (with offset_m)")]
    MarkerPlacement { marker: String },
    /// A marker's rest position is NaN or infinite.
    #[error("marker {marker:?}: position is not finite")]
    MarkerNotFinite { marker: String },
    /// A binding setting the file gives (`bind.NAME`) is not a positive, finite number.
    #[error("{setting} must be a positive finite number, got {value}")]
    NotPositive { setting: &'static str, value: f64 },
    /// `bind.cell_size_m` above [`MAX_CELL_SHARE`] of the character's size (metres).
    #[error("bind.cell_size_m {cell_size_m:?} is more than {MAX_CELL_SHARE} of the character's size {size_m:.3} m (its longest extent): the lattice would be one or two cells across")]
    CellTooLarge { cell_size_m: f64, size_m: f64 },
    /// `bind.cell_size_m` below 1/400 of the character's size (longest extent, metres).
    #[error("bind.cell_size_m {cell_size_m:?} is below 1/400 of the character's size {size_m:.3} m (its longest extent): the control mesh would be enormous")]
    CellTooSmall { cell_size_m: f64, size_m: f64 },
    /// More `[[skeleton.joints]]` than a skin may have.
    #[error("{count} [[skeleton.joints]] (at most {MAX_SKIN_JOINTS})")]
    TooManyJoints { count: usize },
    /// `bind.skeleton_step_m` below 1/100 of the cell size (metres).
    #[error("bind.skeleton_step_m {step_m:?} is below 1/100 of the cell size {cell_size_m:?} m: the skeleton would be sampled absurdly finely")]
    StepTooSmall { step_m: f64, cell_size_m: f64 },
    /// `mesh.weld_tolerance_m` not a number from 0 to 1/100 of the character's size.
    #[error("mesh.weld_tolerance_m {value_m:?} is not from 0 to 1/100 of the character's size {size_m:.3} m (its longest extent): a larger one welds distinct parts of the mesh together")]
    WeldTolerance { value_m: f64, size_m: f64 },
    /// `correspondences[index]` repeats a joint listed before it.
    #[error("correspondences[{index}] (joint {joint:?}): the joint is listed twice")]
    CorrespondenceTwice { index: usize, joint: String },
    /// `correspondences[index]` names a joint the skeleton does not have.
    #[error("correspondences[{index}] (joint {joint:?}): no joint is named {joint:?}")]
    CorrespondenceUnknownJoint { index: usize, joint: String },
    /// `correspondences[index]` has no triangles.
    #[error("correspondences[{index}] (joint {joint:?}): no triangles")]
    CorrespondenceEmpty { index: usize, joint: String },
    /// `correspondences[index]` names a triangle past the mesh's last.
    #[error("correspondences[{index}] (joint {joint:?}): triangle {triangle} is out of range (the mesh has {triangle_count} triangles)")]
    CorrespondenceTriangleOutOfRange {
        index: usize,
        joint: String,
        triangle: usize,
        triangle_count: usize,
    },
}

/// `" (e.g. between file vertices A and B)"` for an example edge, or nothing.
fn example_edge(example: &Option<(usize, usize)>) -> String {
    example
        .map(|(a, b)| format!(" (e.g. between file vertices {a} and {b})"))
        .unwrap_or_default()
}

/// A loaded character with its binding settings and the bytes that define it.
#[derive(Clone, Debug)]
pub struct LoadedCharacter {
    pub character: Character,
    pub bind: BindParams,
    /// What is unusual about the mesh but does not stop the bind.
    pub warnings: Vec<MeshWarning>,
    /// The default cell size and why, when the file does not set one.
    pub cell_choice: Option<CellChoice>,
    /// The humanoid roles found in the skeleton.
    pub roles: RoleSummary,
    /// Each joint's role, when it has one.
    pub joint_roles: Vec<Option<Role>>,
    /// Character metres per take metre (`calibration.marker_scale`, default 1).
    pub marker_scale: f64,
    /// `calibration.bones`: label globs to joints or roles.
    pub calibration_map: BTreeMap<String, String>,
    /// Hash of the mesh (its file and what the parse found) and this crate's version: the
    /// bake cache's key (its contents are used only for the same control mesh too).
    pub inputs_hash: u64,
    /// The mesh file that was read.
    pub mesh_path: PathBuf,
}

impl LoadedCharacter {
    /// The bind settings for the layout `markers` in place of the file's: when the file
    /// sets no cell size, the default is chosen again for them (as `bake` chooses it once
    /// `calibrate --write` has stored them: it follows the shortest bone that carries a
    /// marker), with the skeleton step that follows it unless the file sets one; every
    /// other setting is the file's.
    pub fn bind_for(&self, markers: &[MarkerDef]) -> BindParams {
        let mut b = self.bind.clone();
        if self.cell_choice.is_some() {
            let ch = &self.character;
            let step_follows =
                (b.skeleton_step_m - 0.9 * b.cell_size_m).abs() <= 1e-9 * b.cell_size_m;
            let c = default_cell_size(
                &ch.vertices,
                &ch.triangles,
                &ch.skeleton,
                markers,
                Figure::of(&self.joint_roles),
                extent(&ch.vertices).max_element(),
            );
            b.cell_size_m = c.cell_size_m;
            if step_follows {
                b.skeleton_step_m = 0.9 * c.cell_size_m;
            }
        }
        b
    }
}

/// FNV-1a, 64 bits: a stable hash (unlike std's) for cache keys.
pub fn fnv1a(data: &[&[u8]]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for part in data {
        for &b in part.iter() {
            h ^= b as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
        h ^= part.len() as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// The keys of a character file's text, every unknown or malformed key reported at its
/// line (nothing is loaded or checked beyond the keys).
pub fn read_spec(text: &str) -> Result<CharacterFile, Vec<String>> {
    use crate::runtime::toml_doc::{in_file_order, syntax_error, typed, Lines};
    let value: toml::Value = toml::from_str(text).map_err(|e| vec![syntax_error(text, &e)])?;
    let mut problems = Vec::new();
    match typed::<CharacterFile>(&value, "", &Lines::scan(text), &mut problems) {
        Some(spec) if problems.is_empty() => Ok(spec),
        _ => {
            in_file_order(&mut problems);
            Err(problems)
        }
    }
}

/// What a file given as a character file is instead, by its extension, and the way from
/// it to a character file; `None` for anything else (read as TOML).
fn not_a_character_file(path: &Path) -> Option<String> {
    let ext = path.extension()?.to_string_lossy().to_lowercase();
    let name = path.file_name()?.to_string_lossy();
    match ext.as_str() {
        "glb" | "gltf" | "vrm" | "obj" => Some(format!(
            "a mesh, not a character file: a character file is TOML that names its mesh, as small as the two lines `[mesh]` and `path = {name:?}` in a file next to it (docs/character.md lists the keys)"
        )),
        "fbx" | "blend" | "dae" | "usd" | "usdz" => Some(
            "a mesh rigless does not read: export it as glTF 2.0 (.glb) or OBJ, then name that in a character file (docs/character.md)"
                .into(),
        ),
        "c3d" | "bvh" | "tsv" | "rlsession" => Some(
            "a recording, not a character file: give the character (hand, body or a character file) first, then the take"
                .into(),
        ),
        _ => None,
    }
}

/// Loads and validates a character file.
pub fn load_character(path: &Path) -> Result<LoadedCharacter, CharacterError> {
    let shown = path.display().to_string();
    if let Some(what) = not_a_character_file(path) {
        return Err(CharacterError::NotACharacterFile { path: shown, what });
    }
    let text = read_text_bounded(path, MAX_TEXT_BYTES).map_err(|source| CharacterError::Read {
        path: shown.clone(),
        source,
    })?;
    // Too many markers are refused before the TOML is parsed (its tables take some 40
    // bytes of memory per byte of text): `[[markers]]` headers are counted by line here,
    // markers written otherwise (an inline array) by `build`.
    let count = text
        .lines()
        .filter(|l| l.trim_start().starts_with("[[markers]]"))
        .count();
    if count > MAX_MARKERS {
        return Err(CharacterError::Invalid {
            path: shown,
            problems: vec![CharacterProblem::TooManyMarkers {
                count,
                max: MAX_MARKERS,
            }],
        });
    }
    let spec = read_spec(&text).map_err(|problems| CharacterError::Toml {
        path: shown.clone(),
        problems,
    })?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let mesh_path = dir.join(&spec.mesh.path);
    let mesh_shown = mesh_path.display().to_string();
    let mesh_bytes =
        read_bounded(&mesh_path, MAX_DATA_BYTES).map_err(|source| CharacterError::Read {
            path: mesh_shown.clone(),
            source,
        })?;
    let ext = mesh_path
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let mesh = match ext.as_str() {
        "obj" => parse_obj(&mesh_bytes, &spec.mesh.groups),
        // A VRM file is a binary glTF with VRM's extensions.
        "glb" | "gltf" | "vrm" => parse_gltf_file(&mesh_bytes, &mesh_path),
        other => {
            return Err(CharacterError::Invalid {
                path: shown,
                problems: vec![CharacterProblem::UnknownMeshFormat {
                    path: spec.mesh.path.clone(),
                    extension: other.to_string(),
                }],
            })
        }
    }
    .map_err(|source| CharacterError::Mesh {
        path: mesh_shown,
        source,
    })?;
    let name = spec.name.clone().unwrap_or_else(|| {
        path.file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "character".into())
    });
    // What the mesh file and any buffers beside it hold (a glTF's external `.bin` is
    // not in `mesh_bytes`): part of the cache key.
    let mesh_key = mesh_fingerprint(&mesh);
    let built = build(&spec, name, mesh).map_err(|problems| CharacterError::Invalid {
        path: shown,
        problems,
    })?;
    // The mesh (its file and what the parse found, external buffers included) and this
    // build: what the stored Green coordinates need to stay current. The character file's
    // own settings are not in it: the cache is used only when the control mesh rebuilt
    // from them is the one the coordinates were made in (the rig's lattice key), so a
    // marker layout added or edited later reuses them.
    let inputs_hash = fnv1a(&[
        &mesh_bytes,
        &mesh_key.to_le_bytes(),
        env!("CARGO_PKG_VERSION").as_bytes(),
    ]);
    Ok(LoadedCharacter {
        character: built.character,
        bind: built.bind,
        warnings: built.warnings,
        cell_choice: built.cell_choice,
        roles: built.roles,
        joint_roles: built.joint_roles,
        marker_scale: spec.calibration.marker_scale.unwrap_or(1.0),
        calibration_map: spec.calibration.bones.clone(),
        inputs_hash,
        mesh_path,
    })
}

/// The little-endian bytes of points' coordinates, to hash them with [`fnv1a`].
pub fn point_bytes(points: &[DVec3]) -> Vec<u8> {
    points
        .iter()
        .flat_map(|p| p.to_array())
        .flat_map(f64::to_le_bytes)
        .collect()
}

/// A hash of a parsed mesh: its positions, triangles and skin joints.
fn mesh_fingerprint(mesh: &MeshData) -> u64 {
    let positions = point_bytes(&mesh.positions);
    let triangles: Vec<u8> = mesh
        .triangles
        .iter()
        .flatten()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let joints: Vec<u8> = mesh
        .skin_joints
        .iter()
        .flat_map(|j| format!("{j:?}").into_bytes())
        .collect();
    fnv1a(&[&positions, &triangles, &joints])
}

/// What [`build`] makes of a character file.
#[derive(Clone, Debug)]
pub struct Built {
    pub character: Character,
    pub bind: BindParams,
    /// What is unusual about the mesh but does not stop the bind.
    pub warnings: Vec<MeshWarning>,
    /// How the default cell size was chosen (when the file sets none).
    pub cell_choice: Option<CellChoice>,
    /// The humanoid roles of the skeleton's joints.
    pub roles: RoleSummary,
    /// Each joint's role, when it has one.
    pub joint_roles: Vec<Option<Role>>,
}

/// The extent of the vertices' bounding box, metres.
fn extent(vertices: &[DVec3]) -> DVec3 {
    let (lo, hi) = bounds(vertices);
    (hi - lo).max(DVec3::ZERO)
}

/// Converts the mesh to the world frame and builds the character, with what is unusual
/// about the mesh; every problem found is returned at once.
pub fn build(
    spec: &CharacterFile,
    name: String,
    mesh: MeshData,
) -> Result<Built, Vec<CharacterProblem>> {
    let mut problems = Vec::new();
    let scale = spec.mesh.scale;
    if !(scale.is_finite() && (MIN_MESH_SCALE..=MAX_MESH_SCALE).contains(&scale)) {
        problems.push(CharacterProblem::MeshScale { value: scale });
    }
    let frame = WorldFrame::of(&spec.mesh);
    let (vertices, height) = world_vertices(&mesh, frame, &mut problems);
    // Settings scale with the character's size (its longest extent), not its height: a
    // mesh declared with the wrong up axis must not get a lattice from a sliver. Only a
    // size from sound vertices, within the plausible range, is used to judge or default
    // them (`None` otherwise: its problem is already said).
    let size = problems.is_empty().then(|| extent(&vertices).max_element());
    let size = size.filter(|&size_m| plausible_size(spec, &mesh, &vertices, size_m, &mut problems));
    let size_m = size.unwrap_or(height);
    let weld_tol = spec.mesh.weld_tolerance_m.unwrap_or(1e-6 * size_m);
    if size.is_some() && !(0.0..=0.01 * size_m).contains(&weld_tol) {
        problems.push(CharacterProblem::WeldTolerance {
            value_m: weld_tol,
            size_m,
        });
    }
    // The surface is only judged once its vertices and weld tolerance are sound (a stray
    // or non-finite vertex would show up again as a misleading topology problem).
    let warnings = if problems.is_empty() {
        check_surface(&mesh, &vertices, weld_tol, size_m)
    } else {
        Vec::new()
    };
    let sk = &spec.skeleton;
    let (mut merged, mut unweighted) = (Vec::new(), Vec::new());
    let (mut joints, skin_x_axis) = if sk.from_skin.unwrap_or(!mesh.skin_joints.is_empty()) {
        let dropped = (&mut merged, &mut unweighted);
        skin_joints(sk, &mesh, frame, &mut problems, dropped)
    } else {
        listed_joints(sk, &mesh, frame, &mut problems)
    };
    check_tree(&joints, &mut problems);
    let roles = joint_roles(sk, &joints, &mut problems);
    let role_limits = default_limits(&joints, &roles);
    if sk.role_limits.unwrap_or(true) {
        for (j, l) in joints.iter_mut().zip(&role_limits) {
            if let Some((limits, axis)) = *l {
                j.limits = Some(limits);
                j.bend_axis = axis;
            }
        }
    }
    let role_axis: Vec<Option<DVec3>> = role_limits.iter().map(|l| l.map(|l| l.1)).collect();
    apply_limits(sk, &mut joints, &role_axis, &skin_x_axis, &mut problems);
    let joint_roles = roles;
    let roles = roles_summary(&joints, &joint_roles);
    let skeleton = finish_skeleton(joints, &mut problems);
    let markers = place_markers(&spec.markers, skeleton.as_ref(), &mut problems);
    let cell_choice = match (&skeleton, spec.bind.cell_size_m, problems.is_empty()) {
        (Some(sk), None, true) => Some(default_cell_size(
            &vertices,
            &mesh.triangles,
            sk,
            &markers,
            Figure::of(&joint_roles),
            size_m,
        )),
        _ => None,
    };
    let mut warnings = warnings;
    if !unweighted.is_empty() {
        warnings.push(MeshWarning::UnweightedJoints {
            dropped: unweighted,
        });
    }
    if !merged.is_empty() {
        warnings.push(MeshWarning::ZeroLengthBones { merged });
    }
    let lean_deg = skeleton
        .as_ref()
        .and_then(|s| trunk_lean_deg(s, &joint_roles));
    if problems.is_empty() {
        warnings.extend(lying_down(lean_deg, height, size_m, spec.mesh.up));
    }
    let params = bind_params(&spec.bind, size, cell_choice.as_ref(), &mut problems);
    if let Some(v) = spec.calibration.marker_scale {
        if !(v.is_finite() && (MIN_MARKER_SCALE..=MAX_MARKER_SCALE).contains(&v)) {
            problems.push(CharacterProblem::MarkerScale { value: v });
        }
    }
    let correspondences = correspondences(
        &spec.correspondences,
        skeleton.as_ref(),
        mesh.triangles.len(),
        &mut problems,
    );
    match (problems.is_empty(), skeleton) {
        (true, Some(skeleton)) => Ok(Built {
            character: Character {
                name,
                vertices,
                triangles: mesh.triangles,
                skeleton,
                markers,
                skin: None,
                correspondences,
                parts: mesh.parts,
            },
            bind: params,
            warnings,
            cell_choice,
            roles,
            joint_roles,
        }),
        _ => Err(problems),
    }
}

/// The mesh file's units and up axis: how its points and directions reach the world
/// frame (metres, Y up).
#[derive(Clone, Copy, Debug)]
struct WorldFrame {
    /// Metres per file unit.
    metres: f64,
    up: UpAxis,
}

impl WorldFrame {
    /// The frame `[mesh]` describes.
    fn of(mesh: &MeshSpec) -> Self {
        let scale = if mesh.scale.is_finite() && mesh.scale > 0.0 {
            mesh.scale
        } else {
            1.0
        };
        WorldFrame {
            metres: mesh.units.metres() * scale,
            up: mesh.up,
        }
    }

    /// A point of the mesh file in the world frame: scaled to metres, then turned Y up.
    fn point(self, p: DVec3) -> DVec3 {
        self.direction(p * self.metres)
    }

    /// A direction of the mesh file in the world frame (turned Y up, not scaled).
    fn direction(self, d: DVec3) -> DVec3 {
        match self.up {
            UpAxis::Y => d,
            UpAxis::Z => y_up_from_z_up(d),
        }
    }
}

/// The mesh's vertices in the world frame and the character's height (metres); a
/// non-finite vertex, or (when all are finite) a mesh with no height, is a problem.
fn world_vertices(
    mesh: &MeshData,
    frame: WorldFrame,
    problems: &mut Vec<CharacterProblem>,
) -> (Vec<DVec3>, f64) {
    let vertices: Vec<DVec3> = mesh.positions.iter().map(|&p| frame.point(p)).collect();
    let non_finite = vertices.iter().position(|v| !v.is_finite());
    if let Some(i) = non_finite {
        problems.push(CharacterProblem::NonFiniteVertex {
            vertex: i,
            position: mesh.positions[i],
        });
        return (vertices, 0.0);
    }
    let (lo, hi) = robust_box(&vertices);
    let far: Vec<usize> = (0..vertices.len())
        .filter(|&i| is_far(vertices[i], lo, hi))
        .collect();
    if let Some(&first) = far.first() {
        problems.push(CharacterProblem::FarVertices {
            count: far.len(),
            vertex: first,
            at: mesh.vertex_at(first),
            position: mesh.positions[first],
            extent_m: (hi - lo).max_element(),
        });
    }
    let (lo, hi) = vertices.iter().filter(|v| !is_far(**v, lo, hi)).fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(a, b), v| (a.min(*v), b.max(*v)),
    );
    let height = (hi.y - lo.y).max(0.0);
    if height <= 0.0 {
        problems.push(CharacterProblem::NoHeight);
    }
    (vertices, height)
}

/// Whether the character's size (`size_m`, its largest extent in the world frame) is
/// from [`MIN_CHARACTER_SIZE_M`] to [`MAX_CHARACTER_SIZE_M`]; if not, the problem names
/// the size, the units and scale in force, and the vertex farthest (along an axis) from
/// the middle of the mesh (its vertices' median on each axis), with where the file gives
/// it (its OBJ line, or the glTF node whose transform placed it).
fn plausible_size(
    spec: &CharacterFile,
    mesh: &MeshData,
    vertices: &[DVec3],
    size_m: f64,
    problems: &mut Vec<CharacterProblem>,
) -> bool {
    if (MIN_CHARACTER_SIZE_M..=MAX_CHARACTER_SIZE_M).contains(&size_m) {
        return true;
    }
    let middle = percentile_point(vertices, 0.5);
    let farthest = (0..vertices.len())
        .max_by(|&a, &b| {
            let d = |v: usize| (vertices[v] - middle).abs().max_element();
            d(a).total_cmp(&d(b))
        })
        .unwrap_or(0);
    problems.push(CharacterProblem::ImplausibleSize {
        size_m,
        units: spec.mesh.units.name(),
        scale: spec.mesh.scale,
        vertex: farthest,
        at: mesh.vertex_at(farthest),
        position: mesh.positions.get(farthest).copied().unwrap_or_default(),
    });
    false
}

/// Share of the vertices, at each end of each axis, left out of the robust box.
const ROBUST_TAIL: f64 = 0.01;

/// How many robust boxes away from it a vertex is far (an extremity of a real asset,
/// a fingertip or an antenna, stays well within this).
const FAR_BOXES: f64 = 10.0;

/// The box holding the central 98 % of the vertices along each axis (the 1st to the
/// 99th percentile), so that a stray vertex does not stretch it.
fn robust_box(vertices: &[DVec3]) -> (DVec3, DVec3) {
    (
        percentile_point(vertices, ROBUST_TAIL),
        percentile_point(vertices, 1.0 - ROBUST_TAIL),
    )
}

/// The `q`-th percentile of the vertices along each axis (zero for no vertex).
fn percentile_point(vertices: &[DVec3], q: f64) -> DVec3 {
    let mut out = DVec3::ZERO;
    let mut axis: Vec<f64> = Vec::with_capacity(vertices.len());
    for a in 0..3 {
        axis.clear();
        axis.extend(vertices.iter().map(|v| v[a]));
        if !axis.is_empty() {
            out[a] = crate::runtime::stats::percentile(&mut axis, q);
        }
    }
    out
}

/// Whether `v` lies more than [`FAR_BOXES`] robust boxes outside `lo..hi`.
fn is_far(v: DVec3, lo: DVec3, hi: DVec3) -> bool {
    let size = (hi - lo).max_element().max(f64::MIN_POSITIVE);
    let outside = (lo - v).max(v - hi).max(DVec3::ZERO).max_element();
    outside > FAR_BOXES * size
}

/// Checks that the mesh, its world-frame `vertices` welded within `weld_tol` metres, is
/// a closed, manifold, consistently oriented surface, and that some triangle has an area
/// (more than a millionth of the size `size_m` squared; a mesh without one is said
/// once, as the only warning).
fn check_surface(
    mesh: &MeshData,
    vertices: &[DVec3],
    weld_tol: f64,
    size_m: f64,
) -> Vec<MeshWarning> {
    let tiny = (1e-6 * size_m).powi(2);
    let flat = mesh.triangles.iter().all(|t| {
        let [a, b, c] = t.map(|i| vertices[i as usize]);
        0.5 * (b - a).cross(c - a).length() <= tiny
    });
    if flat {
        return vec![MeshWarning::NoArea {
            triangles: mesh.triangles.len(),
        }];
    }
    let (map, _) = weld(vertices, weld_tol);
    let welded_tris: Vec<[u32; 3]> = mesh
        .triangles
        .iter()
        .map(|t| t.map(|i| map[i as usize]))
        .collect();
    let issues = surface_issues(&welded_tris);
    let mut warnings = Vec::new();
    if issues.is_clean() {
        return warnings;
    }
    // An edge of welded vertices, as the first file vertex of each.
    let at = |e: Option<(u32, u32)>| {
        e.map(|(a, b)| {
            let first = |w: u32| map.iter().position(|&m| m == w).unwrap_or(0);
            (first(a), first(b))
        })
    };
    if issues.open_edges > 0 {
        warnings.push(MeshWarning::Open {
            edges: issues.open_edges,
            example: at(issues.open_example),
        });
    }
    if issues.non_manifold_edges > 0 {
        warnings.push(MeshWarning::NonManifold {
            edges: issues.non_manifold_edges,
            example: at(issues.non_manifold_example),
        });
    }
    if issues.inconsistent_edges > 0 {
        warnings.push(MeshWarning::InconsistentOrientation {
            edges: issues.inconsistent_edges,
        });
    }
    warnings
}

/// The joints of the glTF skin, parents first (`skeleton.parents` overriding the file's
/// hierarchy), at their bind-pose positions, joints that carry no skin weight and have
/// none below them dropped ([`drop_unweighted`], named in `dropped.1`), zero-length
/// bones merged ([`merge_zero_length_bones`], into `dropped.0`); with each joint's
/// bind-pose X axis in the world frame (the default bend axis).
fn skin_joints(
    sk: &SkeletonSpec,
    mesh: &MeshData,
    frame: WorldFrame,
    problems: &mut Vec<CharacterProblem>,
    dropped: (&mut Vec<(String, String)>, &mut Vec<String>),
) -> (Vec<Joint>, Vec<Option<DVec3>>) {
    let (merged, unweighted) = dropped;
    if mesh.skin_joints.is_empty() {
        problems.push(CharacterProblem::NoSkin);
    }
    if !sk.joints.is_empty() {
        problems.push(CharacterProblem::JointsWithSkin);
    }
    // The first joint of each name (as a search in file order would find it).
    let mut index_of: HashMap<&str, usize> = HashMap::with_capacity(mesh.skin_joints.len());
    for (k, j) in mesh.skin_joints.iter().enumerate() {
        index_of.entry(j.name.as_str()).or_insert(k);
    }
    for (child, parent) in &sk.parents {
        for n in [child, parent] {
            if !index_of.contains_key(n.as_str()) {
                problems.push(CharacterProblem::UnknownSkinJoint { name: n.clone() });
            }
        }
    }
    // Parent by name overrides the file's hierarchy; order parents first.
    let parent: Vec<Option<usize>> = mesh
        .skin_joints
        .iter()
        .map(|j| match sk.parents.get(&j.name) {
            Some(p) => index_of.get(p.as_str()).copied(),
            None => j.parent,
        })
        .collect();
    let order = parents_first(&parent);
    if order.len() < parent.len() {
        problems.push(CharacterProblem::ParentCycle);
    }
    let mut joints = Vec::with_capacity(order.len());
    let mut skin_x_axis = Vec::with_capacity(order.len());
    let mut weighted = Vec::with_capacity(order.len());
    let mut slot = vec![usize::MAX; parent.len()];
    for (i, &k) in order.iter().enumerate() {
        weighted.push(mesh.skin_joints[k].weighted);
        slot[k] = i;
        let sj = &mesh.skin_joints[k];
        let m: DMat4 = sj.world_from_joint;
        joints.push(Joint {
            name: sj.name.clone(),
            parent: parent[k].map(|p| slot[p]),
            rest: frame.point(m.w_axis.truncate()),
            limits: None,
            bend_axis: DVec3::X,
        });
        skin_x_axis.push(Some(
            frame.direction(m.x_axis.truncate()).normalize_or_zero(),
        ));
    }
    let (joints, skin_x_axis) = drop_unweighted(joints, skin_x_axis, &weighted, unweighted);
    merge_zero_length_bones(joints, skin_x_axis, merged)
}

/// `joints` (parents first) without those that carry no skin weight and have no
/// weighted joint below them: a rig's IK poles, foot and hand controls, and sockets,
/// which move no vertex and would make roots and branches of their own. An end joint
/// (a weighted joint's only child, a leaf) stays. Their names go to `dropped`. Nothing
/// is dropped when no joint is weighted (a skin without weights).
fn drop_unweighted(
    joints: Vec<Joint>,
    axes: Vec<Option<DVec3>>,
    weighted: &[bool],
    dropped: &mut Vec<String>,
) -> (Vec<Joint>, Vec<Option<DVec3>>) {
    if !weighted.iter().any(|&w| w) {
        return (joints, axes);
    }
    // An end joint (a leaf, the only child of a weighted joint: `HeadTop_End`,
    // `LeftToe_End`) carries no weight but gives its parent's bone its length and
    // direction: kept.
    let n = joints.len();
    let mut children = vec![0usize; n];
    for j in &joints {
        if let Some(p) = j.parent.filter(|&p| p < n) {
            children[p] += 1;
        }
    }
    let end_joint = |i: usize| {
        children[i] == 0
            && joints[i]
                .parent
                .is_some_and(|p| p < n && weighted[p] && children[p] == 1)
    };
    // Children after parents: one pass from the end carries "keep" up.
    let mut keep: Vec<bool> = (0..n).map(|i| weighted[i] || end_joint(i)).collect();
    for i in (0..joints.len()).rev() {
        if let Some(p) = joints[i].parent.filter(|&p| keep[i] && p < i) {
            keep[p] = true;
        }
    }
    let mut new_index = vec![usize::MAX; joints.len()];
    let (mut out, mut out_axes) = (Vec::with_capacity(joints.len()), Vec::new());
    for (i, (j, axis)) in joints.into_iter().zip(axes).enumerate() {
        if !keep[i] {
            dropped.push(j.name);
            continue;
        }
        new_index[i] = out.len();
        // A kept joint's parent is kept (keep runs up the tree).
        let parent = j.parent.map(|p| new_index[p]);
        out.push(Joint { parent, ..j });
        out_axes.push(axis);
    }
    (out, out_axes)
}

/// `joints` (parents first) with every joint that sits on its parent (within a
/// millionth of the skeleton's extent: a file's root node above its first bone, an
/// armature's origin on the hips) merged into it: its children hang from the parent,
/// and `merged` gets (its name, the parent's). A glTF skin has such joints, and a bone
/// of no length has no direction to pose.
fn merge_zero_length_bones(
    joints: Vec<Joint>,
    axes: Vec<Option<DVec3>>,
    merged: &mut Vec<(String, String)>,
) -> (Vec<Joint>, Vec<Option<DVec3>>) {
    let origin = joints.first().map_or(DVec3::ZERO, |j| j.rest);
    let extent = joints
        .iter()
        .map(|j| (j.rest - origin).length())
        .filter(|d| d.is_finite())
        .fold(0.0, f64::max);
    let tol = (1e-6 * extent).max(1e-9);
    // Each joint's kept stand-in (itself, or the ancestor it merged into), and the kept
    // joints' new indices.
    let mut kept_as = vec![usize::MAX; joints.len()];
    let mut new_index = vec![usize::MAX; joints.len()];
    let (mut out, mut out_axes) = (Vec::with_capacity(joints.len()), Vec::new());
    for (i, (j, axis)) in joints.iter().zip(&axes).enumerate() {
        let parent = j.parent.filter(|&p| p < i).map(|p| kept_as[p]);
        if let Some(p) = parent.filter(|&p| (joints[p].rest - j.rest).length() <= tol) {
            kept_as[i] = p;
            merged.push((j.name.clone(), joints[p].name.clone()));
            continue;
        }
        kept_as[i] = i;
        new_index[i] = out.len();
        out.push(Joint {
            parent: parent.map(|p| new_index[p]),
            ..j.clone()
        });
        out_axes.push(*axis);
    }
    (out, out_axes)
}

/// The joints in the order of passes over them in index order, each pass placing every
/// joint whose parent is placed (so a parent listed after its child puts the child in
/// the next pass), in n log n time: a joint's pass is its parent's, or the
/// one after when the parent comes later. Joints on or below a cycle are left out.
fn parents_first(parent: &[Option<usize>]) -> Vec<usize> {
    let n = parent.len();
    let mut pass: Vec<Option<usize>> = vec![None; n];
    let mut visited = vec![false; n];
    let mut chain = Vec::new();
    for start in 0..n {
        // Up to a joint visited before (done, or on this walk: a cycle) or a root ...
        chain.clear();
        let mut k = start;
        while !visited[k] {
            visited[k] = true;
            chain.push(k);
            match parent[k] {
                Some(p) if p < n => k = p,
                _ => break,
            }
        }
        // ... then down, each joint's pass from its parent's (none yet on a cycle).
        for &c in chain.iter().rev() {
            pass[c] = match parent[c] {
                None => Some(0),
                Some(p) => pass
                    .get(p)
                    .copied()
                    .flatten()
                    .map(|q| if p < c { q } else { q + 1 }),
            };
        }
    }
    let mut order: Vec<usize> = (0..n).filter(|&k| pass[k].is_some()).collect();
    order.sort_by_key(|&k| (pass[k], k));
    order
}

/// The joints listed in `skeleton.joints`, in their order, with no default bend axes.
fn listed_joints(
    sk: &SkeletonSpec,
    mesh: &MeshData,
    frame: WorldFrame,
    problems: &mut Vec<CharacterProblem>,
) -> (Vec<Joint>, Vec<Option<DVec3>>) {
    if !sk.parents.is_empty() {
        problems.push(CharacterProblem::ParentsWithoutSkin);
    }
    if sk.joints.len() > MAX_SKIN_JOINTS {
        problems.push(CharacterProblem::TooManyJoints {
            count: sk.joints.len(),
        });
        return (Vec::new(), Vec::new());
    }
    let mut joints = Vec::with_capacity(sk.joints.len());
    for (i, j) in sk.joints.iter().enumerate() {
        let parent = match &j.parent {
            None => None,
            Some(p) => match sk.joints[..i].iter().position(|o| &o.name == p) {
                Some(pi) => Some(pi),
                None => {
                    problems.push(CharacterProblem::ParentNotListedBefore {
                        joint: j.name.clone(),
                        parent: p.clone(),
                    });
                    None
                }
            },
        };
        let rest = listed_rest(j, mesh, frame, problems);
        joints.push(Joint {
            name: j.name.clone(),
            parent,
            rest,
            limits: None,
            bend_axis: DVec3::X,
        });
    }
    let skin_x_axis = vec![None; joints.len()];
    (joints, skin_x_axis)
}

/// A listed joint's rest position, world frame: `rest_m`, or the mean of its
/// `rest_vertices` of the mesh file (zero when neither, or both, are usable).
fn listed_rest(
    j: &JointSpec,
    mesh: &MeshData,
    frame: WorldFrame,
    problems: &mut Vec<CharacterProblem>,
) -> DVec3 {
    match (&j.rest_m, &j.rest_vertices) {
        (Some(r), None) => DVec3::from_array(*r),
        (None, Some(ids)) if !ids.is_empty() => {
            let src = &mesh.source_positions;
            match ids.iter().find(|&&v| v >= src.len()) {
                Some(bad) => {
                    problems.push(CharacterProblem::RestVertexOutOfRange {
                        joint: j.name.clone(),
                        vertex: *bad,
                        vertex_count: src.len(),
                    });
                    DVec3::ZERO
                }
                None => ids.iter().map(|&v| frame.point(src[v])).sum::<DVec3>() / ids.len() as f64,
            }
        }
        _ => {
            problems.push(CharacterProblem::RestPosition {
                joint: j.name.clone(),
            });
            DVec3::ZERO
        }
    }
}

/// Checks that the joints make one tree with at least one bone (no joints at all is a
/// problem of its own only when nothing else is wrong).
fn check_tree(joints: &[Joint], problems: &mut Vec<CharacterProblem>) {
    if joints.is_empty() && problems.is_empty() {
        problems.push(CharacterProblem::NoSkeleton);
    }
    let roots: Vec<String> = joints
        .iter()
        .filter(|j| j.parent.is_none())
        .map(|j| j.name.clone())
        .collect();
    if roots.len() > 1 {
        problems.push(CharacterProblem::SeveralRoots { roots });
    }
    if joints.len() == 1 {
        problems.push(CharacterProblem::NoBone {
            joint: joints[0].name.clone(),
        });
    }
}

/// The humanoid role of each joint: recognised from the names and the tree, then
/// `skeleton.roles` applied (an unknown joint or role name is a problem).
fn joint_roles(
    sk: &SkeletonSpec,
    joints: &[Joint],
    problems: &mut Vec<CharacterProblem>,
) -> Vec<Option<Role>> {
    let mut overrides = Vec::with_capacity(sk.roles.len());
    for (name, role) in &sk.roles {
        let Some(j) = joints.iter().position(|j| &j.name == name) else {
            problems.push(CharacterProblem::RolesUnknownJoint {
                joint: name.clone(),
            });
            continue;
        };
        if role.eq_ignore_ascii_case("none") {
            overrides.push((j, None));
        } else if let Ok(r) = role.parse::<Role>() {
            overrides.push((j, Some(r)));
        } else {
            problems.push(CharacterProblem::UnknownRole {
                joint: name.clone(),
                role: role.clone(),
            });
        }
    }
    recognise(joints, &overrides)
}

/// Sets the limits of `skeleton.limits` on their joints, in radians, with their bend
/// axes (given; or the role's, whose positive bend is flexion; or the skin joint's X
/// axis).
fn apply_limits(
    sk: &SkeletonSpec,
    joints: &mut [Joint],
    role_axis: &[Option<DVec3>],
    skin_x_axis: &[Option<DVec3>],
    problems: &mut Vec<CharacterProblem>,
) {
    for (name, l) in &sk.limits {
        let Some(j) = joints.iter().position(|j| &j.name == name) else {
            problems.push(CharacterProblem::LimitsUnknownJoint {
                joint: name.clone(),
            });
            continue;
        };
        for (which, [a, b]) in [
            ("twist_deg", l.twist_deg),
            ("bend_deg", l.bend_deg),
            ("side_deg", l.side_deg),
        ] {
            if !(a.is_finite() && b.is_finite()) || a > b {
                problems.push(CharacterProblem::BadLimitRange {
                    joint: name.clone(),
                    which,
                    min: a,
                    max: b,
                });
            }
        }
        let axis = l
            .bend_axis
            .map(DVec3::from_array)
            .or(role_axis.get(j).copied().flatten())
            .or(skin_x_axis.get(j).copied().flatten());
        match axis {
            Some(a) if a.is_finite() && a.length() > 1e-9 => joints[j].bend_axis = a.normalize(),
            _ => problems.push(CharacterProblem::BendAxisRequired {
                joint: name.clone(),
            }),
        }
        let r = |v: [f64; 2]| (v[0].to_radians(), v[1].to_radians());
        joints[j].limits = Some(JointLimits {
            twist: r(l.twist_deg),
            bend: r(l.bend_deg),
            side: r(l.side_deg),
        });
    }
}

/// The skeleton, if the joints make a valid one, with every bend axis made
/// perpendicular to its joint's twist axis (a limited joint's bend axis along its bone
/// is a problem).
fn finish_skeleton(joints: Vec<Joint>, problems: &mut Vec<CharacterProblem>) -> Option<Skeleton> {
    let mut s = match Skeleton::new(joints) {
        Ok(s) => s,
        Err(errs) => {
            problems.extend(errs.into_iter().map(CharacterProblem::Skeleton));
            return None;
        }
    };
    let given: Vec<DVec3> = s.joints.iter().map(|j| j.bend_axis).collect();
    for j in s.orthogonalize_bend_axes() {
        if s.joints[j].limits.is_some() {
            problems.push(CharacterProblem::BendAxisAlongBone {
                joint: s.joints[j].name.clone(),
                axis: given[j],
            });
        }
    }
    Some(s)
}

/// The marker layout of `[[markers]]`, in file order (names unique, positions finite;
/// at most [`MAX_MARKERS`], else none is placed). Linear in the markers: names and
/// joints are looked up by hash.
fn place_markers(
    specs: &[MarkerSpec],
    skeleton: Option<&Skeleton>,
    problems: &mut Vec<CharacterProblem>,
) -> Vec<MarkerDef> {
    if specs.len() > MAX_MARKERS {
        problems.push(CharacterProblem::TooManyMarkers {
            count: specs.len(),
            max: MAX_MARKERS,
        });
        return Vec::new();
    }
    let joints = skeleton.map(JointIndex::of);
    let skeleton = skeleton.zip(joints.as_ref());
    let mut seen = std::collections::HashSet::with_capacity(specs.len());
    let mut markers = Vec::with_capacity(specs.len());
    for m in specs {
        if !seen.insert(m.name.as_str()) {
            problems.push(CharacterProblem::DuplicateMarker {
                marker: m.name.clone(),
            });
        }
        let (rest, joint) = marker_rest(m, skeleton, problems);
        if !rest.is_finite() {
            problems.push(CharacterProblem::MarkerNotFinite {
                marker: m.name.clone(),
            });
        }
        markers.push(MarkerDef {
            name: m.name.clone(),
            rest,
            joint,
        });
    }
    markers
}

/// A skeleton's joints by name (the first of a name, as a search in order finds it), and
/// which are leaves.
struct JointIndex<'a> {
    by_name: HashMap<&'a str, usize>,
    leaf: Vec<bool>,
}

impl<'a> JointIndex<'a> {
    fn of(s: &'a Skeleton) -> Self {
        let mut by_name = HashMap::with_capacity(s.joints.len());
        let mut leaf = vec![true; s.joints.len()];
        for (j, joint) in s.joints.iter().enumerate() {
            by_name.entry(joint.name.as_str()).or_insert(j);
            if let Some(p) = joint.parent.and_then(|p| leaf.get_mut(p)) {
                *p = false;
            }
        }
        Self { by_name, leaf }
    }
}

/// A marker's rest position and the joint whose bone carries it: `position_m` (joint
/// decided at bind time), or its bone's joint plus `offset_m` (a leaf joint's bone is
/// its parent's). Zero and no joint when the marker cannot be placed.
fn marker_rest(
    m: &MarkerSpec,
    skeleton: Option<(&Skeleton, &JointIndex)>,
    problems: &mut Vec<CharacterProblem>,
) -> (DVec3, Option<usize>) {
    match (&m.position_m, &m.bone, skeleton) {
        (Some(p), None, _) => (DVec3::from_array(*p), None),
        (None, Some(b), Some((s, index))) => match index.by_name.get(b.as_str()) {
            Some(&j) => {
                let off = DVec3::from_array(m.offset_m.unwrap_or([0.0; 3]));
                // A leaf joint's bone is the segment that ends at it.
                let carrier = if index.leaf[j] {
                    s.joints[j].parent.unwrap_or(j)
                } else {
                    j
                };
                (s.joints[j].rest + off, Some(carrier))
            }
            None => {
                problems.push(CharacterProblem::MarkerUnknownBone {
                    marker: m.name.clone(),
                    bone: b.clone(),
                });
                (DVec3::ZERO, None)
            }
        },
        (None, Some(_), None) => (DVec3::ZERO, None),
        _ => {
            problems.push(CharacterProblem::MarkerPlacement {
                marker: m.name.clone(),
            });
            (DVec3::ZERO, None)
        }
    }
}

/// The binding settings of `[bind]`, defaults scaled to the character's size (`size`:
/// its longest extent, metres, when it is known and plausible). Each setting the file
/// gives must be a positive, finite number, the cell neither absurdly small nor larger
/// than [`MAX_CELL_SHARE`] of the size, the skeleton step not absurdly small against the
/// cell; every problem names the key the file sets. Defaults follow a size from 1 mm to
/// 1 km and are then positive and finite; without one they are not judged (the size's
/// problem is said instead of a key the file does not set).
fn bind_params(
    b: &BindSpec,
    size: Option<f64>,
    default_cell: Option<&CellChoice>,
    problems: &mut Vec<CharacterProblem>,
) -> BindParams {
    let size_m = size.unwrap_or(0.0);
    let cell = b
        .cell_size_m
        .or(default_cell.map(|c| c.cell_size_m))
        .unwrap_or(0.032 * size_m);
    let params = BindParams {
        cell_size_m: cell,
        skeleton_step_m: b.skeleton_step_m.unwrap_or(0.9 * cell),
        w_shape: b.w_shape.unwrap_or(1.0),
        w_marker: b.w_marker.unwrap_or(30.0),
        w_skeleton: b.w_skeleton.unwrap_or(1000.0),
        max_marker_distance_m: b.max_marker_distance_m.unwrap_or(0.1 * size_m),
    };
    let mut sound = true;
    for (name, given) in [
        ("bind.cell_size_m", b.cell_size_m),
        ("bind.skeleton_step_m", b.skeleton_step_m),
        ("bind.w_shape", b.w_shape),
        ("bind.w_marker", b.w_marker),
        ("bind.w_skeleton", b.w_skeleton),
        ("bind.max_marker_distance_m", b.max_marker_distance_m),
    ] {
        if let Some(value) = given.filter(|v| !(v.is_finite() && *v > 0.0)) {
            sound = false;
            problems.push(CharacterProblem::NotPositive {
                setting: name,
                value,
            });
        }
    }
    if !sound {
        return params;
    }
    let cell_size_m = params.cell_size_m;
    if let Some(size_m) = size.filter(|_| b.cell_size_m.is_some()) {
        if cell_size_m < size_m / 400.0 {
            problems.push(CharacterProblem::CellTooSmall {
                cell_size_m,
                size_m,
            });
        }
        if cell_size_m > MAX_CELL_SHARE * size_m {
            problems.push(CharacterProblem::CellTooLarge {
                cell_size_m,
                size_m,
            });
        }
    }
    if (size.is_some() || b.cell_size_m.is_some()) && params.skeleton_step_m < cell_size_m / 100.0 {
        problems.push(CharacterProblem::StepTooSmall {
            step_m: params.skeleton_step_m,
            cell_size_m,
        });
    }
    params
}

/// The harmonic method's correspondences of `[[correspondences]]` by joint index (each
/// joint once, known to the skeleton, with triangles of the mesh's `triangle_count`).
fn correspondences(
    specs: &[CorrespondenceSpec],
    skeleton: Option<&Skeleton>,
    triangle_count: usize,
    problems: &mut Vec<CharacterProblem>,
) -> Vec<Correspondence> {
    let mut out = Vec::new();
    let mut seen = std::collections::HashSet::with_capacity(specs.len());
    for (index, c) in specs.iter().enumerate() {
        if !seen.insert(c.joint.as_str()) {
            problems.push(CharacterProblem::CorrespondenceTwice {
                index,
                joint: c.joint.clone(),
            });
        }
        let joint = skeleton.and_then(|s| s.joints.iter().position(|j| j.name == c.joint));
        if skeleton.is_some() && joint.is_none() {
            problems.push(CharacterProblem::CorrespondenceUnknownJoint {
                index,
                joint: c.joint.clone(),
            });
        }
        if c.triangles.is_empty() {
            problems.push(CharacterProblem::CorrespondenceEmpty {
                index,
                joint: c.joint.clone(),
            });
        }
        if let Some(&t) = c.triangles.iter().find(|&&t| t >= triangle_count) {
            problems.push(CharacterProblem::CorrespondenceTriangleOutOfRange {
                index,
                joint: c.joint.clone(),
                triangle: t,
                triangle_count,
            });
        }
        if let Some(joint) = joint {
            out.push(Correspondence {
                joint,
                triangles: c.triangles.iter().map(|&t| t as u32).collect(),
            });
        }
    }
    out
}

/// Writes a character as `DIR/NAME.obj` and a character file `DIR/NAME.toml` that loads
/// it back (listed joints with limits and bend axes, markers on their bones). Returns the
/// character file's path. The procedural characters use it to become files users can
/// start from; the tests use it to run the file path end to end.
pub fn write_character_files(
    ch: &Character,
    bind: Option<&BindParams>,
    dir: &Path,
) -> std::io::Result<PathBuf> {
    use std::io::Write as _;
    std::fs::create_dir_all(dir)?;
    let create = |path: &Path| std::fs::File::create(path).map(std::io::BufWriter::new);
    let mut obj = create(&dir.join(format!("{}.obj", ch.name)))?;
    writeln!(obj, "# {} (written by rigless)\no {}", ch.name, ch.name)?;
    for v in &ch.vertices {
        writeln!(obj, "v {:?} {:?} {:?}", v.x, v.y, v.z)?;
    }
    for t in &ch.triangles {
        writeln!(obj, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
    }
    obj.flush()?;
    let path = dir.join(format!("{}.toml", ch.name));
    let mut toml = create(&path)?;
    writeln!(
        toml,
        "# {} (written by rigless): metres, Y up.\nname = {:?}\n\n[mesh]\npath = \"{}.obj\"\nunits = \"m\"\nup = \"y\"\n",
        ch.name, ch.name, ch.name
    )?;
    if let Some(b) = bind {
        writeln!(
            toml,
            "[bind]\ncell_size_m = {:?}\nskeleton_step_m = {:?}\nw_shape = {:?}\nw_marker = {:?}\nw_skeleton = {:?}\nmax_marker_distance_m = {:?}\n",
            b.cell_size_m, b.skeleton_step_m, b.w_shape, b.w_marker, b.w_skeleton, b.max_marker_distance_m
        )?;
    }
    // Every limit is written: a joint free here stays free, whatever its role.
    writeln!(toml, "[skeleton]\nrole_limits = false\n")?;
    let sk = &ch.skeleton;
    for j in &sk.joints {
        writeln!(toml, "[[skeleton.joints]]\nname = {:?}", j.name)?;
        if let Some(p) = j.parent {
            writeln!(toml, "parent = {:?}", sk.joints[p].name)?;
        }
        writeln!(
            toml,
            "rest_m = [{:?}, {:?}, {:?}]\n",
            j.rest.x, j.rest.y, j.rest.z
        )?;
    }
    for j in &sk.joints {
        if let Some(l) = j.limits {
            let d = |(a, b): (f64, f64)| format!("[{:?}, {:?}]", degrees_of(a), degrees_of(b));
            writeln!(
                toml,
                "[skeleton.limits.{:?}]\ntwist_deg = {}\nbend_deg = {}\nside_deg = {}\nbend_axis = [{:?}, {:?}, {:?}]\n",
                j.name,
                d(l.twist),
                d(l.bend),
                d(l.side),
                j.bend_axis.x,
                j.bend_axis.y,
                j.bend_axis.z
            )?;
        }
    }
    for m in &ch.markers {
        writeln!(toml, "[[markers]]\nname = {:?}", m.name)?;
        match m.joint {
            Some(j) => {
                let o = m.rest - sk.joints[j].rest;
                writeln!(
                    toml,
                    "bone = {:?}\noffset_m = [{:?}, {:?}, {:?}]\n",
                    sk.joints[j].name, o.x, o.y, o.z
                )?;
            }
            None => {
                writeln!(
                    toml,
                    "position_m = [{:?}, {:?}, {:?}]\n",
                    m.rest.x, m.rest.y, m.rest.z
                )?;
            }
        }
    }
    for c in &ch.correspondences {
        writeln!(
            toml,
            "[[correspondences]]\njoint = {:?}\ntriangles = {:?}\n",
            sk.joints[c.joint].name, c.triangles
        )?;
    }
    toml.flush()?;
    Ok(path)
}

/// `radians` in degrees, as the value nearest `radians.to_degrees()` (within 8 ulps)
/// that reads back to `radians` exactly through `to_radians`, so a limit that was read
/// from degrees (every loaded and procedural one) is written back bit for bit; 3° written
/// as `to_degrees` alone reads back an ulp off. Some radian values have no such degree
/// value (`to_radians` steps over them); those are written as `to_degrees` gives them.
fn degrees_of(radians: f64) -> f64 {
    let mut up = radians.to_degrees();
    let mut down = up;
    for _ in 0..=8 {
        for d in [up, down] {
            if d.to_radians() == radians {
                return d;
            }
        }
        (up, down) = (up.next_up(), down.next_down());
    }
    radians.to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A skin's root node sitting on its first bone (the Khronos Fox's) is merged into
    /// it, and the bones below hang from it; a real bone stays.
    /// A joint at height `y` on the Y axis.
    fn joint(name: &str, parent: Option<usize>, y: f64) -> Joint {
        Joint {
            name: name.into(),
            parent,
            rest: DVec3::new(0.0, y, 0.0),
            limits: None,
            bend_axis: DVec3::X,
        }
    }

    #[test]
    fn zero_length_bones_are_merged_into_their_parents() {
        let joints = vec![
            joint("root", None, 1.0),
            joint("b_Root_00", Some(0), 1.0 + 1e-9),
            joint("b_Spine", Some(1), 1.3),
            joint("b_Hip_L", Some(1), 0.9),
            joint("b_Spine_end", Some(2), 1.3),
        ];
        let axes = vec![Some(DVec3::X); joints.len()];
        let mut merged = Vec::new();
        let (out, axes) = merge_zero_length_bones(joints, axes, &mut merged);
        let names: Vec<&str> = out.iter().map(|j| j.name.as_str()).collect();
        assert_eq!(names, ["root", "b_Spine", "b_Hip_L"]);
        let parents: Vec<Option<usize>> = out.iter().map(|j| j.parent).collect();
        assert_eq!(parents, [None, Some(0), Some(0)]);
        assert_eq!(axes.len(), 3);
        assert_eq!(
            merged,
            [
                ("b_Root_00".to_string(), "root".to_string()),
                ("b_Spine_end".to_string(), "b_Spine".to_string())
            ]
        );
        assert!(Skeleton::new(out).is_ok());
    }

    /// A Blender rig's IK pole (a root of its own) and foot control (a leaf under the
    /// hips), which no vertex is weighted to, are dropped; an unweighted joint with a
    /// weighted one below it (an armature root) stays.
    #[test]
    fn unweighted_joints_with_nothing_weighted_below_are_dropped() {
        let joints = vec![
            joint("root", None, 0.0),
            joint("knee_pole.L", None, 0.5),
            joint("hips", Some(0), 1.0),
            joint("foot_ctrl.L", Some(2), 0.1),
            joint("spine", Some(2), 1.3),
            joint("ctrl_child", Some(3), 0.05),
            joint("spine_end", Some(4), 1.6),
        ];
        let weighted = [false, false, true, false, true, false, false];
        let axes = vec![Some(DVec3::X); joints.len()];
        let mut dropped = Vec::new();
        let (out, axes) = drop_unweighted(joints.clone(), axes, &weighted, &mut dropped);
        let names: Vec<&str> = out.iter().map(|j| j.name.as_str()).collect();
        // The spine's end joint, its only child, stays: it gives the spine its length.
        assert_eq!(names, ["root", "hips", "spine", "spine_end"]);
        let parents: Vec<Option<usize>> = out.iter().map(|j| j.parent).collect();
        assert_eq!(parents, [None, Some(0), Some(1), Some(2)]);
        assert_eq!(axes.len(), 4);
        assert_eq!(dropped, ["knee_pole.L", "foot_ctrl.L", "ctrl_child"]);
        assert!(Skeleton::new(out).is_ok());
        // No weights known: nothing dropped.
        let none = [false; 7];
        let mut dropped = Vec::new();
        let axes = vec![None; joints.len()];
        let (out, _) = drop_unweighted(joints, axes, &none, &mut dropped);
        assert_eq!((out.len(), dropped.len()), (7, 0));
    }

    /// Lying down is judged by the trunk: a half-body avatar with wide arms is wider
    /// than tall and stands; a trunk along the floor lies whatever the extents say.
    #[test]
    fn lying_down_is_judged_by_the_trunk_when_there_is_one() {
        let body = crate::character::demo::demo_body();
        let roles = recognise(&body.skeleton.joints, &[]);
        let upright = trunk_lean_deg(&body.skeleton, &roles).expect("hips and head");
        assert!(upright < 5.0, "{upright}");
        let mut joints = body.skeleton.joints.clone();
        for j in &mut joints {
            j.rest = y_up_from_z_up(j.rest);
        }
        let lying = Skeleton::new(joints).expect("a skeleton");
        let lean = trunk_lean_deg(&lying, &roles).expect("hips and head");
        assert!(lean > 85.0, "{lean}");
        assert!(lying_down(Some(upright), 0.8, 1.7, UpAxis::Y).is_none());
        assert!(matches!(
            lying_down(Some(lean), 1.7, 1.7, UpAxis::Z),
            Some(MeshWarning::TrunkLyingDown { .. })
        ));
        // No trunk (a hand): the mesh's extents.
        assert!(matches!(
            lying_down(None, 0.3, 1.7, UpAxis::Y),
            Some(MeshWarning::LyingDown { .. })
        ));
        assert!(lying_down(None, 1.7, 1.7, UpAxis::Y).is_none());
    }

    #[test]
    fn limits_in_degrees_read_back_to_the_bit() {
        for deg in [3.0f64, -3.0, 5.0, 10.0, 145.0, -70.0, 0.1, 33.3, 179.9] {
            let r = deg.to_radians();
            assert_eq!(degrees_of(r).to_radians(), r, "{deg}");
        }
    }

    #[test]
    fn a_stray_vertex_is_named_not_taken_for_a_huge_mesh() {
        // A unit cube with one vertex pulled to 1e5 m (and an 8-vertex cube is too small
        // for percentiles: a 10x10x10 grid of points stands in for the mesh).
        let mut positions: Vec<DVec3> = (0..1000)
            .map(|i| DVec3::new((i % 10) as f64, (i / 10 % 10) as f64, (i / 100) as f64) * 0.1)
            .collect();
        positions[17] = DVec3::new(1e5, 0.0, 0.0);
        let mesh = MeshData {
            positions,
            ..MeshData::default()
        };
        let mut problems = Vec::new();
        let frame = WorldFrame {
            metres: 1.0,
            up: UpAxis::Y,
        };
        let (_, height) = world_vertices(&mesh, frame, &mut problems);
        assert!(
            (height - 0.9).abs() < 1e-12,
            "the rest's height, not the stray's: {height}"
        );
        let text: Vec<String> = problems.iter().map(ToString::to_string).collect();
        assert_eq!(text.len(), 1, "{text:?}");
        assert!(
            text[0]
                .starts_with("1 mesh vertices lie far from the rest of the mesh, e.g. vertex 17"),
            "{text:?}"
        );
    }

    /// The order before [`parents_first`]: passes over the joints in index order, each
    /// placing every joint whose parent is placed (quadratic in the joints).
    fn passes(parent: &[Option<usize>]) -> Vec<usize> {
        let n = parent.len();
        let mut order = Vec::new();
        let mut placed = vec![false; n];
        for _ in 0..n {
            for k in 0..n {
                if !placed[k] && parent[k].is_none_or(|p| placed[p]) {
                    placed[k] = true;
                    order.push(k);
                }
            }
        }
        order
    }

    #[test]
    fn parents_first_orders_as_the_passes_did_in_n_log_n_time() {
        // Every parent array of up to 6 joints (each joint's parent: none or any joint,
        // itself included), against the passes.
        for n in 0..=6usize {
            let mut choice = vec![0usize; n];
            loop {
                let parent: Vec<Option<usize>> = choice.iter().map(|&c| c.checked_sub(1)).collect();
                assert_eq!(parents_first(&parent), passes(&parent), "{parent:?}");
                let Some(k) = (0..n).find(|&k| choice[k] < n) else {
                    break;
                };
                choice[k] += 1;
                choice[..k].iter_mut().for_each(|c| *c = 0);
            }
        }
        // A million joints, each the parent of the one before it (the passes placed one a
        // pass: 10^12 steps), and a million on a cycle.
        let n = 1_000_000;
        let chain: Vec<Option<usize>> = (0..n).map(|k| (k + 1 < n).then_some(k + 1)).collect();
        let t0 = std::time::Instant::now();
        let order = parents_first(&chain);
        assert_eq!(order.len(), n);
        assert_eq!((order[0], order[n - 1]), (n - 1, 0));
        let cycle: Vec<Option<usize>> = (0..n).map(|k| Some((k + 1) % n)).collect();
        assert!(parents_first(&cycle).is_empty());
        assert!(t0.elapsed().as_secs_f64() < 2.0, "{:?}", t0.elapsed());
    }

    #[test]
    fn every_unknown_key_of_a_character_file_is_reported_at_once() {
        let text = "name = \"x\"\nfoo = 1\nbar = 2\n[mesh]\npath = \"a.obj\"\nbaz = 3\n";
        let problems = read_spec(text).unwrap_err();
        assert_eq!(problems.len(), 3, "{problems:#?}");
        assert!(
            problems[0].starts_with("line 2: foo: unknown field"),
            "{problems:?}"
        );
        assert!(
            problems[1].starts_with("line 3: bar: unknown field"),
            "{problems:?}"
        );
        assert!(
            problems[2].starts_with("line 6: mesh.baz: unknown field"),
            "{problems:?}"
        );
    }
}
