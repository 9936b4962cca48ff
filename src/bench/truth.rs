//! The `truth` suite: known truth on real assets. Each skinned glTF asset of the shared
//! data folder plays its own animations through its own skinning
//! ([`crate::character::animation`]); a Plug-in Gait marker set ([`LANDMARKS`]) is put on
//! its skin at rest, 8 mm out (a 14 mm marker on its base, scaled with the character),
//! and follows the posed skin. The take those markers make is calibrated onto the asset
//! with its layout unknown, as a user's take would be, and solved through the live
//! pipeline; the solve is then held against the skinned mesh.
//!
//! Per case: the calibration's verdict, scale error (the truth is 1) and placement error
//! (each placed label's rest position against its true one); the vertex error (mean over
//! the mesh, as a share of the character's height) of the mean frame and the worst; the
//! worst head and trunk orientation error (each joint's rotation from rest against the
//! skinning's); the lowest vertex against the true lowest; and how far the animation
//! itself takes a joint past the human range the solve holds it to. A clip whose end
//! meets its start loops to a few seconds; any other is played once ([`truth_take`]).

use super::assets::gltf_file;
use super::{json_line, BenchError};
use crate::calibrate::landmarks::{body_axes, segment_axes};
use crate::calibrate::marker_sets::{candidate_joints, normalise};
use crate::calibrate::{calibrate, Calibration, CalibrationOptions, Verdict};
use crate::character::animation::{Clip, SkinnedAsset};
use crate::character::file::{load_character, LoadedCharacter};
use crate::character::mesh::welded_outward;
use crate::character::roles::{Part, Role, Side};
use crate::character::{Character, MarkerDef};
use crate::daemon::offline::{replay_offline_with, OfflineOptions};
use crate::geom::polar::{best_rotation, rotation_angle_between, rotation_of};
use crate::geom::ray::{leaves_volume, Reach};
use crate::geom::winding::WindingNumber;
use crate::replay::recording::Recording;
use crate::solve::frame::SolverParams;
use glam::{DMat3, DMat4, DQuat, DVec3};
use std::io::Write;
use std::ops::ControlFlow;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// The take's rate, Hz (the replay's too: tick `i` is frame `i`).
const RATE_HZ: f64 = 120.0;
/// Shortest take, seconds: a short clip that loops is played again until it lasts this
/// long.
const MIN_TAKE_S: f64 = 4.0;
/// A clip loops when no marker moves across its seam (last frame to first) more than
/// this many times the clip's longest step between two frames: the seam then looks like
/// any other frame.
const SEAM_STEPS: f64 = 1.5;
/// A marker's centre above the skin, metres (a 14 mm marker: 7 mm, plus its base),
/// whatever the character's size: the take is at the character's size, and a marker is
/// a marker.
const MARKER_OUT_M: f64 = 0.008;
/// Thickest layer of a character's surface on a 1.75 m actor (clothing over a body,
/// armour over clothing), metres; scaled with the character's height.
const LAYER_M: f64 = 0.03;
const ACTOR_HEIGHT_M: f64 = 1.75;

/// Which joint of a part anchors a landmark.
#[derive(Clone, Copy, Debug)]
enum Pick {
    /// The first joint with the role (parents first).
    First,
    /// The last (the top of a spine chain).
    Last,
    /// The middle one.
    Middle,
}

/// A landmark of the marker set: label (`{S}` for the side letter), the part whose joint
/// anchors it, which of several, how far along the part's bone (0 at its joint, 1 at its
/// end; below 0 before the joint), and the direction out to the skin in the body's axes
/// (front, up, away from the midline; orthogonalised against the bone).
type Landmark = (&'static str, Part, Pick, f64, [f64; 3]);

/// Vicon Plug-in Gait's 39 markers, placed as its manual places them, roughly: what
/// matters here is that each sits on the skin of the part its table names.
const LANDMARKS: &[Landmark] = &[
    ("{S}FHD", Part::Head, Pick::First, 0.5, [1.0, 0.4, 0.6]),
    ("{S}BHD", Part::Head, Pick::First, 0.5, [-1.0, 0.4, 0.6]),
    ("C7", Part::Spine, Pick::Last, 1.0, [-1.0, 0.3, 0.0]),
    ("CLAV", Part::Spine, Pick::Last, 1.0, [1.0, 0.0, 0.0]),
    ("T10", Part::Spine, Pick::Middle, 0.5, [-1.0, 0.0, 0.0]),
    ("STRN", Part::Spine, Pick::Middle, 1.0, [1.0, 0.0, 0.0]),
    // On the right scapula: "away from the midline" is the left, so negative.
    ("RBAK", Part::Spine, Pick::Last, 0.5, [-1.0, 0.0, -0.6]),
    ("{S}SHO", Part::UpperArm, Pick::First, 0.0, [0.0, 1.0, 0.2]),
    ("{S}UPA", Part::UpperArm, Pick::First, 0.5, [-0.3, 0.0, 1.0]),
    ("{S}ELB", Part::UpperArm, Pick::First, 1.0, [-1.0, 0.0, 0.5]),
    ("{S}FRM", Part::LowerArm, Pick::First, 0.5, [0.0, 1.0, 0.5]),
    ("{S}WRA", Part::LowerArm, Pick::First, 1.0, [1.0, 0.0, 0.0]),
    ("{S}WRB", Part::LowerArm, Pick::First, 1.0, [-1.0, 0.0, 0.0]),
    ("{S}FIN", Part::Hand, Pick::First, 0.5, [0.0, 1.0, 0.5]),
    (
        "{S}ASI",
        Part::UpperLeg,
        Pick::First,
        -0.15,
        [1.0, 0.2, 0.4],
    ),
    (
        "{S}PSI",
        Part::UpperLeg,
        Pick::First,
        -0.2,
        [-1.0, 0.0, 0.3],
    ),
    ("{S}THI", Part::UpperLeg, Pick::First, 0.65, [0.3, 0.0, 1.0]),
    ("{S}KNE", Part::UpperLeg, Pick::First, 1.0, [0.0, 0.0, 1.0]),
    ("{S}TIB", Part::LowerLeg, Pick::First, 0.65, [0.3, 0.0, 1.0]),
    ("{S}ANK", Part::LowerLeg, Pick::First, 1.0, [0.0, 0.0, 1.0]),
    ("{S}HEE", Part::Foot, Pick::First, 0.0, [-1.0, -0.3, 0.0]),
    ("{S}TOE", Part::Foot, Pick::First, 0.9, [0.0, 1.0, 0.0]),
];

/// One case's figures.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TruthRecord {
    pub suite: &'static str,
    pub asset: String,
    pub clip: String,
    pub height_m: f64,
    pub take_s: f64,
    /// Markers put on the skin, and labels the calibration placed.
    pub markers: usize,
    pub placed: usize,
    pub verdict: Verdict,
    pub concerns: Vec<String>,
    /// The calibration's misfit RMS, take millimetres.
    pub misfit_mm_rms: f64,
    /// |scale − 1|.
    pub scale_error: f64,
    /// Placed labels' rest positions against the truth, millimetres.
    pub placement_mm_mean: f64,
    pub placement_mm_max: f64,
    /// The [`WORST_PLACED`] labels placed furthest from the truth, millimetres.
    pub worst_placed: Vec<(String, f64)>,
    /// The marker set's templates on the character ([`crate::calibrate::landmarks`])
    /// against the truth, mean, millimetres: where the labels would be were the take no
    /// help.
    pub template_mm_mean: f64,
    /// The placed labels' rest positions against their templates, mean and the largest
    /// with its label, millimetres: how far the take moved them from where they started.
    pub from_template_mm_mean: f64,
    pub from_template_mm_max: (String, f64),
    /// Mean vertex error over the mesh as a share of the height: its mean over the
    /// frames, its worst frame, and the largest single vertex error.
    pub vertex_share_mean: f64,
    pub vertex_share_worst_frame: f64,
    pub vertex_share_max: f64,
    /// Where the vertex error lies: per region of the body ([`REGIONS`]) that holds
    /// vertices, its share of the mesh's vertices and its own mean vertex error as a
    /// share of the height (over every frame).
    pub by_region: Vec<(&'static str, f64, f64)>,
    /// Worst orientation error over the frames, degrees: the head, the trunk (hips and
    /// the top of the spine), and any joint that carries a marker.
    pub head_deg_max: f64,
    pub trunk_deg_max: f64,
    pub carrying_deg_max: f64,
    /// Lowest solved vertex less the lowest true one, millimetres: median and worst.
    pub floor_mm_median: f64,
    pub floor_mm_worst: f64,
    /// How far the file's rest pose is from its bind pose (largest skinning-matrix
    /// entry off the identity; an armature's unit scale and axis turn count).
    pub rest_off_bind: f64,
    /// The animation's own worst excursion past the character's joint limits (the human
    /// ranges of its joints' roles; fingers left out): the joint and how far, degrees.
    /// A solve held to human ranges cannot follow it there (see [`beyond_limits`]).
    pub beyond_limits: Option<(String, f64)>,
    /// How far the skin's own markers turn from their bone ([`skin_slide`]): each joint
    /// that carries three or more, with the angle, degrees, furthest first. A solve that
    /// holds markers rigid on their bones (this one, and any marker-based one) sees
    /// that joint's turn no closer.
    pub skin_slide: Vec<(String, f64)>,
    pub calibrate_s: f64,
    pub solve_s: f64,
    /// The same take solved with the markers' true layout and scale: what the solve
    /// alone reaches, the floor under every calibrated figure.
    pub true_layout: Reference,
}

/// Figures of a solve with the true layout (see [`TruthRecord`] for each).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Reference {
    pub vertex_share_mean: f64,
    pub by_region: Vec<(&'static str, f64, f64)>,
    pub vertex_share_worst_frame: f64,
    pub head_deg_max: f64,
    pub trunk_deg_max: f64,
}

/// `rec` solved with the markers where they truly are (each on the joint it was put on
/// by) at scale 1, held against `truth`.
fn true_layout_solve(
    loaded: &LoadedCharacter,
    markers: &[(String, SkinPoint, usize)],
    truth: &mut Truth<'_>,
    rec: &Recording,
    watched: &[Vec<usize>; 3],
    what: &str,
) -> Result<Reference, BenchError> {
    let ch = &loaded.character;
    let (lo, hi) = crate::geom::shapes::bounds(&ch.vertices);
    let layout: Vec<MarkerDef> = markers
        .iter()
        .map(|(name, point, joint)| MarkerDef {
            name: name.clone(),
            rest: point.at(&ch.vertices),
            joint: Some(*joint),
        })
        .collect();
    let bind = loaded.bind_for(&layout);
    let laid = Character {
        markers: layout,
        ..ch.clone()
    };
    let rig = crate::rig::bind::Rig::bind(&laid, &bind).map_err(|e| BenchError::case(what, e))?;
    let regions = vertex_regions(loaded, truth.asset);
    let tally = solve_against(
        truth,
        Arc::new(rig),
        rec,
        1.0,
        watched,
        &regions,
        hi.y - lo.y,
    )
    .map_err(|e| BenchError::case(what, e))?;
    let n = tally.frame_means.len().max(1) as f64;
    Ok(Reference {
        vertex_share_mean: tally.frame_means.iter().sum::<f64>() / n,
        by_region: by_region(&tally),
        vertex_share_worst_frame: tally.frame_means.iter().copied().fold(0.0, f64::max),
        head_deg_max: tally.head_deg,
        trunk_deg_max: tally.trunk_deg,
    })
}

/// The file space to the character's world frame (units and up axis), fitted on the
/// rest vertices: `world = scale · rotation · file + translation`.
#[derive(Clone, Copy, Debug)]
struct Similarity {
    scale: f64,
    rotation: DQuat,
    translation: DVec3,
}

impl Similarity {
    /// Umeyama's least-squares similarity (1991) from `from` to `to`, and its largest
    /// residual.
    fn fit(from: &[DVec3], to: &[DVec3]) -> (Self, f64) {
        let n = from.len().max(1) as f64;
        let (cf, ct) = (from.iter().sum::<DVec3>() / n, to.iter().sum::<DVec3>() / n);
        let mut m = DMat3::ZERO;
        let (mut sf, mut st) = (0.0, 0.0);
        for (a, b) in from.iter().zip(to) {
            let (a, b) = (*a - cf, *b - ct);
            m += DMat3::from_cols(b * a.x, b * a.y, b * a.z);
            sf += a.length_squared();
            st += b.length_squared();
        }
        let rotation = rotation_of(&m);
        let scale = if sf > 0.0 { (st / sf).sqrt() } else { 1.0 };
        let s = Self {
            scale,
            rotation,
            translation: ct - scale * (rotation * cf),
        };
        let worst = from
            .iter()
            .zip(to)
            .map(|(a, b)| (s.point(*a) - *b).length())
            .fold(0.0, f64::max);
        (s, worst)
    }

    fn point(&self, p: DVec3) -> DVec3 {
        self.scale * (self.rotation * p) + self.translation
    }
}

/// A marker on the skin: a triangle, barycentric weights, and its distance out along
/// the triangle's normal (`side` orients the normal outward).
#[derive(Clone, Copy, Debug)]
struct SkinPoint {
    triangle: [u32; 3],
    bary: [f64; 3],
    out_m: f64,
    side: f64,
}

impl SkinPoint {
    fn at(&self, v: &[DVec3]) -> DVec3 {
        let [a, b, c] = self.triangle.map(|i| v[i as usize]);
        let n = (b - a).cross(c - a).normalize_or_zero() * self.side;
        a * self.bary[0] + b * self.bary[1] + c * self.bary[2] + n * self.out_m
    }
}

/// Where a ray from `o` along `d` leaves the body's volume ([`leaves_volume`], `surface`
/// saying what is inside), `out_m` out: a marker sits on whatever covers the skin, as
/// far out again as a layer reaches.
fn cast(
    o: DVec3,
    d: DVec3,
    v: &[DVec3],
    tris: &[[u32; 3]],
    surface: &WindingNumber,
    out_m: f64,
    layer_m: f64,
) -> Option<SkinPoint> {
    let inside = |p: DVec3| surface.at(p) > 0.5;
    let reach_m = crate::calibrate::landmarks::REACH_LAYERS * layer_m;
    let reach = Reach {
        layer_m,
        out_m,
        reach_m,
    };
    let h = leaves_volume(o, d, v, tris, reach, inside)?;
    Some(SkinPoint {
        triangle: h.triangle,
        bary: h.bary,
        out_m,
        side: h.side,
    })
}

/// How far a marker is turned about its bone from where [`LANDMARKS`] puts it, degrees
/// at most: people place markers by touch, and the calibration's own template of the
/// set ([`crate::calibrate::landmarks`]) must not be the truth.
const MAX_TURN_DEG: f64 = 20.0;
/// How far it slides along its bone, as a share of the bone at most.
const MAX_SLIDE: f64 = 0.05;

/// Two numbers in −1..1 fixed by `label` (FNV-1a), for [`MAX_TURN_DEG`] and
/// [`MAX_SLIDE`].
fn placement_jitter(label: &str) -> [f64; 2] {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in label.bytes() {
        h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
    }
    let unit = |x: u64| (x & 0xffff) as f64 / 32767.5 - 1.0;
    [unit(h), unit(h >> 16)]
}

/// The marker set on the rest skin of `loaded`: labels, points and the joints that carry
/// them (those whose part the skeleton lacks, or whose ray finds no skin, are not put
/// on).
fn place_markers(
    loaded: &LoadedCharacter,
    height: f64,
    surface: &WindingNumber,
) -> Vec<(String, SkinPoint, usize)> {
    let ch = &loaded.character;
    let sk = &ch.skeleton;
    let Some((front, up, left)) = body_axes(sk, &loaded.joint_roles) else {
        return Vec::new();
    };
    let out_m = MARKER_OUT_M;
    let mut placed = Vec::new();
    for &(pattern, part, pick, along, [f, u, o]) in LANDMARKS {
        let sides: &[(Option<Side>, &str, f64)] = if pattern.contains("{S}") {
            &[(Some(Side::Left), "L", 1.0), (Some(Side::Right), "R", -1.0)]
        } else {
            &[(None, "", 1.0)]
        };
        for &(side, letter, sign) in sides {
            let joints = candidate_joints(Role { part, side }, &loaded.joint_roles);
            let Some(&j) = (match pick {
                Pick::First => joints.first(),
                Pick::Last => joints.last(),
                Pick::Middle => joints.get(joints.len() / 2),
            }) else {
                continue;
            };
            let start = sk.joints[j].rest;
            let end = sk
                .children(j)
                .map(|c| sk.joints[c].rest)
                .next()
                .unwrap_or_else(|| match sk.joints[j].parent {
                    Some(p) => {
                        start + (start - sk.joints[p].rest).normalize_or_zero() * 0.06 * height
                    }
                    None => start + up * 0.06 * height,
                });
            let bone = (end - start).normalize_or_zero();
            // Away from the midline as the templates take it: up for an arm held out
            // level (its lateral side, palms down), where the body's left runs along
            // the bone.
            let (_, away) = segment_axes((front, up, left), end - start, sign);
            let mut d = front * f + up * u + away * o;
            d -= d.dot(bone) * bone;
            if d.length() < 0.2 {
                d = front * f.signum() - up * 0.0;
                d -= d.dot(bone) * bone;
            }
            // Where a person puts it, not where the manual says: a turn about the bone
            // and a slide along it, the same for every run.
            let label = pattern.replace("{S}", letter);
            let [turn, slide] = placement_jitter(&label);
            let d = DQuat::from_axis_angle(bone, turn * MAX_TURN_DEG.to_radians()) * d;
            let p = start + (end - start) * (along + slide * MAX_SLIDE);
            let layer_m = LAYER_M * height / ACTOR_HEIGHT_M;
            let ray = d.normalize_or_zero();
            if let Some(sp) = cast(p, ray, &ch.vertices, &ch.triangles, surface, out_m, layer_m) {
                // Before its joint, a landmark rides the bone above (a pelvis marker
                // placed by the hip joint rides the pelvis).
                let carrier = if along < 0.0 {
                    sk.joints[j].parent.unwrap_or(j)
                } else {
                    j
                };
                placed.push((label, sp, carrier));
            }
        }
    }
    placed
}

/// The true mesh at `t_s` in the character's frame, into `out`.
struct Truth<'a> {
    asset: &'a SkinnedAsset,
    clip: &'a Clip,
    to_world: Similarity,
    worlds: Vec<DMat4>,
    file: Vec<DVec3>,
    /// Whether the clip plays again from its start after its end (set by
    /// [`truth_take`]).
    looped: bool,
}

impl Truth<'_> {
    /// The clip at `t_s`: looped when [`Self::looped`], else held at its ends.
    fn at(&mut self, t_s: f64, out: &mut Vec<DVec3>) {
        self.pose_at(t_s);
        self.asset.pose(&self.worlds, &mut self.file);
        out.clear();
        out.extend(self.file.iter().map(|&p| self.to_world.point(p)));
    }

    /// The nodes' poses at `t_s` (what [`Self::rotation`] reads), without the mesh: the
    /// clip looped when [`Self::looped`], else held at its ends.
    fn pose_at(&mut self, t_s: f64) {
        let d = self.clip.duration_s;
        let t = if d <= 0.0 {
            0.0
        } else if self.looped {
            t_s % d
        } else {
            t_s.clamp(0.0, d)
        };
        self.asset.node_worlds(Some(self.clip), t, &mut self.worlds);
    }

    /// Node `node`'s rotation from bind in the character's frame (after [`Self::at`] or
    /// [`Self::pose_at`]).
    fn rotation(&self, node: usize) -> Option<DQuat> {
        let q = self.asset.joint_rotation(&self.worlds, node)?;
        Some(self.to_world.rotation * q * self.to_world.rotation.conjugate())
    }
}

/// The take the markers on `truth`'s skin make, at [`RATE_HZ`]: a clip whose end meets
/// its start (no marker moves further across the seam than [`SEAM_STEPS`] of the
/// clip's longest step between frames) played again until the take lasts
/// [`MIN_TAKE_S`]; any other clip played once. Looping a clip whose last pose is not its
/// first would move the markers in one frame as far as the two poses lie apart (21 cm
/// in the soldier's run), and playing it back and forth would turn every marker round
/// in one frame; no actor does either.
fn truth_take(
    truth: &mut Truth<'_>,
    markers: &[(String, SkinPoint, usize)],
    name: String,
) -> (Recording, f64) {
    let d = truth.clip.duration_s;
    let once = (d * RATE_HZ).floor() as usize + 1;
    let at = |truth: &mut Truth<'_>, t: f64, mesh: &mut Vec<DVec3>| -> Vec<DVec3> {
        truth.at(t, mesh);
        markers.iter().map(|m| m.1.at(mesh)).collect()
    };
    let mut mesh = Vec::new();
    truth.looped = false;
    let once_frames: Vec<Vec<DVec3>> = (0..once)
        .map(|i| at(truth, i as f64 / RATE_HZ, &mut mesh))
        .collect();
    let apart = |a: &[DVec3], b: &[DVec3]| {
        a.iter()
            .zip(b)
            .map(|(p, q)| (*p - *q).length())
            .fold(0.0, f64::max)
    };
    let step = once_frames
        .windows(2)
        .map(|w| apart(&w[0], &w[1]))
        .fold(0.0, f64::max);
    let seam = match (once_frames.first(), once_frames.last()) {
        (Some(a), Some(b)) => apart(a, b),
        _ => 0.0,
    };
    truth.looped = d <= 0.0 || seam <= SEAM_STEPS * step;
    let (frames, take_s) = if truth.looped {
        let take_s = (d * (MIN_TAKE_S / d.max(1e-3)).ceil()).max(MIN_TAKE_S);
        ((take_s * RATE_HZ).round() as usize, take_s)
    } else {
        (once, once as f64 / RATE_HZ)
    };
    let mut mesh = Vec::new();
    let rec = Recording {
        name,
        rate_hz: RATE_HZ,
        labels: markers.iter().map(|m| m.0.clone()).collect(),
        frames: if truth.looped {
            (0..frames)
                .map(|i| at(truth, i as f64 / RATE_HZ, &mut mesh))
                .collect()
        } else {
            once_frames
        },
        warnings: Vec::new(),
        file_units: "m".into(),
        point_groups: Vec::new(),
    };
    (rec, take_s)
}

/// The joints whose rotations are held against the truth: the head, the trunk (hips
/// and the top of the spine), and those that carry a label of `cal`.
fn watched_joints(loaded: &LoadedCharacter, cal: &Calibration) -> [Vec<usize>; 3] {
    let role_joint = |part: Part, last: bool| {
        let j = candidate_joints(Role { part, side: None }, &loaded.joint_roles);
        if last {
            j.last().copied()
        } else {
            j.first().copied()
        }
    };
    [
        role_joint(Part::Head, false).into_iter().collect(),
        [role_joint(Part::Hips, false), role_joint(Part::Spine, true)]
            .into_iter()
            .flatten()
            .collect(),
        cal.placed.iter().map(|p| p.joint).collect(),
    ]
}

/// `rec` solved through the pipeline with `rig` at `scale`, every tick held against
/// `truth` (the head, trunk and carrying joints of `watched`).
fn solve_against(
    truth: &mut Truth<'_>,
    rig: Arc<crate::rig::bind::Rig>,
    rec: &Recording,
    scale: f64,
    watched: &[Vec<usize>; 3],
    regions: &[u8],
    height: f64,
) -> Result<Tally, crate::solve::harmonic::HarmonicError> {
    let mut tally = Tally::default();
    let mut mesh = Vec::new();
    let names: Vec<String> = rig.skeleton.joints.iter().map(|j| j.name.clone()).collect();
    let opts = OfflineOptions {
        marker_scale: scale,
        deadline: false,
        ..OfflineOptions::default()
    };
    replay_offline_with(rig, SolverParams::default(), rec, opts, &mut |tick| {
        // The replay's last tick comes a frame after the take's last sample: the take
        // holds no truth for it.
        if tick.index >= rec.frames.len() {
            return ControlFlow::Continue(());
        }
        truth.at(tick.index as f64 / RATE_HZ, &mut mesh);
        let (mut sum, mut max) = (0.0, 0.0f64);
        for ((a, b), &r) in mesh.iter().zip(tick.vertices).zip(regions) {
            let e = (*a - *b).length();
            sum += e;
            max = max.max(e);
            tally.region_sum[usize::from(r)] += e / height;
            tally.region_count[usize::from(r)] += 1;
        }
        tally.frame_means.push(sum / mesh.len() as f64 / height);
        tally.vertex_max = tally.vertex_max.max(max / height);
        let lowest = |v: &[DVec3]| v.iter().map(|p| p.y).fold(f64::INFINITY, f64::min);
        tally
            .floor_mm
            .push((lowest(tick.vertices) - lowest(&mesh)) * 1e3);
        let angle = |j: usize| {
            let q = truth.rotation(truth.asset.node_of_joint(&names[j])?)?;
            Some(rotation_angle_between(q, tick.joint_rot[j]).to_degrees())
        };
        let worst = |js: &[usize]| js.iter().filter_map(|&j| angle(j)).fold(0.0, f64::max);
        tally.head_deg = tally.head_deg.max(worst(&watched[0]));
        tally.trunk_deg = tally.trunk_deg.max(worst(&watched[1]));
        tally.carrying_deg = tally.carrying_deg.max(worst(&watched[2]));
        ControlFlow::Continue(())
    })?;
    Ok(tally)
}

/// How many of the worst-placed labels a record names.
const WORST_PLACED: usize = 5;

/// One asset and clip.
fn case(
    loaded: &LoadedCharacter,
    asset: &SkinnedAsset,
    clip: &Clip,
    name: &str,
) -> Result<TruthRecord, BenchError> {
    let what = || format!("{name} {}", clip.name);
    let ch = &loaded.character;
    if asset.positions.len() != ch.vertices.len() {
        return Err(BenchError::case(
            what(),
            std::io::Error::other("vertex counts differ"),
        ));
    }
    // The reader's mesh to the character's frame: units, scale and up axis.
    let (to_world, off) = Similarity::fit(&asset.positions, &ch.vertices);
    let (lo, hi) = crate::geom::shapes::bounds(&ch.vertices);
    let height = hi.y - lo.y;
    if off > 1e-6 * height {
        return Err(BenchError::case(
            what(),
            std::io::Error::other(format!(
                "the file's mesh is not the character's ({off} m off)"
            )),
        ));
    }
    // What is inside the skin, as the calibration judges it.
    let (unique, oriented, _) = welded_outward(&ch.vertices, &ch.triangles);
    let surface = WindingNumber::new(&unique, &oriented);
    let markers = place_markers(loaded, height, &surface);
    let mut truth = Truth {
        asset,
        clip,
        to_world,
        worlds: Vec::new(),
        file: Vec::new(),
        looped: false,
    };
    let (rec, take_s) = truth_take(&mut truth, &markers, format!("{name}-{}", clip.name));
    let mut bare = ch.clone();
    bare.markers.clear();
    let opts = CalibrationOptions {
        max_marker_distance_m: loaded.bind.max_marker_distance_m,
        ..CalibrationOptions::default()
    };
    let t0 = Instant::now();
    let mut cal = calibrate(&bare, &loaded.joint_roles, rec.as_take(), &opts)
        .map_err(|e| BenchError::case(what(), e))?;
    let calibrate_s = t0.elapsed().as_secs_f64();
    let mut off: Vec<(String, f64)> = cal
        .placed
        .iter()
        .filter_map(|p| {
            let m = markers
                .iter()
                .find(|m| normalise(&m.0) == normalise(&p.label))?;
            let rest = ch.skeleton.joints[p.joint].rest + p.offset_m;
            Some((
                p.label.clone(),
                (rest - m.1.at(&ch.vertices)).length() * 1e3,
            ))
        })
        .collect();
    let placement: Vec<f64> = off.iter().map(|o| o.1).collect();
    off.sort_by(|a, b| b.1.total_cmp(&a.1));
    off.truncate(WORST_PLACED);
    // The templates alone: where the calibration starts the labels and holds them near.
    let templates = crate::calibrate::landmarks::Templates::new(
        &ch.skeleton,
        &loaded.joint_roles,
        &ch.vertices,
        &ch.triangles,
        height,
        &surface,
    );
    let template_off: Vec<f64> = markers
        .iter()
        .filter_map(|m| {
            let t = templates.as_ref()?.at(&m.0)?;
            Some((t - m.1.at(&ch.vertices)).length() * 1e3)
        })
        .collect();
    let from_template: Vec<(String, f64)> = cal
        .placed
        .iter()
        .filter_map(|p| Some((p.label.clone(), p.from_template_m? * 1e3)))
        .collect();
    let bind = loaded.bind_for(&cal.layout(&bare));
    let rig = Arc::new(
        cal.bind(&bare, &bind, &mut |_, _| {})
            .map_err(|e| BenchError::case(what(), e))?,
    );
    let watched = watched_joints(loaded, &cal);
    let t1 = Instant::now();
    let regions = vertex_regions(loaded, asset);
    let mut tally = solve_against(&mut truth, rig, &rec, cal.scale, &watched, &regions, height)
        .map_err(|e| BenchError::case(what(), e))?;
    let solve_s = t1.elapsed().as_secs_f64();
    let reference = true_layout_solve(loaded, &markers, &mut truth, &rec, &watched, &what())?;
    let n = tally.frame_means.len().max(1) as f64;
    let mut floor_abs: Vec<f64> = tally.floor_mm.iter().map(|x| x.abs()).collect();
    let floor_median = crate::runtime::stats::percentile(&mut tally.floor_mm, 0.5);
    Ok(TruthRecord {
        suite: "truth",
        asset: name.to_string(),
        clip: clip.name.clone(),
        height_m: height,
        take_s,
        markers: markers.len(),
        placed: cal.placed.len(),
        verdict: cal.verdict(),
        concerns: cal.concerns().iter().map(ToString::to_string).collect(),
        misfit_mm_rms: cal.residual_mm_rms,
        scale_error: (cal.scale - 1.0).abs(),
        placement_mm_mean: placement.iter().sum::<f64>() / placement.len().max(1) as f64,
        placement_mm_max: placement.iter().copied().fold(0.0, f64::max),
        worst_placed: off,
        template_mm_mean: template_off.iter().sum::<f64>() / template_off.len().max(1) as f64,
        from_template_mm_mean: from_template.iter().map(|f| f.1).sum::<f64>()
            / from_template.len().max(1) as f64,
        from_template_mm_max: from_template
            .into_iter()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or_default(),
        vertex_share_mean: tally.frame_means.iter().sum::<f64>() / n,
        vertex_share_worst_frame: tally.frame_means.iter().copied().fold(0.0, f64::max),
        vertex_share_max: tally.vertex_max,
        by_region: by_region(&tally),
        head_deg_max: tally.head_deg,
        trunk_deg_max: tally.trunk_deg,
        carrying_deg_max: tally.carrying_deg,
        floor_mm_median: floor_median,
        floor_mm_worst: crate::runtime::stats::percentile(&mut floor_abs, 1.0),
        true_layout: reference,
        rest_off_bind: asset.rest_off_bind(),
        beyond_limits: beyond_limits(&mut truth, loaded, rec.frames.len()),
        skin_slide: skin_slide(&mut truth, loaded, &markers, &rec),
        calibrate_s,
        solve_s,
    })
}

/// The body's regions the vertex error is told by: each vertex belongs to the region
/// of the joint that moves it most (a joint with no role, or a limb's split segment,
/// takes its nearest ancestor's). Plug-in Gait has no finger markers: the fingers are
/// posed by the solve's priors alone.
pub const REGIONS: [&str; 8] = [
    "head", "trunk", "arms", "hands", "fingers", "legs", "feet", "other",
];

/// Each vertex's region of [`REGIONS`] (an index), by `asset`'s skin weights.
fn vertex_regions(loaded: &LoadedCharacter, asset: &SkinnedAsset) -> Vec<u8> {
    const OTHER: u8 = REGIONS.len() as u8 - 1;
    let sk = &loaded.character.skeleton;
    let joint_region = |j: usize| {
        let mut at = Some(j);
        while let Some(j) = at {
            let region = match loaded.joint_roles[j].map(|r| r.part) {
                Some(Part::Neck | Part::Head) => 0,
                Some(Part::Hips | Part::Spine | Part::Shoulder) => 1,
                Some(Part::UpperArm | Part::LowerArm) => 2,
                Some(Part::Hand) => 3,
                Some(Part::Finger(..)) => 4,
                Some(Part::UpperLeg | Part::LowerLeg) => 5,
                Some(Part::Foot | Part::Toes) => 6,
                Some(Part::LimbSegment) | None => {
                    at = sk.joints[j].parent;
                    continue;
                }
            };
            return region;
        }
        OTHER
    };
    let mut node_region = vec![OTHER; asset.node_names.len()];
    for (j, joint) in sk.joints.iter().enumerate() {
        if let Some(n) = asset.node_of_joint(&joint.name) {
            node_region[n] = joint_region(j);
        }
    }
    (0..asset.positions.len())
        .map(|v| asset.dominant_node(v).map_or(OTHER, |n| node_region[n]))
        .collect()
}

/// A tally's regions that hold vertices: name, share of the vertices, mean error.
fn by_region(t: &Tally) -> Vec<(&'static str, f64, f64)> {
    let all: usize = t.region_count.iter().sum();
    REGIONS
        .iter()
        .zip(t.region_sum.iter().zip(&t.region_count))
        .filter(|(_, (_, &n))| n > 0)
        .map(|(&r, (&sum, &n))| (r, n as f64 / all as f64, sum / n as f64))
        .collect()
}

/// The regions as printed: `head 1.20 % (9 %)`, the region's mean vertex error as a
/// share of the height and, in brackets, its share of the vertices.
fn regions_text(regions: &[(&'static str, f64, f64)]) -> String {
    regions
        .iter()
        .map(|(r, share, err)| format!("{r} {:.2} % ({:.0} %)", 100.0 * err, 100.0 * share))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Per-frame figures of a solve against its truth.
#[derive(Default)]
struct Tally {
    frame_means: Vec<f64>,
    /// Per region of [`REGIONS`]: summed vertex error (share of the height) and count.
    region_sum: [f64; REGIONS.len()],
    region_count: [usize; REGIONS.len()],
    vertex_max: f64,
    floor_mm: Vec<f64>,
    head_deg: f64,
    trunk_deg: f64,
    carrying_deg: f64,
}

fn print(r: &TruthRecord, json: bool, out: &mut dyn Write) -> Result<(), BenchError> {
    if json {
        return json_line(out, r);
    }
    writeln!(
        out,
        "{:<22} {:<16} {:.2} m {:>4.1} s  {:>2}/{:<2} placed  {:<8} misfit {:>4.1} mm  scale {:>5.2} %  placement {:>5.1} mean {:>5.1} max mm  vertices {:.2} % mean {:.2} % worst frame {:.2} % max  head {:>5.1}° trunk {:>5.1}° carrying {:>5.1}°  floor {:+.0} median {:.0} worst mm  ({:.1} s + {:.1} s)",
        r.asset, r.clip, r.height_m, r.take_s, r.placed, r.markers, r.verdict.to_string(),
        r.misfit_mm_rms, 100.0 * r.scale_error, r.placement_mm_mean, r.placement_mm_max,
        100.0 * r.vertex_share_mean, 100.0 * r.vertex_share_worst_frame, 100.0 * r.vertex_share_max,
        r.head_deg_max, r.trunk_deg_max, r.carrying_deg_max, r.floor_mm_median, r.floor_mm_worst,
        r.calibrate_s, r.solve_s
    )?;
    let t = &r.true_layout;
    writeln!(
        out,
        "{:<22} with the true layout: vertices {:.2} % mean {:.2} % worst frame  head {:>5.1}° trunk {:>5.1}°",
        "", 100.0 * t.vertex_share_mean, 100.0 * t.vertex_share_worst_frame, t.head_deg_max, t.trunk_deg_max
    )?;
    writeln!(out, "{:<22} by region: {}", "", regions_text(&r.by_region))?;
    writeln!(
        out,
        "{:<22} true layout by region: {}",
        "",
        regions_text(&t.by_region)
    )?;
    let worst: Vec<String> = r
        .worst_placed
        .iter()
        .map(|(l, mm)| format!("{l} {mm:.0}"))
        .collect();
    writeln!(
        out,
        "{:<22} placed furthest off (mm): {}; the templates alone {:.1} mm mean; placed from the templates {:.1} mm mean, {:.0} mm at most ({})",
        "",
        worst.join(", "),
        r.template_mm_mean,
        r.from_template_mm_mean,
        r.from_template_mm_max.1,
        r.from_template_mm_max.0
    )?;
    if let Some((joint, deg)) = &r.beyond_limits {
        writeln!(
            out,
            "{:<22} the animation takes {joint} {deg:.0}° past its human range",
            ""
        )?;
    }
    if !r.skin_slide.is_empty() {
        let slides: Vec<String> = r
            .skin_slide
            .iter()
            .map(|(joint, deg)| format!("{joint} {deg:.1}°"))
            .collect();
        writeln!(
            out,
            "{:<22} the skin's own markers turn away from their bone by up to: {}",
            "",
            slides.join(", ")
        )?;
    }
    for c in &r.concerns {
        writeln!(out, "{:<22} {c}", "")?;
    }
    Ok(())
}

/// Fewest markers on one bone for [`skin_slide`] to judge its turn.
const SLIDE_MIN_MARKERS: usize = 3;
/// Frames [`skin_slide`] samples, at most.
const SLIDE_FRAMES: usize = 100;

/// For each joint that carries [`SLIDE_MIN_MARKERS`] or more of the take's markers (on
/// its skin, moved by the asset's skinning), the turn of their cluster from the take's
/// first frame (Kabsch's fit, the polar rotation of the cross-covariance about the
/// centroids) against the bone's own turn, worst over the sampled frames: where the
/// skin blends between bones (CesiumMan's hips, weighted to the thighs), the markers do
/// not follow their bone, and no solve that holds them rigid on it recovers the bone's
/// turn closer than this. Each such joint and its angle, degrees, furthest first.
fn skin_slide(
    truth: &mut Truth<'_>,
    loaded: &LoadedCharacter,
    markers: &[(String, SkinPoint, usize)],
    rec: &Recording,
) -> Vec<(String, f64)> {
    let sk = &loaded.character.skeleton;
    let mut out: Vec<(String, f64)> = Vec::new();
    let step = rec.frames.len().div_ceil(SLIDE_FRAMES).max(1);
    for j in 0..sk.len() {
        let on: Vec<usize> = (0..markers.len()).filter(|&k| markers[k].2 == j).collect();
        let node = truth.asset.node_of_joint(&sk.joints[j].name);
        let (Some(node), true) = (node, on.len() >= SLIDE_MIN_MARKERS) else {
            continue;
        };
        let centred = |f: usize| -> Vec<DVec3> {
            let p: Vec<DVec3> = on.iter().map(|&k| rec.frames[f][k]).collect();
            let c = p.iter().sum::<DVec3>() / p.len() as f64;
            p.iter().map(|x| *x - c).collect()
        };
        let first = centred(0);
        truth.pose_at(0.0);
        let Some(bone_first) = truth.rotation(node) else {
            continue;
        };
        let mut deg = 0.0f64;
        for f in (0..rec.frames.len()).step_by(step) {
            let mut a = DMat3::ZERO;
            for (x, y) in centred(f).iter().zip(&first) {
                a += DMat3::from_cols(*x * y.x, *x * y.y, *x * y.z);
            }
            truth.pose_at(f as f64 / RATE_HZ);
            let Some(bone) = truth.rotation(node) else {
                continue;
            };
            let turn = rotation_angle_between(best_rotation(&a), bone * bone_first.inverse());
            deg = deg.max(turn.to_degrees());
        }
        out.push((sk.joints[j].name.clone(), deg));
    }
    out.sort_by(|a, b| b.1.total_cmp(&a.1));
    out
}

/// Past this, degrees, an animation's excursion beyond a joint's limits is reported.
const BEYOND_LIMITS_DEG: f64 = 1.0;

/// The worst excursion of the first `frames` frames of `truth` past the limits of
/// `loaded`'s skeleton (each joint's rotation from rest relative to its parent's, as
/// [`crate::character::skeleton`] limits it), fingers left out: the joint and degrees,
/// `None` below [`BEYOND_LIMITS_DEG`]. Stylised animations go where no person's joint
/// goes (CesiumMan's walk swings a thigh back past a hip's extension), and a solve held
/// to human ranges must then turn another joint instead: this says when.
fn beyond_limits(
    truth: &mut Truth<'_>,
    loaded: &LoadedCharacter,
    frames: usize,
) -> Option<(String, f64)> {
    let sk = &loaded.character.skeleton;
    let mut world = vec![DQuat::IDENTITY; sk.joints.len()];
    let mut local = world.clone();
    let mut worst: Option<(usize, f64)> = None;
    for i in 0..frames {
        truth.pose_at(i as f64 / RATE_HZ);
        for (j, joint) in sk.joints.iter().enumerate() {
            let parent = joint.parent.map_or(DQuat::IDENTITY, |p| world[p]);
            world[j] = truth
                .asset
                .node_of_joint(&joint.name)
                .and_then(|n| truth.rotation(n))
                .unwrap_or(parent);
            let finger = loaded.joint_roles[j].is_some_and(|r| matches!(r.part, Part::Finger(..)));
            // A finger at rest is inside its limits: left out.
            local[j] = if finger {
                DQuat::IDENTITY
            } else {
                parent.conjugate() * world[j]
            };
        }
        if let Some((j, excess)) = sk.worst_limit_excess(&local) {
            if worst.is_none_or(|(_, e)| excess > e) {
                worst = Some((j, excess));
            }
        }
    }
    let (j, excess) = worst?;
    let deg = excess.to_degrees();
    (deg > BEYOND_LIMITS_DEG).then(|| (sk.joints[j].name.clone(), deg))
}

/// The assets of the shared data folder the suite plays: file, the clips (empty: every
/// clip), and the `[mesh] scale` it is loaded at. The Mixamo soldier is 0.21 m tall as
/// exported: played at that size (the calibration says the actor would be as small), and
/// at a person's size, as its user would load it.
pub const ASSETS: &[(&str, &[&str], f64)] = &[
    ("meshes/gltf-samples/CesiumMan.glb", &[], 1.0),
    ("meshes/real/threejs_soldier_mixamo.glb", &[], 1.0),
    ("meshes/real/threejs_soldier_mixamo.glb", &[], 8.5),
    (
        "meshes/real/kenney_mini_character_female_a.glb",
        &["walk", "idle"],
        1.0,
    ),
];

/// Runs every case of one asset, printing each as it is measured.
pub fn asset_cases(
    data: &Path,
    file: &str,
    clips: &[&str],
    mesh_scale: f64,
    json: bool,
    out: &mut dyn Write,
    records: &mut Vec<TruthRecord>,
) -> Result<(), BenchError> {
    let glb = data.join(file);
    if !glb.is_file() {
        return Ok(());
    }
    // One folder per call: calls may run at once (the tests do).
    static CALLS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("rigless-truth-{}-{call}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let asset = |e| BenchError::case(file, e);
    let character = gltf_file(&glb, &dir).map_err(asset)?;
    if mesh_scale != 1.0 {
        let text = std::fs::read_to_string(&character)?;
        std::fs::write(&character, format!("{text}scale = {mesh_scale}\n"))?;
    }
    let loaded = load_character(&character).map_err(|e| BenchError::case(file, e))?;
    std::fs::remove_dir_all(&dir)?;
    let skinned = SkinnedAsset::read(&glb).map_err(|e| BenchError::case(file, e))?;
    let stem = glb
        .file_stem()
        .map_or_else(|| file.to_string(), |s| s.to_string_lossy().into_owned());
    let name = if mesh_scale == 1.0 {
        stem
    } else {
        format!("{stem}×{mesh_scale}")
    };
    for clip in &skinned.clips {
        if !clips.is_empty() && !clips.iter().any(|c| clip.name.eq_ignore_ascii_case(c)) {
            continue;
        }
        match case(&loaded, &skinned, clip, &name) {
            Ok(r) => {
                print(&r, json, out)?;
                records.push(r);
            }
            // A case that cannot be calibrated or solved is a result, said as such.
            Err(e) if json => json_line(
                out,
                &serde_json::json!({"suite": "truth", "asset": name, "clip": clip.name, "failed": e.to_string()}),
            )?,
            Err(e) => writeln!(out, "{name:<22} {:<16} failed: {e}", clip.name)?,
        }
    }
    Ok(())
}

/// Runs the suite.
pub fn suite(data: &Path, json: bool, out: &mut dyn Write) -> Result<(), BenchError> {
    if !data.is_dir() {
        return Err(BenchError::NoData {
            suite: "truth",
            dir: data.display().to_string(),
        });
    }
    let mut records = Vec::new();
    for (file, clips, scale) in ASSETS {
        asset_cases(data, file, clips, *scale, json, out, &mut records)?;
    }
    Ok(())
}
