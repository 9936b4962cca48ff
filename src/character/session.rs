//! A synthetic session: a procedural character playing one of its motions, sampled as
//! markers with noise and occlusion gaps whose truth is known. The synthetic input plays
//! it live; the bundled sessions, tests and the gap-filling benchmark read it frame by
//! frame.

use super::demo::Motion;
use super::procedural::{skin_pose, Character};
use crate::markers::MarkerSample;
use crate::runtime::rng::Rng;
use glam::DVec3;
use std::sync::Arc;

/// How a synthetic session is made.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SyntheticParams {
    /// Capture rate, Hz.
    pub rate_hz: f64,
    /// Length of the session, seconds.
    pub duration_secs: f64,
    /// Uniform noise amplitude per axis, metres.
    pub noise_m: f64,
    /// Fraction of marker samples inside occlusion gaps (0 for none).
    pub gap_fraction: f64,
    /// Shortest and longest gap, seconds (lengths are log-uniform in between).
    pub min_gap_secs: f64,
    pub max_gap_secs: f64,
    /// Seed of the noise and the gaps.
    pub seed: u64,
}

impl Default for SyntheticParams {
    fn default() -> Self {
        Self {
            rate_hz: 120.0,
            duration_secs: 20.0,
            noise_m: 0.0005,
            gap_fraction: 0.05,
            min_gap_secs: 0.02,
            max_gap_secs: 1.0,
            seed: 1,
        }
    }
}

/// A session: a character, a motion, and per marker the occlusion gaps.
#[derive(Clone, Debug)]
pub struct SyntheticSession {
    ch: Arc<Character>,
    motion: Motion,
    params: SyntheticParams,
    /// Per marker, sorted `[start, end)` gap intervals in seconds.
    gaps: Vec<Vec<(f64, f64)>>,
    truth: Vec<DVec3>,
}

impl SyntheticSession {
    pub fn new(ch: Arc<Character>, motion: Motion, params: SyntheticParams) -> Self {
        let mut rng = Rng::new(params.seed);
        let f = params.gap_fraction.clamp(0.0, 0.9);
        let (lo, hi) = (params.min_gap_secs.max(1e-3), params.max_gap_secs.max(1e-3));
        // Mean of a log-uniform length on [lo, hi].
        let mean_gap = if hi > lo {
            (hi - lo) / (hi / lo).ln()
        } else {
            lo
        };
        let gaps = (0..ch.markers.len())
            .map(|_| {
                let mut out = Vec::new();
                if f <= 0.0 {
                    return out;
                }
                let mean_visible = mean_gap * (1.0 - f) / f;
                let mut t = -mean_visible * (1.0 - rng.next_f64()).ln();
                while t < params.duration_secs {
                    let len = lo * (hi / lo).powf(rng.next_f64());
                    out.push((t, t + len));
                    t += len - mean_visible * (1.0 - rng.next_f64()).ln();
                }
                out
            })
            .collect();
        let n = ch.markers.len();
        Self {
            ch,
            motion,
            params,
            gaps,
            truth: vec![DVec3::ZERO; n],
        }
    }

    pub fn character(&self) -> &Arc<Character> {
        &self.ch
    }

    pub fn motion(&self) -> Motion {
        self.motion
    }

    pub fn params(&self) -> &SyntheticParams {
        &self.params
    }

    /// Frames in the session.
    pub fn frames(&self) -> usize {
        (self.params.duration_secs * self.params.rate_hz).round() as usize
    }

    /// Whether marker `k` is occluded at session time `t_s`.
    pub fn occluded(&self, k: usize, t_s: f64) -> bool {
        let g = &self.gaps[k];
        let i = g.partition_point(|&(s, _)| s <= t_s);
        i > 0 && t_s < g[i - 1].1
    }

    /// The true marker positions of the last [`Self::frame`].
    pub fn truth(&self) -> &[DVec3] {
        &self.truth
    }

    /// Samples of frame `i` (session time `i / rate_hz`), stamped `time_s` on the daemon's
    /// clock, appended to `out`: every marker, occluded ones flagged.
    pub fn frame(&mut self, i: usize, time_s: f64, out: &mut Vec<MarkerSample>) {
        let t = i as f64 / self.params.rate_hz;
        let pose = self.motion.pose(&self.ch.skeleton, t);
        skin_pose(&self.ch, &pose, &mut [], &mut self.truth);
        let mut rng = Rng::new(self.params.seed ^ (i as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
        for (k, p) in self.truth.iter().enumerate() {
            let noise =
                DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 2.0 - DVec3::ONE;
            let occluded = self.occluded(k, t);
            out.push(MarkerSample {
                marker: k as u32,
                time_s,
                source_time_s: t,
                position_m: if occluded {
                    DVec3::NAN
                } else {
                    *p + noise * self.params.noise_m
                },
                occluded,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::character::demo::demo_hand;

    #[test]
    fn gaps_cover_about_the_requested_fraction() {
        let ch = Arc::new(demo_hand());
        let params = SyntheticParams {
            duration_secs: 600.0,
            gap_fraction: 0.1,
            ..SyntheticParams::default()
        };
        let s = SyntheticSession::new(ch, Motion::FingerPlay, params);
        let (mut occluded, mut total) = (0usize, 0usize);
        for k in 0..8 {
            for i in 0..60_000 {
                occluded += s.occluded(k, i as f64 * 0.01) as usize;
                total += 1;
            }
        }
        let f = occluded as f64 / total as f64;
        // 8 markers × 600 s hold about 8·600/(mean cycle ≈ 2.4 s) ≈ 2,000 gaps: the
        // fraction's standard error is well under 0.01.
        assert!((f - 0.1).abs() < 0.02, "occluded fraction {f}");
    }

    #[test]
    fn samples_are_the_truth_plus_bounded_noise() {
        let ch = Arc::new(demo_hand());
        let params = SyntheticParams {
            gap_fraction: 0.0,
            noise_m: 0.001,
            ..SyntheticParams::default()
        };
        let mut s = SyntheticSession::new(ch, Motion::FingerPlay, params);
        let mut out = Vec::new();
        s.frame(30, 5.0, &mut out);
        assert_eq!(out.len(), 8);
        for (o, t) in out.iter().zip(s.truth()) {
            assert_eq!(o.time_s, 5.0);
            assert!((o.source_time_s - 0.25).abs() < 1e-12);
            let d = o.position_m - *t;
            assert!(d.abs().max_element() <= 0.001, "noise {d}");
        }
    }
}
