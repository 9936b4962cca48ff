//! Fitting a take's marker layout onto a character: for every label, the joint whose
//! segments carry it and its offset there, and the scale between actor and character.
//!
//! - [`points`]: which of the take's points are markers on the actor (model outputs,
//!   unlabelled points, another subject, props and fixed points are not);
//! - [`marker_sets`]: built-in tables (the humanoid part each label of the common optical
//!   sets rides);
//! - [`labels`]: each label's candidate joints and on whose word (layout, user map, table,
//!   or the motion itself);
//! - [`frames`]: the frames used and the first guess of scale and headings;
//! - [`scale`]: the scale from segment lengths over many frames, a second start;
//! - [`solve`]: the offsets and scale over those frames (MoSh's first stage on this
//!   skeleton);
//! - [`layout`]: the result written into a character file;
//! - [`config`]: a stage's `[calibration]` (from the first seconds of live input).
//!
//! [`calibrate`] runs them in order: plan, choose frames, align, fit the labels whose
//! bone is known (several candidates: the one the marker moves most rigidly with), place
//! the others on the joint they move rigidly with, fit everything, and report each
//! label's misfit with a flag where it fits badly.

pub mod config;
pub mod frames;
pub mod labels;
pub mod landmarks;
pub mod layout;
pub mod marker_sets;
pub mod points;
pub mod scale;
pub mod solve;

use crate::character::bind_params::BindParams;
use crate::character::mesh::welded_outward;
use crate::character::roles::{Part, Role};
use crate::character::{Character, MarkerDef};
use crate::geom::winding::WindingNumber;
use crate::rig::bind::{BindError, BindStage, Rig};
use crate::rig::ik_model::IkModel;
use frames::{choose_frames, fit_heading, Heading, Turn};
use glam::{DQuat, DVec3};
use labels::{plan, LabelPlan, LeftOut, MapEntry, MapError, Source};
use marker_sets::MarkerSet;
use points::{screen_by_geometry, screen_by_name, PointFilter};
use scale::ScaleStart;
use solve::{Lowest, OffsetSolve, Parts, Skin, SolveParams, SolveReport};

/// Seconds either side of the rest-like frame a calibration fits first, before the
/// whole take ([`Problem::solve_from`]).
pub const NEAR_REST_S: f64 = 1.0;
/// How much worse the whole span may fit than the frames near rest before the layout
/// near rest is kept (the bound on `--frames` beating the default: 20 %).
pub const WHOLE_SPAN_WORSE: f64 = 1.2;
/// And by more than this, take millimetres: a few millimetres more over more poses is
/// skin sliding, not poses the character cannot take.
pub const WHOLE_SPAN_SLACK_MM: f64 = 5.0;
/// Frames a calibration uses unless told otherwise (MoSh uses 12; more cover more of
/// the range of motion at a linear cost).
pub const DEFAULT_FRAMES: usize = 20;
/// Largest coordinate of a point a calibration uses, metres (capture volumes are tens of
/// metres across; farther points count as missing).
pub const MAX_COORDINATE_M: f64 = 1e4;
/// Fewest labels with a known bone (layout, map or table) that align take and character.
pub const MIN_KNOWN_LABELS: usize = 4;

/// What a calibration is asked.
#[derive(Clone, Debug)]
pub struct CalibrationOptions {
    /// Frames to use.
    pub frames: usize,
    /// Only frames in this span of the take, seconds from its start.
    pub span_s: Option<(f64, f64)>,
    /// The marker-set table; `None`: the one that knows most labels.
    pub marker_set: Option<&'static MarkerSet>,
    /// The user's label map, tried before the tables.
    pub map: Vec<MapEntry>,
    /// The user's word on which labels are markers (`--exclude`, `--include`).
    pub points: PointFilter,
    /// Whether the take's points are markers on the skin (an optical take) or joint
    /// centres inside the body (a BVH's joints): then each labelled point starts at its
    /// joint and the skin prior is off.
    pub markers_on_skin: bool,
    /// Labels fitted farther outside the skin than this are left out (the bind refuses
    /// a marker this far from the character: pass its `max_marker_distance_m`), metres;
    /// default: no limit.
    pub max_marker_distance_m: f64,
    pub solve: SolveParams,
}

impl Default for CalibrationOptions {
    fn default() -> Self {
        Self {
            frames: DEFAULT_FRAMES,
            span_s: None,
            marker_set: None,
            map: Vec::new(),
            points: PointFilter::default(),
            markers_on_skin: true,
            max_marker_distance_m: f64::INFINITY,
            solve: SolveParams::default(),
        }
    }
}

/// What is odd about a placed label.
#[derive(Clone, Debug, PartialEq)]
pub enum Flag {
    /// Its misfit is well above the others': a mislabel, a marker on another part than
    /// its table says, or a bone the character lacks.
    FitsBadly { times_median: f64 },
    /// It fits in most frames and jumps in some: a swap or a mislabel partway through.
    Jumps { frames_off: usize },
    /// It sits farther from the skin than a marker can.
    OffSkin { distance_mm: f64 },
}

impl std::fmt::Display for Flag {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Flag::FitsBadly { times_median } => write!(
                f,
                "fits badly ({times_median:.1}× the median misfit): mislabelled, or on another part?"
            ),
            Flag::Jumps { frames_off } => write!(
                f,
                "off by far in {frames_off} frames: swapped or mislabelled partway?"
            ),
            Flag::OffSkin { distance_mm } => {
                write!(f, "{distance_mm:.0} mm from the skin: on another part?")
            }
        }
    }
}

/// One label placed on the character.
#[derive(Clone, Debug)]
pub struct PlacedLabel {
    pub label: String,
    /// The joint whose segments carry it.
    pub joint: usize,
    pub joint_name: String,
    /// Its offset from the joint at rest, metres, world axes.
    pub offset_m: DVec3,
    /// Signed distance of its rest position from the skin, metres (positive outside).
    pub skin_m: f64,
    pub source: Source,
    /// Misfit over the frames used that have it, take millimetres.
    pub residual_mm_rms: f64,
    pub residual_mm_max: f64,
    /// Frames used that have it.
    pub frames: usize,
    pub flag: Option<Flag>,
    /// Distance of its rest position from its template, where its marker set's manual
    /// puts it ([`landmarks`]), take metres; `None` without a template.
    pub from_template_m: Option<f64>,
}

/// A calibration's result.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// Character metres per take metre (the actor is `1 / scale` times the character).
    pub scale: f64,
    pub placed: Vec<PlacedLabel>,
    pub left_out: Vec<(String, LeftOut)>,
    /// The table used, and how many of the take's labels it knows.
    pub marker_set: Option<(&'static str, usize)>,
    /// The take's frames used.
    pub frames: Vec<usize>,
    /// Misfit over every placed label and frame used, take millimetres.
    pub residual_mm_rms: f64,
    pub residual_mm_max: f64,
    pub report: SolveReport,
    /// Labels with samples that may be markers (the take's labels less those that are
    /// no markers): the count the placed share is judged against.
    pub markers: usize,
    /// The table declined because it knows too few labels, with how many it knows.
    pub declined_set: Option<(&'static str, usize)>,
    /// The take's rest-like frame (the actor nearest the character's rest pose).
    pub rest_frame: usize,
    /// Where the scale's fit started: what the rest-like frame and the segment lengths
    /// each said, and which start the fit kept came from.
    pub scale_start: ScaleStart,
    /// When the layout was fitted on the frames near the rest-like frame alone because
    /// the whole span fitted far worse: the whole span's misfit RMS, take millimetres.
    pub whole_span_mm: Option<f64>,
    /// The character's standing height, metres, when it stands on legs and has a head
    /// (the actor's is this over the scale).
    pub standing_height_m: Option<f64>,
    /// A standing character's limbs and head ([`body_parts`]): each one's name and its
    /// joints, which a placed label must ride for it to be driven.
    pub body_parts: Vec<(String, Vec<usize>)>,
    /// Where the fitted postures put the character against the take's floor.
    pub floor: Option<FloorCheck>,
    /// The head joints whose turn only their own labels see (a head some label rides,
    /// with none riding below it, on a neck that carries none: turning it and its
    /// labels' offsets back fits every frame alike), each with its turn from rest, in
    /// degrees, in the rest-like frame's fitted posture (against the nearest ancestor a
    /// label rides). A person standing as the character does faces forward; a hand or a
    /// foot may be bent there, and is not judged so.
    pub rest_turns: Vec<(String, f64)>,
    /// Joints the fitted postures hold at one of their limits in all but a tenth of the
    /// frames used ([`strained_joints`]), each with in how many, and the frames used.
    pub strained: (Vec<(String, usize)>, usize),
    /// Each knee's least bend over the frames used, degrees (the angle between thigh and
    /// shin in the fitted postures), when every knee stays bent more than
    /// [`BENT_KNEES_DEG`] in every frame used ([`bent_knees`]); empty otherwise.
    pub bent_knees: Vec<(String, f64)>,
}

/// How far a calibration can be trusted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Verdict {
    Good,
    /// Usable, with named concerns.
    Doubtful,
    /// Not to be used: nothing is written.
    Failed,
}

impl std::fmt::Display for Verdict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Verdict::Good => "good",
            Verdict::Doubtful => "doubtful",
            Verdict::Failed => "failed",
        })
    }
}

/// Scales a calibration may find and still be good, character metres per take metre:
/// an adult actor on an adult or child character, or the reverse. Outside, the take or
/// the character is in other units, or the fit matched the wrong frames.
pub const GOOD_SCALE: std::ops::RangeInclusive<f64> = 0.5..=2.0;
/// Misfit RMS over which a calibration fails, take millimetres: markers 3 cm from where
/// their bones put them are on the wrong bones or the wrong character.
pub const FAILED_MISFIT_MM: f64 = 30.0;
/// Misfit RMS over which a calibration is doubtful, take millimetres (optical takes
/// fitted onto their own actor's character come out at 2 to 10 mm).
pub const DOUBTFUL_MISFIT_MM: f64 = 15.0;

/// What is wrong with a calibration, with the verdict it calls for.
#[derive(Clone, Debug, PartialEq)]
pub enum Concern {
    /// The scale is outside [`GOOD_SCALE`].
    Scale { scale: f64 },
    /// The misfit is over [`DOUBTFUL_MISFIT_MM`] or [`FAILED_MISFIT_MM`].
    Misfit { rms_mm: f64, limit_mm: f64 },
    /// Fewer than half of the markers were placed.
    FewPlaced { placed: usize, markers: usize },
    /// Labels flagged as fitting badly, jumping or off the skin.
    Flagged { labels: Vec<String> },
    /// The layout was fitted near the rest-like frame; the whole span fits it far worse.
    WholeSpan { near_mm: f64, whole_mm: f64 },
    /// The actor the scale implies (a standing character's height over the scale) is
    /// outside [`HUMAN_HEIGHT_M`]: the markers' sizes and distances from the skin, which
    /// the fit takes as a person's, do not hold.
    ActorSize { height_m: f64 },
    /// A standing character's lowest point is farther than [`FLOOR_TOLERANCE_M`] from
    /// the floor the take shows ([`FloorCheck`]).
    Floor(FloorCheck),
    /// Where the take shows no floor, a standing character's soles at least
    /// [`FLOOR_TOLERANCE_M`] below or above the actor's ([`FloorCheck::soles_off_m`]).
    Soles { floor: FloorCheck, off_m: f64 },
    /// A head whose turn only its own labels see ([`Calibration::rest_turns`]),
    /// turned more than [`TURNED_AT_REST_DEG`] from rest in the rest-like frame.
    TurnedAtRest { joints: Vec<(String, f64)> },
    /// Limbs, the head or the trunk of a standing character that no placed label rides.
    Undriven { parts: Vec<String> },
    /// Joints held at a limit in most frames used ([`Calibration::strained`]).
    Strained {
        joints: Vec<(String, usize)>,
        frames: usize,
    },
    /// Every knee bent in every frame used ([`Calibration::bent_knees`]).
    BentKnees { knees: Vec<(String, f64)> },
}

/// How far from rest a head whose turn only its own labels see may be turned in the
/// rest-like frame, degrees: an actor standing as the character does holds the head
/// within about 15° of facing forward; 30° leaves room for a character's rest pose unlike
/// the actor's natural stance.
pub const TURNED_AT_REST_DEG: f64 = 30.0;

/// How far a standing character's lowest point may come from the take's floor in the
/// median frame used and the calibration still be good, take metres: a foot 3 cm
/// through the floor or above it is plain to see (the bound on a replay).
pub const FLOOR_TOLERANCE_M: f64 = 0.03;
/// Heights of a take's lowest marker, in the median frame used, that show its floor is
/// `y = 0`, take metres: the lowest marker of a standing actor is a foot's, from its own
/// radius (a toe marker, about 1 cm) to an ankle's height (about 10 cm) above the
/// floor, with 2 cm below for a floor set a little high. Elsewhere (no foot markers, a
/// floor at another height) the take says nothing of its floor.
pub const FLOOR_MARKER_M: std::ops::RangeInclusive<f64> = -0.02..=0.15;

/// Highest a person's heel or toe marker stands above the ground its foot rests on,
/// take metres: the toe marker on the second metatarsal head, the heel marker at the
/// same height above the sole (Vicon, "Plug-in Gait Reference Guide"), a 14 mm marker
/// on the skin or on a shoe's upper: 2 to 4 cm barefoot, up to about 6 cm in shoes (the
/// CMU actor's lowest markers stand 3.0 to 3.3 cm above the take's floor).
pub const FOOT_MARKER_MAX_M: f64 = 0.06;

/// Where a calibration puts the character against the take's floor (`y = 0`), and,
/// where the take shows none, against the ground its feet rest on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FloorCheck {
    /// Median over the frames used of the height of the posed character's lowest skin
    /// point, take metres (negative: under the floor).
    pub lowest_skin_m: f64,
    /// Median over the frames used of the height of the lowest marker in view, take
    /// metres.
    pub lowest_marker_m: f64,
    /// Median, over the frames used whose lowest marker rides a foot (a foot or toe
    /// joint: a heel or toe marker) and whose lowest skin point is that foot's (its
    /// part, its shin's or its toes': the foot that bears the weight), of that marker's
    /// height above that point, take metres; `None` when fewer than half of the frames
    /// used have one.
    pub foot_marker_above_skin_m: Option<f64>,
}

impl FloorCheck {
    /// From each frame's lowest skin point and lowest marker ([`solve::OffsetSolve::lowest_m`]),
    /// and whether a marker `k` rides a foot whose sole is joint `j`'s part
    /// (`on_foot(k, j)`); `None` when no frame has both heights.
    pub fn from_frames(lowest: &[Lowest], on_foot: impl Fn(usize, usize) -> bool) -> Option<Self> {
        let both: Vec<&Lowest> = lowest
            .iter()
            .filter(|l| l.skin_m.is_finite() && l.marker_m.is_finite())
            .collect();
        if both.is_empty() {
            return None;
        }
        let median = |mut v: Vec<f64>| crate::runtime::stats::percentile(&mut v, 0.5);
        let above: Vec<f64> = both
            .iter()
            .filter(|l| matches!((l.marker, l.skin_joint), (Some(k), Some(j)) if on_foot(k, j)))
            .map(|l| l.marker_m - l.skin_m)
            .collect();
        let foot_marker_above_skin_m = (above.len() * 2 >= both.len()).then(|| median(above));
        Some(Self {
            lowest_skin_m: median(both.iter().map(|l| l.skin_m).collect()),
            lowest_marker_m: median(both.iter().map(|l| l.marker_m).collect()),
            foot_marker_above_skin_m,
        })
    }

    /// Whether the take shows its floor at `y = 0` ([`FLOOR_MARKER_M`]).
    pub fn floor_shown(&self) -> bool {
        FLOOR_MARKER_M.contains(&self.lowest_marker_m)
    }

    /// Whether the character stands off that floor by more than [`FLOOR_TOLERANCE_M`].
    pub fn off_floor(&self) -> bool {
        self.floor_shown() && self.lowest_skin_m.abs() > FLOOR_TOLERANCE_M
    }

    /// Where the take shows no floor: how far at least the character's soles stand
    /// below the actor's (positive) or above them (negative), take metres, when that is
    /// more than [`FLOOR_TOLERANCE_M`]. The lowest marker of a foot that bears the
    /// weight stands between the ground and [`FOOT_MARKER_MAX_M`] above it; the
    /// character's sole, that marker's height below it, lies as far under or over the
    /// actor's ground as that height is outside the range. `None` where the floor is
    /// shown (the floor itself is judged: [`Self::off_floor`]) or no foot bears the
    /// weight in most frames used.
    pub fn soles_off_m(&self) -> Option<f64> {
        let above = self
            .foot_marker_above_skin_m
            .filter(|_| !self.floor_shown())?;
        let off = if above > FOOT_MARKER_MAX_M {
            above - FOOT_MARKER_MAX_M
        } else {
            above.min(0.0)
        };
        (off.abs() > FLOOR_TOLERANCE_M).then_some(off)
    }
}

/// Heights of a person wearing markers, metres (a small child to a tall adult); a
/// standing character's take whose actor comes out outside it is doubtful.
pub const HUMAN_HEIGHT_M: std::ops::RangeInclusive<f64> = 0.9..=2.5;

impl Concern {
    /// The verdict this concern calls for.
    pub fn verdict(&self) -> Verdict {
        match self {
            Concern::Scale { .. } | Concern::FewPlaced { .. } => Verdict::Failed,
            Concern::Misfit { limit_mm, .. } if *limit_mm >= FAILED_MISFIT_MM => Verdict::Failed,
            Concern::Misfit { .. }
            | Concern::Flagged { .. }
            | Concern::WholeSpan { .. }
            | Concern::ActorSize { .. }
            | Concern::Floor(_)
            | Concern::Soles { .. }
            | Concern::TurnedAtRest { .. }
            | Concern::Undriven { .. }
            | Concern::Strained { .. }
            | Concern::BentKnees { .. } => Verdict::Doubtful,
        }
    }
}

impl std::fmt::Display for Concern {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Concern::Scale { scale } => write!(
                f,
                "the scale {scale:.4} is outside {}..{} (the actor {:.2} times the character): \
                 the take or the character is in other units (the take's POINT:UNITS, --bvh-scale, \
                 the character's [mesh] units), or the frames fitted are not the actor standing \
                 as the character does; try --frames START..END on a span where the actor stands \
                 in the character's rest pose",
                GOOD_SCALE.start(),
                GOOD_SCALE.end(),
                1.0 / scale
            ),
            Concern::Misfit { rms_mm, limit_mm } => write!(
                f,
                "the misfit {rms_mm:.1} mm RMS is over {limit_mm:.0} mm: labels on the wrong \
                 bones, or a character unlike the actor; look at the flagged labels, name their \
                 bones in [calibration.bones], leave them out with --exclude, or try --frames"
            ),
            Concern::FewPlaced { placed, markers } => write!(
                f,
                "only {placed} of the take's {markers} marker labels were placed: see why each \
                 was left out; name their bones in [calibration.bones] or choose a table with \
                 --marker-set"
            ),
            Concern::WholeSpan { near_mm, whole_mm } => write!(
                f,
                "fitted on the frames within {NEAR_REST_S} s of the rest-like frame ({near_mm:.1} mm \
                 RMS): over the whole take it fits at {whole_mm:.1} mm, poses the character's \
                 joint limits do not reach or markers that slide; a replay misfits there"
            ),
            Concern::ActorSize { height_m } => write!(
                f,
                "the actor would be {height_m:.2} m tall, outside {}..{} m: a person's markers \
                 on a character this size are too big and too far from its skin for a fit to \
                 be trusted; give the character its real size ([mesh] scale or units) or check the \
                 take's units",
                HUMAN_HEIGHT_M.start(),
                HUMAN_HEIGHT_M.end()
            ),
            Concern::Floor(floor) => write!(
                f,
                "the character's lowest point comes {:.1} cm {} the take's floor (y = 0, where \
                 its lowest marker is {:.1} cm above it) in the median frame used: the foot \
                 labels sit higher or lower on the character's feet than on the actor's, or \
                 the legs are scaled wrong; look at the feet in a replay (--rerun), and \
                 name the foot labels' bones in [calibration.bones] or try --frames on a span \
                 where the actor stands",
                floor.lowest_skin_m.abs() * 100.0,
                if floor.lowest_skin_m < 0.0 { "under" } else { "above" },
                floor.lowest_marker_m * 100.0
            ),
            Concern::Soles { floor, off_m } => write!(
                f,
                "the lowest marker, on the foot that bears the weight, stands {:.1} cm above \
                 the character's lowest point in the median frame used, where a person's heel \
                 or toe marker stands {} cm above the ground: the character's soles stand at \
                 least {:.1} cm {} the actor's (the take shows no floor at y = 0 to judge \
                 them against); the character's feet reach {} below their labels than the \
                 actor's (a thick sole, a bulky boot, or labels fitted {} on the feet); look \
                 at the feet in a replay (--rerun), and try a character whose feet are like \
                 the actor's or name the foot labels' bones in [calibration.bones]",
                floor.foot_marker_above_skin_m.unwrap_or(f64::NAN) * 100.0,
                if *off_m > 0.0 {
                    format!("at most {:.0}", FOOT_MARKER_MAX_M * 100.0)
                } else {
                    "at least 0".to_owned()
                },
                off_m.abs() * 100.0,
                if *off_m > 0.0 { "under" } else { "over" },
                if *off_m > 0.0 { "farther" } else { "less far" },
                if *off_m > 0.0 { "high" } else { "low" },
            ),
            Concern::Strained { joints, frames } => write!(
                f,
                "the fitted postures hold {} at a joint limit in nearly all of the {frames} \
                 frames used, where an actor does not stay: labels sit elsewhere on the character \
                 than on the actor (on the other side of a limb, or slid along it), and the \
                 pose turns to reach them; look at those joints in a replay (--rerun), name \
                 their labels' bones in [calibration.bones], or calibrate on a span with a T \
                 or A pose or a range of motion (--frames)",
                joints
                    .iter()
                    .map(|(j, n)| format!("{j} ({n})"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            Concern::BentKnees { knees } => write!(
                f,
                "the fitted postures keep the knees bent in every frame used (at least {}), \
                 where a standing or walking actor straightens them: the character's legs are \
                 long for its height against the actor's (or its pelvis labels sit higher), \
                 and the avatar crouches to reach the foot labels; look at the legs in a \
                 replay (--rerun), try --frames on a span where the actor stands straight, or \
                 a character of the actor's proportions",
                knees
                    .iter()
                    .map(|(j, deg)| format!("{j} {deg:.0}°"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            Concern::Undriven { parts } => write!(
                f,
                "no placed label rides the {}: the solve does not drive {}, and {} \
                 whatever pose the rest of the body leaves {} (the take has no markers there, \
                 or they were left out: see the labels left out); a take with markers on \
                 them drives them",
                parts.join(", "),
                if parts.len() == 1 { "it" } else { "them" },
                if parts.len() == 1 { "it keeps" } else { "they keep" },
                if parts.len() == 1 { "it in" } else { "them in" },
            ),
            Concern::TurnedAtRest { joints } => write!(
                f,
                "the head ({}) is turned from rest in the frame where the actor stands most \
                 like the character's rest pose, where a person faces forward: only the head's \
                 own labels see its turn, so they may sit elsewhere on the character's head \
                 than on the actor's (a head larger or smaller than the actor's), and the head \
                 is then turned as much in every frame; look at it in a replay (--rerun), and \
                 try --frames on a span where the actor stands facing forward",
                joints
                    .iter()
                    .map(|(name, deg)| format!("{name} {deg:.0}°"))
                    .collect::<Vec<_>>()
                    .join(", "),
            ),
            Concern::Flagged { labels } => write!(
                f,
                "{} label{} fit badly: {}",
                labels.len(),
                if labels.len() == 1 { "" } else { "s" },
                labels.join(", ")
            ),
        }
    }
}

impl Calibration {
    /// Its concerns (none: good), worst first.
    pub fn concerns(&self) -> Vec<Concern> {
        let mut out = Vec::new();
        if !GOOD_SCALE.contains(&self.scale) {
            out.push(Concern::Scale { scale: self.scale });
        }
        if self.placed.len() * 2 < self.markers {
            out.push(Concern::FewPlaced {
                placed: self.placed.len(),
                markers: self.markers,
            });
        }
        let rms = self.residual_mm_rms;
        if rms.is_nan() || rms > DOUBTFUL_MISFIT_MM {
            let limit_mm = if rms > FAILED_MISFIT_MM || !rms.is_finite() {
                FAILED_MISFIT_MM
            } else {
                DOUBTFUL_MISFIT_MM
            };
            out.push(Concern::Misfit {
                rms_mm: rms,
                limit_mm,
            });
        }
        let flagged: Vec<String> = self
            .placed
            .iter()
            .filter(|p| p.flag.is_some())
            .map(|p| p.label.clone())
            .collect();
        if !flagged.is_empty() {
            out.push(Concern::Flagged { labels: flagged });
        }
        if let Some(height_m) = self.standing_height_m.map(|h| h / self.scale) {
            if !HUMAN_HEIGHT_M.contains(&height_m) && GOOD_SCALE.contains(&self.scale) {
                out.push(Concern::ActorSize { height_m });
            }
        }
        let turned: Vec<(String, f64)> = self
            .rest_turns
            .iter()
            .filter(|(_, deg)| *deg > TURNED_AT_REST_DEG)
            .cloned()
            .collect();
        if !turned.is_empty() {
            out.push(Concern::TurnedAtRest { joints: turned });
        }
        if let (Some(floor), Some(_)) = (self.floor, self.standing_height_m) {
            if floor.off_floor() {
                out.push(Concern::Floor(floor));
            } else if let Some(off_m) = floor.soles_off_m() {
                out.push(Concern::Soles { floor, off_m });
            }
        }
        let parts: Vec<String> = self
            .body_parts
            .iter()
            .filter(|(_, joints)| !self.placed.iter().any(|p| joints.contains(&p.joint)))
            .map(|(name, _)| name.clone())
            .collect();
        if !parts.is_empty() {
            out.push(Concern::Undriven { parts });
        }
        if !self.strained.0.is_empty() {
            out.push(Concern::Strained {
                joints: self.strained.0.clone(),
                frames: self.strained.1,
            });
        }
        if !self.bent_knees.is_empty() {
            out.push(Concern::BentKnees {
                knees: self.bent_knees.clone(),
            });
        }
        if let Some(whole_mm) = self.whole_span_mm {
            out.push(Concern::WholeSpan {
                near_mm: self.residual_mm_rms,
                whole_mm,
            });
        }
        out.sort_by_key(|c| std::cmp::Reverse(c.verdict()));
        out
    }

    /// The verdict: the worst its concerns call for.
    pub fn verdict(&self) -> Verdict {
        self.concerns()
            .iter()
            .map(Concern::verdict)
            .max()
            .unwrap_or(Verdict::Good)
    }
}

impl Calibration {
    /// Binds `ch` with this layout. A label the bind refuses as too far from its bone's
    /// part of the control mesh is moved to the left-out labels (with the distance) and
    /// the bind tried again without it, so the rig returned carries every label it can.
    pub fn bind(
        &mut self,
        ch: &Character,
        params: &BindParams,
        progress: &mut dyn FnMut(BindStage, f64),
    ) -> Result<Rig, BindError> {
        loop {
            let laid = Character {
                markers: self.layout(ch),
                ..ch.clone()
            };
            match Rig::bind_with_progress(&laid, params, progress) {
                Err(BindError::MarkerTooFar {
                    name,
                    distance_m,
                    limit_m,
                }) if self.placed.len() > 1 => {
                    let Some(k) = self.placed.iter().position(|p| p.label == name) else {
                        return Err(BindError::MarkerTooFar {
                            name,
                            distance_m,
                            limit_m,
                        });
                    };
                    self.placed.remove(k);
                    self.left_out.push((
                        name,
                        LeftOut::TooFarFromBone {
                            distance_mm: distance_m * 1e3,
                            limit_mm: limit_m * 1e3,
                        },
                    ));
                }
                result => return result,
            }
        }
    }

    /// The placed labels as `ch`'s marker layout (rest positions in `ch`'s metres, each
    /// carried by its joint), in the placing order.
    pub fn layout(&self, ch: &Character) -> Vec<MarkerDef> {
        self.placed
            .iter()
            .map(|p| MarkerDef {
                name: p.label.clone(),
                rest: ch.skeleton.joints[p.joint].rest + p.offset_m,
                joint: Some(p.joint),
            })
            .collect()
    }
}

/// Why a take cannot be calibrated onto a character.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    #[error("{}", .0.iter().map(ToString::to_string).collect::<Vec<_>>().join("\n"))]
    Map(Vec<MapError>),
    #[error(
        "{take}: only {known} of its {labels} marker labels have a bone on this character ({MIN_KNOWN_LABELS} \
         are needed to align take and character); {}. Name their bones in the character \
         file's [calibration.bones] (globs to joints or roles) or choose a table with \
         --marker-set",
        match best {
            Some((set, n)) => format!(
                "the table that knows most of them, {set}, knows {n} ({:.0} %; a table is taken \
                 unasked when it knows half)",
                100.0 * *n as f64 / (*labels).max(1) as f64
            ),
            None => "no built-in table knows any".into(),
        }
    )]
    TooFewKnown {
        take: String,
        known: usize,
        labels: usize,
        best: Option<(&'static str, usize)>,
    },
    #[error("{take}: no frame in the span asked for has {MIN_KNOWN_LABELS} known labels in view")]
    NoFrames { take: String },
    /// Frames had labels in view, but none could be laid onto the character.
    #[error(
        "{take}: {frames} of the frames tried have {MIN_KNOWN_LABELS} or more known \
         labels in view, but in none of them do the labels come near the skin of their \
         bones at any heading and scale tried: labels on other bones than the table says, \
         or a character whose bones do not match the actor's (a limb of one joint with no \
         child has no bone of its own). Try --frames on a span where the actor stands as \
         the character does, or name the labels' bones in the character file's \
         [calibration.bones]"
    )]
    NoFirstGuess { take: String, frames: usize },
    /// Every point of the take was left out before the fit: there is nothing to fit.
    #[error(
        "{take}: none of its {points} points can be a marker, so nothing can be fitted: {}",
        .why.iter().map(|(reason, n, label)| format!("{n} point(s), such as {label:?}: {reason}")).collect::<Vec<_>>().join("; ")
    )]
    NoMarkers {
        take: String,
        points: usize,
        /// Each reason given, with how many labels it left out and the first of them.
        why: Vec<(String, usize, String)>,
    },
    #[error("the character has no skeleton joint with children")]
    NoJoints,
    #[error("{take}: the fit found no scale (too few distinct points in view)")]
    Degenerate { take: String },
    #[error("{take}: frame {frame} has {points} points for {labels} labels")]
    Ragged {
        take: String,
        frame: usize,
        points: usize,
        labels: usize,
    },
}

/// A take as the calibration reads it: labelled marker trajectories, `frames[f][k]` in
/// metres, world frame (Y up), NaN where missing (what `replay::recording::Recording`
/// holds; [`crate::replay::recording::Recording::as_take`] lends one).
#[derive(Clone, Copy, Debug)]
pub struct Take<'a> {
    /// Shown in errors (the file's name).
    pub name: &'a str,
    pub rate_hz: f64,
    pub labels: &'a [String],
    pub frames: &'a [Vec<DVec3>],
    /// For each label, the model-output group the file lists it under (empty when the
    /// file says nothing: see [`crate::replay::recording::Recording::point_groups`]).
    pub point_groups: &'a [Option<String>],
}

/// Calibrates take `rec` onto character `ch` (whose joints have `roles`).
pub fn calibrate(
    ch: &Character,
    roles: &[Option<Role>],
    rec: Take,
    opts: &CalibrationOptions,
) -> Result<Calibration, CalibrationError> {
    if let Some(f) = rec.frames.iter().position(|f| f.len() != rec.labels.len()) {
        return Err(CalibrationError::Ragged {
            take: rec.name.to_owned(),
            frame: f,
            points: rec.frames[f].len(),
            labels: rec.labels.len(),
        });
    }
    // A point farther than this from the origin is no marker of a capture volume: it
    // counts as missing (a take's coordinates are not trusted).
    let sane = |p: &DVec3| p.is_finite() && p.abs().max_element() <= MAX_COORDINATE_M;
    let cleaned: Vec<Vec<DVec3>> = rec
        .frames
        .iter()
        .map(|f| {
            f.iter()
                .map(|p| if sane(p) { *p } else { DVec3::NAN })
                .collect()
        })
        .collect();
    let rec = Take {
        frames: &cleaned,
        ..rec
    };
    let present: Vec<usize> = (0..rec.labels.len())
        .map(|k| rec.frames.iter().filter(|f| f[k].is_finite()).count())
        .collect();
    let named = screen_by_name(rec.labels, rec.point_groups, &opts.points);
    let excluded: Vec<bool> = named.iter().map(Option::is_some).collect();
    let mut plan = plan(
        ch,
        roles,
        rec.labels,
        &present,
        &excluded,
        &opts.map,
        opts.marker_set,
    )
    .map_err(CalibrationError::Map)?;
    let not_markers: Vec<(String, LeftOut)> = named
        .into_iter()
        .enumerate()
        .filter_map(|(k, why)| Some((rec.labels[k].clone(), LeftOut::NotAMarker(why?))))
        .collect();
    exclude_by_geometry(&mut plan, rec, &opts.points);
    plan.left_out.splice(0..0, not_markers);
    let mut params = opts.solve;
    if !opts.markers_on_skin {
        // Joint centres: each starts at its joint (as a layout's rest position would),
        // and nothing pulls it to the skin.
        for l in plan
            .labels
            .iter_mut()
            .filter(|l| l.source != Source::Motion)
        {
            l.rest = l.rest.or(Some(ch.skeleton.joints[l.candidates[0]].rest));
        }
        params.skin_band_weight = 0.0;
        params.skin_pull_weight = 0.0;
    }
    if plan.markers == 0 {
        return Err(no_markers(rec, &plan.left_out));
    }
    let stance = stance_of(ch, roles);
    let (unique, oriented, _) = welded_outward(&ch.vertices, &ch.triangles);
    let surface = WindingNumber::new(&unique, &oriented);
    if opts.markers_on_skin {
        put_templates(ch, roles, stance, &surface, &mut plan);
    }
    let known: Vec<&LabelPlan> = plan
        .labels
        .iter()
        .filter(|l| l.source != Source::Motion)
        .collect();
    if known.len() < MIN_KNOWN_LABELS {
        return Err(CalibrationError::TooFewKnown {
            take: rec.name.to_owned(),
            known: known.len(),
            labels: plan.markers,
            best: plan.declined.or(plan.set).map(|(s, n)| (s.name, n)),
        });
    }
    if ch.skeleton.is_empty() {
        return Err(CalibrationError::NoJoints);
    }
    let span = frame_span(rec, opts.span_s);
    let parts = Parts::new(&ch.skeleton, &unique, &oriented);
    let segments = scale::segment_scale(&plan.labels, rec.frames, span.clone(), stance.height);
    let (guesses, frames_in_view) = first_guesses_or_at(
        segments.map(|s| s.scale),
        (ch, &known),
        rec.frames,
        span.clone(),
        stance,
        &surface,
    );
    if guesses.is_empty() && frames_in_view == 0 {
        return Err(CalibrationError::NoFrames {
            take: rec.name.to_owned(),
        });
    }
    if guesses.is_empty() {
        return Err(CalibrationError::NoFirstGuess {
            take: rec.name.to_owned(),
            frames: frames_in_view,
        });
    }
    let problem = Problem {
        ch,
        roles,
        plan: &plan,
        rec,
        span,
        opts,
        params,
        stance,
        surface: &surface,
        parts: &parts,
    };
    // From each guess to the end (one for a standing character, one per kind of turn
    // for a hand). The guess with more labels on their skin in its rest-like frame wins
    // (fewer means that frame was not matched: a hand shrunk into the character's palm
    // fits its markers as well, with the fingers bent into them), then the lower
    // objective.
    let mut best: Option<(Calibration, (usize, f64))> = None;
    for guess in guesses {
        let on_skin = guess.on_skin.len();
        tracing::debug!(
            frame = guess.frame,
            scale = guess.scale,
            on_skin,
            known = known.len(),
            ?segments,
            "first guess"
        );
        let (cal, cost) = problem.solve_guess(guess, segments, &known)?;
        let better = |b: &(Calibration, (usize, f64))| {
            on_skin > b.1 .0 || (on_skin == b.1 .0 && cost < b.1 .1)
        };
        if best.as_ref().is_none_or(better) {
            best = Some((cal, (on_skin, cost)));
        }
    }
    best.map(|b| b.0).ok_or_else(|| CalibrationError::NoFrames {
        take: rec.name.to_owned(),
    })
}

/// `cal` with what its verdict needs of the character's body: its standing height and
/// parts when it stands on legs and has a head ([`body_parts`]), and the turns at rest
/// of its head joints alone.
fn with_the_body(
    cal: Calibration,
    ch: &Character,
    roles: &[Option<Role>],
    stance: Stance,
) -> Calibration {
    let has_head = roles.iter().flatten().any(|r| r.part == Part::Head);
    let standing = (stance.turn == Turn::Yaw && has_head).then_some(stance.height);
    let is_head = |name: &str| {
        ch.skeleton
            .joints
            .iter()
            .zip(roles)
            .any(|(j, r)| j.name == name && r.is_some_and(|r| r.part == Part::Head))
    };
    Calibration {
        rest_turns: cal
            .rest_turns
            .iter()
            .filter(|(name, _)| is_head(name))
            .cloned()
            .collect(),
        standing_height_m: standing,
        body_parts: if standing.is_some() {
            body_parts(ch, roles)
        } else {
            Vec::new()
        },
        ..cal
    }
}

/// A standing character's limbs (an upper arm or upper leg joint by its role, with every
/// joint below it), head (the head joint and below) and trunk (the lowest spine joint
/// and everything above it: a label on the chest, the head or an arm turns it), each
/// named by its side and part, with its joints.
fn body_parts(ch: &Character, roles: &[Option<Role>]) -> Vec<(String, Vec<usize>)> {
    use crate::character::roles::Side;
    let sk = &ch.skeleton;
    let mut out = Vec::new();
    for (j, role) in roles.iter().enumerate().take(sk.len()) {
        let Some(role) = role else { continue };
        let parent_role = sk.joints[j]
            .parent
            .and_then(|p| roles.get(p).copied().flatten());
        let what = match role.part {
            Part::UpperArm => "arm",
            Part::UpperLeg => "leg",
            Part::Head => "head",
            Part::Spine if parent_role.is_none_or(|r| r.part != Part::Spine) => "trunk",
            _ => continue,
        };
        let name = match role.side {
            Some(Side::Left) => format!("left {what}"),
            Some(Side::Right) => format!("right {what}"),
            None => what.to_owned(),
        };
        let inside = sk.subtree(j);
        out.push((name, (0..sk.len()).filter(|&k| inside[k]).collect()));
    }
    out
}

/// Each label a landmark table knows ([`landmarks::SETS`]) gets its template on the
/// character's skin (`surface`: its winding number, welded and wound outward).
fn put_templates(
    ch: &Character,
    roles: &[Option<Role>],
    stance: Stance,
    surface: &WindingNumber,
    plan: &mut labels::Plan,
) {
    let Some(t) = landmarks::Templates::new(
        &ch.skeleton,
        roles,
        &ch.vertices,
        &ch.triangles,
        stance.height,
        surface,
    ) else {
        return;
    };
    for l in &mut plan.labels {
        if matches!(l.source, Source::Table { set, .. } if landmarks::SETS.contains(&set)) {
            l.template = t.at(&l.label);
        }
    }
}

/// Moves the labels of `plan` that no table, map or layout places and that the take's
/// geometry shows are no markers on the actor ([`screen_by_geometry`]) to its left-out
/// labels.
fn exclude_by_geometry(plan: &mut labels::Plan, rec: Take, filter: &PointFilter) {
    let (known, unknown): (Vec<&LabelPlan>, Vec<&LabelPlan>) =
        plan.labels.iter().partition(|l| l.source != Source::Motion);
    let known: Vec<usize> = known.iter().map(|l| l.take_index).collect();
    let unknown: Vec<usize> = unknown.iter().map(|l| l.take_index).collect();
    let keep: Vec<bool> = rec.labels.iter().map(|l| filter.included(l)).collect();
    let out = screen_by_geometry(rec.frames, &known, &unknown, &keep, RIGID_SPREAD_M);
    plan.markers -= out.len().min(plan.markers);
    for (k, why) in out {
        plan.labels.retain(|l| l.take_index != k);
        plan.left_out
            .push((rec.labels[k].clone(), LeftOut::NotAMarker(why)));
    }
}

/// Everything a solve from one first guess needs.
struct Problem<'a> {
    ch: &'a Character,
    roles: &'a [Option<Role>],
    plan: &'a labels::Plan,
    rec: Take<'a>,
    span: std::ops::Range<usize>,
    opts: &'a CalibrationOptions,
    params: SolveParams,
    stance: Stance,
    surface: &'a WindingNumber,
    parts: &'a Parts<'a>,
}

impl Problem<'_> {
    /// The calibration from `guess`, with its objective, and again from the segment
    /// lengths' scale (`segments`) when that differs from the guess's by more than
    /// [`SEGMENTS_DIFFER`]: the fit stays in the valley its start is in. The lower
    /// objective wins, but the second start may not turn away a head the first left
    /// facing forward in the rest-like frame: a head's turn there is the one unknown
    /// the misfit cannot see (its labels' offsets turn back against it), only the
    /// priors judge it (the skin, and the mirror symmetry of labels whose set is
    /// known), and a person faces forward where they stand most like rest (on the
    /// Plug-in Gait static trial onto CesiumMan, without the symmetry, that start
    /// fitted 0.5 mm better with the head turned 82°, against 26°).
    fn solve_guess(
        &self,
        guess: FirstGuess,
        segments: Option<scale::SegmentScale>,
        known: &[&LabelPlan],
    ) -> Result<(Calibration, f64), CalibrationError> {
        let again = segments
            .filter(|s| (s.scale / guess.scale - 1.0).abs() > SEGMENTS_DIFFER)
            .map(|s| guess.rescaled(s.scale, self.rec.frames, known));
        let rest_frame = guess.scale;
        let finish = |(cal, cost): (Calibration, f64), from_segments: bool| {
            let cal = Calibration {
                scale_start: ScaleStart {
                    rest_frame,
                    segments,
                    from_segments,
                },
                ..with_the_body(cal, self.ch, self.roles, self.stance)
            };
            let forward = cal
                .rest_turns
                .iter()
                .all(|(_, deg)| *deg <= TURNED_AT_REST_DEG);
            (cal, cost, forward)
        };
        let (cal, cost, forward) = finish(self.solve_from(guess)?, false);
        let Some(again) = again else {
            return Ok((cal, cost));
        };
        // Over the whole span alone: the frames near rest are a second chance for a
        // start far off, and this start is itself one; and a second chance is not a
        // second way to fail.
        match self.solve_over(again, self.span.clone(), None) {
            Ok(done) => {
                let (other, other_cost, other_forward) = finish(done, true);
                tracing::debug!(
                    cost,
                    other_cost,
                    scale = other.scale,
                    other_forward,
                    "solved again from the segment lengths"
                );
                if other_cost < cost && (other_forward || !forward) {
                    return Ok((other, other_cost));
                }
            }
            Err(e) => tracing::debug!(error = %e, "the segment lengths' start found nothing"),
        }
        Ok((cal, cost))
    }

    /// The calibration from `guess`, with the solve's final objective: over the whole
    /// span. When that fits worse than a calibration can be good
    /// ([`DOUBTFUL_MISFIT_MM`]), a far pose may have led the fit astray (a CMU take's
    /// whole range from its rest-like frame stuck at 59 mm RMS; its first second alone
    /// fits at 6 mm): the frames within [`NEAR_REST_S`] of the rest-like frame are
    /// fitted first, where the poses differ least from rest, and the whole span again
    /// from there; the better of the two whole-span fits wins, unless both fit far worse
    /// than the frames near rest ([`WHOLE_SPAN_WORSE`], [`WHOLE_SPAN_SLACK_MM`]): then
    /// the layout near rest is kept, the whole span's misfit and flags said.
    fn solve_from(&self, guess: FirstGuess) -> Result<(Calibration, f64), CalibrationError> {
        let whole = self.solve_over(guess.clone(), self.span.clone(), None)?;
        let rate = self.rec.rate_hz;
        let reach = if rate.is_finite() && rate > 0.0 {
            (NEAR_REST_S * rate).round().min(self.span.len() as f64) as usize
        } else {
            self.span.len()
        };
        let near = guess.frame.saturating_sub(reach).max(self.span.start)
            ..(guess.frame + reach + 1).min(self.span.end);
        if whole.0.residual_mm_rms <= DOUBTFUL_MISFIT_MM || near.len() >= self.span.len() {
            return Ok(whole);
        }
        let (mut local, local_cost) = self.solve_over(guess.clone(), near, None)?;
        let seeded = self.solve_over(guess, self.span.clone(), Some(&local))?;
        tracing::debug!(
            whole_mm = whole.0.residual_mm_rms,
            near_mm = local.residual_mm_rms,
            seeded_mm = seeded.0.residual_mm_rms,
            "the whole span, near rest, and the whole span from there"
        );
        let best = if seeded.0.residual_mm_rms < whole.0.residual_mm_rms {
            seeded
        } else {
            whole
        };
        if best.0.residual_mm_rms <= WHOLE_SPAN_WORSE * local.residual_mm_rms + WHOLE_SPAN_SLACK_MM
        {
            return Ok(best);
        }
        // Poses the character's limits do not reach, or markers that slide, would bend
        // the offsets: the layout near rest is kept; what the whole span shows of each
        // label (a swap partway, a label that fits badly away from rest) is said.
        local.whole_span_mm = Some(best.0.residual_mm_rms);
        for p in local.placed.iter_mut().filter(|p| p.flag.is_none()) {
            p.flag = best
                .0
                .placed
                .iter()
                .find(|w| w.label == p.label)
                .and_then(|w| w.flag.clone());
        }
        Ok((local, local_cost))
    }

    /// The calibration over frames of `span` from `guess`, each label started where
    /// `seed` placed it when given (else where the rest-like frame puts it).
    fn solve_over(
        &self,
        guess: FirstGuess,
        span: std::ops::Range<usize>,
        seed: Option<&Calibration>,
    ) -> Result<(Calibration, f64), CalibrationError> {
        let (ch, plan, rec) = (self.ch, self.plan, self.rec);
        let used: Vec<usize> = plan.labels.iter().map(|l| l.take_index).collect();
        let chosen = choose_frames(
            rec.frames,
            &used,
            span,
            self.opts.frames.max(1),
            Some(guess.frame),
        );
        let frames: Vec<Vec<DVec3>> = chosen.iter().map(|&f| rec.frames[f].clone()).collect();
        let first = FirstGuess {
            frame: chosen.iter().position(|&f| f == guess.frame).unwrap_or(0),
            ..guess
        };
        let hold = (first.frame, held_joints(ch, &plan.labels, &first.on_skin));
        let fit = Fit {
            ch,
            height: self.stance.height,
            frames: &frames,
            surface: self.surface,
            parts: self.parts,
            params: self.params,
            hold,
            midline: midline_joints(ch, self.roles, self.stance.height),
        };
        // Every label where the seed placed it, or where the rest-like frame puts it, on
        // the nearest candidate bone.
        let seeded = |l: &LabelPlan| {
            let p = seed?.placed.iter().find(|p| p.label == l.label)?;
            Some(Placing {
                plan: l.clone(),
                joint: p.joint,
                offset: p.offset_m,
                guess: Some(ch.skeleton.joints[p.joint].rest + p.offset_m),
                template: fit.initial_placing(l, &first).template,
            })
        };
        let (mut placed, mut moving): (Vec<Placing>, Vec<Placing>) = plan
            .labels
            .iter()
            .map(|l| seeded(l).unwrap_or_else(|| fit.initial_placing(l, &first)))
            .partition(|p| p.plan.source != Source::Motion);
        let scale = seed.map_or(first.scale, |c| c.scale);
        let start = headings(ch, &placed, &frames, scale, self.stance);
        let mut solve = fit.problem(&placed, &start, scale, None);
        for _ in 0..3 {
            solve.alternate();
        }
        fit.choose_candidates(&solve, &mut placed);
        // Then the labels no one places, on the joint they move with; markers that keep
        // their distances ride one segment, so each such group goes where most of it
        // went.
        if !moving.is_empty() {
            fit.choose_candidates(&solve, &mut moving);
            fit.agree_within_rigid_groups(&solve, &mut moving);
            placed.extend(moving);
        }
        placed.sort_by_key(|p| p.plan.take_index);
        let mut solve = fit.problem(&placed, &start, solve.scale, Some(&solve));
        for _ in 0..2 {
            solve.alternate();
        }
        fit.choose_candidates(&solve, &mut placed);
        let mut solve = fit.problem(&placed, &start, solve.scale, Some(&solve));
        let report = solve.run();
        let (solve, report) =
            self.heads_turned_back(&fit, &placed, &start, (solve, report), first.frame);
        if !(solve.scale.is_finite() && solve.scale > 0.0) {
            return Err(CalibrationError::Degenerate {
                take: rec.name.to_owned(),
            });
        }
        let rest_frame = chosen.get(first.frame).copied().unwrap_or(0);
        let cal = finish(
            (ch, self.roles),
            &solve,
            &placed,
            plan.clone(),
            (chosen, rest_frame),
            report,
            self.opts,
        );
        Ok((cal, report.cost_end))
    }

    /// The fit again with each head whose turn only its own labels see, turned more than
    /// [`TURNED_AT_REST_DEG`] from rest in the rest-like frame (`rest`), turned back
    /// there, its labels' offsets turned with it: the labels fit every frame alike either
    /// way (the head's turn and its labels' offsets trade exactly), so the fit may settle
    /// on either; the one of lower objective is kept.
    fn heads_turned_back<'s>(
        &self,
        fit: &Fit<'s>,
        placed: &[Placing],
        start: &[(DQuat, DVec3)],
        (solve, report): (OffsetSolve<'s>, SolveReport),
        rest: usize,
    ) -> (OffsetSolve<'s>, SolveReport) {
        let joints: Vec<usize> = placed.iter().map(|p| p.joint).collect();
        let turned: Vec<(usize, DQuat)> = gauge_turns(&self.ch.skeleton, &joints, &solve, rest)
            .into_iter()
            .filter(|&(j, q)| {
                self.roles
                    .get(j)
                    .copied()
                    .flatten()
                    .is_some_and(|r| r.part == Part::Head)
                    && q.angle_between(DQuat::IDENTITY).to_degrees() > TURNED_AT_REST_DEG
            })
            .collect();
        if turned.is_empty() {
            return (solve, report);
        }
        let back: Vec<Placing> = placed
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let offset = solve.model.marker_offset[k];
                let turn = turned.iter().find(|t| t.0 == p.joint).map(|t| t.1);
                Placing {
                    offset: turn.map_or(offset, |q| q * offset),
                    ..p.clone()
                }
            })
            .collect();
        let mut other = fit.problem(&back, start, solve.scale, Some(&solve));
        let other_report = other.run();
        let rms = |s: &OffsetSolve| {
            let r = s.residuals();
            (r.iter().map(|x| x.0 * x.0).sum::<f64>() / r.len().max(1) as f64).sqrt() * 1e3
        };
        tracing::debug!(
            cost = report.cost_end,
            turned_back = other_report.cost_end,
            rms = rms(&solve),
            rms_back = rms(&other),
            "heads turned back"
        );
        if other_report.cost_end < report.cost_end {
            (other, other_report)
        } else {
            (solve, report)
        }
    }
}

/// Reasons [`CalibrationError::NoMarkers`] lists one by one.
const NO_MARKERS_REASONS: usize = 6;

/// The error of a take none of whose points can be a marker (a label given to every
/// point, every column empty, every label excluded): each reason with how many labels
/// it left out and the first of them.
fn no_markers(rec: Take, left_out: &[(String, LeftOut)]) -> CalibrationError {
    let mut why: Vec<(String, usize, String)> = Vec::new();
    for (label, reason) in left_out {
        let reason = reason.to_string();
        match why.iter_mut().find(|w| w.0 == reason) {
            Some(w) => w.1 += 1,
            None => why.push((reason, 1, label.clone())),
        }
    }
    // Reasons with figures in them (distances) may each differ: the first few and a
    // count of the rest.
    if why.len() > NO_MARKERS_REASONS {
        let rest: usize = why[NO_MARKERS_REASONS..].iter().map(|w| w.1).sum();
        let first = why[NO_MARKERS_REASONS].2.clone();
        why.truncate(NO_MARKERS_REASONS);
        why.push(("other reasons".into(), rest, first));
    }
    CalibrationError::NoMarkers {
        take: rec.name.to_owned(),
        points: rec.labels.len(),
        why,
    }
}

/// The frame indices of `span_s` (seconds from the take's start), or all.
fn frame_span(rec: Take, span_s: Option<(f64, f64)>) -> std::ops::Range<usize> {
    match span_s {
        Some((a, b)) => {
            let f = |s: f64| ((s * rec.rate_hz).round().max(0.0) as usize).min(rec.frames.len());
            f(a)..f(b).max(f(a))
        }
        None => 0..rec.frames.len(),
    }
}

/// How the character meets its take: its size and the turns that align it.
#[derive(Clone, Copy, Debug)]
struct Stance {
    /// The rest mesh's vertical extent when it stands, its largest extent when not,
    /// metres: the length tolerances of the first guess are fractions of it.
    height: f64,
    turn: Turn,
}

/// A character with legs stands in its take as at rest (upright, turned about Y); any
/// other (a hand) may be held any way.
fn stance_of(ch: &Character, roles: &[Option<Role>]) -> Stance {
    use crate::character::roles::Part;
    let (lo, hi) = crate::geom::shapes::bounds(&ch.vertices);
    let stands = roles
        .iter()
        .flatten()
        .any(|r| matches!(r.part, Part::UpperLeg | Part::LowerLeg | Part::Foot));
    let extent = hi - lo;
    let (height, turn) = if stands {
        (extent.y, Turn::Yaw)
    } else {
        (extent.max_element(), Turn::Any)
    };
    Stance {
        height: height.max(1e-3),
        turn,
    }
}

/// A point on joint `j`'s segments standing for a marker it carries before the fit: the
/// middle of its bone when it has one child, else the joint.
fn anchor(ch: &Character, j: usize) -> DVec3 {
    let sk = &ch.skeleton;
    let kids: Vec<usize> = sk.children(j).collect();
    match kids.as_slice() {
        [c] => 0.5 * (sk.joints[j].rest + sk.joints[*c].rest),
        _ => sk.joints[j].rest,
    }
}

/// The first guess: the frame whose similarity fit to the known labels' anchors is best
/// (the actor nearest the character's rest pose), its heading and scale.
#[derive(Clone)]
struct FirstGuess {
    /// Index into the frames used.
    frame: usize,
    heading: Heading,
    scale: f64,
    /// The take's labels that lie on their bone's skin there.
    on_skin: Vec<usize>,
}

impl FirstGuess {
    /// This guess at scale `scale`: its heading's translation moved so that the
    /// centroid of the known labels seen in its frame lands where it did.
    fn rescaled(&self, scale: f64, frames: &[Vec<DVec3>], known: &[&LabelPlan]) -> Self {
        let seen: Vec<DVec3> = known
            .iter()
            .filter_map(|l| frames.get(self.frame)?.get(l.take_index).copied())
            .filter(|m| m.is_finite())
            .collect();
        let centroid = seen.iter().sum::<DVec3>() / seen.len().max(1) as f64;
        Self {
            heading: Heading {
                q: self.heading.q,
                t: self.heading.t + (scale - self.scale) * centroid,
            },
            scale,
            ..self.clone()
        }
    }
}

/// The body's left at rest and, per joint, whether it lies on the midline: a hips,
/// spine, neck or head joint within [`MIDLINE_SHARE`] of `height` (the character's,
/// metres) from the sagittal plane through the hips. `None` without the upper legs' sides.
fn midline_joints(
    ch: &Character,
    roles: &[Option<Role>],
    height: f64,
) -> Option<(DVec3, Vec<bool>)> {
    let sk = &ch.skeleton;
    let (_, _, left) = landmarks::body_axes(sk, roles)?;
    let hips = sk.joints[*marker_sets::candidate_joints(
        Role {
            part: Part::Hips,
            side: None,
        },
        roles,
    )
    .first()?]
    .rest;
    let midline = (0..sk.len())
        .map(|j| {
            let trunk = roles.get(j).copied().flatten().is_some_and(|r| {
                r.side.is_none()
                    && matches!(r.part, Part::Hips | Part::Spine | Part::Neck | Part::Head)
            });
            trunk && (sk.joints[j].rest - hips).dot(left).abs() <= MIDLINE_SHARE * height
        })
        .collect();
    Some((left, midline))
}

/// How far from the midline a label's template, or a joint, may lie and count as on
/// it, as a share of the height (1.75 cm at a person's size; Plug-in Gait's head and
/// pelvis pairs sit 4 to 12 cm out).
const MIDLINE_SHARE: f64 = 0.01;

/// How far a template may lie from the mirror image of its partner's, as a share of
/// the height (3.5 cm at a person's size).
const PARTNER_SHARE: f64 = 0.02;

/// The mirror terms of `placed` ([`solve::Mirror`]): on each midline joint, each label
/// whose template lies left of the joint by more than [`MIDLINE_SHARE`] paired with the
/// label whose template lies nearest its mirror image (within [`PARTNER_SHARE`]).
/// Labels without a template (placed by motion), those the set puts on one side only
/// (Plug-in Gait's RBAK) and those it puts on the midline (C7, STRN) get none: a
/// midline label is found by touch a centimetre or two to one side, and the chest's
/// four held to the midline turned the truth bench's chests 3 to 7° further off.
fn mirror_terms(
    sk: &crate::character::skeleton::Skeleton,
    placed: &[Placing],
    left: DVec3,
    midline: &[bool],
    height: f64,
) -> Vec<solve::Mirror> {
    let lateral = |p: &Placing, t: DVec3| (t - sk.joints[p.joint].rest).dot(left);
    let mut terms = Vec::new();
    for (a, pa) in placed.iter().enumerate() {
        let Some(ta) = pa.plan.template else { continue };
        if !midline.get(pa.joint).copied().unwrap_or(false) {
            continue;
        }
        let side = lateral(pa, ta);
        if side <= MIDLINE_SHARE * height {
            continue;
        }
        let image = ta - 2.0 * side * left;
        let partner = placed
            .iter()
            .enumerate()
            .filter(|(b, pb)| *b != a && pb.joint == pa.joint)
            .filter_map(|(b, pb)| Some((b, (pb.plan.template? - image).length())))
            .min_by(|x, y| x.1.total_cmp(&y.1));
        if let Some((b, _)) = partner.filter(|p| p.1 <= PARTNER_SHARE * height) {
            terms.push(solve::Mirror { a, b });
        }
    }
    terms
}

/// The joints a rest-like frame holds near rest: those that carry a label lying on its
/// skin there (any of its candidates), and their ancestors.
fn held_joints(ch: &Character, labels: &[LabelPlan], on_skin: &[usize]) -> Vec<bool> {
    let sk = &ch.skeleton;
    let mut held = vec![false; sk.len()];
    for l in labels.iter().filter(|l| on_skin.contains(&l.take_index)) {
        for &c in &l.candidates {
            let mut j = Some(c);
            while let Some(jj) = j {
                held[jj] = true;
                j = sk.joints[jj].parent;
            }
        }
    }
    held
}

/// Known labels' anchors and measured positions in `frame`.
fn anchor_pairs(ch: &Character, known: &[&LabelPlan], frame: &[DVec3]) -> Vec<(DVec3, DVec3)> {
    known
        .iter()
        .filter(|l| frame[l.take_index].is_finite())
        .map(|l| {
            let a = l.rest.unwrap_or_else(|| anchor(ch, l.candidates[0]));
            (a, frame[l.take_index])
        })
        .collect()
}

/// How far the segment lengths' scale ([`scale::segment_scale`]) must lie from a first
/// guess's for the fit to run again from it, as a share: within 3 % the two starts
/// fall in one valley (the soldier's T-pose: 1.0003 and 1.0070 both end at 0.9990).
const SEGMENTS_DIFFER: f64 = 0.03;

/// What the first guess charges for all labels off their skin, as misfit in metres.
const OFF_SKIN_COST_M: f64 = 0.02;

/// How far the fit onto the skin may take a frame's scale from the ratio of the
/// spreads of the markers and of their bones' anchors (a factor either way): the
/// markers lie outside the body, the anchors inside, and a pose folds some of them
/// (tens of per cent); a frame whose fit runs farther has collapsed onto one spot of the
/// skin, where every marker pairs with one point at no cost (a CMU take onto the body
/// went to a scale of 5e-6 so).
const ICP_SCALE_BAND: f64 = 3.0;

/// RMS distance of `points` from their centroid.
fn rms_spread(points: &[DVec3]) -> f64 {
    let n = points.len().max(1) as f64;
    let c = points.iter().sum::<DVec3>() / n;
    (points
        .iter()
        .map(|p| (*p - c).length_squared())
        .sum::<f64>()
        / n)
        .sqrt()
}

/// Frames of the span the first guess compares (evenly spaced).
const GUESS_CANDIDATES: usize = 60;
/// Of those, how many (the best after a few rounds) are refined to the end.
const GUESS_REFINED: usize = 3;

/// See [`FirstGuess`] (`frame` is a take frame index here): one per kind of turn
/// ([`Turn::Yaw`] for a standing character; for one held any way, by turns about Y and
/// by any rotation: a hand's markers lie near a plane, the back of the hand, and with
/// its fingers bent a tilted or mirrored hand at another scale fits them about as well,
/// while a take in the character's own frame is fitted best by turns about Y alone);
/// none when no frame of `span` has [`MIN_KNOWN_LABELS`] known labels; with the count
/// of candidate frames that have them. Each candidate frame is fitted to the anchors, then to the skin (an iterative closest
/// point with each label kept near its bone, which removes the anchors' bias: they lie
/// inside the body, the markers outside, and the scale would come out small); the best
/// few are refined further and the best of those wins. `fixed_scale`, when given, is
/// every frame's scale ([`scale::segment_scale`]'s, where no frame fits at its own).
fn first_guesses(
    ch: &Character,
    known: &[&LabelPlan],
    frames: &[Vec<DVec3>],
    span: std::ops::Range<usize>,
    stance: Stance,
    surface: &WindingNumber,
    fixed_scale: Option<f64>,
) -> (Vec<FirstGuess>, usize) {
    let height = stance.height;
    let mut in_view = 0;
    let step = span.len().div_ceil(GUESS_CANDIDATES).max(1);
    let seeds: &[Turn] = match stance.turn {
        Turn::Yaw => &[Turn::Yaw],
        Turn::Any => &[Turn::Yaw, Turn::Any],
    };
    let mut guesses = Vec::new();
    for &seed in seeds {
        let stance = Stance {
            turn: seed,
            ..stance
        };
        let mut ranked: Vec<(usize, Heading, f64, f64)> = Vec::new();
        for f in span.clone().step_by(step) {
            let p = anchor_pairs(ch, known, &frames[f]);
            if p.len() < MIN_KNOWN_LABELS {
                continue;
            }
            if seed == seeds[0] {
                in_view += 1;
            }
            let Some((heading, scale, _)) = fit_heading(&p, fixed_scale, 0.1 * height, seed) else {
                continue;
            };
            if let Some((h, s, r, _)) = refine_on_skin(
                ch,
                known,
                &frames[f],
                (heading, scale, fixed_scale.is_some()),
                30,
                stance,
                surface,
            ) {
                ranked.push((f, h, s, r));
            }
        }
        ranked.sort_by(|a, b| a.3.total_cmp(&b.3));
        let best = ranked
            .into_iter()
            .take(GUESS_REFINED)
            .filter_map(|(f, heading, scale, _)| {
                refine_on_skin(
                    ch,
                    known,
                    &frames[f],
                    (heading, scale, fixed_scale.is_some()),
                    60,
                    stance,
                    surface,
                )
                .map(|(h, s, r, on)| (f, h, s, r, on))
            })
            .min_by(|a, b| a.3.total_cmp(&b.3));
        if let Some((frame, heading, scale, _, on_skin)) = best {
            guesses.push(FirstGuess {
                frame,
                heading,
                scale,
                on_skin,
            });
        }
    }
    (guesses, in_view)
}

/// [`first_guesses`], and where no frame fits onto the skin at a scale of its own (a
/// character whose limbs are one joint each: the anchors stand far from where its
/// markers go), again with every frame at `scale` (the segment lengths'), when given.
fn first_guesses_or_at(
    scale: Option<f64>,
    (ch, known): (&Character, &[&LabelPlan]),
    frames: &[Vec<DVec3>],
    span: std::ops::Range<usize>,
    stance: Stance,
    surface: &WindingNumber,
) -> (Vec<FirstGuess>, usize) {
    let found = first_guesses(ch, known, frames, span.clone(), stance, surface, None);
    match scale {
        Some(s) if found.0.is_empty() => {
            first_guesses(ch, known, frames, span, stance, surface, Some(s))
        }
        _ => found,
    }
}

/// Iterative closest point of one frame's known labels onto the skin, from a heading and
/// scale: each marker, taken into the character's rest frame, is paired with the point
/// 8 mm outside the skin nearest to it when that skin is its bone's, and the similarity
/// is fitted again (on those pairs alone once they are half the labels); the scale is
/// held where it starts when the third of the start's triple says so. Returns the
/// heading, scale and relative RMS misfit (per metre of height, plus 1 % for all labels off their skin or
/// out of view, in proportion) after `rounds` rounds at most (fewer when the scale
/// settles).
fn refine_on_skin(
    ch: &Character,
    known: &[&LabelPlan],
    frame: &[DVec3],
    (mut heading, mut scale, scale_fixed): (Heading, f64, bool),
    rounds: usize,
    stance: Stance,
    surface: &WindingNumber,
) -> Option<(Heading, f64, f64, Vec<usize>)> {
    let height = stance.height;
    let sk = &ch.skeleton;
    let mut rms = f64::INFINITY;
    let mut on_skin = Vec::new();
    // The character's size the frame's markers span at scale 1: the spread of their
    // bones' anchors over the spread of the markers.
    let (anchors, seen): (Vec<DVec3>, Vec<DVec3>) = known
        .iter()
        .filter(|l| frame[l.take_index].is_finite())
        .map(|l| (anchor(ch, l.candidates[0]), frame[l.take_index]))
        .unzip();
    let size_ratio = rms_spread(&anchors) / rms_spread(&seen);
    let band = (size_ratio / ICP_SCALE_BAND)..=(size_ratio * ICP_SCALE_BAND);
    // How far from the skin a marker may lie and still pair with it: loose while the
    // guess is rough, then what a marker on the skin can be (its centre within 3 cm).
    let mut reach = 0.1 * height;
    for _ in 0..rounds {
        let (mut good, mut rough) = (Vec::new(), Vec::new());
        on_skin.clear();
        for l in known.iter().filter(|l| frame[l.take_index].is_finite()) {
            let m = frame[l.take_index];
            let x = heading.q.inverse() * (m * scale - heading.t);
            match (l.rest, surface.signed_closest(x)) {
                (Some(r), _) => {
                    good.push((r, m));
                    on_skin.push(l.take_index);
                }
                (None, Some((c, d, out)))
                    if d.abs() < reach && on_candidate(sk, c, &l.candidates).is_some() =>
                {
                    good.push((c + out * 0.008, m));
                    on_skin.push(l.take_index);
                }
                // Nearest the skin of another bone: that part of the actor is posed
                // otherwise, or the guess is still rough; its bone's anchor stands in
                // until half the labels find their skin.
                _ => rough.push((anchor(ch, l.candidates[0]), m)),
            }
        }
        let n = good.len() + rough.len();
        let pairs = if good.len() >= MIN_KNOWN_LABELS && 2 * good.len() >= n {
            good.clone()
        } else {
            good.iter().chain(&rough).copied().collect()
        };
        let (h, s, r) = fit_heading(
            &pairs,
            scale_fixed.then_some(scale),
            0.05 * height,
            stance.turn,
        )?;
        if !scale_fixed && !band.contains(&s) {
            // Collapsed: markers shrunk onto one spot of the skin pair with it and
            // fit there at no cost. This frame gives no guess.
            return None;
        }
        let settled = (s - scale).abs() < 1e-5 * scale && reach <= 0.03;
        reach = (reach * 0.85).max(0.03);
        // Labels off their skin or out of view count against the frame: all of them as
        // much as a misfit of 2 cm (the farthest a marker sits off its skin; 1 % of a
        // body's height, a tenth of a hand's).
        let off = 1.0 - good.len() as f64 / known.len().max(1) as f64;
        (heading, scale, rms) = (h, s, (r * s + OFF_SKIN_COST_M * off) / height);
        if settled {
            break;
        }
    }
    Some((heading, scale, rms, on_skin))
}

/// Each frame's heading at scale `scale`, from the placed labels' rest positions.
fn headings(
    ch: &Character,
    placed: &[Placing],
    frames: &[Vec<DVec3>],
    scale: f64,
    stance: Stance,
) -> Vec<(DQuat, DVec3)> {
    frames
        .iter()
        .map(|frame| {
            let pairs: Vec<(DVec3, DVec3)> = placed
                .iter()
                .filter(|p| frame[p.plan.take_index].is_finite())
                .map(|p| {
                    (
                        ch.skeleton.joints[p.joint].rest + p.offset,
                        frame[p.plan.take_index],
                    )
                })
                .collect();
            fit_heading(&pairs, Some(scale), 0.1 * stance.height, stance.turn)
                .map_or((DQuat::IDENTITY, DVec3::ZERO), |(h, _, _)| (h.q, h.t))
        })
        .collect()
}

/// How far, as a share of the character's height, a label seen on its bone's skin in the
/// rest-like frame may lie from its template ([`landmarks`]) and still be placed where it
/// was seen: 5 cm on a 1.75 m actor, the most a marker put on by touch strays from where
/// its manual says (a turn of 20° about a limb and a slide of a few per cent along it).
const TEMPLATE_AGREES: f64 = 0.05 / 1.75;

/// A label on its current joint with its current offset.
#[derive(Clone, Debug)]
struct Placing {
    plan: LabelPlan,
    joint: usize,
    offset: DVec3,
    /// Its rest position by the rest-like frame (or the layout), when it was seen there
    /// near a candidate bone, or by its template.
    guess: Option<DVec3>,
    /// Its template when no frame placed it: the fit holds it loosely near there (a
    /// label the rest-like frame shows on its skin is held by that frame).
    template: Option<DVec3>,
}

/// What every stage of the fit shares.
struct Fit<'a> {
    ch: &'a Character,
    height: f64,
    frames: &'a [Vec<DVec3>],
    surface: &'a WindingNumber,
    /// The skin's parts.
    parts: &'a Parts<'a>,
    params: SolveParams,
    /// The rest-like frame (index into `frames`) and the joints it holds near rest.
    hold: (usize, Vec<bool>),
    /// The sagittal plane's normal (the body's left at rest) and the joints on the
    /// midline whose labels are held to their mirror symmetry, when the skeleton says
    /// where its sides are.
    midline: Option<(DVec3, Vec<bool>)>,
}

impl<'a> Fit<'a> {
    /// A label's first placing: its rest position by the layout, or by the rest-like
    /// frame when it lies on the skin of a candidate's bone, else by its template, else
    /// the first candidate's anchor.
    fn initial_placing(&self, l: &LabelPlan, first: &FirstGuess) -> Placing {
        let sk = &self.ch.skeleton;
        let m = self.frames[first.frame][l.take_index];
        let seen = m
            .is_finite()
            .then(|| first.heading.q.inverse() * (m * first.scale - first.heading.t));
        let near = match (l.rest, seen) {
            // The layout's word: on the nearest candidate.
            (Some(x), _) => l
                .candidates
                .iter()
                .map(|&j| (j, bone_distance(sk, j, x)))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(j, _)| (j, x)),
            // Seen on the skin of a candidate (a marker's centre lies a few millimetres
            // to two centimetres out): that candidate.
            (None, Some(x)) => self.surface.signed_closest(x).and_then(|(c, d, _)| {
                let on_skin = (-0.005..0.03).contains(&d);
                on_skin
                    .then(|| on_candidate(sk, c, &l.candidates))
                    .flatten()
                    .map(|j| (j, x))
            }),
            (None, None) => None,
        };
        // Not seen on its skin: where its marker set's manual puts it, on the nearest
        // candidate.
        // Seen on its bone's skin far from where its marker set puts it: that part of
        // the actor is posed otherwise than at rest there (an arm turned, a label seen
        // on the other side of the limb), and the template is the better start.
        let near = near.filter(|(_, x)| {
            l.template
                .is_none_or(|t| (*x - t).length() <= TEMPLATE_AGREES * self.height)
        });
        let template = near.is_none().then_some(l.template).flatten();
        let near = near.or_else(|| {
            let t = template?;
            l.candidates
                .iter()
                .map(|&j| (j, bone_distance(sk, j, t)))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(j, _)| (j, t))
        });
        match near {
            Some((j, x)) => Placing {
                plan: l.clone(),
                joint: j,
                offset: x - sk.joints[j].rest,
                guess: Some(x),
                template,
            },
            None => {
                let j = l.candidates[0];
                Placing {
                    plan: l.clone(),
                    joint: j,
                    offset: anchor(self.ch, j) - sk.joints[j].rest,
                    guess: None,
                    template: None,
                }
            }
        }
    }

    /// The offset problem of `placed` over the frames, started from `start` headings or
    /// from the postures of `from`, with its postures fitted.
    fn problem(
        &self,
        placed: &[Placing],
        start: &[(DQuat, DVec3)],
        scale: f64,
        from: Option<&OffsetSolve>,
    ) -> OffsetSolve<'a> {
        let sk = &self.ch.skeleton;
        let twist: Vec<DVec3> = (0..sk.len()).map(|j| sk.twist_axis(j)).collect();
        let joints: Vec<usize> = placed.iter().map(|p| p.joint).collect();
        let rest: Vec<DVec3> = placed
            .iter()
            .map(|p| sk.joints[p.joint].rest + p.offset)
            .collect();
        let model = IkModel::new(sk, &twist, &joints, &rest, self.height);
        let frames: Vec<Vec<DVec3>> = self
            .frames
            .iter()
            .map(|f| placed.iter().map(|p| f[p.plan.take_index]).collect())
            .collect();
        let skin = Skin {
            surface: self.surface,
            parts: self.parts,
        };
        let mut solve = OffsetSolve::new(model, frames, start, scale, skin, self.params);
        if let Some(from) = from {
            for (to, st) in solve.states.iter_mut().zip(&from.states) {
                solve.model.copy_posture(to, st);
            }
        }
        solve.hold_rest(self.hold.0, &self.hold.1);
        solve.hold_templates(placed.iter().map(|p| p.template).collect());
        if let Some((left, midline)) = &self.midline {
            solve.hold_mirrors(*left, mirror_terms(sk, placed, *left, midline, self.height));
        }
        solve.fit_postures();
        solve
    }

    /// Moves each label of `placed` with several candidates to the one whose segments
    /// it moves with most rigidly over `solve`'s fitted frames, with its mean position
    /// there as its offset.
    fn choose_candidates(&self, solve: &OffsetSolve, placed: &mut [Placing]) {
        let sk = &self.ch.skeleton;
        for p in placed.iter_mut() {
            if p.plan.candidates.len() < 2 {
                continue;
            }
            let samples: Vec<DVec3> = self.frames.iter().map(|f| f[p.plan.take_index]).collect();
            let guess = p.guess;
            let score = |j: usize| -> Option<(f64, DVec3)> {
                let (mean, spread) = solve.mean_in_joint_frame(&samples, j)?;
                // Far from the bone is unlikely: a marker sits on the skin over it; and
                // so is far from where the rest-like frame saw it.
                let bone = bone_distance(sk, j, sk.joints[j].rest + mean);
                let seen = guess.map_or(0.0, |x| bone_distance(sk, j, x));
                Some((spread + 0.25 * bone + 0.5 * seen, mean))
            };
            let best = p
                .plan
                .candidates
                .iter()
                .filter_map(|&j| score(j).map(|(s, m)| (j, s, m)))
                .min_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((j, _, mean)) = best {
                p.joint = j;
                p.offset = mean;
            }
        }
    }
}

/// How much two markers on one segment may change their distance (RMS over the frames
/// used), metres: noise and skin sliding; two segments' markers change theirs by
/// centimetres as soon as the joint between them moves.
pub const RIGID_SPREAD_M: f64 = 0.003;

/// The candidate of `candidates` whose skin point `c` is: the joint whose bones pass
/// nearest to it, or the candidate next to it in the tree (a point at a joint's crease
/// may lie nearer the bone on the other side).
fn on_candidate(
    sk: &crate::character::skeleton::Skeleton,
    c: DVec3,
    candidates: &[usize],
) -> Option<usize> {
    let owner = (0..sk.len())
        .filter(|&j| sk.children(j).next().is_some())
        .min_by(|&a, &b| bone_distance(sk, a, c).total_cmp(&bone_distance(sk, b, c)))?;
    candidates
        .iter()
        .copied()
        .find(|&j| j == owner)
        .or_else(|| {
            candidates
                .iter()
                .copied()
                .find(|&j| sk.joints[j].parent == Some(owner) || sk.joints[owner].parent == Some(j))
        })
}

impl Fit<'_> {
    /// Moves every label of a rigid group ([`points::rigid_groups`]) to the joint most of the
    /// group chose (on a tie, the one voted for last), with its mean position there as
    /// offset.
    fn agree_within_rigid_groups(&self, solve: &OffsetSolve, placed: &mut [Placing]) {
        let labels: Vec<usize> = placed.iter().map(|p| p.plan.take_index).collect();
        let groups = points::rigid_groups(self.frames, &labels, RIGID_SPREAD_M);
        for g in 0..placed.len() {
            let members: Vec<usize> = (0..placed.len()).filter(|&i| groups[i] == g).collect();
            if members.len() < 2 {
                continue;
            }
            let mut votes: Vec<(usize, usize)> = Vec::new();
            for &i in &members {
                match votes.iter_mut().find(|v| v.0 == placed[i].joint) {
                    Some(v) => v.1 += 1,
                    None => votes.push((placed[i].joint, 1)),
                }
            }
            let Some(&(joint, _)) = votes.iter().max_by_key(|v| v.1) else {
                continue;
            };
            for &i in &members {
                let samples: Vec<DVec3> = self
                    .frames
                    .iter()
                    .map(|f| f[placed[i].plan.take_index])
                    .collect();
                if let Some((mean, _)) = solve.mean_in_joint_frame(&samples, joint) {
                    placed[i].joint = joint;
                    placed[i].offset = mean;
                }
            }
        }
    }
}

/// Distance from `x` to joint `j`'s bones (the segments to its children; the joint
/// itself for a leaf), at rest.
fn bone_distance(sk: &crate::character::skeleton::Skeleton, j: usize, x: DVec3) -> f64 {
    let a = sk.joints[j].rest;
    sk.children(j)
        .map(|c| {
            let b = sk.joints[c].rest;
            let ab = b - a;
            let t = ((x - a).dot(ab) / ab.length_squared().max(1e-18)).clamp(0.0, 1.0);
            (x - (a + ab * t)).length()
        })
        .fold((x - a).length(), f64::min)
}

/// The result of a finished solve, with each label's misfit and flags.
fn finish(
    (ch, roles): (&Character, &[Option<Role>]),
    solve: &OffsetSolve,
    placed: &[Placing],
    plan: labels::Plan,
    (frames, rest_frame): (Vec<usize>, usize),
    report: SolveReport,
    opts: &CalibrationOptions,
) -> Calibration {
    let on_skin = opts.markers_on_skin;
    let state = frames.iter().position(|&f| f == rest_frame).unwrap_or(0);
    let joints: Vec<usize> = placed.iter().map(|p| p.joint).collect();
    let rest_turns = rest_turns(ch, &joints, solve, state);
    let mut left_out = plan.left_out;
    let residuals = solve.residuals();
    let mut rms: Vec<f64> = residuals.iter().map(|r| r.0).collect();
    rms.sort_by(f64::total_cmp);
    let median = rms.get(rms.len() / 2).copied().unwrap_or(0.0).max(1e-4);
    let (mut sum, mut n, mut max) = (0.0, 0usize, 0.0f64);
    let mut out = Vec::with_capacity(placed.len());
    for (k, p) in placed.iter().enumerate() {
        let (r_rms, r_max, count) = residuals[k];
        let offset = solve.model.marker_offset[k];
        let x = ch.skeleton.joints[p.joint].rest + offset;
        let skin = solve.surface_distance(x).unwrap_or(f64::NAN);
        if skin > opts.max_marker_distance_m {
            left_out.push((
                p.plan.label.clone(),
                LeftOut::TooFarOff {
                    distance_mm: skin * 1e3,
                    limit_mm: opts.max_marker_distance_m * 1e3,
                },
            ));
            continue;
        }
        sum += r_rms * r_rms * count as f64;
        n += count;
        max = max.max(r_max);
        let frames_off = solve.frames_off(k, (4.0 * median).max(0.03));
        let flag = if r_rms > 3.0 * median && r_rms > 0.01 {
            Some(Flag::FitsBadly {
                times_median: r_rms / median,
            })
        } else if frames_off >= (count / 10).max(2) && frames_off * 2 < count {
            Some(Flag::Jumps { frames_off })
        } else if on_skin && skin.abs() > 2.0 * solve.params().skin_max_m {
            Some(Flag::OffSkin {
                distance_mm: skin * 1e3,
            })
        } else {
            None
        };
        out.push(PlacedLabel {
            label: p.plan.label.clone(),
            joint: p.joint,
            joint_name: ch.skeleton.joints[p.joint].name.clone(),
            offset_m: offset,
            skin_m: skin,
            source: p.plan.source.clone(),
            residual_mm_rms: r_rms * 1e3,
            residual_mm_max: r_max * 1e3,
            frames: count,
            flag,
            from_template_m: p.plan.template.map(|t| (x - t).length() / solve.scale),
        });
    }
    Calibration {
        scale: solve.scale,
        placed: out,
        left_out,
        marker_set: plan.set.map(|(s, n)| (s.name, n)),
        frames,
        residual_mm_rms: (sum / n.max(1) as f64).sqrt() * 1e3,
        residual_mm_max: max * 1e3,
        report,
        markers: plan.markers,
        declined_set: plan.declined.map(|(s, n)| (s.name, n)),
        rest_frame,
        // Said by `calibrate`, which knows the starts.
        scale_start: ScaleStart::default(),
        whole_span_mm: None,
        standing_height_m: None,
        body_parts: Vec::new(),
        // Joint centres (a BVH) are no heel or toe markers: their height above the
        // sole is the character's ankle's, not a person's marker's.
        floor: FloorCheck::from_frames(&solve.lowest_m(), |k, j| {
            on_skin
                && placed
                    .get(k)
                    .is_some_and(|p| on_its_foot(ch, roles, p.joint, j))
        }),
        rest_turns,
        strained: strained_joints(ch, roles, solve),
        bent_knees: bent_knees(ch, roles, solve),
    }
}

/// Whether joint `j` is a foot or toe joint and joint `o`'s part is on the same leg
/// below the knee: the shin (the nearest ancestor of `j` that is a lower leg, or `j`'s
/// parent without one; its part holds the heel where the bind divides the skin by
/// nearest bone) or any joint below it (the foot, the toes, their ends).
fn on_its_foot(ch: &Character, roles: &[Option<Role>], j: usize, o: usize) -> bool {
    let sk = &ch.skeleton;
    let part = |x: usize| roles.get(x).copied().flatten().map(|r| r.part);
    if !matches!(part(j), Some(Part::Foot | Part::Toes)) || j >= sk.len() || o >= sk.len() {
        return false;
    }
    let mut shin = sk.joints[j].parent.unwrap_or(j);
    let mut up = Some(j);
    while let Some(x) = up {
        if part(x) == Some(Part::LowerLeg) {
            shin = x;
            break;
        }
        up = sk.joints[x].parent;
    }
    let mut up = Some(o);
    while let Some(x) = up {
        if x == shin {
            return true;
        }
        up = sk.joints[x].parent;
    }
    false
}

/// Least bend, degrees, that every knee must keep in every frame used for the fit to be
/// called crouched: a walk straightens the knee to about 5° at heel strike and bends it
/// 15 to 20° in stance (Perry and Burnfield, "Gait Analysis", 2010), a person standing
/// holds it within 5°; a crouch held through a whole take is rare.
pub const BENT_KNEES_DEG: f64 = 30.0;

/// Each knee's least bend over `solve`'s fitted postures (the angle between the thigh,
/// from the bone above the knee, and the shin, to the knee's first child), degrees,
/// when every knee stays bent more than [`BENT_KNEES_DEG`] in every frame ([`Calibration::bent_knees`]);
/// empty otherwise, and with fewer than [`STRAINED_MIN_FRAMES`] frames.
fn bent_knees(ch: &Character, roles: &[Option<Role>], solve: &OffsetSolve) -> Vec<(String, f64)> {
    let sk = &ch.skeleton;
    if solve.states.len() < STRAINED_MIN_FRAMES {
        return Vec::new();
    }
    let knees = (0..sk.len()).filter_map(|j| {
        let knee = roles.get(j).copied().flatten()?.part == Part::LowerLeg;
        let (p, c) = (sk.joints[j].parent?, sk.children(j).next()?);
        knee.then_some((j, p, c))
    });
    let mut out = Vec::new();
    for (j, p, c) in knees {
        let least = solve
            .states
            .iter()
            .map(|st| {
                let thigh = st.world_pos[j] - st.world_pos[p];
                let shin = st.world_pos[c] - st.world_pos[j];
                thigh.angle_between(shin).to_degrees()
            })
            .fold(f64::INFINITY, f64::min);
        if least.is_nan() || least <= BENT_KNEES_DEG {
            return Vec::new();
        }
        out.push((sk.joints[j].name.clone(), least));
    }
    out
}

/// Least frames used for [`Calibration::strained`] to be judged: in fewer, a pose held
/// at a limit may be the actor's.
const STRAINED_MIN_FRAMES: usize = 4;
/// Least share of the frames used in which a joint must sit at a limit to be called
/// strained: a take that reaches (an arm raised through most of it) holds a clavicle at
/// its limit in three frames of four, and is right to.
const STRAINED_SHARE: f64 = 0.9;

/// The joints `solve`'s fitted postures hold at one of their limits in all but a tenth
/// of its frames ([`STRAINED_SHARE`]), with in how many, and the frames: an actor moves
/// through a take, and
/// a joint that stays at its limit is pushed there by labels placed where the actor's
/// are not (a leg's lateral labels on its inner side turn the hip to its twist limit).
/// Knees, elbows and finger joints are not judged: a standing leg or a relaxed finger is
/// straight, at the end of its bend, and a hinge's twist and sideways ranges are a few
/// degrees wide, touched whenever a pose bends it a little out of its plane.
fn strained_joints(
    ch: &Character,
    roles: &[Option<Role>],
    solve: &OffsetSolve,
) -> (Vec<(String, usize)>, usize) {
    use crate::rig::ik_model::Dofs;
    let (m, frames) = (&solve.model, solve.states.len());
    if frames < STRAINED_MIN_FRAMES {
        return (Vec::new(), frames);
    }
    let mut out = Vec::new();
    for (j, d) in m.dofs.iter().enumerate() {
        let Dofs::Angles { first } = *d else { continue };
        let hinge =
            roles.get(j).copied().flatten().is_some_and(|r| {
                matches!(r.part, Part::LowerLeg | Part::LowerArm | Part::Finger(..))
            });
        if hinge {
            continue;
        }
        let at_limit = |st: &crate::solve::ik::IkState| {
            (first..first + 3).any(|i| st.angles[i] <= m.lo[i] || st.angles[i] >= m.hi[i])
        };
        let n = solve.states.iter().filter(|st| at_limit(st)).count();
        if n as f64 >= STRAINED_SHARE * frames as f64 {
            out.push((ch.skeleton.joints[j].name.clone(), n));
        }
    }
    (out, frames)
}

/// Per joint whose turn only its own labels see ([`Calibration::rest_turns`]; the labels
/// ride `joints`), its name and its turn from rest in state `state` of `solve`, degrees.
fn rest_turns(
    ch: &Character,
    joints: &[usize],
    solve: &OffsetSolve,
    state: usize,
) -> Vec<(String, f64)> {
    gauge_turns(&ch.skeleton, joints, solve, state)
        .into_iter()
        .map(|(j, q)| {
            let deg = q.angle_between(DQuat::IDENTITY).to_degrees();
            (ch.skeleton.joints[j].name.clone(), deg)
        })
        .collect()
}

/// Per joint whose turn only its own labels see (it carries labels, nothing below it
/// does; the labels ride `joints`), its turn from rest in state `state` of `solve`
/// against the nearest ancestor that carries labels (rest axes: world rotations are the
/// identity at rest).
fn gauge_turns(
    sk: &crate::character::skeleton::Skeleton,
    joints: &[usize],
    solve: &OffsetSolve,
    state: usize,
) -> Vec<(usize, DQuat)> {
    let Some(st) = solve.states.get(state) else {
        return Vec::new();
    };
    let n = sk.len();
    let mut carries = vec![false; n];
    for &j in joints {
        carries[j] = true;
    }
    // Whether a joint or one below it carries labels (children after their parents).
    let mut below = carries.clone();
    for j in (0..n).rev() {
        if let Some(p) = sk.joints[j].parent.filter(|_| below[j]) {
            below[p] = true;
        }
    }
    let mut out = Vec::new();
    for j in (0..n).filter(|&j| carries[j] && sk.children(j).all(|c| !below[c])) {
        let mut up = sk.joints[j].parent;
        while let Some(p) = up.filter(|&p| !carries[p]) {
            up = sk.joints[p].parent;
        }
        let Some(anchor) = up else { continue };
        out.push((
            j,
            (st.world_rot[anchor].inverse() * st.world_rot[j]).normalize(),
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The medians of the frames that have both heights; a take whose lowest marker is
    /// no foot's on `y = 0` shows no floor, and nothing is judged against it.
    #[test]
    fn a_floor_check_takes_medians_and_judges_only_a_floor_the_take_shows() {
        let at = |skin_m: f64, marker_m: f64, marker: Option<usize>| Lowest {
            skin_m,
            skin_joint: Some(7),
            marker_m,
            marker,
        };
        let frames = [
            at(-0.05, 0.03, Some(0)),
            at(-0.04, 0.04, Some(1)),
            at(f64::NAN, 0.01, Some(0)),
            at(-0.06, f64::NAN, None),
            at(-0.20, 0.40, Some(2)),
        ];
        let on_foot = |k: usize, j: usize| k < 2 && j == 7;
        let f = FloorCheck::from_frames(&frames, on_foot).expect("three frames have both");
        assert_eq!(f.lowest_skin_m, -0.05);
        assert_eq!(f.lowest_marker_m, 0.04);
        assert!(f.floor_shown() && f.off_floor());
        // Two of the three frames with both have a foot's marker lowest, 8 cm above the
        // skin; the floor is shown, so the soles are judged against it alone.
        let above = f.foot_marker_above_skin_m.expect("two of three frames");
        assert!((above - 0.08).abs() < 1e-12, "{above}");
        assert_eq!(f.soles_off_m(), None);
        let near = FloorCheck {
            lowest_skin_m: -0.02,
            ..f
        };
        assert!(!near.off_floor());
        let high = FloorCheck {
            lowest_marker_m: 0.6,
            ..f
        };
        assert!(!high.floor_shown() && !high.off_floor());
        // No floor shown: a foot's marker 8 cm above the soles is within a shoe's 6 cm
        // and the 3 cm tolerance; 12 cm puts the soles at least 6 cm under the actor's;
        // 4 cm under them, the soles 4 cm over it.
        assert_eq!(high.soles_off_m(), None);
        let sunk = FloorCheck {
            foot_marker_above_skin_m: Some(0.12),
            ..high
        };
        assert!((sunk.soles_off_m().expect("sunk") - 0.06).abs() < 1e-12);
        let floating = FloorCheck {
            foot_marker_above_skin_m: Some(-0.04),
            ..high
        };
        assert!((floating.soles_off_m().expect("floating") + 0.04).abs() < 1e-12);
        // Most frames' lowest marker on no foot: nothing said of the soles.
        let hands = FloorCheck::from_frames(&frames, |k, _| k == 1).expect("frames");
        assert_eq!(hands.foot_marker_above_skin_m, None);
        // A foot's marker lowest while the lowest skin point is elsewhere (lying down,
        // kneeling): that foot bears no weight, and nothing is said of the soles.
        let lying = FloorCheck::from_frames(&frames, |k, j| k < 2 && j == 3).expect("frames");
        assert_eq!(lying.foot_marker_above_skin_m, None);
        assert!(FloorCheck::from_frames(&[at(f64::NAN, 0.0, Some(0))], on_foot).is_none());
    }
}
