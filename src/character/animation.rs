//! A glTF asset's own skins and animations, played through its own skinning: the node
//! tree's rest transforms, each animation's samplers (LINEAR, STEP and CUBICSPLINE, glTF
//! 2.0 §3.11 and Appendix C), and linear-blend skinning of every vertex in the order
//! [`crate::character::mesh::read_gltf`] gives them (glTF 2.0 §3.7.3:
//! `v(t) = Σ_k w_k · world_from_joint_k(t) · inverse_bind_k · v`). It makes the known
//! truth of `rigless bench --suite truth`: where markers on the posed skin are, and the
//! mesh those markers should give.
//!
//! Poses come out in the file's world space (file units and axes), as a viewer shows
//! them. The mesh reader's rest mesh is in that space when the rest pose is the bind
//! pose; when it is not, the reader keeps the bind pose, and exporters store it in world
//! units and axes (Blender's glTF export does).
//!
//! The file is opened with every check of the mesh reader first
//! ([`crate::character::mesh::open_gltf`]); the calls into the `gltf` crate's readers run
//! under `catch_unwind`, and nothing is sized by a number read from the file but what
//! those checks bound (accessor counts within their buffers).

use crate::character::mesh::{guarded, open_gltf, GltfSource, MeshError};
use crate::geom::polar::rotation_of;
use glam::{DMat3, DMat4, DQuat, DVec3, DVec4};
use std::path::Path;

/// Longest animation played, seconds (a clip's last key time past this is refused).
pub const MAX_CLIP_S: f64 = 3600.0;

/// Why an asset cannot be played.
#[derive(Debug, thiserror::Error)]
pub enum AnimationError {
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error("{path}: no mesh node has a skin: nothing to play")]
    NoSkin { path: String },
    #[error("{path}: meshes[{mesh}] primitives[{primitive}]: {problem}")]
    Primitive {
        path: String,
        mesh: usize,
        primitive: usize,
        problem: String,
    },
    #[error("{path}: animations[{animation}] channels[{channel}]: {problem}")]
    Channel {
        path: String,
        animation: usize,
        channel: usize,
        problem: String,
    },
}

/// A node's transform relative to its parent.
#[derive(Clone, Copy, Debug)]
enum Local {
    Trs {
        translation: DVec3,
        rotation: DQuat,
        scale: DVec3,
    },
    Matrix(DMat4),
}

/// What an animation channel moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Property {
    Translation,
    Rotation,
    Scale,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Interpolation {
    Linear,
    Step,
    CubicSpline,
}

/// One channel: key times (seconds, non-decreasing) and values (`xyz0` for translation
/// and scale, `xyzw` for rotation); CUBICSPLINE keeps three values per key (in-tangent,
/// value, out-tangent).
#[derive(Clone, Debug)]
struct Channel {
    node: usize,
    property: Property,
    interpolation: Interpolation,
    times: Vec<f64>,
    values: Vec<DVec4>,
}

/// One animation of the file.
#[derive(Clone, Debug)]
pub struct Clip {
    /// The file's name for it, else `animations[N]`.
    pub name: String,
    /// Its last key time, seconds.
    pub duration_s: f64,
    channels: Vec<Channel>,
}

/// A skin: its joints' nodes and inverse bind matrices.
#[derive(Clone, Debug)]
struct Skin {
    joints: Vec<usize>,
    inverse_bind: Vec<DMat4>,
}

/// How a vertex moves.
#[derive(Clone, Copy, Debug)]
enum Binding {
    /// With a node (an unskinned mesh node).
    Rigid { node: usize },
    /// With up to four joints of a skin (slots into its `joints`), weights summing to 1.
    Skinned {
        skin: usize,
        joints: [u16; 4],
        weights: [f64; 4],
    },
}

/// A glTF asset ready to be posed.
#[derive(Clone, Debug)]
pub struct SkinnedAsset {
    parent: Vec<Option<usize>>,
    /// Nodes, parents before children.
    order: Vec<usize>,
    rest: Vec<Local>,
    /// Each node's name, if it has one.
    pub node_names: Vec<Option<String>>,
    skins: Vec<Skin>,
    /// The mesh's vertices as the mesh reader gives them (file units and axes).
    pub positions: Vec<DVec3>,
    /// From the reader's space back to the skins' bind space (the inverse of
    /// [`crate::character::mesh::MeshData::rest_from_bind`]; the identity when the
    /// reader keeps the bind space).
    bind_from_reader: DMat4,
    binding: Vec<Binding>,
    pub clips: Vec<Clip>,
}

impl SkinnedAsset {
    /// Reads the glTF file at `path`.
    pub fn read(path: &Path) -> Result<Self, AnimationError> {
        let shown = path.display().to_string();
        let src = open_gltf(path)?;
        guarded(&shown, "skins and animations", || from_source(&src, &shown))?
    }

    /// Every node's world transform at `t_s` seconds into `clip` (its rest pose for
    /// `None`), into `out` (one per node).
    pub fn node_worlds(&self, clip: Option<&Clip>, t_s: f64, out: &mut Vec<DMat4>) {
        let mut local: Vec<Local> = self.rest.clone();
        if let Some(clip) = clip {
            for c in &clip.channels {
                let v = sample(c, t_s);
                if let Some(Local::Trs {
                    translation,
                    rotation,
                    scale,
                }) = local.get_mut(c.node)
                {
                    match c.property {
                        Property::Translation => *translation = v.truncate(),
                        Property::Rotation => *rotation = DQuat::from_vec4(v).normalize(),
                        Property::Scale => *scale = v.truncate(),
                    }
                }
            }
        }
        out.clear();
        out.resize(self.parent.len(), DMat4::IDENTITY);
        for &n in &self.order {
            let m = match local[n] {
                Local::Matrix(m) => m,
                Local::Trs {
                    translation,
                    rotation,
                    scale,
                } => DMat4::from_scale_rotation_translation(scale, rotation, translation),
            };
            out[n] = match self.parent[n] {
                Some(p) => out[p] * m,
                None => m,
            };
        }
    }

    /// Every vertex posed by the node transforms `worlds` ([`Self::node_worlds`]), in the
    /// mesh reader's space, into `out`.
    pub fn pose(&self, worlds: &[DMat4], out: &mut Vec<DVec3>) {
        let skin_mats: Vec<Vec<DMat4>> = self
            .skins
            .iter()
            .map(|s| {
                s.joints
                    .iter()
                    .zip(&s.inverse_bind)
                    .map(|(&n, ibm)| worlds[n] * *ibm * self.bind_from_reader)
                    .collect()
            })
            .collect();
        out.clear();
        out.extend(self.positions.iter().zip(&self.binding).map(|(&p, b)| {
            match *b {
                Binding::Rigid { node } => worlds[node].transform_point3(p),
                Binding::Skinned {
                    skin,
                    joints,
                    weights,
                } => (0..4)
                    .filter(|&k| weights[k] != 0.0)
                    .map(|k| weights[k] * skin_mats[skin][joints[k] as usize].transform_point3(p))
                    .sum(),
            }
        }));
    }

    /// The rotation that takes joint node `node` from its bind pose to the pose
    /// `worlds`, in the mesh reader's space (the rotation factor of its skinning
    /// matrix); `None` when no skin has it as a joint.
    pub fn joint_rotation(&self, worlds: &[DMat4], node: usize) -> Option<DQuat> {
        self.skins.iter().find_map(|s| {
            let k = s.joints.iter().position(|&j| j == node)?;
            let m = worlds[node] * s.inverse_bind[k];
            Some(rotation_of(&DMat3::from_mat4(m)))
        })
    }

    /// The node a skeleton joint read by the mesh reader stands for: the skin joint
    /// with its name, or the node its `#N` / `jointN` name gives.
    pub fn node_of_joint(&self, name: &str) -> Option<usize> {
        let joints = || self.skins.iter().flat_map(|s| s.joints.iter().copied());
        joints()
            .find(|&n| self.node_names[n].as_deref() == Some(name))
            .or_else(|| {
                let n: usize = name
                    .rsplit_once('#')
                    .map(|(_, n)| n)
                    .or_else(|| name.strip_prefix("joint"))?
                    .parse()
                    .ok()?;
                joints().find(|&j| j == n)
            })
    }

    /// The node that moves vertex `v` most: an unskinned mesh's node, or the skin joint
    /// of largest weight; `None` past the last vertex.
    pub fn dominant_node(&self, v: usize) -> Option<usize> {
        match *self.binding.get(v)? {
            Binding::Rigid { node } => Some(node),
            Binding::Skinned {
                skin,
                joints,
                weights,
            } => {
                let k = (0..4).max_by(|&a, &b| weights[a].total_cmp(&weights[b]))?;
                self.skins[skin].joints.get(joints[k] as usize).copied()
            }
        }
    }

    /// Largest distance of a skinning matrix at rest from the identity (how far the
    /// file's rest pose is from its bind pose; 0 when they agree), over every joint.
    pub fn rest_off_bind(&self) -> f64 {
        let mut worlds = Vec::new();
        self.node_worlds(None, 0.0, &mut worlds);
        let mut worst: f64 = 0.0;
        for s in &self.skins {
            for (&n, ibm) in s.joints.iter().zip(&s.inverse_bind) {
                let d = worlds[n] * *ibm - DMat4::IDENTITY;
                worst = worst.max(d.to_cols_array().iter().fold(0.0, |a, x| a.max(x.abs())));
            }
        }
        worst
    }
}

/// A channel's value at `t_s` (held before its first key and after its last).
fn sample(c: &Channel, t_s: f64) -> DVec4 {
    let per_key = if c.interpolation == Interpolation::CubicSpline {
        3
    } else {
        1
    };
    let value = |k: usize, which: usize| c.values[k * per_key + which];
    let mid = if per_key == 3 { 1 } else { 0 };
    let n = c.times.len();
    if n == 0 {
        return DVec4::ZERO;
    }
    if t_s <= c.times[0] || n == 1 {
        return value(0, mid);
    }
    if t_s >= c.times[n - 1] {
        return value(n - 1, mid);
    }
    let k = c.times.partition_point(|&t| t <= t_s) - 1;
    let dt = c.times[k + 1] - c.times[k];
    let s = if dt > 0.0 {
        (t_s - c.times[k]) / dt
    } else {
        0.0
    };
    match c.interpolation {
        Interpolation::Step => value(k, 0),
        Interpolation::Linear if c.property == Property::Rotation => {
            let a = DQuat::from_vec4(value(k, 0)).normalize();
            let b = DQuat::from_vec4(value(k + 1, 0)).normalize();
            DVec4::from(a.slerp(b, s))
        }
        Interpolation::Linear => value(k, 0).lerp(value(k + 1, 0), s),
        Interpolation::CubicSpline => {
            // glTF 2.0 Appendix C: Hermite with tangents scaled by the key interval.
            let (s2, s3) = (s * s, s * s * s);
            let v0 = value(k, 1);
            let b0 = value(k, 2);
            let v1 = value(k + 1, 1);
            let a1 = value(k + 1, 0);
            v0 * (2.0 * s3 - 3.0 * s2 + 1.0)
                + b0 * (dt * (s3 - 2.0 * s2 + s))
                + v1 * (-2.0 * s3 + 3.0 * s2)
                + a1 * (dt * (s3 - s2))
        }
    }
}

/// Reads the node tree, skins, vertex bindings and clips of an opened file.
fn from_source(src: &GltfSource, path: &str) -> Result<SkinnedAsset, AnimationError> {
    let doc = &src.document;
    let count = doc.nodes().len();
    let mut parent = vec![None; count];
    for node in doc.nodes() {
        for child in node.children() {
            parent[child.index()] = Some(node.index());
        }
    }
    // The mesh reader checked that the nodes make a forest.
    let mut order: Vec<usize> = (0..count).filter(|&n| parent[n].is_none()).collect();
    let mut k = 0;
    while k < order.len() {
        let n = order[k];
        order.extend(
            doc.nodes()
                .nth(n)
                .into_iter()
                .flat_map(|node| node.children().map(|c| c.index())),
        );
        k += 1;
    }
    let rest: Vec<Local> = doc
        .nodes()
        .map(|node| match node.transform() {
            gltf::scene::Transform::Matrix { matrix } => {
                Local::Matrix(DMat4::from_cols_array_2d(&matrix.map(|c| c.map(f64::from))))
            }
            gltf::scene::Transform::Decomposed {
                translation,
                rotation,
                scale,
            } => Local::Trs {
                translation: DVec3::from_array(translation.map(f64::from)),
                rotation: DQuat::from_array(rotation.map(f64::from)).normalize(),
                scale: DVec3::from_array(scale.map(f64::from)),
            },
        })
        .collect();
    let mut asset = SkinnedAsset {
        parent,
        order,
        rest,
        node_names: doc.nodes().map(|n| n.name().map(str::to_string)).collect(),
        skins: Vec::new(),
        positions: src.mesh.positions.clone(),
        bind_from_reader: src
            .mesh
            .rest_from_bind
            .map_or(DMat4::IDENTITY, |c| c.inverse()),
        binding: Vec::with_capacity(src.mesh.positions.len()),
        clips: Vec::new(),
    };
    for skin in doc.skins() {
        let joints: Vec<usize> = skin.joints().map(|j| j.index()).collect();
        let reader = skin.reader(|b| src.buffer(b.index()));
        let inverse_bind: Vec<DMat4> = match reader.read_inverse_bind_matrices() {
            Some(m) => m
                .map(|c| DMat4::from_cols_array_2d(&c.map(|r| r.map(f64::from))))
                .collect(),
            None => vec![DMat4::IDENTITY; joints.len()],
        };
        // The mesh reader checked one matrix per joint; a short list is padded.
        let mut inverse_bind = inverse_bind;
        inverse_bind.resize(joints.len(), DMat4::IDENTITY);
        asset.skins.push(Skin {
            joints,
            inverse_bind,
        });
    }
    read_bindings(src, path, &mut asset)?;
    if asset.skins.is_empty()
        || !asset
            .binding
            .iter()
            .any(|b| matches!(b, Binding::Skinned { .. }))
    {
        return Err(AnimationError::NoSkin {
            path: path.to_string(),
        });
    }
    for (a, anim) in doc.animations().enumerate() {
        asset.clips.push(read_clip(src, path, a, &anim)?);
    }
    Ok(asset)
}

/// Each vertex's binding, in the mesh reader's order (mesh nodes in document order,
/// their triangle primitives in order).
fn read_bindings(
    src: &GltfSource,
    path: &str,
    asset: &mut SkinnedAsset,
) -> Result<(), AnimationError> {
    for node in src.document.nodes() {
        let Some(mesh) = node.mesh() else { continue };
        for prim in mesh
            .primitives()
            .filter(|p| p.mode() == gltf::mesh::Mode::Triangles)
        {
            let err = |problem: String| AnimationError::Primitive {
                path: path.to_string(),
                mesh: mesh.index(),
                primitive: prim.index(),
                problem,
            };
            let reader = prim.reader(|b| src.buffer(b.index()));
            let n = prim
                .get(&gltf::Semantic::Positions)
                .map_or(0, |a| a.count());
            let skin = node.skin().map(|s| s.index());
            let Some(skin) = skin else {
                asset
                    .binding
                    .extend((0..n).map(|_| Binding::Rigid { node: node.index() }));
                continue;
            };
            let (Some(joints), Some(weights)) = (reader.read_joints(0), reader.read_weights(0))
            else {
                return Err(err(
                    "a skinned node's primitive without JOINTS_0 and WEIGHTS_0".into(),
                ));
            };
            let joints: Vec<[u16; 4]> = joints.into_u16().take(n).collect();
            let weights: Vec<[f32; 4]> = weights.into_f32().take(n).collect();
            if joints.len() != n || weights.len() != n {
                return Err(err(format!(
                    "{n} positions but {} JOINTS_0 and {} WEIGHTS_0",
                    joints.len(),
                    weights.len()
                )));
            }
            let slots = asset.skins[skin].joints.len();
            for (v, (j, w)) in joints.iter().zip(&weights).enumerate() {
                let mut w = w.map(|x| {
                    if x.is_finite() && x > 0.0 {
                        f64::from(x)
                    } else {
                        0.0
                    }
                });
                if let Some(k) = (0..4).find(|&k| w[k] > 0.0 && usize::from(j[k]) >= slots) {
                    return Err(err(format!(
                        "vertex {v}: JOINTS_0 names joint {} of a {slots}-joint skin",
                        j[k]
                    )));
                }
                let sum: f64 = w.iter().sum();
                if sum <= 0.0 {
                    return Err(err(format!("vertex {v}: no positive weight")));
                }
                w.iter_mut().for_each(|x| *x /= sum);
                asset.binding.push(Binding::Skinned {
                    skin,
                    joints: *j,
                    weights: w,
                });
            }
        }
    }
    if asset.binding.len() != asset.positions.len() {
        return Err(AnimationError::Primitive {
            path: path.to_string(),
            mesh: 0,
            primitive: 0,
            problem: format!(
                "{} vertices bound, but the mesh reader read {}",
                asset.binding.len(),
                asset.positions.len()
            ),
        });
    }
    Ok(())
}

/// One animation's node channels (morph-target weights are not played).
fn read_clip(
    src: &GltfSource,
    path: &str,
    a: usize,
    anim: &gltf::Animation<'_>,
) -> Result<Clip, AnimationError> {
    use gltf::animation::util::ReadOutputs;
    let mut clip = Clip {
        name: anim
            .name()
            .map_or_else(|| format!("animations[{a}]"), str::to_string),
        duration_s: 0.0,
        channels: Vec::new(),
    };
    for (c, channel) in anim.channels().enumerate() {
        let err = |problem: String| AnimationError::Channel {
            path: path.to_string(),
            animation: a,
            channel: c,
            problem,
        };
        let reader = channel.reader(|b| src.buffer(b.index()));
        let times: Vec<f64> = reader
            .read_inputs()
            .ok_or_else(|| err("no key times".into()))?
            .map(f64::from)
            .collect();
        if let Some(k) = (0..times.len()).find(|&k| {
            !times[k].is_finite() || times[k] < 0.0 || (k > 0 && times[k] < times[k - 1])
        }) {
            return Err(err(format!(
                "key time {k} ({}) is not a time after the one before",
                times[k]
            )));
        }
        if let Some(&last) = times.last().filter(|&&t| t > MAX_CLIP_S) {
            return Err(err(format!(
                "last key at {last} s, past the {MAX_CLIP_S} s played"
            )));
        }
        let (property, values): (Property, Vec<DVec4>) = match reader.read_outputs() {
            Some(ReadOutputs::Translations(v)) => (
                Property::Translation,
                v.map(|x| DVec3::from_array(x.map(f64::from)).extend(0.0))
                    .collect(),
            ),
            Some(ReadOutputs::Scales(v)) => (
                Property::Scale,
                v.map(|x| DVec3::from_array(x.map(f64::from)).extend(0.0))
                    .collect(),
            ),
            Some(ReadOutputs::Rotations(v)) => (
                Property::Rotation,
                v.into_f32()
                    .map(|x| DVec4::from_array(x.map(f64::from)))
                    .collect(),
            ),
            Some(ReadOutputs::MorphTargetWeights(_)) => continue,
            None => return Err(err("no output values".into())),
        };
        let interpolation = match channel.sampler().interpolation() {
            gltf::animation::Interpolation::Linear => Interpolation::Linear,
            gltf::animation::Interpolation::Step => Interpolation::Step,
            gltf::animation::Interpolation::CubicSpline => Interpolation::CubicSpline,
        };
        let per_key = if interpolation == Interpolation::CubicSpline {
            3
        } else {
            1
        };
        if values.len() != per_key * times.len() || values.iter().any(|v| !v.is_finite()) {
            return Err(err(format!(
                "{} keys but {} finite output values ({per_key} per key expected)",
                times.len(),
                values.len()
            )));
        }
        clip.duration_s = clip.duration_s.max(times.last().copied().unwrap_or(0.0));
        clip.channels.push(Channel {
            node: channel.target().node().index(),
            property,
            interpolation,
            times,
            values,
        });
    }
    Ok(clip)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(interpolation: Interpolation, times: &[f64], values: &[f64]) -> Channel {
        Channel {
            node: 0,
            property: Property::Translation,
            interpolation,
            times: times.to_vec(),
            values: values
                .iter()
                .map(|&x| DVec4::new(x, 0.0, 0.0, 0.0))
                .collect(),
        }
    }

    #[test]
    fn samplers_follow_the_specification() {
        let lin = channel(Interpolation::Linear, &[0.0, 1.0, 3.0], &[0.0, 2.0, 6.0]);
        assert_eq!(sample(&lin, -1.0).x, 0.0, "held before the first key");
        assert!((sample(&lin, 0.5).x - 1.0).abs() < 1e-12);
        assert!((sample(&lin, 2.0).x - 4.0).abs() < 1e-12);
        assert_eq!(sample(&lin, 9.0).x, 6.0, "held after the last key");
        let step = channel(Interpolation::Step, &[0.0, 1.0], &[3.0, 5.0]);
        assert_eq!(sample(&step, 0.99).x, 3.0);
        assert_eq!(sample(&step, 1.0).x, 5.0);
        // Cubic with zero tangents: smoothstep between the values (value 1 at s = 0.5
        // of 0 -> 2; at s = 0.25, 2 * (3 s² - 2 s³) = 0.3125).
        let cubic = channel(
            Interpolation::CubicSpline,
            &[0.0, 1.0],
            &[0.0, 0.0, 0.0, 0.0, 2.0, 0.0],
        );
        assert!((sample(&cubic, 0.5).x - 1.0).abs() < 1e-12);
        assert!((sample(&cubic, 0.25).x - 0.3125).abs() < 1e-12);
        // Cubic with a slope-1 tangent on a straight line reproduces it exactly.
        let line = channel(
            Interpolation::CubicSpline,
            &[0.0, 2.0],
            &[1.0, 0.0, 1.0, 1.0, 2.0, 1.0],
        );
        assert!((sample(&line, 0.5).x - 0.5).abs() < 1e-12);
    }

    #[test]
    fn rotations_are_slerped() {
        let q = DQuat::from_rotation_y(std::f64::consts::FRAC_PI_2);
        let c = Channel {
            node: 0,
            property: Property::Rotation,
            interpolation: Interpolation::Linear,
            times: vec![0.0, 1.0],
            values: vec![DVec4::from(DQuat::IDENTITY), DVec4::from(q)],
        };
        let half = DQuat::from_vec4(sample(&c, 0.5));
        let angle = half.angle_between(DQuat::IDENTITY);
        assert!(
            (angle - std::f64::consts::FRAC_PI_4).abs() < 1e-12,
            "{angle}"
        );
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
        /// Arbitrary bytes as a `.glb` are refused or read, never a panic.
        #[test]
        fn arbitrary_files_never_panic(tail in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..512)) {
            let dir = std::env::temp_dir().join(format!("rigless-anim-{}", std::process::id()));
            std::fs::create_dir_all(&dir).unwrap();
            let path = dir.join(format!("{}.glb", tail.len()));
            let mut bytes = b"glTF\x02\0\0\0".to_vec();
            bytes.extend(&tail);
            std::fs::write(&path, &bytes).unwrap();
            if let Ok(asset) = SkinnedAsset::read(&path) {
                proptest::prop_assert_eq!(asset.binding.len(), asset.positions.len());
            }
        }
    }
}
