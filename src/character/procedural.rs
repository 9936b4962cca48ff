//! Procedural characters with known truth, owned by the project: a right hand (wrist plus
//! three joints per finger, finger joint limits, 8 markers as in Le Naour et al.).
//!
//! The surface is an implicit smooth union of tapered capsules (one per bone), an oval
//! palm pad and a thenar pad, meshed by marching tetrahedra on a Kuhn lattice (watertight and
//! manifold by construction). Truth at any time is the same mesh skinned (linear blend
//! skinning with distance-based weights) by the same skeleton, so every frame's true mesh
//! and marker positions are known exactly.
//!
//! Frame: metres, Y up; the hand points +Y, palm facing +Z, thumb towards −X.

use super::mesh::MeshPart;
use super::skeleton::{Joint, JointLimits, Skeleton};
use crate::geom::lattice::{Grid, KUHN};
use glam::{DQuat, DVec3};
use std::collections::HashMap;

pub use super::{Character, MarkerDef, Skin};

/// A tapered capsule: endpoints and radii.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Capsule {
    pub a: DVec3,
    pub b: DVec3,
    pub ra: f64,
    pub rb: f64,
}

/// A primitive of a procedural character's flesh (for meshing and skinning).
#[derive(Clone, Copy, Debug)]
pub(crate) enum Shape {
    Capsule(Capsule),
    /// Axis-aligned ellipsoid: centre and radii.
    Ellipsoid {
        c: DVec3,
        r: DVec3,
    },
}

impl Shape {
    /// Signed distance (exact for capsules; for ellipsoids the usual bound
    /// `(‖p/r‖ − 1)·min(r)`, exact on the surface).
    pub fn sdf(&self, p: DVec3) -> f64 {
        match self {
            Shape::Capsule(c) => capsule_sdf(c, p),
            Shape::Ellipsoid { c, r } => (((p - *c) / *r).length() - 1.0) * r.min_element(),
        }
    }
}

/// The point `offset_m` outside the zero crossing of `sdf` met when marching from
/// `from` (inside) along unit `dir`, at most `reach_m` far (bisection to round-off).
pub(crate) fn on_skin(
    sdf: &dyn Fn(DVec3) -> f64,
    from: DVec3,
    dir: DVec3,
    reach_m: f64,
    offset_m: f64,
) -> DVec3 {
    let step = reach_m / 400.0;
    let (mut lo, mut hi) = (0.0, reach_m);
    let mut t = 0.0;
    while t < reach_m {
        if sdf(from + dir * t) > 0.0 {
            hi = t;
            break;
        }
        lo = t;
        t += step;
    }
    for _ in 0..60 {
        let m = 0.5 * (lo + hi);
        if sdf(from + dir * m) > 0.0 {
            hi = m;
        } else {
            lo = m;
        }
    }
    from + dir * (0.5 * (lo + hi) + offset_m)
}

/// Signed distance to a tapered capsule: from its axis's nearest point, less the radius
/// interpolated there.
fn capsule_sdf(c: &Capsule, p: DVec3) -> f64 {
    let ab = c.b - c.a;
    let t = ((p - c.a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
    (p - (c.a + ab * t)).length() - (c.ra + (c.rb - c.ra) * t)
}

/// Polynomial smooth minimum (Quilez), blend width `k` in metres.
pub(crate) fn smin(a: f64, b: f64, k: f64) -> f64 {
    let h = (0.5 + 0.5 * (b - a) / k).clamp(0.0, 1.0);
    b + (a - b) * h - k * h * (1.0 - h)
}

/// Finger description: name, MCP position, direction fan angle (degrees from +Y towards
/// +X), segment lengths and radii at MCP and tip.
struct FingerSpec {
    name: &'static str,
    base: DVec3,
    fan_deg: f64,
    lengths: [f64; 3],
    radius: (f64, f64),
}

const FINGERS: [FingerSpec; 4] = [
    FingerSpec {
        name: "index",
        base: DVec3::new(-0.028, 0.088, 0.0),
        fan_deg: -9.0,
        lengths: [0.041, 0.025, 0.020],
        radius: (0.0092, 0.0075),
    },
    FingerSpec {
        name: "middle",
        base: DVec3::new(-0.008, 0.092, 0.0),
        fan_deg: 0.0,
        lengths: [0.046, 0.029, 0.021],
        radius: (0.0095, 0.0077),
    },
    FingerSpec {
        name: "ring",
        base: DVec3::new(0.012, 0.089, 0.0),
        fan_deg: 9.0,
        lengths: [0.043, 0.027, 0.020],
        radius: (0.0090, 0.0073),
    },
    FingerSpec {
        name: "pinky",
        base: DVec3::new(0.030, 0.080, 0.0),
        fan_deg: 19.0,
        lengths: [0.033, 0.020, 0.018],
        radius: (0.0080, 0.0066),
    },
];

const DEG: f64 = std::f64::consts::PI / 180.0;

/// The procedural right hand's skeleton alone (what a data glove poses), without meshing
/// its surface: microseconds, where [`hand`] takes over a second.
pub fn hand_skeleton() -> Skeleton {
    Skeleton::new(hand_joints_and_bones().0).expect("procedural hand skeleton is valid")
}

/// Builds the procedural right hand: the implicit surface is meshed on a lattice of
/// `mesh_cell_m` and simplified to about `target_triangles` (10,000 gives about 5,000
/// vertices).
pub fn hand(mesh_cell_m: f64, target_triangles: usize) -> Character {
    let (joints, capsules) = hand_joints_and_bones();
    let skeleton = Skeleton::new(joints).expect("procedural hand skeleton is valid");
    let flesh = HandFlesh::around(capsules);
    let sdf = |p: DVec3| flesh.sdf(p);
    let (vertices, triangles) = surface_of(
        &sdf,
        DVec3::new(-0.12, -0.07, -0.06),
        DVec3::new(0.1, 0.23, 0.07),
        mesh_cell_m,
        target_triangles,
    );
    let skin = flesh.skin(&vertices);
    let markers = hand_markers(&skeleton, &sdf);
    Character {
        name: "hand".into(),
        parts: vec![MeshPart::whole("hand", vertices.len(), triangles.len())],
        vertices,
        triangles,
        skeleton,
        markers,
        skin: Some(skin),
        correspondences: Vec::new(),
    }
}

/// The limits of a finger's three joints (MCP, PIP, DIP).
fn finger_limits() -> [JointLimits; 3] {
    [
        JointLimits {
            twist: (-5.0 * DEG, 5.0 * DEG),
            bend: (-10.0 * DEG, 90.0 * DEG),
            side: (-20.0 * DEG, 20.0 * DEG),
        },
        JointLimits {
            twist: (-5.0 * DEG, 5.0 * DEG),
            bend: (0.0, 110.0 * DEG),
            side: (-5.0 * DEG, 5.0 * DEG),
        },
        JointLimits {
            twist: (-5.0 * DEG, 5.0 * DEG),
            bend: (0.0, 80.0 * DEG),
            side: (-5.0 * DEG, 5.0 * DEG),
        },
    ]
}

/// The limits of the thumb's three joints (CMC, MCP, IP).
fn thumb_limits() -> [JointLimits; 3] {
    [
        JointLimits {
            twist: (-15.0 * DEG, 15.0 * DEG),
            bend: (-15.0 * DEG, 50.0 * DEG),
            side: (-30.0 * DEG, 30.0 * DEG),
        },
        JointLimits {
            twist: (-5.0 * DEG, 5.0 * DEG),
            bend: (-5.0 * DEG, 60.0 * DEG),
            side: (-8.0 * DEG, 8.0 * DEG),
        },
        JointLimits {
            twist: (-5.0 * DEG, 5.0 * DEG),
            bend: (-10.0 * DEG, 80.0 * DEG),
            side: (-5.0 * DEG, 5.0 * DEG),
        },
    ]
}

/// One digit for [`add_chain`]: three straight segments from `base` along unit `dir`.
struct Chain<'a> {
    /// Joint names are `NAME_1`, `NAME_2`, `NAME_3` and `NAME_tip`.
    name: &'a str,
    base: DVec3,
    dir: DVec3,
    lengths: [f64; 3],
    /// Radius at the base and at the tip (linear along the digit).
    radius: (f64, f64),
    /// Made perpendicular to `dir` for every joint.
    bend_axis: DVec3,
    limits: [JointLimits; 3],
}

/// Appends a digit's four joints (children of the wrist, joint 0) and its three bone
/// capsules, each owned by the joint it leaves.
fn add_chain(joints: &mut Vec<Joint>, capsules: &mut Vec<(usize, Capsule)>, chain: &Chain) {
    let Chain {
        name,
        base,
        dir,
        lengths,
        radius,
        bend_axis,
        limits,
    } = *chain;
    let names = ["1", "2", "3", "tip"];
    let mut pos = base;
    let total: f64 = lengths.iter().sum();
    let mut along = 0.0;
    let mut parent = 0usize;
    for k in 0..4 {
        let bend = (bend_axis - dir * bend_axis.dot(dir)).normalize();
        joints.push(Joint {
            name: format!("{name}_{}", names[k]),
            parent: Some(parent),
            rest: pos,
            limits: if k < 3 { Some(limits[k]) } else { None },
            bend_axis: bend,
        });
        let me = joints.len() - 1;
        if k < 3 {
            let next = pos + dir * lengths[k];
            let r0 = radius.0 + (radius.1 - radius.0) * along / total;
            along += lengths[k];
            let r1 = radius.0 + (radius.1 - radius.0) * along / total;
            capsules.push((
                me,
                Capsule {
                    a: pos,
                    b: next,
                    ra: r0,
                    rb: r1,
                },
            ));
            pos = next;
        }
        parent = me;
    }
}

/// The hand's 21 joints (the wrist, each finger's chain, the thumb's) and its bone
/// capsules with their owner joints (the metacarpals, last, owned by the wrist).
fn hand_joints_and_bones() -> (Vec<Joint>, Vec<(usize, Capsule)>) {
    let mut joints = vec![Joint {
        name: "wrist".into(),
        parent: None,
        rest: DVec3::ZERO,
        limits: None,
        bend_axis: DVec3::X,
    }];
    let mut capsules: Vec<(usize, Capsule)> = Vec::new();
    for f in &FINGERS {
        let dir = DVec3::new((f.fan_deg * DEG).sin(), (f.fan_deg * DEG).cos(), 0.0);
        let chain = Chain {
            name: f.name,
            base: f.base,
            dir,
            lengths: f.lengths,
            radius: f.radius,
            bend_axis: DVec3::X,
            limits: finger_limits(),
        };
        add_chain(&mut joints, &mut capsules, &chain);
    }
    let thumb = Chain {
        name: "thumb",
        base: DVec3::new(-0.022, 0.022, 0.008),
        dir: DVec3::new(-0.55, 0.8, 0.25).normalize(),
        lengths: [0.045, 0.032, 0.027],
        radius: (0.0125, 0.0085),
        bend_axis: DVec3::new(0.3, 0.0, -1.0),
        limits: thumb_limits(),
    };
    add_chain(&mut joints, &mut capsules, &thumb);
    // Metacarpals (owned by the wrist): wrist to each finger base, inside the palm.
    let metacarpals: Vec<Capsule> = FINGERS
        .iter()
        .map(|f| Capsule {
            a: DVec3::new(f.base.x * 0.6, 0.0, 0.0),
            b: f.base,
            ra: 0.011,
            rb: 0.010,
        })
        .collect();
    for m in &metacarpals {
        capsules.push((0, *m));
    }
    (joints, capsules)
}

/// The hand's flesh: the palm (an oval pad, narrow at the wrist, full at the knuckles,
/// where the metacarpals widen it), the thenar pad at the thumb's base, a forearm stub,
/// and the bone capsules.
struct HandFlesh {
    palm: Shape,
    thenar: Shape,
    forearm: Capsule,
    /// Bone capsules with their owner joints.
    bones: Vec<(usize, Capsule)>,
}

impl HandFlesh {
    /// The pads and the forearm stub around the given bones.
    fn around(bones: Vec<(usize, Capsule)>) -> Self {
        HandFlesh {
            palm: Shape::Ellipsoid {
                c: DVec3::new(0.0, 0.05, 0.0),
                r: DVec3::new(0.043, 0.054, 0.0145),
            },
            thenar: Shape::Ellipsoid {
                c: DVec3::new(-0.021, 0.03, 0.005),
                r: DVec3::new(0.02, 0.032, 0.0135),
            },
            forearm: Capsule {
                a: DVec3::new(0.0, -0.05, 0.0),
                b: DVec3::new(0.0, 0.0, 0.0),
                ra: 0.022,
                rb: 0.022,
            },
            bones,
        }
    }

    /// The implicit surface at `p`: pads, forearm (cut flat below the wrist) and bones in
    /// a smooth union.
    fn sdf(&self, p: DVec3) -> f64 {
        let pad = smin(self.palm.sdf(p), self.thenar.sdf(p), 0.01);
        let arm = capsule_sdf(&self.forearm, p).max(-(p.y + 0.045));
        let mut d = smin(pad, arm, 0.012);
        for (_, c) in &self.bones {
            d = smin(d, capsule_sdf(c, p), 0.0025);
        }
        d
    }

    /// Skin: weights from distance to each bone capsule surface, owned by its joint (the
    /// forearm by the wrist).
    fn skin(&self, vertices: &[DVec3]) -> Skin {
        let bones: Vec<(usize, Shape)> = self
            .bones
            .iter()
            .map(|&(j, c)| (j, Shape::Capsule(c)))
            .chain(std::iter::once((0usize, Shape::Capsule(self.forearm))))
            .collect();
        skin_by_distance(vertices, &bones, 0.006)
    }
}

/// The hand's 8 markers: 5 on the nails (dorsal side of each distal segment near the
/// tip), 3 on the back of the hand; 6 mm off the skin (a 12 mm marker ball's centre).
fn hand_markers(skeleton: &Skeleton, sdf: &dyn Fn(DVec3) -> f64) -> Vec<MarkerDef> {
    let mut markers = Vec::new();
    let dorsal = DVec3::new(0.0, 0.0, -1.0);
    let on_skin = |from: DVec3, dir: DVec3| on_skin(sdf, from, dir, 0.1, 0.006);
    for name in ["thumb", "index", "middle", "ring", "pinky"] {
        let j3 = skeleton
            .joints
            .iter()
            .position(|j| j.name == format!("{name}_3"))
            .expect("finger joint");
        let tip = skeleton.joints[j3 + 1].rest;
        let base = skeleton.joints[j3].rest;
        let at = base + (tip - base) * 0.7;
        markers.push(MarkerDef {
            name: format!("{name}_nail"),
            rest: on_skin(at, dorsal),
            joint: Some(j3),
        });
    }
    for (name, at) in [
        ("hand_index", DVec3::new(-0.025, 0.07, 0.0)),
        ("hand_pinky", DVec3::new(0.028, 0.062, 0.0)),
        ("hand_wrist", DVec3::new(0.0, 0.012, 0.0)),
    ] {
        markers.push(MarkerDef {
            name: name.into(),
            rest: on_skin(at, dorsal),
            joint: Some(0),
        });
    }
    markers
}

/// The surface of a procedural character: the zero level of `sdf` inside the box
/// `lo..hi` meshed on a lattice of `cell_m` ([`marching_tets`]), then simplified to about
/// `target_triangles` ([`simplify`]).
pub fn surface_of(
    sdf: &dyn Fn(DVec3) -> f64,
    lo: DVec3,
    hi: DVec3,
    cell_m: f64,
    target_triangles: usize,
) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let (fine_v, fine_t) = marching_tets(sdf, lo, hi, cell_m);
    simplify(&fine_v, &fine_t, target_triangles)
}

/// Simplifies a closed mesh with meshoptimizer to about `target_triangles`, dropping
/// unreferenced vertices.
pub fn simplify(
    vertices: &[DVec3],
    triangles: &[[u32; 3]],
    target_triangles: usize,
) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    if triangles.len() <= target_triangles {
        return (vertices.to_vec(), triangles.to_vec());
    }
    let flat: Vec<f32> = vertices
        .iter()
        .flat_map(|v| [v.x as f32, v.y as f32, v.z as f32])
        .collect();
    let bytes: Vec<u8> = flat.iter().flat_map(|f| f.to_le_bytes()).collect();
    let adapter = meshopt::VertexDataAdapter::new(&bytes, 12, 0).expect("12-byte float3 vertices");
    let indices: Vec<u32> = triangles.iter().flatten().copied().collect();
    let out = meshopt::simplify(
        &indices,
        &adapter,
        target_triangles * 3,
        1e-2,
        meshopt::SimplifyOptions::empty(),
        None,
    );
    // Simplification can fold a thin pocket into a fin: the same triangle twice, back to
    // back, which makes its edges non-manifold. Drop such pairs.
    let mut seen: HashMap<[u32; 3], usize> = HashMap::new();
    let tris: Vec<[u32; 3]> = out.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
    let mut dropped = vec![false; tris.len()];
    for (k, t) in tris.iter().enumerate() {
        let mut key = *t;
        key.sort_unstable();
        if let Some(&other) = seen.get(&key) {
            if !dropped[other] {
                dropped[other] = true;
                dropped[k] = true;
                seen.remove(&key);
                continue;
            }
        }
        seen.insert(key, k);
    }
    let mut remap = vec![u32::MAX; vertices.len()];
    let mut new_v = Vec::new();
    let mut new_t = Vec::with_capacity(out.len() / 3);
    for t in tris
        .iter()
        .zip(&dropped)
        .filter(|(_, d)| !**d)
        .map(|(t, _)| t)
    {
        let tri = [t[0], t[1], t[2]].map(|i| {
            if remap[i as usize] == u32::MAX {
                remap[i as usize] = new_v.len() as u32;
                new_v.push(vertices[i as usize]);
            }
            remap[i as usize]
        });
        new_t.push(tri);
    }
    (new_v, new_t)
}

/// Linear-blend skin weights from the distance to each bone's surface: weight
/// `∝ exp(−(d − d_min)/falloff)` over the four nearest owners.
pub(crate) fn skin_by_distance(
    vertices: &[DVec3],
    bones: &[(usize, Shape)],
    falloff_m: f64,
) -> Skin {
    let influences = vertices
        .iter()
        .map(|&p| {
            let mut best: HashMap<usize, f64> = HashMap::new();
            for (owner, c) in bones {
                let d = c.sdf(p);
                let e = best.entry(*owner).or_insert(f64::INFINITY);
                *e = e.min(d);
            }
            let mut v: Vec<(usize, f64)> = best.into_iter().collect();
            v.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            let dmin = v[0].1;
            let mut out = [(0u32, 0.0f64); 4];
            let mut sum = 0.0;
            for (k, &(j, d)) in v.iter().take(4).enumerate() {
                let w = (-(d - dmin) / falloff_m).exp();
                out[k] = (j as u32, w);
                sum += w;
            }
            for o in &mut out {
                o.1 /= sum;
            }
            out
        })
        .collect();
    Skin { influences }
}

/// Marching tetrahedra of `f < 0` (inside) over a Kuhn lattice of `cell` spacing in
/// `lo..hi`. Vertices on lattice edges are shared, so the result is watertight; triangles
/// are oriented with normals pointing to increasing `f` (outwards).
pub fn marching_tets(
    f: &dyn Fn(DVec3) -> f64,
    lo: DVec3,
    hi: DVec3,
    cell: f64,
) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let grid = Grid::covering(lo, hi, cell, 0);
    let [nx, ny, nz] = grid.dims;
    let node = |x: usize, y: usize, z: usize| x + (nx + 1) * (y + (ny + 1) * z);
    let pos = |x: usize, y: usize, z: usize| {
        grid.origin + DVec3::new(x as f64, y as f64, z as f64) * cell
    };
    let mut val = vec![0.0; (nx + 1) * (ny + 1) * (nz + 1)];
    for z in 0..=nz {
        for y in 0..=ny {
            for x in 0..=nx {
                let on_boundary = x == 0 || y == 0 || z == 0 || x == nx || y == ny || z == nz;
                // Outside on the domain boundary, so the surface is always closed.
                let v = if on_boundary {
                    f(pos(x, y, z)).max(1e-12)
                } else {
                    f(pos(x, y, z))
                };
                // Nudge exact zeros so every lattice edge crossing is strict.
                val[node(x, y, z)] = if v == 0.0 { 1e-12 } else { v };
            }
        }
    }
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    let mut edge_vertex: HashMap<(usize, usize), u32> = HashMap::new();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let corner = |b: usize| (x + (b & 1), y + ((b >> 1) & 1), z + ((b >> 2) & 1));
                for kt in KUHN {
                    let ids = kt.map(|b| {
                        let (cx, cy, cz) = corner(b);
                        (node(cx, cy, cz), pos(cx, cy, cz))
                    });
                    let inside: Vec<usize> = (0..4).filter(|&k| val[ids[k].0] < 0.0).collect();
                    if inside.is_empty() || inside.len() == 4 {
                        continue;
                    }
                    let mut cross = |a: usize, b: usize| -> u32 {
                        let (ia, pa) = ids[a];
                        let (ib, pb) = ids[b];
                        let key = (ia.min(ib), ia.max(ib));
                        *edge_vertex.entry(key).or_insert_with(|| {
                            let (fa, fb) = (val[ia], val[ib]);
                            let t = fa / (fa - fb);
                            vertices.push(pa + (pb - pa) * t);
                            (vertices.len() - 1) as u32
                        })
                    };
                    let outside: Vec<usize> = (0..4).filter(|k| !inside.contains(k)).collect();
                    // Each triangle as three lattice edges (inside corner, outside corner).
                    let tris: Vec<[(usize, usize); 3]> = match inside.len() {
                        1 => vec![[
                            (inside[0], outside[0]),
                            (inside[0], outside[1]),
                            (inside[0], outside[2]),
                        ]],
                        3 => vec![[
                            (inside[0], outside[0]),
                            (inside[1], outside[0]),
                            (inside[2], outside[0]),
                        ]],
                        _ => {
                            let (a, b) = (inside[0], inside[1]);
                            let (c, d) = (outside[0], outside[1]);
                            vec![[(a, c), (a, d), (b, d)], [(a, c), (b, d), (b, c)]]
                        }
                    };
                    // Orientation is decided on the triangle through the edges' midpoints,
                    // which is never degenerate, so it is exact whatever the interpolation.
                    let cin: DVec3 =
                        inside.iter().map(|&k| ids[k].1).sum::<DVec3>() / inside.len() as f64;
                    let cout: DVec3 =
                        outside.iter().map(|&k| ids[k].1).sum::<DVec3>() / outside.len() as f64;
                    for mut tri in tris {
                        let mid = tri.map(|(a, b)| 0.5 * (ids[a].1 + ids[b].1));
                        if (mid[1] - mid[0]).cross(mid[2] - mid[0]).dot(cout - cin) < 0.0 {
                            tri.swap(1, 2);
                        }
                        triangles.push(tri.map(|(a, b)| cross(a, b)));
                    }
                }
            }
        }
    }
    (vertices, triangles)
}

/// A pose: local joint rotations (relative to rest) and a root translation.
#[derive(Clone, Debug)]
pub struct Pose {
    pub local: Vec<DQuat>,
    pub root_offset: DVec3,
}

/// Procedural motions of the hand.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HandMotion {
    /// Fingers curl and uncurl in a wave, spread and close, the wrist turns a little.
    FingerPlay,
}

/// The hand's pose at time `t_s` for a motion (all within the joint limits).
pub fn hand_pose(sk: &Skeleton, motion: HandMotion, t_s: f64) -> Pose {
    let HandMotion::FingerPlay = motion;
    let mut local = vec![DQuat::IDENTITY; sk.len()];
    let tau = std::f64::consts::TAU;
    let spread = (tau * t_s / 3.1).sin();
    for (fi, name) in ["thumb", "index", "middle", "ring", "pinky"]
        .iter()
        .enumerate()
    {
        let curl = 0.5 * (1.0 - (tau * t_s / 2.4 - fi as f64 * 0.7).cos());
        let side_deg = [0.0, -10.0, 0.0, 8.0, 14.0][fi] * spread;
        let flex = if fi == 0 {
            [35.0, 45.0, 60.0]
        } else {
            [70.0, 95.0, 65.0]
        };
        for (k, flex_deg) in flex.iter().enumerate() {
            let j = sk
                .joints
                .iter()
                .position(|jt| jt.name == format!("{name}_{}", k + 1))
                .expect("finger joint");
            let axis = sk.twist_axis(j);
            let bend = sk.joints[j].bend_axis;
            let st = super::skeleton::SwingTwist {
                twist: 0.0,
                bend: curl * flex_deg * DEG,
                side: if k == 0 { side_deg * DEG } else { 0.0 },
            };
            local[j] = super::skeleton::compose(st, axis, bend);
        }
    }
    local[0] = DQuat::from_rotation_x(15.0 * DEG * (tau * t_s / 4.3).sin())
        * DQuat::from_rotation_y(25.0 * DEG * (tau * t_s / 5.7).sin());
    let root_offset = DVec3::new(
        0.02 * (tau * t_s / 3.7).sin(),
        0.01 * (tau * t_s / 2.9).sin(),
        0.0,
    );
    Pose { local, root_offset }
}

/// A motion for any skeleton, inside its limits: every joint with children swings
/// through part of its range (at most ±57° about rest), each on its own phase, and the
/// root turns and sways a little. Used to exercise characters from files, which have no
/// motion of their own.
pub fn flex_pose(sk: &Skeleton, t_s: f64) -> Pose {
    let mut local = vec![DQuat::IDENTITY; sk.len()];
    let tau = std::f64::consts::TAU;
    let mut has_child = vec![false; sk.len()];
    for j in &sk.joints {
        if let Some(p) = j.parent {
            has_child[p] = true;
        }
    }
    for (j, joint) in sk.joints.iter().enumerate() {
        if joint.parent.is_none() || !has_child[j] {
            continue;
        }
        let phase = j as f64 * 0.9;
        let wave = |(lo, hi): (f64, f64), amount: f64, period: f64| {
            let (lo, hi) = (lo.max(-1.0), hi.min(1.0));
            0.5 * (lo + hi) + amount * 0.5 * (hi - lo) * (tau * t_s / period + phase).sin()
        };
        let l = joint.limits.unwrap_or(JointLimits {
            twist: (-0.15, 0.15),
            bend: (-0.3, 0.3),
            side: (-0.15, 0.15),
        });
        let st = super::skeleton::SwingTwist {
            twist: wave(l.twist, 0.3, 3.3),
            bend: wave(l.bend, 0.9, 2.1),
            side: wave(l.side, 0.5, 2.9),
        };
        local[j] = super::skeleton::compose(st, sk.twist_axis(j), joint.bend_axis);
    }
    for (j, joint) in sk.joints.iter().enumerate() {
        if joint.parent.is_none() {
            local[j] = DQuat::from_rotation_y(0.3 * (tau * t_s / 4.1).sin())
                * DQuat::from_rotation_x(0.1 * (tau * t_s / 3.7).sin());
        }
    }
    let size = sk
        .joints
        .iter()
        .map(|j| (j.rest - sk.joints[0].rest).length())
        .fold(0.0, f64::max);
    Pose {
        local,
        root_offset: DVec3::new(0.1 * size * (tau * t_s / 3.1).sin(), 0.0, 0.0),
    }
}

/// Truth at a pose: skinned mesh vertices and marker positions.
pub fn skin_pose(
    ch: &Character,
    pose: &Pose,
    vertices_out: &mut [DVec3],
    markers_out: &mut [DVec3],
) {
    let sk = &ch.skeleton;
    let mut rot = vec![DQuat::IDENTITY; sk.len()];
    let mut pos = vec![DVec3::ZERO; sk.len()];
    sk.forward(&pose.local, pose.root_offset, &mut rot, &mut pos);
    let xf = |j: usize, x: DVec3| pos[j] + rot[j] * (x - sk.joints[j].rest);
    if let Some(skin) = &ch.skin {
        for (v, (out, inf)) in ch
            .vertices
            .iter()
            .zip(vertices_out.iter_mut().zip(&skin.influences))
        {
            *out = inf
                .iter()
                .filter(|(_, w)| *w > 0.0)
                .map(|&(j, w)| xf(j as usize, *v) * w)
                .sum();
        }
    }
    for (k, m) in ch.markers.iter().enumerate() {
        markers_out[k] = xf(m.joint.unwrap_or(0), m.rest);
    }
}

/// Signed volume enclosed by a closed, outward-oriented triangle mesh.
pub fn mesh_volume(vertices: &[DVec3], triangles: &[[u32; 3]]) -> f64 {
    mesh_volume_of(triangles, |i| vertices[i as usize])
}

/// [`mesh_volume`] with vertex `i`'s position given by `position(i)` (for vertex buffers
/// of another type): the sum of the signed tetrahedra from the origin to each triangle.
pub fn mesh_volume_of(triangles: &[[u32; 3]], position: impl Fn(u32) -> DVec3) -> f64 {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(&position);
            a.dot(b.cross(c)) / 6.0
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_is_a_closed_hand_sized_mesh() {
        let h = hand(0.0016, 10_000);
        let n = h.vertices.len();
        assert!((3_000..9_000).contains(&n), "{n} vertices");
        // Watertight and manifold: every edge is used by exactly two triangles, in
        // opposite directions.
        let issues = crate::character::mesh::surface_issues(&h.triangles);
        assert_eq!(
            issues,
            crate::character::mesh::SurfaceIssues::default(),
            "the hand's surface has defects"
        );
        let vol = mesh_volume(&h.vertices, &h.triangles);
        // A real hand with a short forearm stub: 250–600 cm³.
        assert!((250e-6..600e-6).contains(&vol), "volume {} cm³", vol * 1e6);
        assert_eq!(h.markers.len(), 8);
        assert_eq!(h.skeleton.len(), 21);
    }

    #[test]
    fn motion_stays_within_limits() {
        let h = hand(0.003, 4_000);
        for k in 0..200 {
            let pose = hand_pose(&h.skeleton, HandMotion::FingerPlay, k as f64 * 0.05);
            if let Some((j, excess)) = h.skeleton.worst_limit_excess(&pose.local) {
                // Round-off of composing and decomposing swing and twist stays far below.
                assert!(
                    excess < 1e-9,
                    "joint {} exceeds its limits by {excess} rad",
                    h.skeleton.joints[j].name
                );
            }
        }
    }
}

#[cfg(test)]
mod mt_tests {
    use super::*;

    pub(crate) fn open_edges(triangles: &[[u32; 3]]) -> usize {
        let mut edges: HashMap<(u32, u32), i32> = HashMap::new();
        for t in triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_default() += if a < b { 1 } else { -1 };
            }
        }
        edges.values().filter(|&&v| v != 0).count()
    }

    #[test]
    fn marching_tets_sphere_is_closed_with_right_volume() {
        let r = 0.3;
        let (v, t) = marching_tets(
            &|p: DVec3| p.length() - r,
            DVec3::splat(-0.5),
            DVec3::splat(0.5),
            0.02,
        );
        assert_eq!(open_edges(&t), 0);
        let vol = mesh_volume(&v, &t);
        let exact = 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
        // Piecewise-linear interpolation at h = r/15 underestimates by well under 2 %.
        assert!(
            (vol / exact - 1.0).abs() < 0.02,
            "volume ratio {}",
            vol / exact
        );
    }
}
