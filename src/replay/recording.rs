//! A recording as the replayer plays it: labelled marker trajectories at a fixed rate, from
//! a C3D or TSV file (or a bundled session), and the mapping of its labels onto a
//! character's markers.

use super::bvh::{parse_bvh, BvhError};
use super::c3d::{read_c3d, C3dError};
use super::session::{read_session, Session, SessionError};
use super::tsv::{parse_tsv, TsvError};
use glam::DVec3;
use std::path::Path;

/// Metres per BVH unit unless told otherwise (centimetres, the commonest convention).
pub const DEFAULT_BVH_METRES_PER_UNIT: f64 = 0.01;

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
}

impl Recording {
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
        })
        .and_then(Self::nonempty)
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
        let bytes = std::fs::read(path).map_err(|source| RecordingError::Read {
            path: shown.clone(),
            source,
        })?;
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        match ext.as_str() {
            "c3d" => Self::from_c3d(&shown, &bytes),
            "tsv" => {
                let t = parse_tsv(&String::from_utf8_lossy(&bytes)).map_err(|source| {
                    RecordingError::Tsv {
                        path: shown.clone(),
                        source,
                    }
                })?;
                Self::nonempty(Self {
                    name: shown,
                    rate_hz: t.rate_hz,
                    labels: t.marker_names,
                    frames: t.frames,
                    warnings: Vec::new(),
                    file_units: "mm".into(),
                })
            }
            "bvh" => {
                let b = parse_bvh(&String::from_utf8_lossy(&bytes), bvh_metres_per_unit).map_err(
                    |source| RecordingError::Bvh {
                        path: shown.clone(),
                        source,
                    },
                )?;
                let raw = 1.0 / b.frame_time_s;
                // "Frame Time: .0083333" means 120 Hz.
                let rate_hz = if (raw - raw.round()).abs() < 0.01 {
                    raw.round()
                } else {
                    raw
                };
                Self::nonempty(Self {
                    name: shown,
                    rate_hz,
                    labels: b.joint_names,
                    frames: b.positions,
                    warnings: Vec::new(),
                    file_units: format!("BVH units ({bvh_metres_per_unit} m each)"),
                })
            }
            "rlsession" => {
                let sess = read_session(&bytes).map_err(|source| RecordingError::Session {
                    path: shown.clone(),
                    source,
                })?;
                Self::nonempty(Self::from_session(&shown, sess))
            }
            _ => Err(RecordingError::Format { path: shown }),
        }
    }

    /// Frames from a session's samples: grouped by receive time at the session's rate
    /// (frame `round((t - t0) · rate)`); the newest sample of a marker in a frame wins;
    /// markers with no sample in a frame are missing.
    pub fn from_session(name: &str, s: Session) -> Self {
        let n = s.header.marker_names.len();
        let rate = s.header.rate_hz;
        let t0 = s
            .samples
            .iter()
            .map(|x| x.time_s)
            .fold(f64::INFINITY, f64::min);
        let mut frames: Vec<Vec<DVec3>> = Vec::new();
        for x in &s.samples {
            let k = x.marker as usize;
            if k >= n || !x.time_s.is_finite() {
                continue;
            }
            let f = ((x.time_s - t0) * rate).round().max(0.0) as usize;
            // A sample years away would ask for a huge frame table: skip it.
            if f > 100_000_000 {
                continue;
            }
            if frames.len() <= f {
                frames.resize(f + 1, vec![DVec3::NAN; n]);
            }
            frames[f][k] = if x.occluded { DVec3::NAN } else { x.position_m };
        }
        Self {
            name: name.to_owned(),
            rate_hz: rate,
            labels: s.header.marker_names,
            frames,
            warnings: s.warnings,
            file_units: "m".into(),
        }
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
