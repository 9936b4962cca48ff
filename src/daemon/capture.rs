//! A take from live input: a stage's marker inputs opened with every name they meet an
//! index of its own (as `rigless listen` opens them), run for a given time on the stage's
//! clock, their packets gathered into a [`Recording`] that `calibrate` reads like a file.
//! Used by `rigless calibrate CHARACTER URL --seconds N` and by a stage's
//! `[calibration] first_secs`.
//!
//! Packets become frames: a packet with the sender's frame number joins the frame of
//! that number; one without (an OSC message per marker) joins the newest frame until a
//! label repeats or [`FRAME_SPAN_S`] has passed. Memory is bounded: at most
//! [`MAX_CAPTURE_LABELS`] labels (later ones are counted and dropped) and
//! [`MAX_CAPTURE_FRAMES`] frames (past that, every second frame is dropped, the kept
//! frames still covering the whole capture).

pub use crate::calibrate::config::MAX_CAPTURE_SECS;
use crate::input::config::InputConfig;
use crate::input::glove::HandMap;
use crate::input::{Input, InputError, InputFrame, InputSink, OpenContext};
use crate::protocol::glove::GloveReading;
use crate::replay::recording::{Recording, MAX_RATE_HZ, MIN_RATE_HZ};
use crate::runtime::clock::{Attached, Clock};
use glam::DVec3;
use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// Most labels a capture keeps.
pub const MAX_CAPTURE_LABELS: usize = 512;
/// Most frames a capture keeps (a minute at 240 Hz).
pub const MAX_CAPTURE_FRAMES: usize = 14_400;
/// Packets without a frame number that arrive within this of a frame's first one, with
/// labels it lacks, join it, seconds.
pub const FRAME_SPAN_S: f64 = 0.002;

/// Why a capture failed.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    #[error("input {index} ({kind}): {source}")]
    Input {
        index: usize,
        kind: &'static str,
        source: Box<InputError>,
    },
    #[error("no marker input to capture from (a data glove or synthetic input carries no labelled markers)")]
    NoMarkerInput,
    #[error("the capture must last 0 to {MAX_CAPTURE_SECS} s, got {seconds:?}")]
    Seconds { seconds: f64 },
    #[error("no labelled marker arrived in {seconds} s from {inputs}")]
    Nothing { seconds: f64, inputs: String },
    #[error("starting a capture thread: {0}")]
    Thread(std::io::Error),
}

/// Frames being gathered: the pure part of a capture, fed packet by packet.
#[derive(Debug, Default)]
pub struct TakeBuilder {
    labels: Vec<String>,
    by_name: HashMap<String, usize>,
    /// Each kept frame: its time (seconds on the stage's clock) and its positions, in
    /// label order (shorter than `labels` when labels came later; NaN: missing).
    frames: Vec<(f64, Vec<DVec3>)>,
    /// The open frame's sender number (when it had one), its first packet's time and
    /// the columns it has had.
    open_number: Option<i64>,
    open_t: f64,
    open_seen: Vec<bool>,
    /// Keep one frame in `stride` (doubles each time the frames reach the limit).
    stride: usize,
    /// Frames started so far (kept or not).
    started: usize,
    /// The open frame is kept.
    keeping: bool,
    /// Samples of labels past [`MAX_CAPTURE_LABELS`] or with no name in the input's
    /// index.
    pub labels_dropped: u64,
    /// Packets taken.
    pub packets: u64,
}

impl TakeBuilder {
    pub fn new() -> Self {
        Self {
            stride: 1,
            ..Self::default()
        }
    }

    /// Takes one packet's samples (names by the input's own indices).
    pub fn push(&mut self, f: &InputFrame<'_>) {
        self.packets += 1;
        let joins = self.started > 0
            && match f.frame {
                Some(n) => self.open_number == Some(n),
                None => {
                    self.open_number.is_none()
                        && f.time_s - self.open_t <= FRAME_SPAN_S
                        && f.samples.iter().all(|s| {
                            self.column(f.names, s.marker)
                                .is_none_or(|c| !self.open_seen.get(c).copied().unwrap_or(false))
                        })
                }
            };
        if !joins {
            self.start_frame(f.time_s, f.frame);
        }
        for s in f.samples {
            let Some(c) = self.column_or_add(f.names, s.marker) else {
                self.labels_dropped += 1;
                continue;
            };
            if self.open_seen.len() <= c {
                self.open_seen.resize(c + 1, false);
            }
            self.open_seen[c] = true;
            if !self.keeping || s.occluded || !s.position_m.is_finite() {
                continue;
            }
            let Some((_, row)) = self.frames.last_mut() else {
                continue;
            };
            if row.len() <= c {
                row.resize(c + 1, DVec3::NAN);
            }
            row[c] = s.position_m;
        }
    }

    /// The column of the input's marker `k`, if the label has one.
    fn column(&self, names: &[String], k: u32) -> Option<usize> {
        names
            .get(k as usize)
            .and_then(|n| self.by_name.get(n).copied())
    }

    /// The column of the input's marker `k`, added when new and there is room.
    fn column_or_add(&mut self, names: &[String], k: u32) -> Option<usize> {
        let name = names.get(k as usize)?;
        if let Some(&c) = self.by_name.get(name) {
            return Some(c);
        }
        if self.labels.len() >= MAX_CAPTURE_LABELS {
            return None;
        }
        self.labels.push(name.clone());
        self.by_name.insert(name.clone(), self.labels.len() - 1);
        Some(self.labels.len() - 1)
    }

    fn start_frame(&mut self, time_s: f64, number: Option<i64>) {
        self.open_number = number;
        self.open_t = time_s;
        self.open_seen.fill(false);
        self.keeping = self.started.is_multiple_of(self.stride);
        self.started += 1;
        if !self.keeping {
            return;
        }
        if self.frames.len() >= MAX_CAPTURE_FRAMES {
            // Halve what is kept: every second frame goes, and from now on one frame
            // in twice as many is kept.
            let mut k = 0;
            self.frames.retain(|_| {
                k += 1;
                k % 2 == 1
            });
            self.stride *= 2;
            self.keeping = (self.started - 1).is_multiple_of(self.stride);
            if !self.keeping {
                return;
            }
        }
        self.frames.push((time_s, Vec::new()));
    }

    /// The frames as a recording named `name` (`None` with no labelled position): rows
    /// padded to every label; the rate is the kept frames over their time span, within
    /// the rates a recording may have.
    pub fn finish(self, name: &str) -> Option<Recording> {
        let n = self.labels.len();
        let any = self
            .frames
            .iter()
            .any(|(_, r)| r.iter().any(|p| p.is_finite()));
        if n == 0 || !any {
            return None;
        }
        let span_s = match (self.frames.first(), self.frames.last()) {
            (Some(a), Some(b)) => b.0 - a.0,
            _ => 0.0,
        };
        let rate_hz = if span_s > 0.0 && self.frames.len() > 1 {
            ((self.frames.len() - 1) as f64 / span_s).clamp(MIN_RATE_HZ, MAX_RATE_HZ)
        } else {
            1.0
        };
        let mut warnings = Vec::new();
        if self.labels_dropped > 0 {
            warnings.push(format!(
                "{} samples of labels past the first {MAX_CAPTURE_LABELS} dropped",
                self.labels_dropped
            ));
        }
        if self.stride > 1 {
            warnings.push(format!(
                "one frame in {} kept (more than {MAX_CAPTURE_FRAMES} arrived)",
                self.stride
            ));
        }
        let frames = self
            .frames
            .into_iter()
            .map(|(_, mut r)| {
                r.resize(n, DVec3::NAN);
                r
            })
            .collect();
        Some(Recording {
            name: name.to_owned(),
            rate_hz,
            labels: self.labels,
            frames,
            warnings,
            file_units: "m".into(),
            point_groups: Vec::new(),
        })
    }
}

/// One input's packets into a shared builder, until the capture's end time.
struct CaptureSink {
    take: Arc<Mutex<TakeBuilder>>,
    end_s: f64,
}

impl InputSink for CaptureSink {
    fn frame(&mut self, f: &InputFrame<'_>) -> bool {
        if f.time_s > self.end_s {
            return false;
        }
        match self.take.lock() {
            Ok(mut t) => {
                t.push(f);
                true
            }
            // Another capture thread panicked: nobody will read the take.
            Err(_) => false,
        }
    }

    fn glove(&mut self, _: f64, _: &GloveReading, _: &HandMap) -> bool {
        true
    }
}

/// Runs the marker inputs of `inputs` for `seconds` on `clock` (from now) and returns
/// what arrived as a recording named `name`, with each input's closing line. Relative
/// recording paths are taken from `base_dir`. Data gloves and synthetic inputs are
/// skipped.
pub fn capture(
    inputs: &[InputConfig],
    base_dir: &Path,
    clock: &Arc<dyn Clock>,
    seconds: f64,
    name: &str,
    subject: &crate::markers::index::SubjectFilter,
) -> Result<(Recording, Vec<String>), CaptureError> {
    if !(seconds > 0.0 && seconds <= MAX_CAPTURE_SECS) {
        return Err(CaptureError::Seconds { seconds });
    }
    let ctx = OpenContext {
        base_dir,
        markers: None,
        skeleton: None,
        procedural: None,
        subject,
        actors: None,
    };
    let mut opened = Vec::new();
    for (index, c) in inputs.iter().enumerate() {
        if matches!(c, InputConfig::Glove(_) | InputConfig::Synthetic(_)) {
            continue;
        }
        let input = Input::open(c, &ctx).map_err(|source| CaptureError::Input {
            index,
            kind: c.kind(),
            source: Box::new(source),
        })?;
        opened.push(input);
    }
    if opened.is_empty() {
        return Err(CaptureError::NoMarkerInput);
    }
    let shown: Vec<String> = opened.iter().map(Input::opened).collect();
    let take = Arc::new(Mutex::new(TakeBuilder::new()));
    let stop = Arc::new(AtomicBool::new(false));
    let start_s = clock.now_s();
    let end_s = start_s + seconds;
    // Places on the clock (this thread and each paced input) are taken before any input
    // starts, so that a manual clock moves only when all of them wait.
    let here = Attached::new(clock);
    let places: Vec<Option<Attached>> = opened
        .iter()
        .map(|i| i.is_paced().then(|| Attached::new(clock)))
        .collect();
    let mut threads = Vec::new();
    for (input, place) in opened.into_iter().zip(places) {
        let mut sink = CaptureSink {
            take: Arc::clone(&take),
            end_s,
        };
        let (clock, stop_input) = (Arc::clone(clock), Arc::clone(&stop));
        let handle = std::thread::Builder::new()
            .name(format!("capture-{}", input.kind()))
            .spawn(move || {
                let _place = place;
                input.run(&*clock, start_s, &stop_input, &mut sink)
            })
            .map_err(|e| {
                // The inputs already running end with the capture.
                stop.store(true, Ordering::Relaxed);
                CaptureError::Thread(e)
            })?;
        threads.push(handle);
    }
    clock.sleep_until(end_s);
    stop.store(true, Ordering::Relaxed);
    drop(here);
    let mut lines = Vec::new();
    for t in threads {
        lines.push(match t.join() {
            Ok(Ok(line)) => line,
            Ok(Err(e)) => e.to_string(),
            Err(_) => "the input's thread panicked".into(),
        });
    }
    let builder = match Arc::try_unwrap(take) {
        Ok(m) => m.into_inner().unwrap_or_else(|e| e.into_inner()),
        Err(shared) => std::mem::take(&mut *shared.lock().unwrap_or_else(|e| e.into_inner())),
    };
    let rec = builder.finish(name).ok_or_else(|| CaptureError::Nothing {
        seconds,
        inputs: shown.join("; "),
    })?;
    Ok((rec, lines))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::markers::MarkerSample;

    fn sample(marker: u32, x: f64) -> MarkerSample {
        MarkerSample {
            marker,
            time_s: 0.0,
            source_time_s: 0.0,
            position_m: DVec3::new(x, 0.0, 0.0),
            occluded: false,
        }
    }

    fn packet<'a>(
        t: f64,
        frame: Option<i64>,
        samples: &'a [MarkerSample],
        names: &'a [String],
    ) -> InputFrame<'a> {
        InputFrame {
            time_s: t,
            receive_unix_s: t,
            source_time_s: None,
            frame,
            samples,
            names,
        }
    }

    /// Numbered packets make a frame each; messages without a number gather into one
    /// frame until a label repeats; a label met late is missing (NaN) before.
    #[test]
    fn packets_gather_into_frames() {
        let names: Vec<String> = ["a", "b", "c"].map(String::from).to_vec();
        let mut b = TakeBuilder::new();
        for i in 0..3 {
            let t = i as f64 / 100.0;
            b.push(&packet(t, Some(i), &[sample(0, t), sample(1, t)], &names));
        }
        // Three OSC messages of one frame, then the next frame's first.
        b.push(&packet(0.03, None, &[sample(0, 3.0)], &names));
        b.push(&packet(0.0301, None, &[sample(1, 3.0)], &names));
        b.push(&packet(0.0302, None, &[sample(2, 3.0)], &names));
        b.push(&packet(0.0303, None, &[sample(0, 4.0)], &names));
        let r = b.finish("live").unwrap();
        assert_eq!(r.labels, ["a", "b", "c"]);
        assert_eq!(r.frames.len(), 5);
        assert!(r.frames[0][2].is_nan(), "c came later");
        assert_eq!(r.frames[3], vec![DVec3::new(3.0, 0.0, 0.0); 3]);
        assert_eq!(r.frames[4][0].x, 4.0);
        assert!(r.frames[4][1].is_nan());
        // 4 intervals over 30.3 ms.
        assert!((r.rate_hz - 4.0 / 0.0303).abs() < 1e-6, "{}", r.rate_hz);
    }

    /// Past the frame limit every second frame goes; the kept ones span the capture.
    #[test]
    fn a_long_capture_keeps_frames_over_its_whole_span() {
        let names = vec!["a".to_string()];
        let mut b = TakeBuilder::new();
        let n = 3 * MAX_CAPTURE_FRAMES + 7;
        for i in 0..n {
            let t = i as f64 / 1000.0;
            b.push(&packet(t, Some(i as i64), &[sample(0, i as f64)], &names));
        }
        let r = b.finish("long").unwrap();
        assert!(r.frames.len() <= MAX_CAPTURE_FRAMES, "{}", r.frames.len());
        assert!(
            r.frames.len() > MAX_CAPTURE_FRAMES / 2,
            "{}",
            r.frames.len()
        );
        assert_eq!(r.frames[0][0].x, 0.0);
        // The last kept frame is within one stride (4) of the last sent.
        assert!(r.frames.last().unwrap()[0].x >= (n - 4) as f64);
        // The rate follows the keeping: 1000 Hz over a stride of 4.
        assert!((r.rate_hz - 250.0).abs() < 1.0, "{}", r.rate_hz);
        assert_eq!(r.warnings.len(), 1);
    }

    /// Labels past the limit and indices with no name are counted, not kept; a
    /// non-finite position is missing.
    #[test]
    fn labels_past_the_limit_are_dropped() {
        let names: Vec<String> = (0..MAX_CAPTURE_LABELS + 3)
            .map(|i| format!("m{i}"))
            .collect();
        let samples: Vec<MarkerSample> = (0..names.len() as u32 + 2)
            .map(|k| sample(k, if k == 1 { f64::NAN } else { 1.0 }))
            .collect();
        let mut b = TakeBuilder::new();
        b.push(&packet(0.0, Some(0), &samples, &names));
        assert_eq!(b.labels_dropped, 3 + 2);
        let r = b.finish("many").unwrap();
        assert_eq!(r.labels.len(), MAX_CAPTURE_LABELS);
        assert!(r.frames[0][1].is_nan());
        assert_eq!(r.frames[0][0].x, 1.0);
    }

    #[test]
    fn nothing_labelled_is_no_take() {
        let mut b = TakeBuilder::new();
        b.push(&packet(0.0, Some(0), &[sample(0, 1.0)], &[]));
        assert!(b.finish("empty").is_none());
    }

    mod hostile {
        use super::*;
        use proptest::prelude::*;

        fn coordinate() -> impl Strategy<Value = f64> {
            prop_oneof![
                -10.0..10.0f64,
                Just(f64::NAN),
                Just(f64::INFINITY),
                Just(-1e300),
            ]
        }

        proptest! {
            /// Any packets (frame numbers or none, any times, indices past the names,
            /// positions that are not numbers) give a take whose rows all have one
            /// position per label, within the bounds, and a rate a recording may have.
            #[test]
            fn any_packets_give_a_well_formed_take(
                packets in prop::collection::vec(
                    (
                        prop::option::of(-3i64..3),
                        prop_oneof![0.0..1.0f64, Just(f64::NAN), Just(-5.0), Just(1e12)],
                        prop::collection::vec((0u32..12, coordinate(), any::<bool>()), 0..8),
                    ),
                    0..60,
                ),
                n_names in 0usize..10,
            ) {
                let names: Vec<String> = (0..n_names).map(|i| format!("m{i}")).collect();
                let mut b = TakeBuilder::new();
                for (frame, t, samples) in &packets {
                    let samples: Vec<MarkerSample> = samples
                        .iter()
                        .map(|&(k, x, occluded)| MarkerSample {
                            occluded,
                            ..sample(k, x)
                        })
                        .collect();
                    b.push(&packet(*t, *frame, &samples, &names));
                }
                prop_assert_eq!(b.packets, packets.len() as u64);
                if let Some(r) = b.finish("any") {
                    prop_assert!(!r.labels.is_empty() && r.labels.len() <= n_names);
                    prop_assert!(r.frames.len() <= MAX_CAPTURE_FRAMES);
                    prop_assert!(r.frames.iter().all(|f| f.len() == r.labels.len()));
                    prop_assert!(r.frames.iter().flatten().all(|p| p.is_finite() || p.is_nan()));
                    prop_assert!(crate::replay::recording::rate_in_range(r.rate_hz), "{}", r.rate_hz);
                }
            }
        }
    }
}
