//! The scale between actor and character from segment lengths: for each pair of labels
//! that ride one bone and whose marker set puts them on this character
//! ([`super::landmarks`]), the distance of their templates on the character over the
//! distance of their markers in the take, the take's distance being a median over many
//! frames; the scale is the median of those ratios over every pair, each weighted by its
//! length.
//!
//! Why: the first guess ([`super::frames`]) fits one frame, the actor nearest the
//! character's rest pose, onto the skin; on a take with no T or A pose (a walk, a run,
//! an idle with the arms down) that frame is far from rest and its scale 10 to 30 %
//! off, and the offset solve, started there, stays in the valley it starts in (on the
//! truth bench the Mixamo soldier's idle at a person's size ended 1.5 % off from a
//! first guess 25 % off, and its objective was 37 % higher than from the truth). A
//! distance between two markers on one segment does not depend on the pose; many of
//! them, over many frames, give the scale whatever the actor does. The templates are
//! where a marker set's manual puts the markers, found by touch within 1 to 2 cm
//! (Della Croce et al. 2005), so a single pair's ratio is off by up to 20 % on a short
//! segment; the weighted median over 20 to 40 pairs held the truth bench's scale
//! within 1 % on the soldier and 3.8 to 5.3 % on the others.
//!
//! The estimate does not replace the first guess: the calibration solves from both when
//! they differ and keeps the lower objective ([`super::calibrate`]).

use super::labels::LabelPlan;
use glam::DVec3;

/// Shortest pair counted, as a share of the character's height: on a shorter one, the
/// templates' 1 to 2 cm weigh too much (a wrist's two markers lie 5 cm apart).
pub const MIN_PAIR_SHARE: f64 = 0.05;

/// Most a pair's distance in the take may vary, as its 10th to 90th percentile range over
/// its median: two markers on one segment keep their distance up to the skin's slide
/// over the bone (1 to 2 cm on a thigh, Leardini et al. 2005); two that a joint
/// separates (a spine's labels when their candidates are the whole chain) vary with it.
pub const MAX_PAIR_SPREAD: f64 = 0.1;

/// Fewest steady pairs for an estimate.
pub const MIN_PAIRS: usize = 3;

/// Frames of the span sampled, at most (evenly spaced).
const SAMPLED_FRAMES: usize = 300;

/// Fewest frames in which both markers of a pair are seen.
const MIN_FRAMES_SEEN: usize = 5;

/// The scale from segment lengths, and what it rests on.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SegmentScale {
    /// Character metres per take metre.
    pub scale: f64,
    /// Pairs of labels counted.
    pub pairs: usize,
    /// Frames sampled.
    pub frames: usize,
}

/// Where a calibration's scale fit started.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ScaleStart {
    /// The rest-like frame's fit onto the skin ([`super::frames`]), character metres per
    /// take metre.
    pub rest_frame: f64,
    /// The segment lengths' estimate, when there were enough pairs.
    pub segments: Option<SegmentScale>,
    /// Whether the fit kept started from the segment lengths' scale (it ran from both
    /// when they differed by more than 3 %, and the lower objective won).
    pub from_segments: bool,
}

/// See the module doc. `labels`: the plan's labels (a label counts when it has a
/// template and its first candidate joint is its pair's); `frames`: the take's frames
/// (take metres, non-finite where a marker is not seen), of which `span` is sampled;
/// `height_m`: the character's height, metres. `None` with fewer than [`MIN_PAIRS`]
/// steady pairs.
pub fn segment_scale(
    labels: &[LabelPlan],
    frames: &[Vec<DVec3>],
    span: std::ops::Range<usize>,
    height_m: f64,
) -> Option<SegmentScale> {
    let span = span.start.min(frames.len())..span.end.min(frames.len());
    let step = span.len().div_ceil(SAMPLED_FRAMES).max(1);
    let sampled: Vec<&Vec<DVec3>> = frames[span].iter().step_by(step).collect();
    // (ratio, weight): the template length weighs each pair.
    let mut ratios: Vec<(f64, f64)> = Vec::new();
    let mut distances = Vec::with_capacity(sampled.len());
    for (i, a) in labels.iter().enumerate() {
        for b in &labels[i + 1..] {
            let (Some(ta), Some(tb)) = (a.template, b.template) else {
                continue;
            };
            if a.candidates.is_empty() || a.candidates.first() != b.candidates.first() {
                continue;
            }
            let length_m = (ta - tb).length();
            // Also false for a NaN length.
            let long_enough = length_m >= MIN_PAIR_SHARE * height_m;
            if !long_enough {
                continue;
            }
            distances.clear();
            distances.extend(sampled.iter().filter_map(|f| {
                let (x, y) = (*f.get(a.take_index)?, *f.get(b.take_index)?);
                let d = (x - y).length();
                (d.is_finite() && d > 0.0).then_some(d)
            }));
            if distances.len() < MIN_FRAMES_SEEN {
                continue;
            }
            distances.sort_by(f64::total_cmp);
            let at = |q: f64| distances[((distances.len() - 1) as f64 * q).round() as usize];
            let median = at(0.5);
            if (at(0.9) - at(0.1)) / median > MAX_PAIR_SPREAD {
                continue;
            }
            ratios.push((length_m / median, length_m));
        }
    }
    if ratios.len() < MIN_PAIRS {
        return None;
    }
    ratios.sort_by(|a, b| a.0.total_cmp(&b.0));
    let half = 0.5 * ratios.iter().map(|r| r.1).sum::<f64>();
    let mut seen = 0.0;
    let scale = ratios.iter().find_map(|&(r, w)| {
        seen += w;
        (seen >= half).then_some(r)
    })?;
    Some(SegmentScale {
        scale,
        pairs: ratios.len(),
        frames: sampled.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::labels::Source;

    fn label(i: usize, joint: usize, template: DVec3) -> LabelPlan {
        LabelPlan {
            take_index: i,
            label: format!("M{i}"),
            source: Source::Layout,
            candidates: vec![joint],
            rest: None,
            template: Some(template),
        }
    }

    /// Four markers on a "thigh" (joint 0) and two on a "shank" (joint 1) of a 1.8 m
    /// character; the take's actor is 1/scale times its size, the shank swings about a
    /// knee (its two markers keep their distance, as markers on one bone do).
    fn take(scale: f64, frames: usize) -> (Vec<LabelPlan>, Vec<Vec<DVec3>>) {
        let thigh = [
            DVec3::new(0.1, 0.9, 0.0),
            DVec3::new(0.1, 0.7, 0.1),
            DVec3::new(0.2, 0.7, -0.05),
            DVec3::new(0.0, 0.75, 0.08),
        ];
        let shank = [DVec3::new(0.1, 0.4, 0.05), DVec3::new(0.1, 0.1, 0.0)];
        let mut labels: Vec<LabelPlan> = thigh
            .iter()
            .enumerate()
            .map(|(i, &t)| label(i, 0, t))
            .collect();
        labels.extend(shank.iter().enumerate().map(|(i, &t)| label(4 + i, 1, t)));
        let knee = DVec3::new(0.1, 0.5, 0.0);
        let rec = (0..frames)
            .map(|f| {
                let bend = glam::DQuat::from_rotation_x(f as f64 * 0.02);
                thigh
                    .iter()
                    .copied()
                    .chain(shank.iter().map(|&s| knee + bend * (s - knee)))
                    .map(|p| p / scale + DVec3::new(1.0, 0.0, 2.0))
                    .collect()
            })
            .collect();
        (labels, rec)
    }

    #[test]
    fn pairs_on_one_bone_give_the_scale_whatever_the_pose() {
        let (labels, rec) = take(0.8, 100);
        let s = segment_scale(&labels, &rec, 0..100, 1.8).expect("seven pairs");
        // Exact data: 4 choose 2 thigh pairs and one shank pair.
        assert_eq!(s.pairs, 7);
        assert!((s.scale - 0.8).abs() < 1e-9, "{s:?}");
        // A pair across the knee (two "thigh" labels whose second is on the shank)
        // varies with the bend and is not counted.
        let mut mixed = labels.clone();
        mixed[5].candidates = vec![0];
        let s = segment_scale(&mixed, &rec, 0..100, 1.8).expect("pairs left");
        assert_eq!(
            s.pairs, 6,
            "the shank's lower marker pairs with no thigh marker"
        );
        assert!((s.scale - 0.8).abs() < 1e-9);
    }

    #[test]
    fn one_template_far_off_does_not_move_the_median() {
        let (mut labels, rec) = take(1.25, 50);
        // One thigh template 6 cm off (a marker placed elsewhere than the manual says):
        // its three pairs are off, the other four are not.
        labels[1].template = labels[1].template.map(|t| t + DVec3::new(0.0, 0.06, 0.0));
        let s = segment_scale(&labels, &rec, 0..50, 1.8).unwrap();
        // Measured: exact (the median lands on an unmoved pair).
        assert!((s.scale - 1.25).abs() < 0.01 * 1.25, "{s:?}");
    }

    #[test]
    fn too_few_pairs_or_frames_give_no_estimate() {
        let (labels, rec) = take(1.0, 100);
        // Two labels: one pair.
        assert_eq!(segment_scale(&labels[4..], &rec, 0..100, 1.8), None);
        // No frame seen.
        let blank = vec![vec![DVec3::NAN; 6]; 100];
        assert_eq!(segment_scale(&labels, &blank, 0..100, 1.8), None);
        // A span past the take's end samples nothing.
        assert_eq!(segment_scale(&labels, &rec, 200..300, 1.8), None);
        // A character so large that every pair is short.
        assert_eq!(segment_scale(&labels, &rec, 0..100, 100.0), None);
    }
}
