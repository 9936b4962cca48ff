//! The offset solve: every marker's offset on its joint and the global scale between
//! take and character, fitted over a few frames of the take at once (MoSh's first stage,
//! Loper, Mahmood and Black, "MoSh: Motion and Shape Capture from Sparse Markers",
//! SIGGRAPH Asia 2014, Section 4, on this character's skeleton instead of a body model).
//!
//! Unknowns: per frame `f` the posture `θ_f` of [`crate::solve::ik`]; per marker `k` its
//! offset `o_k` from its joint `J_k` at rest (world axes, metres); the scale `s`
//! (character metres per take metre). Objective:
//!
//! ```text
//! E = Σ_f Σ_k ‖(P_J(θ_f) + Q_J(θ_f) o_k) / s − m_fk‖² + (ε_rest h)² Σ_f ‖θ_f‖²
//!   + Σ_k w_band² band(d_k)² + w_pull² (d_k − d_0)² + w_band² own(e_k)²
//!   + Σ_k w_t² ‖r_J + o_k − t_k‖² + w_s² (s / s⁰ − 1)²
//!   + Σ_(a,b) w_m² ‖M o_a − o_b‖² + Σ_c w_m² (n · o_c)²
//! ```
//!
//! The misfit is measured in the take's units: measured in the character's, shrinking
//! the take (`s → 0`) would shrink the misfit with it. For fixed `s` and offsets each
//! frame's posture is the posture solver's fit to the targets `s m` with the rest prior
//! `ε_rest s` (the same minimiser: the objective times `s²`).
//!
//! where `d_k` is the signed distance (positive outside) of the marker's rest position
//! `r_J + o_k` from the rest surface, `band(d)` its excess outside `[d_lo, d_hi]` (a
//! marker sits a few millimetres to two centimetres off the skin: its radius and soft
//! tissue), `d_0` the usual distance (a 14 mm ball on the skin) and `s⁰` the scale the
//! run starts from (the first guess's): a hand's eight markers fit a smaller or larger
//! hand equally well by bending its fingers, and without the prior the scale would
//! drift; a change of 5 % costs as much as 0.3 mm of misfit on every marker in every
//! frame.
//! `e_k` is the distance of the rest position from the skin of the marker's own part
//! or its neighbours' ([`Parts`]) and `own(e)` its excess over the farthest a marker may
//! sit there: a finger's marker fits as well near the palm's skin, with the finger bent
//! into it and the scale off, and the bind refuses it there. `t_k` is where the marker's
//! set puts it on this character ([`super::landmarks`]), for a marker no frame placed:
//! MoSh's marker placement prior, loose (5 cm from it costs as much as 3 mm of misfit in
//! every frame), so that the take moves the marker wherever its motion shows it, and
//! the template holds what the motion leaves free (a marker slid along a limb that
//! barely bends, turned about one that never twists).
//!
//! The last term holds the labels of a joint on the body's midline (the head, the
//! pelvis, the chest) to the mirror symmetry their marker set gives them: `(a, b)` a
//! left label and its right partner on one such joint, `n` the body's left at rest and
//! `M = I − 2 n nᵀ` the mirror across the sagittal plane through the joint. A segment whose markers all ride on it (a head)
//! turns in every frame as its labels' offsets turn back, at no cost in misfit: the
//! take cannot tell an actor whose head looks 8° aside in the rest-like frame from a
//! headband put on 8° askew, and the rest-like frame's hold below takes the first. The
//! symmetry tells them apart about the vertical and the forward axis (a pair's mirror
//! images stay mirror images under a nod only), and a headband is put on straight more
//! surely than an actor looks straight ahead.
//!
//! One frame may be held near the rest pose: in a frame where the actor stands as the
//! character does at rest (a T or A pose at the start of a take), the joints whose
//! markers lie on their skin get a rest prior `ε_hold` instead of `ε_rest`. That is
//! MoSh's marker placement prior (Section 4.1: markers start where the marker set puts
//! them on the template body) taken from the take itself, and it holds what the
//! markers cannot tell: two markers on a foot whose leg carries none leave the foot free
//! to roll about their line and the offsets free to slide with it, in every frame but
//! the held one.
//!
//! Method: variable projection (Golub and Pereyra 1973; Ruhe and Wedin 1980, algorithm
//! II): the postures are eliminated, each fitted by the posture solver for the current
//! offsets and scale, and Levenberg–Marquardt runs on the offsets and scale alone with
//! the reduced Gauss–Newton matrix `H_gg − Σ_f H_gθ H_θθ⁻¹ H_θg` (the Schur complement of
//! each frame's posture block, over the unknowns that are free in that frame). Plain
//! alternation (posture, then the mean offset in each joint's frame) has the same fixed
//! points but crawls along the valleys where an offset and an unobserved joint angle
//! trade off; the Schur complement sees that trade.

use crate::character::skeleton::Skeleton;
use crate::geom::winding::WindingNumber;
use crate::rig::ik_model::{Dofs, IkModel};
use crate::solve::ik::{IkParams, IkState};
use glam::{DQuat, DVec3};

/// Weights and tolerances of the offset solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveParams {
    /// Nearest a marker's centre may sit to the skin without cost, metres.
    pub skin_min_m: f64,
    /// Farthest, metres.
    pub skin_max_m: f64,
    /// The usual distance, metres (a 14 mm marker on the skin: 7 mm, plus a millimetre).
    pub skin_usual_m: f64,
    /// Farthest a marker may sit from the skin of its own bone's part or its
    /// neighbours' ([`Parts`]), metres; past it the band's weight applies. 3 cm: the
    /// procedural hand's bind takes a marker that far from its part (a character file's,
    /// a tenth of the character's size).
    pub own_part_max_m: f64,
    /// Weight of the band, per frame used (a marker 1 cm outside the band costs as much
    /// as `skin_band_weight` cm of misfit in every frame).
    pub skin_band_weight: f64,
    /// Weight of the pull to the usual distance, per frame used.
    pub skin_pull_weight: f64,
    /// Misfit (metres, on every marker in every frame) that a 5 % change of the scale
    /// from its start is worth.
    pub scale_prior_m: f64,
    /// Misfit (metres, on the marker in every frame) that its rest position 5 cm from
    /// its template ([`OffsetSolve::hold_templates`]) is worth.
    pub template_prior_m: f64,
    /// Misfit (metres, on the marker in every frame) that two labels of a midline joint
    /// 1 cm from mirror images are worth ([`OffsetSolve::hold_mirrors`]).
    pub mirror_prior_m: f64,
    /// `ε_hold`: the rest prior of the joints a frame holds near rest (see the module
    /// doc), in the units of [`IkParams::rest_prior`].
    pub rest_hold_prior: f64,
    /// Levenberg–Marquardt iterations on the offsets at most.
    pub max_iterations: usize,
    /// Stop when no offset moves more than this in one step, metres (and the scale by
    /// less than this per metre of height) ...
    pub step_tolerance_m: f64,
    /// ... or a step lowers the objective by less than this fraction of it.
    pub cost_tolerance: f64,
    /// The posture fits' settings.
    pub posture: IkParams,
}

impl Default for SolveParams {
    fn default() -> Self {
        Self {
            skin_min_m: 0.003,
            skin_max_m: 0.02,
            skin_usual_m: 0.008,
            own_part_max_m: 0.03,
            skin_band_weight: 2.0,
            skin_pull_weight: 0.3,
            rest_hold_prior: 0.05,
            // Weak: the first guess's scale comes from one frame, and on a take with no
            // frame like the rest pose it is 5 to 11 % off (a walk's arms hang where a
            // T-posed character's are level); at 1 mm the fit stayed near it (the
            // Mixamo soldier's idle at a person's size 5 % off, against 0.7 % at 0.3 mm).
            scale_prior_m: 0.0003,
            // Landmarks are found by touch within 1 to 2 cm (Della Croce et al. 2005,
            // between examiners), so a label 5 cm from its template is unlikely. At 1 mm
            // a forearm's labels turned about the limb, the forearm's twist undoing the
            // turn in every frame, with nothing in the misfit to stop them: on the truth
            // bench the placements were 17 to 38 mm off on average and up to 117 mm,
            // against 12 to 28 mm and 66 mm here.
            template_prior_m: 0.003,
            // Over 20 frames, a Plug-in Gait headband turned 8° about the vertical
            // (its pairs 2.7 cm from mirror images at a person's size) costs twice
            // what the rest-like frame's hold costs the head turned 8°: the symmetry
            // decides the turn, the hold the nod. Three times stronger, the truth
            // bench's heads came out no better and CesiumMan's vertices 0.1 % of its
            // height further off (markers there are put on up to 20° about the bone
            // from where the manual says, each its own way).
            mirror_prior_m: 0.001,
            max_iterations: 60,
            step_tolerance_m: 2e-5,
            cost_tolerance: 1e-4,
            posture: IkParams {
                // A tenth of the live prior: the prior pulls every posture toward rest,
                // and offsets can give way to it (a foot's two markers turned about
                // their line); at the live weight that bias moved them 2 cm.
                rest_prior: 2e-4,
                prev_prior: 0.0,
                // Tight: the offset steps are judged on the postures' objective, which
                // must not move for a posture left half fitted (at 1e-5 rad and 1e-9
                // the offsets came out 3 to 10 times worse on the bundled takes).
                max_iterations: 200,
                step_tolerance_rad: 1e-6,
                cost_tolerance: 1e-11,
            },
        }
    }
}

/// The offset problem over a set of frames, and its current solution.
pub struct OffsetSolve<'a> {
    /// The posture problem with the current offsets (`marker_offset`).
    pub model: IkModel,
    /// The frames used: `frames[f][k]`, take coordinates (metres, Y up), NaN for a gap.
    pub frames: Vec<Vec<DVec3>>,
    /// Per frame the fitted posture.
    pub states: Vec<IkState>,
    /// Character metres per take metre.
    pub scale: f64,
    skin: Skin<'a>,
    params: SolveParams,
    /// `s⁰`: the scale [`Self::run`] started from.
    start_scale: f64,
    /// Scratch: scaled targets of one frame.
    targets: Vec<DVec3>,
    /// Per marker, where its marker set puts it at rest, if known.
    templates: Vec<Option<DVec3>>,
    /// The mirror terms ([`Self::hold_mirrors`]) and the body's left at rest.
    mirrors: Vec<Mirror>,
    left: DVec3,
}

/// A mirror term of the objective (see the module doc): marker `a` (on the left) and
/// its mirror partner `b`, both on the same midline joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mirror {
    pub a: usize,
    pub b: usize,
}

/// The mirror across the sagittal plane of normal `left` (a unit vector): `M = I − 2 n nᵀ`,
/// symmetric and its own inverse.
pub fn mirror_across(left: DVec3) -> glam::DMat3 {
    let n = left;
    glam::DMat3::IDENTITY - 2.0 * glam::DMat3::from_cols(n * n.x, n * n.y, n * n.z)
}

/// How far two offsets from one midline joint lie from mirror images: `M o_a − o_b`,
/// metres, `left` the body's left (a unit vector). Zero for a symmetric pair, and
/// still zero after the joint nods (turns about `left`) with both; not after it turns
/// about any axis across `left`.
pub fn asymmetry(left: DVec3, o_a: DVec3, o_b: DVec3) -> DVec3 {
    mirror_across(left) * o_a - o_b
}

/// What [`OffsetSolve::run`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SolveReport {
    pub iterations: usize,
    /// The objective at the start and the end (metres²).
    pub cost_start: f64,
    pub cost_end: f64,
    /// Whether it stopped on a tolerance (rather than the iteration cap).
    pub converged: bool,
}

/// The character's rest skin divided into parts as the bind divides it: each vertex
/// belongs to the joint whose bone segment is nearest ([`crate::rig::bind::nearest_owner`]).
pub struct Parts<'a> {
    skeleton: &'a Skeleton,
    segments: Vec<(usize, usize)>,
    /// Per joint, the triangles with a vertex in its part (empty for a joint without
    /// children).
    triangles: Vec<Vec<[DVec3; 3]>>,
    /// Per joint, the rest vertices of its part as offsets from the joint's rest
    /// position (world axes, metres).
    owned: Vec<Vec<DVec3>>,
}

impl<'a> Parts<'a> {
    /// The parts of the skin `vertices`, `triangles` (welded) over `skeleton` at rest.
    pub fn new(skeleton: &'a Skeleton, vertices: &[DVec3], triangles: &[[u32; 3]]) -> Self {
        let segments = crate::rig::bind::segments(skeleton);
        let owner: Vec<u32> = vertices
            .iter()
            .map(|&v| crate::rig::bind::nearest_owner(skeleton, &segments, v))
            .collect();
        let mut owned = vec![Vec::new(); skeleton.len()];
        for (v, &o) in vertices.iter().zip(&owner) {
            owned[o as usize].push(*v - skeleton.joints[o as usize].rest);
        }
        let mut parts = vec![Vec::new(); skeleton.len()];
        for t in triangles {
            let mut owners = t.map(|i| owner[i as usize]);
            owners.sort_unstable();
            for (n, &o) in owners.iter().enumerate() {
                if n == 0 || owners[n - 1] != o {
                    parts[o as usize].push(t.map(|i| vertices[i as usize]));
                }
            }
        }
        Self {
            skeleton,
            segments,
            triangles: parts,
            owned,
        }
    }

    /// The height (`y`) of the lowest point of the skin with the joints at world
    /// rotations `rot` and positions `pos` (indexed by joint), each part moving rigidly
    /// with its joint, and the joint whose part holds it; NaN when there is no skin. Near the joints the solve's deformed
    /// mesh blends neighbouring parts; a foot's sole, the lowest point of a standing
    /// character, moves with its foot.
    pub fn lowest(&self, rot: &[DQuat], pos: &[DVec3]) -> (f64, Option<usize>) {
        let mut low = (f64::INFINITY, None);
        for (j, ((vs, q), t)) in self.owned.iter().zip(rot).zip(pos).enumerate() {
            for v in vs {
                let y = t.y + (*q * *v).y;
                if y < low.0 {
                    low = (y, Some(j));
                }
            }
        }
        if low.0.is_finite() {
            low
        } else {
            (f64::NAN, None)
        }
    }

    /// Whether a point of joint `o`'s part counts as on joint `j`'s: the same joint, its
    /// parent or a child (the parts meet at the joints, where the bind's division is not
    /// the anatomy's: a heel lies nearer the shin's segment than the foot's).
    fn near(&self, j: usize, o: usize) -> bool {
        let parent = |x: usize| self.skeleton.joints.get(x).and_then(|jj| jj.parent);
        o == j || parent(j) == Some(o) || parent(o) == Some(j)
    }
}

/// One fitted frame's lowest points ([`OffsetSolve::lowest_m`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lowest {
    /// Height of the posed skin's lowest point, take metres (NaN without a skin).
    pub skin_m: f64,
    /// The joint whose part ([`Parts`]) holds that point.
    pub skin_joint: Option<usize>,
    /// Height of the lowest marker in view, take metres (NaN without one).
    pub marker_m: f64,
    /// That marker's index among the problem's markers.
    pub marker: Option<usize>,
}

/// The character's rest skin as the skin prior sees it.
#[derive(Clone, Copy)]
pub struct Skin<'a> {
    /// The whole skin: signed distances and nearest points.
    pub surface: &'a WindingNumber,
    pub parts: &'a Parts<'a>,
}

impl Skin<'_> {
    /// The point of the skin of joint `j`'s part or its neighbours' ([`Parts`]) nearest to
    /// `x`, and its distance; `None` when they have no skin.
    pub fn nearest_on_part(&self, j: usize, x: DVec3) -> Option<(DVec3, f64)> {
        let parts = self.parts;
        // Most often the nearest skin of all is on the part: one tree search.
        let (c, d) = self.surface.closest(x)?;
        let o = crate::rig::bind::nearest_owner(parts.skeleton, &parts.segments, c) as usize;
        if parts.near(j, o) {
            return Some((c, d));
        }
        (0..parts.triangles.len())
            .filter(|&o| parts.near(j, o))
            .flat_map(|o| &parts.triangles[o])
            .fold(None, |best, t| {
                let c = crate::geom::winding::closest_on_triangle(x, t);
                let d = (c - x).length();
                match best {
                    Some((_, bd)) if bd <= d => best,
                    _ => Some((c, d)),
                }
            })
    }
}

/// The priors of one marker's rest position: six residuals, each with its gradient
/// `∂r/∂o`: the three coordinates of `w_t (r_J + o_k − t_k)` (zero without a template);
/// `w_band band(d)`, `w_pull (d − d_0)` (both along the outward direction from the
/// nearest skin point) and `w_band` times the excess of the distance to its own part
/// over [`SolveParams::own_part_max_m`] (away from that part's nearest point).
struct SkinTerm {
    rows: [(f64, DVec3); 6],
}

impl SkinTerm {
    const NONE: Self = Self {
        rows: [(0.0, DVec3::ZERO); 6],
    };

    fn cost(&self) -> f64 {
        self.rows.iter().map(|(r, _)| r * r).sum()
    }
}

impl<'a> OffsetSolve<'a> {
    /// A problem over `frames` (one entry per marker of `model`, take coordinates) with
    /// per-frame starting poses `start[f]` (the rigid motion taking the character's rest
    /// pose into the frame's scaled take coordinates) and the starting scale.
    pub fn new(
        model: IkModel,
        frames: Vec<Vec<DVec3>>,
        start: &[(DQuat, DVec3)],
        scale: f64,
        skin: Skin<'a>,
        params: SolveParams,
    ) -> Self {
        let states = start
            .iter()
            .map(|&(q, t)| {
                let mut st = model.new_state();
                model.place_roots(&mut st, q, t);
                st
            })
            .collect();
        let targets = vec![DVec3::NAN; model.marker_joint.len()];
        Self {
            model,
            frames,
            states,
            scale,
            skin,
            params,
            start_scale: scale,
            targets,
            templates: Vec::new(),
            mirrors: Vec::new(),
            left: DVec3::ZERO,
        }
    }

    /// `w_s`: a 5 % change of scale weighs `scale_prior_m` on every sample.
    fn scale_weight(&self) -> f64 {
        let samples: usize = self
            .frames
            .iter()
            .map(|f| f.iter().filter(|m| m.is_finite()).count())
            .sum();
        self.params.scale_prior_m * (3.0 * samples as f64).sqrt() / 0.05
    }

    /// Holds frame `frame` near the rest pose at the joints `held[j]` (see the module
    /// doc).
    pub fn hold_rest(&mut self, frame: usize, held: &[bool]) {
        let factor = (self.params.rest_hold_prior / self.params.posture.rest_prior).powi(2);
        let st = &mut self.states[frame];
        for (j, d) in self.model.dofs.iter().enumerate() {
            if let (Dofs::Angles { first }, true) = (*d, held.get(j).copied().unwrap_or(false)) {
                st.rest_scale[first..first + 3].fill(factor);
            }
        }
    }

    /// Holds each marker loosely near its template (`templates[k]`, a rest position,
    /// metres; `None`: no template): the `w_t² ‖r_J + o_k − t_k‖²` term of the module
    /// doc.
    pub fn hold_templates(&mut self, templates: Vec<Option<DVec3>>) {
        self.templates = templates;
    }

    /// Holds the labels of midline joints to their mirror symmetry: `left` the body's
    /// left at rest (a unit vector), `mirrors` the pairs (the `w_m` terms of the module
    /// doc).
    pub fn hold_mirrors(&mut self, left: DVec3, mirrors: Vec<Mirror>) {
        self.left = left;
        self.mirrors = mirrors;
    }

    /// `w_m`, per metre of asymmetry.
    fn mirror_weight(&self) -> f64 {
        self.params.mirror_prior_m * (self.frames.len().max(1) as f64).sqrt() / 0.01
    }

    /// The weighted residual of mirror term `m`: `w_m (M o_a − o_b)`.
    fn mirror_residual(&self, m: Mirror) -> DVec3 {
        let o = &self.model.marker_offset;
        self.mirror_weight() * asymmetry(self.left, o[m.a], o[m.b])
    }

    /// Adds the mirror terms' Gauss–Newton blocks to `h` (`ng × ng`) and `g`: with
    /// `r = w (M o_a − o_b)` the Jacobian is `w M` in `o_a` and `−w I` in `o_b`, and
    /// `MᵀM = I`.
    fn add_mirrors(&self, h: &mut [f64], g: &mut [f64]) {
        let ng = g.len();
        let w = self.mirror_weight();
        let mirror = mirror_across(self.left);
        for &m in &self.mirrors {
            let r = self.mirror_residual(m);
            let (at, bt) = (3 * m.a, 3 * m.b);
            let (ga, gb) = (w * (mirror * r), -w * r);
            for i in 0..3 {
                g[at + i] += ga[i];
                g[bt + i] += gb[i];
                h[(at + i) * ng + at + i] += w * w;
                h[(bt + i) * ng + bt + i] += w * w;
                for j in 0..3 {
                    // (J_aᵀ J_b)[i][j] = −w² M[j][i] = −w² M[i][j] (M symmetric).
                    let c = -w * w * mirror.col(j)[i];
                    h[(at + i) * ng + bt + j] += c;
                    h[(bt + j) * ng + at + i] += c;
                }
            }
        }
    }

    /// Marker `k`'s current offset from its joint at rest (world axes, metres).
    pub fn model_offset(&self, k: usize) -> DVec3 {
        self.model.marker_offset[k]
    }

    /// Per frame used, the posed skin's lowest point ([`Parts::lowest`]) and the lowest
    /// marker in view.
    pub fn lowest_m(&self) -> Vec<Lowest> {
        self.states
            .iter()
            .zip(&self.frames)
            .map(|(st, frame)| {
                let (skin, skin_joint) = self.skin.parts.lowest(&st.world_rot, &st.world_pos);
                let lowest = frame
                    .iter()
                    .enumerate()
                    .filter(|(_, m)| m.is_finite())
                    .min_by(|a, b| a.1.y.total_cmp(&b.1.y));
                Lowest {
                    skin_m: skin / self.scale,
                    skin_joint,
                    marker_m: lowest.map_or(f64::NAN, |(_, m)| m.y),
                    marker: lowest.map(|(k, _)| k),
                }
            })
            .collect()
    }

    /// Markers of the problem.
    pub fn markers(&self) -> usize {
        self.model.marker_joint.len()
    }

    /// Fits every frame's posture to the current offsets and scale (warm-started).
    pub fn fit_postures(&mut self) {
        let params = IkParams {
            rest_prior: self.params.posture.rest_prior * self.scale,
            ..self.params.posture
        };
        for (st, frame) in self.states.iter_mut().zip(&self.frames) {
            for (t, m) in self.targets.iter_mut().zip(frame) {
                *t = *m * self.scale;
            }
            self.model.begin_frame(st);
            self.model.solve(st, &self.targets, &params);
        }
    }

    /// The priors' terms of marker `k` (its template and the skin) at its current offset.
    fn skin_term(&self, k: usize) -> SkinTerm {
        let p = &self.params;
        let n_frames = self.frames.len().max(1) as f64;
        let (wb, wp) = (
            p.skin_band_weight * n_frames.sqrt(),
            p.skin_pull_weight * n_frames.sqrt(),
        );
        let j = self.model.marker_joint[k];
        let x = self.model.rest[j] + self.model.marker_offset[k];
        let Some((_, d, normal)) = self.skin.surface.signed_closest(x) else {
            return SkinTerm::NONE;
        };
        let excess = d - d.clamp(p.skin_min_m, p.skin_max_m);
        let own = match self.skin.nearest_on_part(j, x) {
            Some((c, d_own)) if d_own > p.own_part_max_m => {
                (wb * (d_own - p.own_part_max_m), wb * (x - c) / d_own)
            }
            _ => (0.0, DVec3::ZERO),
        };
        let wt = p.template_prior_m * n_frames.sqrt() / 0.05;
        let t = match self.templates.get(k).copied().flatten() {
            Some(t) => wt * (x - t),
            None => DVec3::ZERO,
        };
        let tw = if t == DVec3::ZERO { 0.0 } else { wt };
        SkinTerm {
            rows: [
                (t.x, DVec3::X * tw),
                (t.y, DVec3::Y * tw),
                (t.z, DVec3::Z * tw),
                (
                    wb * excess,
                    if excess != 0.0 {
                        wb * normal
                    } else {
                        DVec3::ZERO
                    },
                ),
                (wp * (d - p.skin_usual_m), wp * normal),
                own,
            ],
        }
    }

    /// The objective at the current postures, offsets and scale.
    pub fn cost(&self) -> f64 {
        let (rest_w, _) = self.model.prior_weights(&self.params.posture);
        let mut e = 0.0;
        for (st, frame) in self.states.iter().zip(&self.frames) {
            for (p, m) in st.predicted.iter().zip(frame) {
                if m.is_finite() {
                    e += (*p / self.scale - *m).length_squared();
                }
            }
            e += rest_w * angle_norm2(&self.model, &st.angles, &st.rest_scale);
        }
        e += (self.scale_weight() * (self.scale / self.start_scale - 1.0)).powi(2);
        for k in 0..self.markers() {
            e += self.skin_term(k).cost();
        }
        for &m in &self.mirrors {
            e += self.mirror_residual(m).length_squared();
        }
        e
    }

    /// One pass of plain alternation: every offset set to its mean in its joint's frame
    /// over the frames (postures fixed), then pulled onto the skin band if it left it;
    /// the postures refitted. The start of the solve, from offsets that may be far off.
    pub fn alternate(&mut self) {
        for k in 0..self.markers() {
            let samples = self.samples(k);
            if let Some(mean) = self.mean_in_joint_frame(&samples, self.model.marker_joint[k]) {
                self.model.marker_offset[k] = mean.0;
            }
            // Out of the skin band or off its own part: onto the usual distance from the
            // nearest skin of its part (of any part when its own is empty).
            let [_, _, _, band, _, own] = self.skin_term(k).rows;
            if band.0 != 0.0 || own.0 != 0.0 {
                let j = self.model.marker_joint[k];
                let x = self.model.rest[j] + self.model.marker_offset[k];
                if let Some((c, d, out)) = self.skin.surface.signed_closest(x) {
                    // Outward from the part's nearest point: away from it on `x`'s side.
                    let (c, out) = match self.skin.nearest_on_part(j, x) {
                        Some((p, _)) => (p, (x - p).normalize_or_zero() * d.signum()),
                        None => (c, out),
                    };
                    self.model.marker_offset[k] =
                        c + out * self.params.skin_usual_m - self.model.rest[j];
                }
            }
        }
        for st in &mut self.states {
            self.model.refresh(st);
        }
        self.fit_postures();
    }

    /// The mean and RMS spread of a marker's measured positions (`samples[f]`, take
    /// coordinates, one per frame, NaN for a gap) in joint `j`'s rest frame over the
    /// fitted frames (`Q_j⁻¹ (s m − P_j)`, relative to `r_j`), or `None` when no frame
    /// has it.
    pub fn mean_in_joint_frame(&self, samples: &[DVec3], j: usize) -> Option<(DVec3, f64)> {
        let mut xs = Vec::with_capacity(self.frames.len());
        for (st, &m) in self.states.iter().zip(samples) {
            if m.is_finite() {
                xs.push(st.world_rot[j].inverse() * (m * self.scale - st.world_pos[j]));
            }
        }
        if xs.is_empty() {
            return None;
        }
        let mean = xs.iter().copied().sum::<DVec3>() / xs.len() as f64;
        let spread =
            (xs.iter().map(|x| (*x - mean).length_squared()).sum::<f64>() / xs.len() as f64).sqrt();
        Some((mean, spread))
    }

    /// The marker `k`'s samples over the frames.
    fn samples(&self, k: usize) -> Vec<DVec3> {
        self.frames.iter().map(|f| f[k]).collect()
    }

    /// Signed distance of a rest position from the skin, metres (positive outside).
    pub fn surface_distance(&self, x: DVec3) -> Option<f64> {
        self.skin.surface.signed_closest(x).map(|(_, d, _)| d)
    }

    /// Frames where marker `k` misses its fitted position by more than `threshold_m`
    /// (take metres).
    pub fn frames_off(&self, k: usize, threshold_m: f64) -> usize {
        self.states
            .iter()
            .zip(&self.frames)
            .filter(|(st, f)| {
                f[k].is_finite()
                    && (st.predicted[k] - f[k] * self.scale).length() > threshold_m * self.scale
            })
            .count()
    }

    /// The solve's settings.
    pub fn params(&self) -> &SolveParams {
        &self.params
    }

    /// Levenberg–Marquardt on the offsets and scale with the postures eliminated (see
    /// the module doc), until the step falls below the tolerance.
    pub fn run(&mut self) -> SolveReport {
        let ng = 3 * self.markers() + 1;
        self.start_scale = self.scale;
        let mut report = SolveReport {
            cost_start: self.cost(),
            ..SolveReport::default()
        };
        let mut cost = report.cost_start;
        let mut mu = 1e-4;
        let mut h = vec![0.0; ng * ng];
        let mut g = vec![0.0; ng];
        let mut a = vec![0.0; ng * ng];
        let mut step = vec![0.0; ng];
        let height = self.model.height_m;
        while report.iterations < self.params.max_iterations {
            report.iterations += 1;
            self.reduced_system(&mut h, &mut g);
            let cost_before = cost;
            let mut accepted = false;
            let mut largest = 0.0;
            for _ in 0..10 {
                a.copy_from_slice(&h);
                for i in 0..ng {
                    a[i * ng + i] += mu * h[i * ng + i].max(1e-12);
                }
                for (s, gi) in step.iter_mut().zip(&g) {
                    *s = -gi;
                }
                if !cholesky(&mut a, ng) {
                    mu *= 8.0;
                    continue;
                }
                cholesky_solve(&a, ng, &mut step);
                let saved = (
                    self.model.marker_offset.clone(),
                    self.scale,
                    self.states.clone(),
                );
                for k in 0..self.markers() {
                    self.model.marker_offset[k] +=
                        DVec3::new(step[3 * k], step[3 * k + 1], step[3 * k + 2]);
                }
                self.scale = (self.scale + step[ng - 1]).max(1e-3 * saved.1);
                for st in &mut self.states {
                    self.model.refresh(st);
                }
                self.fit_postures();
                let c = self.cost();
                largest = (0..self.markers())
                    .map(|k| DVec3::new(step[3 * k], step[3 * k + 1], step[3 * k + 2]).length())
                    .fold(step[ng - 1].abs() * height, f64::max);
                if c <= cost {
                    cost = c;
                    mu = (mu / 3.0).max(1e-9);
                    accepted = true;
                    break;
                }
                (self.model.marker_offset, self.scale, self.states) = saved;
                mu = (mu * 8.0).min(1e9);
            }
            // Done when no step lowers the objective, the offsets stop moving, or a step
            // gains less than the cost tolerance.
            let gain = (cost_before - cost) / cost_before.max(f64::MIN_POSITIVE);
            if !accepted
                || largest < self.params.step_tolerance_m
                || gain < self.params.cost_tolerance
            {
                report.converged = true;
                break;
            }
        }
        report.cost_end = cost;
        report
    }

    /// The reduced Gauss–Newton system of the offsets and scale: `h` (`ng × ng`,
    /// row-major, `ng = 3 markers + 1`, the scale last) and `g`.
    fn reduced_system(&mut self, h: &mut [f64], g: &mut [f64]) {
        let ng = g.len();
        h.fill(0.0);
        g.fill(0.0);
        let (rest_w, _) = self.model.prior_weights(&self.params.posture);
        let np = self.model.n_params;
        let mut cols = Vec::new();
        // Per frame: active posture unknowns, their block and coupling.
        let mut active_of = vec![usize::MAX; np];
        let mut active: Vec<usize> = Vec::with_capacity(np);
        let (model, scale) = (&self.model, self.scale);
        for (st, frame) in self.states.iter_mut().zip(&self.frames) {
            model.update_omega(st);
            active.clear();
            active_of.fill(usize::MAX);
            for (k, m) in frame.iter().enumerate() {
                if !m.is_finite() {
                    continue;
                }
                model.marker_columns(st, k, &mut cols);
                for &(i, _) in &cols {
                    let on_bound = st.angles[i] <= model.lo[i] || st.angles[i] >= model.hi[i];
                    if active_of[i] == usize::MAX && !on_bound {
                        active_of[i] = active.len();
                        active.push(i);
                    }
                }
            }
            let na = active.len();
            let mut haa = vec![0.0; na * na];
            let mut ga = vec![0.0; na];
            // H_ag as dense na × ng (most columns zero: fine at these sizes).
            let mut hag = vec![0.0; na * ng];
            for (k, m) in frame.iter().enumerate() {
                if !m.is_finite() {
                    continue;
                }
                // Rows in take units: r = p / s − m.
                let inv = 1.0 / scale;
                let p = st.predicted[k];
                let r = p * inv - *m;
                let q = st.world_rot[model.marker_joint[k]];
                let gcols = [
                    (3 * k, q * DVec3::X * inv),
                    (3 * k + 1, q * DVec3::Y * inv),
                    (3 * k + 2, q * DVec3::Z * inv),
                    (ng - 1, -p * inv * inv),
                ];
                for &(x, cx) in &gcols {
                    g[x] += cx.dot(r);
                    for &(y, cy) in &gcols {
                        h[x * ng + y] += cx.dot(cy);
                    }
                }
                model.marker_columns(st, k, &mut cols);
                for c in cols.iter_mut() {
                    c.1 *= inv;
                }
                for &(i, ci) in &cols {
                    let ai = active_of[i];
                    if ai == usize::MAX {
                        continue;
                    }
                    ga[ai] += ci.dot(r);
                    for &(j, cj) in &cols {
                        let aj = active_of[j];
                        if aj != usize::MAX {
                            haa[ai * na + aj] += ci.dot(cj);
                        }
                    }
                    for &(y, cy) in &gcols {
                        hag[ai * ng + y] += ci.dot(cy);
                    }
                }
            }
            for (ai, &i) in active.iter().enumerate() {
                if is_angle(model, i) {
                    let w = rest_w * st.rest_scale[i];
                    haa[ai * na + ai] += w;
                    ga[ai] += w * st.angles[i];
                }
            }
            if na == 0 || !cholesky(&mut haa, na) {
                continue;
            }
            // X = H_aa⁻¹ [H_ag | g_a], column by column; then subtract H_ga X.
            let mut col = vec![0.0; na];
            let mut x = vec![0.0; na * (ng + 1)];
            for y in 0..=ng {
                let mut nonzero = false;
                for ai in 0..na {
                    col[ai] = if y < ng { hag[ai * ng + y] } else { ga[ai] };
                    nonzero |= col[ai] != 0.0;
                }
                if !nonzero {
                    continue;
                }
                cholesky_solve(&haa, na, &mut col);
                for ai in 0..na {
                    x[ai * (ng + 1) + y] = col[ai];
                }
            }
            for xg in 0..ng {
                for ai in 0..na {
                    let c = hag[ai * ng + xg];
                    if c == 0.0 {
                        continue;
                    }
                    let row = &x[ai * (ng + 1)..(ai + 1) * (ng + 1)];
                    for y in 0..ng {
                        h[xg * ng + y] -= c * row[y];
                    }
                    g[xg] -= c * row[ng];
                }
            }
        }
        let ws = self.scale_weight() / self.start_scale;
        g[ng - 1] += ws * ws * (self.scale - self.start_scale);
        h[ng * ng - 1] += ws * ws;
        for k in 0..self.markers() {
            for (res, jrow) in self.skin_term(k).rows {
                for i in 0..3 {
                    g[3 * k + i] += jrow[i] * res;
                    for j in 0..3 {
                        h[(3 * k + i) * ng + 3 * k + j] += jrow[i] * jrow[j];
                    }
                }
            }
        }
        self.add_mirrors(h, g);
    }

    /// Per marker the RMS and largest misfit over the frames that have it, in take
    /// metres (the character's divided by the scale), and how many frames had it.
    pub fn residuals(&self) -> Vec<(f64, f64, usize)> {
        (0..self.markers())
            .map(|k| {
                let (mut sum, mut max, mut n) = (0.0, 0.0f64, 0);
                for (st, frame) in self.states.iter().zip(&self.frames) {
                    if frame[k].is_finite() {
                        let e = (st.predicted[k] - frame[k] * self.scale).length() / self.scale;
                        sum += e * e;
                        max = max.max(e);
                        n += 1;
                    }
                }
                ((sum / n.max(1) as f64).sqrt(), max, n)
            })
            .collect()
    }
}

/// Whether unknown `i` is a joint angle (priors apply) rather than a root's.
fn is_angle(m: &IkModel, i: usize) -> bool {
    m.dofs
        .iter()
        .any(|d| matches!(*d, Dofs::Angles { first } if (first..first + 3).contains(&i)))
}

/// `Σ c θ²` over the joint angles, `c` their rest prior factors.
fn angle_norm2(m: &IkModel, angles: &[f64], factor: &[f64]) -> f64 {
    m.dofs
        .iter()
        .filter_map(|d| match *d {
            Dofs::Angles { first } => Some(
                (first..first + 3)
                    .map(|i| factor[i] * angles[i] * angles[i])
                    .sum::<f64>(),
            ),
            _ => None,
        })
        .sum()
}

/// In-place Cholesky factorization of the symmetric `n × n` row-major `a` (lower
/// triangle read and written); false when it is not positive definite.
pub(crate) fn cholesky(a: &mut [f64], n: usize) -> bool {
    for j in 0..n {
        for k in 0..j {
            let mut v = a[j * n + k];
            for i in 0..k {
                v -= a[j * n + i] * a[k * n + i];
            }
            a[j * n + k] = v / a[k * n + k];
        }
        let mut d = a[j * n + j];
        for i in 0..j {
            d -= a[j * n + i] * a[j * n + i];
        }
        if d.is_nan() || d <= 0.0 {
            return false;
        }
        a[j * n + j] = d.sqrt();
    }
    true
}

/// Solves `L Lᵀ x = b` in place with the factor of [`cholesky`].
pub(crate) fn cholesky_solve(l: &[f64], n: usize, b: &mut [f64]) {
    for i in 0..n {
        let mut v = b[i];
        for k in 0..i {
            v -= l[i * n + k] * b[k];
        }
        b[i] = v / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut v = b[i];
        for k in i + 1..n {
            v -= l[k * n + i] * b[k];
        }
        b[i] = v / l[i * n + i];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A symmetric pair stays symmetric when its joint nods, and not when it turns about
    /// the vertical or the forward axis: the symmetry pins a head's turn and roll, not
    /// its nod.
    #[test]
    fn a_mirror_pair_sees_a_turn_and_a_roll_and_not_a_nod() {
        let (front, up, left) = (DVec3::Z, DVec3::Y, DVec3::X);
        // Plug-in Gait's left front head marker on a person's head, from its joint.
        let o_a = 0.06 * left + 0.08 * front + 0.08 * up;
        let o_b = mirror_across(left) * o_a;
        assert!(asymmetry(left, o_a, o_b).length() < 1e-15);
        let turned = |axis: DVec3| {
            let q = DQuat::from_axis_angle(axis, 8f64.to_radians());
            asymmetry(left, q * o_a, q * o_b).length()
        };
        assert!(turned(left) < 1e-15, "{}", turned(left));
        // Twice the turn's sine times the pair's distance from the axis (0.1 m from
        // the vertical and from the forward axis): 2 sin 8° · 0.1 = 0.0278 m.
        let yaw = turned(up);
        let roll = turned(front);
        println!("turn {yaw:.4} m, roll {roll:.4} m");
        assert!(
            (yaw - 2.0 * 8f64.to_radians().sin() * 0.1).abs() < 1e-4,
            "{yaw}"
        );
        assert!(
            (roll - 2.0 * 8f64.to_radians().sin() * 0.1).abs() < 1e-4,
            "{roll}"
        );
    }
}
