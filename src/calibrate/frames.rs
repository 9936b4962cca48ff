//! The frames a calibration uses and where it starts: frames spread over the take's range
//! of motion (farthest-point sampling on the markers' shapes), and a first guess of the
//! scale and of each frame's heading and position from a similarity fit between
//! labelled markers and the bones that carry them.

use crate::geom::polar::best_rotation;
use glam::{DMat3, DQuat, DVec3};

/// Most frames the sampling compares (evenly spaced over the take).
const MAX_CANDIDATES: usize = 600;

/// Frames of `frames` (`frames[f][k]`, NaN for a gap) over the markers `used`, from
/// `range` (frame indices), that cover the take's range of motion: `seed` (when given),
/// then those with at least 80 % of the used markers in view (or the best-seen ones when
/// none has), sampled by farthest point on the markers' positions about their centroid,
/// `count` at most. In take order.
pub fn choose_frames(
    frames: &[Vec<DVec3>],
    used: &[usize],
    range: std::ops::Range<usize>,
    count: usize,
    seed: Option<usize>,
) -> Vec<usize> {
    let range = range.start.min(frames.len())..range.end.min(frames.len());
    if range.is_empty() || used.is_empty() || count == 0 {
        return Vec::new();
    }
    let step = range.len().div_ceil(MAX_CANDIDATES).max(1);
    let seen = |f: usize| used.iter().filter(|&&k| frames[f][k].is_finite()).count();
    let best_seen = range.clone().step_by(step).map(seen).max().unwrap_or(0);
    let floor = ((used.len() * 4).div_ceil(5)).min(best_seen).max(1);
    let mut candidates: Vec<usize> = range.step_by(step).filter(|&f| seen(f) >= floor).collect();
    if let Some(f) = seed.filter(|f| *f < frames.len()) {
        candidates.retain(|&c| c != f);
        candidates.insert(0, f);
    }
    let shape = |f: usize| -> Vec<DVec3> {
        let pts: Vec<DVec3> = used.iter().map(|&k| frames[f][k]).collect();
        let (sum, n) = pts
            .iter()
            .filter(|p| p.is_finite())
            .fold((DVec3::ZERO, 0.0), |(s, n), p| (s + *p, n + 1.0));
        let c = sum / f64::max(n, 1.0);
        pts.into_iter().map(|p| p - c).collect()
    };
    let shapes: Vec<Vec<DVec3>> = candidates.iter().map(|&f| shape(f)).collect();
    let distance = |a: &[DVec3], b: &[DVec3]| -> f64 {
        let (mut s, mut n) = (0.0, 0);
        for (p, q) in a.iter().zip(b) {
            if p.is_finite() && q.is_finite() {
                s += (*p - *q).length_squared();
                n += 1;
            }
        }
        if n == 0 {
            0.0
        } else {
            (s / n as f64).sqrt()
        }
    };
    // Start from the seed or the best-seen candidate; then the farthest from those
    // chosen.
    let first = if seed.is_some() {
        0
    } else {
        (0..candidates.len())
            .max_by_key(|&i| (seen(candidates[i]), usize::MAX - i))
            .unwrap_or(0)
    };
    let mut chosen = vec![first];
    let mut nearest: Vec<f64> = shapes.iter().map(|s| distance(s, &shapes[first])).collect();
    while chosen.len() < count.min(candidates.len()) {
        let Some((next, &d)) = nearest.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)) else {
            break;
        };
        if d <= 0.0 {
            break;
        }
        chosen.push(next);
        for (i, s) in shapes.iter().enumerate() {
            nearest[i] = nearest[i].min(distance(s, &shapes[next]));
        }
    }
    let mut out: Vec<usize> = chosen.into_iter().map(|i| candidates[i]).collect();
    out.sort_unstable();
    out
}

/// A similarity `x ↦ q x + t` taking character points to scaled take coordinates `s m`:
/// `q` a turn about Y for a character that stands ([`Turn::Yaw`]), any rotation for one
/// that does not ([`Turn::Any`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Heading {
    pub q: DQuat,
    pub t: DVec3,
}

/// Which rotations take the character into the take.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Turn {
    /// A turn about Y: a body stands upright in its take and at rest.
    Yaw,
    /// Any rotation: a hand (or any character without legs) is held every way in its
    /// take, and its rest pose need not match the take's up.
    Any,
}

/// The fit of `s m ≈ q a + t` over pairs `(a, m)` (character anchor, take position; both
/// Y up), `q` as `turn` allows (the best turn about Y in closed form; any rotation by
/// Kabsch's fit, Kabsch 1976, as the polar rotation of the weighted cross-covariance
/// `Σ w (m − m̄)(a − ā)ᵀ`), with robust (Cauchy, width `c_m` in take metres) weights;
/// `scale` fixes `s` when given. Returns the heading, the scale and the weighted RMS
/// misfit in take metres; `None` with fewer than three pairs.
pub fn fit_heading(
    pairs: &[(DVec3, DVec3)],
    scale: Option<f64>,
    c_m: f64,
    turn: Turn,
) -> Option<(Heading, f64, f64)> {
    if pairs.len() < 3 {
        return None;
    }
    let mut w = vec![1.0; pairs.len()];
    let mut result = None;
    for _ in 0..6 {
        let sw: f64 = w.iter().sum();
        let abar = pairs
            .iter()
            .zip(&w)
            .map(|((a, _), w)| *a * *w)
            .sum::<DVec3>()
            / sw;
        let mbar = pairs
            .iter()
            .zip(&w)
            .map(|((_, m), w)| *m * *w)
            .sum::<DVec3>()
            / sw;
        let (mut s1, mut s2, mut mm) = (0.0, 0.0, 0.0);
        let mut cross = DMat3::ZERO;
        for ((a, m), w) in pairs.iter().zip(&w) {
            let (a, m) = (*a - abar, *m - mbar);
            s1 += w * (a.x * m.x + a.z * m.z);
            s2 += w * (a.z * m.x - a.x * m.z);
            mm += w * m.length_squared();
            cross += DMat3::from_cols(m * (w * a.x), m * (w * a.y), m * (w * a.z));
        }
        let q = match turn {
            Turn::Yaw => DQuat::from_rotation_y(s2.atan2(s1)),
            Turn::Any => best_rotation(&cross),
        };
        let s = match scale {
            Some(s) => s,
            None => {
                let num: f64 = pairs
                    .iter()
                    .zip(&w)
                    .map(|((a, m), w)| w * (q * (*a - abar)).dot(*m - mbar))
                    .sum();
                if mm <= 0.0 || num <= 0.0 {
                    return None;
                }
                num / mm
            }
        };
        let t = mbar * s - q * abar;
        let mut sse = 0.0;
        for ((a, m), wi) in pairs.iter().zip(w.iter_mut()) {
            let e = ((*m * s) - (q * *a + t)).length() / s;
            sse += *wi * e * e;
            *wi = 1.0 / (1.0 + (e / c_m).powi(2));
        }
        let rms = (sse / sw).sqrt();
        result = Some((Heading { q, t }, s, rms));
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::polar::rotation_angle_between;

    #[test]
    fn a_turned_scaled_copy_is_found_exactly() {
        let a = [
            DVec3::new(0.0, 1.0, 0.0),
            DVec3::new(0.3, 0.2, 0.1),
            DVec3::new(-0.2, 1.5, -0.1),
            DVec3::new(0.1, 0.9, 0.4),
        ];
        let (q, t, s) = (DQuat::from_rotation_y(2.0), DVec3::new(3.0, 0.1, -2.0), 1.2);
        // s m = q a + t.
        let pairs: Vec<(DVec3, DVec3)> = a.iter().map(|&a| (a, (q * a + t) / s)).collect();
        for turn in [Turn::Yaw, Turn::Any] {
            let (h, s_fit, rms) = fit_heading(&pairs, None, 0.1, turn).expect("a fit");
            assert!((s_fit - s).abs() < 1e-12, "{turn:?}: {s_fit}");
            assert!(rotation_angle_between(h.q, q) < 1e-9, "{turn:?}");
            assert!((h.t - t).length() < 1e-9, "{turn:?}");
            assert!(rms < 1e-9, "{turn:?}");
            assert!(fit_heading(&pairs[..2], None, 0.1, turn).is_none());
        }
    }

    #[test]
    fn any_turn_is_found_where_a_yaw_cannot_fit() {
        let a = [
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(0.1, 0.02, 0.0),
            DVec3::new(0.0, -0.18, 0.01),
            DVec3::new(0.03, -0.1, 0.05),
            DVec3::new(-0.04, -0.15, -0.02),
        ];
        // Fingers down at rest, forward and palm down in the take (a half turn among
        // the rotations tried: the start must not matter).
        for q in [
            DQuat::from_rotation_x(1.3) * DQuat::from_rotation_z(0.4),
            DQuat::from_axis_angle(DVec3::new(1.0, 1.0, 0.2).normalize(), 3.1),
            DQuat::from_rotation_z(std::f64::consts::PI),
        ] {
            let (t, s) = (DVec3::new(0.2, 0.9, -0.3), 0.9);
            let pairs: Vec<(DVec3, DVec3)> = a.iter().map(|&a| (a, (q * a + t) / s)).collect();
            let (h, s_fit, rms) = fit_heading(&pairs, None, 0.1, Turn::Any).expect("a fit");
            assert!((s_fit - s).abs() < 1e-9, "{s_fit}");
            assert!(rotation_angle_between(h.q, q) < 1e-9);
            assert!(rms < 1e-9, "{rms}");
            // A yaw fits it badly, or not at all (the best turn about Y has a negative
            // scale).
            let yaw = fit_heading(&pairs, None, 0.1, Turn::Yaw);
            assert!(
                yaw.is_none_or(|(_, _, rms)| rms > 0.01),
                "a yaw alone fits a tilted hand: {yaw:?}"
            );
        }
    }

    #[test]
    fn frames_cover_distinct_shapes() {
        // Two markers; their separation cycles through 3 shapes, with gaps in frame 0.
        let frames: Vec<Vec<DVec3>> = (0..30)
            .map(|f| {
                let d = (f % 3) as f64;
                if f == 0 {
                    vec![DVec3::NAN, DVec3::X]
                } else {
                    vec![DVec3::ZERO, DVec3::X * (1.0 + d)]
                }
            })
            .collect();
        let got = choose_frames(&frames, &[0, 1], 0..30, 5, None);
        let shapes: std::collections::BTreeSet<usize> = got.iter().map(|f| f % 3).collect();
        assert_eq!(shapes.len(), 3, "{got:?}");
        assert!(!got.contains(&0), "frame 0 misses a marker");
        assert_eq!(got.len(), 3, "identical shapes add nothing: {got:?}");
    }
}
