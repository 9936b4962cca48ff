//! A recording as the replayer plays it: labelled marker trajectories at a fixed rate, from
//! a C3D, TSV, BVH or session file (or a bundled session), and the limits every reader
//! holds a file to.
//!
//! Hostile files: no reader allocates by a number read from a file unless the file's own
//! length bounds it (a frame needs bytes) or a documented limit does ([`MIN_RATE_HZ`],
//! [`MAX_RATE_HZ`], [`position_budget`], and each reader's counts); header arithmetic is
//! checked, and a value out of range is an error naming the field and the value.

use super::bvh::{parse_bvh, BvhError};
use super::c3d::{read_c3d, C3dError};
use super::session::{read_session, Session, SessionError};
use super::tsv::{parse_tsv, TsvError};
use crate::markers::MarkerSample;
use crate::runtime::files::{read_bounded, MAX_DATA_BYTES};
use glam::DVec3;
use std::path::Path;

/// Metres per BVH unit unless told otherwise (centimetres, the commonest convention).
pub const DEFAULT_BVH_METRES_PER_UNIT: f64 = 0.01;

/// Lowest frame rate a recording may declare, Hz (a frame every 10 s).
pub const MIN_RATE_HZ: f64 = 0.1;
/// Highest frame rate a recording may declare, Hz (high-speed optical capture at reduced
/// resolution stays below it).
pub const MAX_RATE_HZ: f64 = 100_000.0;
/// Positions (frames × markers) a recording may hold whatever its file's length: 2^20, or
/// 24 MiB of positions (about 4 minutes of 36 markers at 120 Hz).
pub const FREE_POSITIONS: usize = 1 << 20;
/// Positions a recording may hold per byte of its file, on top of [`FREE_POSITIONS`]. C3D
/// (8 or 16 bytes a position) and TSV (at least 3) stay under it by construction; it bounds
/// BVH, whose joints without channels cost no byte a frame, and sessions, whose frames
/// without a sample cost none (a 33-byte sample may leave 32 cells of its table empty).
pub const POSITIONS_PER_BYTE: usize = 1;

/// Whether a declared frame rate lies in [`MIN_RATE_HZ`]..=[`MAX_RATE_HZ`] (NaN does not).
pub fn rate_in_range(rate_hz: f64) -> bool {
    (MIN_RATE_HZ..=MAX_RATE_HZ).contains(&rate_hz)
}

/// The most positions (frames × markers) a recording read from `file_len` bytes may hold:
/// [`FREE_POSITIONS`] + [`POSITIONS_PER_BYTE`] per byte.
pub fn position_budget(file_len: usize) -> usize {
    FREE_POSITIONS.saturating_add(file_len.saturating_mul(POSITIONS_PER_BYTE))
}

/// Labelled marker trajectories: `frames[f][k]`, metres, world frame, NaN where missing.
#[derive(Clone, Debug)]
pub struct Recording {
    pub name: String,
    pub rate_hz: f64,
    pub labels: Vec<String>,
    pub frames: Vec<Vec<DVec3>>,
    /// What the reader tolerated.
    pub warnings: Vec<String>,
    /// Length unit the file stores (`mm`, `m`, ...), before conversion to metres.
    pub file_units: String,
    /// For each label, the group a C3D file lists it under as a model output (angles,
    /// forces, ... stored as points: [`crate::replay::c3d::C3d::point_groups`]); empty
    /// when the file says nothing of it.
    pub point_groups: Vec<Option<String>>,
}

/// Keeps the items of `v` whose flag in `keep` is set (an item past its end is dropped).
fn retain_by<T>(v: &mut Vec<T>, keep: &[bool]) {
    let mut k = keep.iter();
    v.retain(|_| k.next().copied().unwrap_or(false));
}

/// Why a recording cannot be played.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("{path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    C3d { path: String, source: C3dError },
    #[error("{path}: {source}")]
    Tsv { path: String, source: TsvError },
    #[error("{path}: {source}")]
    Session { path: String, source: SessionError },
    #[error("{path}: {source}")]
    Bvh { path: String, source: BvhError },
    #[error("{path}: unknown recording format (expected .c3d, .tsv, .bvh or .rlsession)")]
    Format { path: String },
    #[error("{path}: no frames")]
    Empty { path: String },
    #[error("{path}: rate_hz {rate_hz:?} is outside {MIN_RATE_HZ}..={MAX_RATE_HZ} Hz")]
    Rate { path: String, rate_hz: f64 },
    #[error(
        "{path}: the samples span {span_s:?} s, {frames:?} frames at {rate_hz:?} Hz, × {markers} \
         markers: more than the {budget} positions a {file_len}-byte file may hold"
    )]
    TooLong {
        path: String,
        span_s: f64,
        rate_hz: f64,
        /// Frames the span needs (may be infinite).
        frames: f64,
        markers: usize,
        file_len: usize,
        budget: usize,
    },
}

impl Recording {
    /// The recording as a calibration reads it.
    pub fn as_take(&self) -> crate::calibrate::Take<'_> {
        crate::calibrate::Take {
            name: &self.name,
            rate_hz: self.rate_hz,
            labels: &self.labels,
            frames: &self.frames,
            point_groups: &self.point_groups,
        }
    }

    /// Reads a C3D file's bytes.
    pub fn from_c3d(name: &str, bytes: &[u8]) -> Result<Self, RecordingError> {
        let c = read_c3d(bytes).map_err(|source| RecordingError::C3d {
            path: name.to_owned(),
            source,
        })?;
        Ok(Self {
            name: name.to_owned(),
            rate_hz: c.rate_hz,
            labels: c.labels,
            frames: c.frames,
            warnings: c.warnings,
            file_units: c.units,
            point_groups: c.point_groups,
        })
        .and_then(Self::nonempty)
    }

    /// The subjects its labels name (`Ann` of `Ann:LFHD`, `""` for labels without a
    /// prefix), each once (any case), in the order first met.
    pub fn subjects(&self) -> Vec<String> {
        use crate::markers::index::subject_of;
        let mut out: Vec<String> = Vec::new();
        for s in self.labels.iter().map(|l| subject_of(l)) {
            if !out.iter().any(|o| o.eq_ignore_ascii_case(s)) {
                out.push(s.to_owned());
            }
        }
        out
    }

    /// Keeps the labels of `subject` alone (`Ann` keeps `Ann:LFHD` and `ann:rfhd`; `""`
    /// the labels without a `Subject:` prefix), with their columns; returns how many
    /// labels it left out.
    pub fn keep_subject(&mut self, subject: &str) -> usize {
        use crate::markers::index::subject_of;
        let keep: Vec<bool> = self
            .labels
            .iter()
            .map(|l| subject_of(l).eq_ignore_ascii_case(subject))
            .collect();
        retain_by(&mut self.labels, &keep);
        for f in &mut self.frames {
            retain_by(f, &keep);
        }
        if self.point_groups.len() == keep.len() {
            retain_by(&mut self.point_groups, &keep);
        }
        keep.iter().filter(|k| !**k).count()
    }

    /// Keeps the labels `claim` claims (an actor's of a stage of several) and drops the
    /// others; a label a one-star pattern claims is renamed to what its `*` stood for
    /// (`Ann_LFHD` under `Ann_*` becomes `LFHD`), so that it reads as the marker's name.
    /// Returns how many labels were dropped.
    pub fn keep_claimed(&mut self, claim: &crate::markers::index::Claim) -> usize {
        use crate::markers::index::subject_of;
        let keep: Vec<bool> = self
            .labels
            .iter()
            .map(|l| claim.claims(l, subject_of(l)))
            .collect();
        retain_by(&mut self.labels, &keep);
        for l in &mut self.labels {
            if let Some(bare) = claim.star_part(l) {
                *l = bare.to_owned();
            }
        }
        for f in &mut self.frames {
            retain_by(f, &keep);
        }
        if self.point_groups.len() == keep.len() {
            retain_by(&mut self.point_groups, &keep);
        }
        keep.iter().filter(|k| !**k).count()
    }

    /// Reads a file by its extension (`.c3d`, `.tsv`, `.rlsession`, `.bvh` with
    /// [`DEFAULT_BVH_METRES_PER_UNIT`]).
    pub fn load(path: &Path) -> Result<Self, RecordingError> {
        Self::load_with(path, DEFAULT_BVH_METRES_PER_UNIT)
    }

    /// Reads a file by its extension; a BVH's positions are scaled by
    /// `bvh_metres_per_unit` (BVH has no units) and its joints become the labels.
    pub fn load_with(path: &Path, bvh_metres_per_unit: f64) -> Result<Self, RecordingError> {
        let shown = path.display().to_string();
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        if !["c3d", "tsv", "bvh", "rlsession"].contains(&ext.as_str()) {
            return Err(RecordingError::Format { path: shown });
        }
        let bytes = read_bounded(path, MAX_DATA_BYTES).map_err(|source| RecordingError::Read {
            path: shown.clone(),
            source,
        })?;
        match ext.as_str() {
            "c3d" => Self::from_c3d(&shown, &bytes),
            "tsv" => Self::from_tsv(&shown, &bytes),
            "bvh" => Self::from_bvh(&shown, &bytes, bvh_metres_per_unit),
            _ => Self::from_session_bytes(&shown, &bytes),
        }
    }

    /// Reads a Qualisys TSV export's bytes.
    pub fn from_tsv(name: &str, bytes: &[u8]) -> Result<Self, RecordingError> {
        let t =
            parse_tsv(&String::from_utf8_lossy(bytes)).map_err(|source| RecordingError::Tsv {
                path: name.to_owned(),
                source,
            })?;
        Self::nonempty(Self {
            name: name.to_owned(),
            rate_hz: t.rate_hz,
            labels: t.marker_names,
            frames: t.frames,
            warnings: Vec::new(),
            file_units: "mm".into(),
            point_groups: Vec::new(),
        })
    }

    /// Reads a BVH file's bytes; positions are scaled by `bvh_metres_per_unit`.
    pub fn from_bvh(
        name: &str,
        bytes: &[u8],
        bvh_metres_per_unit: f64,
    ) -> Result<Self, RecordingError> {
        let b =
            parse_bvh(&String::from_utf8_lossy(bytes), bvh_metres_per_unit).map_err(|source| {
                RecordingError::Bvh {
                    path: name.to_owned(),
                    source,
                }
            })?;
        // The reader holds the frame time to 1/MAX_RATE_HZ..=1/MIN_RATE_HZ.
        let raw = 1.0 / b.frame_time_s;
        // "Frame Time: .0083333" means 120 Hz.
        let rate_hz = if (raw - raw.round()).abs() < 0.01 {
            raw.round()
        } else {
            raw
        };
        Self::nonempty(Self {
            name: name.to_owned(),
            rate_hz,
            labels: b.joint_names,
            frames: b.positions,
            warnings: Vec::new(),
            file_units: format!("BVH units ({bvh_metres_per_unit} m each)"),
            point_groups: Vec::new(),
        })
    }

    /// Reads a session file's bytes and groups its samples into frames
    /// ([`Recording::from_session`]).
    pub fn from_session_bytes(name: &str, bytes: &[u8]) -> Result<Self, RecordingError> {
        let sess = read_session(bytes).map_err(|source| RecordingError::Session {
            path: name.to_owned(),
            source,
        })?;
        Self::from_session(name, sess, bytes.len()).and_then(Self::nonempty)
    }

    /// Frames from a session's samples: grouped by receive time at the session's rate
    /// (frame `round((t - t0) · rate)`); the newest sample of a marker in a frame wins;
    /// markers with no sample in a frame are missing. Samples of no listed marker or with
    /// a non-finite time are left out. The frame table is refused when it would hold more
    /// than [`position_budget`]`(file_len)` positions (`file_len`: the session file's
    /// length), so samples far apart in time cannot ask for a huge table.
    pub fn from_session(name: &str, s: Session, file_len: usize) -> Result<Self, RecordingError> {
        let n = s.header.marker_names.len();
        let rate = s.header.rate_hz;
        if !rate_in_range(rate) {
            return Err(RecordingError::Rate {
                path: name.to_owned(),
                rate_hz: rate,
            });
        }
        let usable = |x: &&MarkerSample| (x.marker as usize) < n && x.time_s.is_finite();
        let (t0, t1) = s
            .samples
            .iter()
            .filter(usable)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                (lo.min(x.time_s), hi.max(x.time_s))
            });
        let mut frames: Vec<Vec<DVec3>> = Vec::new();
        if t0 <= t1 {
            // Infinite when the span overflows; the comparison below refuses it.
            let last = ((t1 - t0) * rate).round();
            let budget = position_budget(file_len);
            let most_frames = budget / n.max(1);
            if last.is_nan() || last >= most_frames as f64 {
                return Err(RecordingError::TooLong {
                    path: name.to_owned(),
                    span_s: t1 - t0,
                    rate_hz: rate,
                    frames: last + 1.0,
                    markers: n,
                    file_len,
                    budget,
                });
            }
            // `last` is a whole number below `most_frames`, so the cast is exact.
            frames = vec![vec![DVec3::NAN; n]; last as usize + 1];
            for x in s.samples.iter().filter(usable) {
                // Within 0..=last: t0 <= time_s <= t1 and rounding keeps the order.
                let f = ((x.time_s - t0) * rate).round() as usize;
                if let Some(slot) = frames
                    .get_mut(f)
                    .and_then(|row| row.get_mut(x.marker as usize))
                {
                    *slot = if x.occluded { DVec3::NAN } else { x.position_m };
                }
            }
        }
        Ok(Self {
            name: name.to_owned(),
            rate_hz: rate,
            labels: s.header.marker_names,
            frames,
            warnings: s.warnings,
            file_units: "m".into(),
            point_groups: Vec::new(),
        })
    }

    fn nonempty(self) -> Result<Self, RecordingError> {
        if self.frames.is_empty() {
            Err(RecordingError::Empty { path: self.name })
        } else {
            Ok(self)
        }
    }

    pub fn duration_secs(&self) -> f64 {
        self.frames.len() as f64 / self.rate_hz
    }

    /// What the recording holds, for `rigless info`.
    pub fn summary(&self) -> RecordingSummary {
        let n = self.labels.len();
        let mut missing = vec![0usize; n];
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for f in &self.frames {
            for (k, p) in f.iter().enumerate().take(n) {
                if p.is_finite() {
                    lo = lo.min(*p);
                    hi = hi.max(*p);
                } else {
                    missing[k] += 1;
                }
            }
        }
        let frames = self.frames.len().max(1) as f64;
        let total_missing: usize = missing.iter().sum();
        RecordingSummary {
            name: self.name.clone(),
            markers: n,
            rate_hz: self.rate_hz,
            frames: self.frames.len(),
            duration_secs: self.duration_secs(),
            gap_percent: 100.0 * total_missing as f64 / (frames * n.max(1) as f64),
            per_marker: self
                .labels
                .iter()
                .zip(&missing)
                .map(|(l, m)| MarkerSummary {
                    name: l.clone(),
                    gap_percent: 100.0 * *m as f64 / frames,
                })
                .collect(),
            bbox_min_m: lo.is_finite().then(|| lo.to_array()),
            bbox_max_m: hi.is_finite().then(|| hi.to_array()),
            warnings: self.warnings.clone(),
        }
    }
}

/// What a recording holds (positions in metres, world frame, Y up).
#[derive(Clone, Debug, serde::Serialize)]
pub struct RecordingSummary {
    pub name: String,
    pub markers: usize,
    pub rate_hz: f64,
    pub frames: usize,
    pub duration_secs: f64,
    /// Share of missing samples over all markers, percent.
    pub gap_percent: f64,
    pub per_marker: Vec<MarkerSummary>,
    /// Bounding box of every present sample (absent when none is).
    pub bbox_min_m: Option<[f64; 3]>,
    pub bbox_max_m: Option<[f64; 3]>,
    pub warnings: Vec<String>,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct MarkerSummary {
    pub name: String,
    pub gap_percent: f64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::replay::session::SessionHeader;

    fn session(names: usize, rate_hz: f64, samples: &[(u32, f64)]) -> Session {
        Session {
            header: SessionHeader {
                marker_names: (0..names).map(|i| format!("m{i}")).collect(),
                rate_hz,
                started_unix_s: 0.0,
                inputs: vec![],
            },
            samples: samples
                .iter()
                .map(|&(marker, time_s)| MarkerSample {
                    marker,
                    time_s,
                    source_time_s: time_s,
                    position_m: DVec3::new(time_s, 1.0, 2.0),
                    occluded: false,
                })
                .collect(),
            warnings: vec![],
        }
    }

    #[test]
    fn sessions_group_samples_into_frames_at_their_rate() {
        // 100 Hz: 0.004 s after the first sample rounds into frame 0, 0.016 s into frame
        // 2 (neither near a tie of the rounding). Marker 5 is not listed, NaN has no frame.
        let s = session(
            2,
            100.0,
            &[
                (0, 10.0),
                (1, 10.004),
                (0, 10.016),
                (5, 10.0),
                (1, f64::NAN),
            ],
        );
        let r = Recording::from_session("s", s, 1000).unwrap();
        assert_eq!(r.frames.len(), 3);
        assert_eq!(r.frames[0][0], DVec3::new(10.0, 1.0, 2.0));
        assert_eq!(r.frames[0][1], DVec3::new(10.004, 1.0, 2.0));
        assert!(!r.frames[1][0].is_finite() && !r.frames[1][1].is_finite());
        assert_eq!(r.frames[2][0], DVec3::new(10.016, 1.0, 2.0));
    }

    #[test]
    fn a_session_table_is_held_to_the_position_budget() {
        // Two samples 800,000 s apart at 120 Hz: 96 million frames for a small file.
        let far = session(2, 120.0, &[(0, 0.0), (1, 800_000.0)]);
        match Recording::from_session("s", far, 233) {
            Err(RecordingError::TooLong {
                frames,
                markers: 2,
                budget,
                ..
            }) => {
                assert_eq!(frames, 96_000_001.0);
                assert_eq!(budget, FREE_POSITIONS + 233 * POSITIONS_PER_BYTE);
            }
            other => panic!("{other:?}"),
        }
        // Times whose difference overflows.
        let inf = session(1, 120.0, &[(0, -1e308), (0, 1e308)]);
        assert!(matches!(
            Recording::from_session("s", inf, 100),
            Err(RecordingError::TooLong { frames, .. }) if frames.is_infinite()
        ));
        // The largest table the budget allows is read.
        let markers = 4;
        let last = (position_budget(0) / markers - 1) as f64;
        let edge = session(markers, 100.0, &[(0, 0.0), (3, last / 100.0)]);
        assert_eq!(
            Recording::from_session("s", edge, 0).unwrap().frames.len(),
            position_budget(0) / markers
        );
        for rate_hz in [0.0, -100.0, f64::NAN, 1e9] {
            assert!(matches!(
                Recording::from_session("s", session(1, rate_hz, &[(0, 0.0)]), 100),
                Err(RecordingError::Rate { .. })
            ));
        }
    }

    #[test]
    fn summary_counts_gaps_per_marker_and_bounds_present_samples() {
        let rec = Recording {
            name: "r".into(),
            rate_hz: 50.0,
            labels: vec!["a".into(), "b".into()],
            frames: vec![
                vec![DVec3::new(1.0, 2.0, 3.0), DVec3::NAN],
                vec![DVec3::new(-1.0, 0.0, 5.0), DVec3::NAN],
                vec![DVec3::NAN, DVec3::ZERO],
                vec![DVec3::ZERO, DVec3::ZERO],
            ],
            warnings: vec![],
            file_units: "mm".into(),
            point_groups: Vec::new(),
        };
        let s = rec.summary();
        assert_eq!((s.markers, s.frames, s.duration_secs), (2, 4, 0.08));
        assert_eq!(s.per_marker[0].gap_percent, 25.0);
        assert_eq!(s.per_marker[1].gap_percent, 50.0);
        assert_eq!(s.gap_percent, 37.5);
        assert_eq!(s.bbox_min_m, Some([-1.0, 0.0, 0.0]));
        assert_eq!(s.bbox_max_m, Some([1.0, 2.0, 5.0]));
    }
}
