//! Plays a recording as live input: each frame's samples go into the daemon's channel at
//! the recording's own timing (scaled by a speed factor), on the daemon's clock.

use super::recording::{LabelMap, Recording};
use crate::daemon::clock::Clock;
use crate::input::{play_paced, SourceCounters};
use crate::markers::MarkerSample;
use crossbeam_channel::Sender;
use std::sync::atomic::AtomicBool;

/// How to play.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlayParams {
    /// Daemon-clock time of the first frame, seconds.
    pub start_s: f64,
    /// Playback speed (1 = the recording's own timing).
    pub speed: f64,
    /// Start again at the end.
    pub looping: bool,
}

/// Sends `rec` into `tx` until it ends (or forever when looping), `stop` is set, or the
/// receiver is gone. Source times are the recording's own (seconds from its first frame,
/// growing across loops). Runs on the calling thread.
pub fn play_recording(
    rec: &Recording,
    map: &LabelMap,
    clock: &dyn Clock,
    params: PlayParams,
    tx: &Sender<MarkerSample>,
    stop: &AtomicBool,
    counters: &SourceCounters,
) {
    let n = rec.frames.len();
    let period = 1.0 / rec.rate_hz;
    play_paced(
        clock,
        params.start_s,
        period / params.speed,
        n,
        params.looping,
        tx,
        stop,
        counters,
        &mut |i, t, batch| {
            let source_t = i as f64 * period;
            for (p, m) in rec.frames[i % n].iter().zip(&map.marker_of_label) {
                if let Some(k) = m {
                    batch.push(MarkerSample {
                        marker: *k,
                        time_s: t,
                        source_time_s: source_t,
                        position_m: *p,
                        occluded: !p.is_finite(),
                    });
                }
            }
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::clock::ManualClock;
    use crate::replay::recording::map_labels;
    use glam::DVec3;
    use std::sync::atomic::Ordering;

    #[test]
    fn plays_mapped_labels_with_the_recordings_timing_scaled_by_speed() {
        let rec = Recording {
            name: "t".into(),
            rate_hz: 100.0,
            labels: vec!["b".into(), "zz".into()],
            frames: (0..10)
                .map(|i| {
                    let p = if i == 4 {
                        DVec3::NAN
                    } else {
                        DVec3::splat(i as f64)
                    };
                    vec![p, DVec3::ONE]
                })
                .collect(),
            warnings: Vec::new(),
            file_units: "m".into(),
        };
        let map = map_labels(&rec.labels, &["a".into(), "b".into()]);
        let (tx, rx) = crossbeam_channel::bounded(100);
        let clock = ManualClock::new(0.0);
        let counters = SourceCounters::default();
        let params = PlayParams {
            start_s: 1.0,
            speed: 2.0,
            looping: false,
        };
        play_recording(
            &rec,
            &map,
            &clock,
            params,
            &tx,
            &AtomicBool::new(false),
            &counters,
        );
        let got: Vec<MarkerSample> = rx.try_iter().collect();
        assert_eq!(got.len(), 10, "one mapped label per frame");
        for (i, s) in got.iter().enumerate() {
            assert_eq!(s.marker, 1);
            assert!((s.time_s - (1.0 + i as f64 * 0.01 / 2.0)).abs() < 1e-12);
            assert!((s.source_time_s - i as f64 * 0.01).abs() < 1e-12);
            assert_eq!(s.occluded, i == 4);
        }
        assert!(counters.finished.load(Ordering::Relaxed));
        assert_eq!(counters.frames.load(Ordering::Relaxed), 10);
        // The clock was driven to the last frame's time, no further.
        assert!((clock.now_s() - 1.045).abs() < 1e-12);
    }
}
