//! The replay input: a recording (a bundled session, or a C3D, TSV, BVH or session file)
//! played as live input, each frame's samples sent at the recording's own timing (scaled
//! by a speed factor) on the stage's clock. Labels find the character's markers through
//! the marker index (exactly, or without case and `Subject:` prefix).

use super::config::ReplayInputConfig;
use super::{play_paced, InputError, InputFrame, InputSink, OpenContext};
use crate::markers::index::{LabelMap, MarkerIndex};
use crate::markers::MarkerSample;
use crate::replay::bundled::bundled;
use crate::replay::recording::Recording;
use crate::runtime::clock::Clock;
use std::sync::atomic::{AtomicBool, Ordering};

/// How to play.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlayParams {
    /// Playback speed (1 = the recording's own timing).
    pub speed: f64,
    /// Start again at the end.
    pub looping: bool,
}

/// An opened replay input: the recording, loaded, and its labels mapped.
pub struct ReplayInput {
    rec: Recording,
    map: LabelMap,
    names: Vec<String>,
    params: PlayParams,
}

impl ReplayInput {
    /// Loads the recording `cfg` names (a path relative to `ctx.base_dir`) and maps its
    /// labels onto the character's markers; refuses a recording none of whose labels is
    /// a marker. Without a character (`ctx.markers` is `None`), every label is a marker.
    pub fn open(cfg: &ReplayInputConfig, ctx: &OpenContext<'_>) -> Result<Self, InputError> {
        let mut rec = match (&cfg.session, &cfg.path) {
            (Some(name), _) => {
                let bytes = bundled(name)
                    .ok_or_else(|| InputError::NoSuchSession { name: name.clone() })?;
                Recording::from_c3d(name, bytes)?
            }
            (None, Some(p)) => Recording::load_with(&ctx.base_dir.join(p), cfg.bvh_scale)?,
            (None, None) => return Err(InputError::NoRecording),
        };
        if let Some(subject) = &cfg.subject {
            for l in &mut rec.labels {
                if crate::markers::index::subject_of(l).is_empty() {
                    *l = format!("{subject}:{l}");
                }
            }
        }
        let index = match ctx.markers {
            Some(_) => ctx.index(),
            None => MarkerIndex::fixed_for(&rec.labels, ctx.subject.clone()),
        };
        let map = LabelMap::new(&rec.labels, &index);
        if map.marker_of_label.iter().all(Option::is_none) {
            return Err(InputError::NoMatchingLabel {
                name: rec.name.clone(),
                labels: rec.labels.len(),
                markers: index.names().join(", "),
            });
        }
        Ok(Self::new(
            rec,
            map,
            index.names().to_vec(),
            PlayParams {
                speed: cfg.speed,
                looping: cfg.looping,
            },
        ))
    }

    /// A recording already loaded and mapped onto `names`.
    pub fn new(rec: Recording, map: LabelMap, names: Vec<String>, params: PlayParams) -> Self {
        Self {
            rec,
            map,
            names,
            params,
        }
    }

    /// `replaying NAME: N frames at R Hz (D s), K of M markers fed[, looping]`.
    pub fn opened(&self) -> String {
        let (rec, n) = (&self.rec, self.names.len());
        format!(
            "replaying {}: {} frames at {} Hz ({:.1} s), {} of {n} markers fed{}",
            rec.name,
            rec.frames.len(),
            rec.rate_hz,
            rec.duration_secs(),
            n - self.map.unfed_markers.len(),
            if self.params.looping { ", looping" } else { "" }
        )
    }

    /// The recording's labels that feed a marker, and those ignored (no such marker, or
    /// another subject's).
    pub fn label_counts(&self) -> (usize, usize) {
        let ignored = self.map.unmatched_labels.len() + self.map.other_subject_labels.len();
        (self.rec.labels.len() - ignored, ignored)
    }

    /// What the reader tolerated, the labels ignored, and the markers left held.
    pub fn warnings(&self) -> Vec<String> {
        let mut out = self.rec.warnings.clone();
        out.extend(self.map.others_text());
        if !self.map.unmatched_labels.is_empty() {
            out.push(format!(
                "labels ignored (no such marker): {}",
                self.map.unmatched_labels.join(", ")
            ));
        }
        if !self.map.unfed_markers.is_empty() {
            out.push(format!(
                "markers with no label (held): {}",
                self.map.unfed_markers.join(", ")
            ));
        }
        out
    }

    /// How long it plays, seconds: the recording's frames over its rate, at the playback
    /// speed (`None` when looping).
    pub fn duration_s(&self) -> Option<f64> {
        (!self.params.looping).then(|| self.rec.duration_secs() / self.params.speed)
    }

    /// Plays the recording from `start_s` on `clock` to its end (forever when looping)
    /// or until `stop` is set. Source times are the recording's own (seconds from its
    /// first frame, growing across loops).
    pub fn run(
        self,
        clock: &dyn Clock,
        start_s: f64,
        stop: &AtomicBool,
        sink: &mut dyn InputSink,
    ) -> String {
        let (rec, p) = (&self.rec, self.params);
        let n = rec.frames.len();
        let period = 1.0 / rec.rate_hz;
        let mut batch = Vec::new();
        let mut sent = 0usize;
        play_paced(
            clock,
            start_s,
            period / p.speed,
            n,
            p.looping,
            stop,
            &mut |i, t| {
                let source_t = i as f64 * period;
                batch.clear();
                for (pos, m) in rec.frames[i % n].iter().zip(&self.map.marker_of_label) {
                    if let Some(k) = m {
                        batch.push(MarkerSample {
                            marker: *k,
                            time_s: t,
                            source_time_s: source_t,
                            position_m: *pos,
                            occluded: !pos.is_finite(),
                        });
                    }
                }
                sent += 1;
                let taken = sink.frame(&InputFrame {
                    time_s: t,
                    receive_unix_s: clock.unix_s(t),
                    source_time_s: Some(source_t),
                    frame: Some(i as i64),
                    samples: &batch,
                    names: &self.names,
                });
                if !taken {
                    stop.store(true, Ordering::Relaxed);
                }
                taken
            },
        );
        format!("{sent} frames of {} played", rec.name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input::{ChannelSink, SourceCounters};
    use crate::runtime::clock::ManualClock;
    use glam::DVec3;
    use std::sync::Arc;

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
            point_groups: Vec::new(),
        };
        let names = vec!["a".to_string(), "b".to_string()];
        let map = LabelMap::new(&rec.labels, &MarkerIndex::fixed(&names));
        let input = ReplayInput::new(
            rec,
            map,
            names,
            PlayParams {
                speed: 2.0,
                looping: false,
            },
        );
        assert_eq!(input.duration_s(), Some(0.05));
        assert_eq!(input.warnings().len(), 2, "zz ignored, a held");
        let (tx, rx) = crossbeam_channel::bounded(100);
        let clock = ManualClock::new(0.0);
        let counters = Arc::new(SourceCounters::default());
        let mut sink = ChannelSink::new(tx, Arc::clone(&counters), None);
        input.run(&clock, 1.0, &AtomicBool::new(false), &mut sink);
        let got: Vec<MarkerSample> = rx.try_iter().collect();
        assert_eq!(got.len(), 10, "one mapped label per frame");
        for (i, s) in got.iter().enumerate() {
            assert_eq!(s.marker, 1);
            assert!((s.time_s - (1.0 + i as f64 * 0.01 / 2.0)).abs() < 1e-12);
            assert!((s.source_time_s - i as f64 * 0.01).abs() < 1e-12);
            assert_eq!(s.occluded, i == 4);
        }
        assert_eq!(counters.frames.load(Ordering::Relaxed), 10);
        // The clock was driven to the last frame's time, no further.
        assert!((clock.now_s() - 1.045).abs() < 1e-12);
    }
}
