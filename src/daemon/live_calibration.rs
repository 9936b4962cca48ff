//! A stage's `[calibration] first_secs`: before the stage binds its character, its marker
//! inputs run for that long ([`super::capture`]), and when labels arrived that the
//! character's layout lacks (or `always`), the capture is calibrated onto the character
//! ([`crate::calibrate::calibrate`]); the stage then binds the character with that layout
//! and scales incoming markers by the scale found. With `write`, the layout and scale go
//! into the character file as `rigless calibrate --write` puts them.

use super::capture::{capture, CaptureError};
use crate::calibrate::config::LiveCalibrationConfig;
use crate::calibrate::labels::MapEntry;
use crate::calibrate::layout::{write_into, LayoutError};
use crate::calibrate::marker_sets::by_name;
use crate::calibrate::{calibrate, Calibration, CalibrationError, CalibrationOptions, Verdict};
use crate::character::bind_params::BindParams;
use crate::character::roles::Role;
use crate::character::{Character, MarkerDef};
use crate::input::config::InputConfig;
use crate::markers::index::{MarkerIndex, SubjectFilter};
use crate::replay::recording::Recording;
use crate::rig::bind::{BindError, BindStage, Rig};
use crate::runtime::clock::Clock;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Why calibrating from live input failed.
#[derive(Debug, thiserror::Error)]
pub enum LiveCalibrationError {
    #[error("capturing live input to calibrate from: {0}")]
    Capture(#[from] CaptureError),
    #[error("calibrating {seconds} s of live input onto {character}: {source}")]
    Calibrate {
        seconds: f64,
        character: String,
        source: Box<CalibrationError>,
    },
    #[error("binding {character} with the layout calibrated from live input: {source}")]
    Bind {
        character: String,
        source: BindError,
    },
    #[error("writing the calibrated layout into {path}: {source}")]
    Write {
        path: String,
        source: Box<LayoutError>,
    },
    #[error(
        "calibrating {seconds} s of live input onto {character} failed: {concerns}; the stage \
         does not start with it (stand in the character's rest pose at the start, or \
         calibrate a take with `rigless calibrate` and write it into the character file)"
    )]
    Failed {
        seconds: f64,
        character: String,
        concerns: String,
    },
    #[error(
        "the calibrated layout was not written into {path}: the file with it would not load \
         ({source}); the file is unchanged"
    )]
    Refused {
        path: String,
        source: Box<crate::character::file::CharacterError>,
    },
    #[error("writing the calibrated layout into {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
}

/// What calibrating from live input did.
#[derive(Clone, Debug)]
pub struct LiveCalibration {
    /// Seconds captured, and the frames and labels that arrived.
    pub seconds: f64,
    pub frames: usize,
    pub labels: usize,
    /// The calibration; `None` when the character's layout already had every label that
    /// arrived (and `always` was not set).
    pub calibration: Option<Calibration>,
    /// The character file the layout was written into (its old text kept as FILE.bak).
    pub written: Option<PathBuf>,
}

impl LiveCalibration {
    /// One line for the user.
    pub fn describe(&self) -> String {
        let head = format!(
            "calibration from {:.1} s of live input ({} frames, {} labels)",
            self.seconds, self.frames, self.labels
        );
        let Some(c) = &self.calibration else {
            return format!("{head}: the layout already has every label, kept");
        };
        let flagged = c.placed.iter().filter(|p| p.flag.is_some()).count();
        let mut s = format!(
            "{head}: {} placed, {} left out, {flagged} flagged; the actor is {:.3} times the character; misfit {:.1} mm RMS, {:.1} mm max",
            c.placed.len(),
            c.left_out.len(),
            1.0 / c.scale,
            c.residual_mm_rms,
            c.residual_mm_max
        );
        if let Some(p) = &self.written {
            s.push_str(&format!("; written into {}", p.display()));
        }
        s
    }
}

/// What a live calibration needs of the character.
pub struct Target<'a> {
    pub character: &'a Character,
    pub bind: &'a BindParams,
    /// The bind settings for a new layout (a character file chooses its default cell
    /// size for the markers: [`crate::character::file::LoadedCharacter::bind_for`]).
    pub bind_for: &'a dyn Fn(&[MarkerDef]) -> BindParams,
    pub roles: &'a [Option<Role>],
    /// The character file's `[calibration.bones]`.
    pub map: Vec<MapEntry>,
    /// The character file, when there is one (for `write`).
    pub file: Option<&'a Path>,
}

/// Captures `cfg.first_secs` of the marker `inputs` on `clock` and calibrates them onto
/// `target` (see the module); `None` when `cfg` asks for no live calibration. With a
/// calibration, also the character bound with its layout (labels the bind refuses left
/// out), reporting to `progress`.
pub fn calibrate_live(
    cfg: &LiveCalibrationConfig,
    inputs: &[InputConfig],
    base_dir: &Path,
    clock: &Arc<dyn Clock>,
    target: Target<'_>,
    progress: &mut dyn FnMut(BindStage, f64),
) -> Result<Option<(LiveCalibration, Option<Rig>)>, LiveCalibrationError> {
    match capture_first_secs(cfg, inputs, base_dir, clock, &SubjectFilter::One)? {
        Some((seconds, rec)) => calibrate_captured(cfg, seconds, &rec, target, progress).map(Some),
        None => Ok(None),
    }
}

/// Captures `cfg.first_secs` of the marker `inputs` on `clock` once, for the live
/// calibration of each actor of a stage of several ([`calibrate_captured`] on each's
/// labels); `None` when `cfg` asks for no live calibration.
pub fn capture_for_calibration(
    cfg: &LiveCalibrationConfig,
    inputs: &[InputConfig],
    base_dir: &Path,
    clock: &Arc<dyn Clock>,
) -> Result<Option<(f64, Recording)>, LiveCalibrationError> {
    capture_first_secs(cfg, inputs, base_dir, clock, &SubjectFilter::All)
}

/// `cfg.first_secs` of the marker `inputs` on `clock`, the labels of the subjects
/// `subject` says, and how long; `None` when `cfg` asks for no live calibration.
fn capture_first_secs(
    cfg: &LiveCalibrationConfig,
    inputs: &[InputConfig],
    base_dir: &Path,
    clock: &Arc<dyn Clock>,
    subject: &SubjectFilter,
) -> Result<Option<(f64, Recording)>, LiveCalibrationError> {
    let Some(seconds) = cfg.first_secs else {
        return Ok(None);
    };
    let (rec, _) = capture(inputs, base_dir, clock, seconds, "live input", subject)?;
    Ok(Some((seconds, rec)))
}

/// Calibrates `rec` (`seconds` of live input already captured) onto `target`, as
/// [`calibrate_live`] does after its capture.
pub fn calibrate_captured(
    cfg: &LiveCalibrationConfig,
    seconds: f64,
    rec: &Recording,
    target: Target<'_>,
    progress: &mut dyn FnMut(BindStage, f64),
) -> Result<(LiveCalibration, Option<Rig>), LiveCalibrationError> {
    let mut out = LiveCalibration {
        seconds,
        frames: rec.frames.len(),
        labels: rec.labels.len(),
        calibration: None,
        written: None,
    };
    let ch = target.character;
    let names: Vec<String> = ch.markers.iter().map(|m| m.name.clone()).collect();
    let index = MarkerIndex::fixed(&names);
    let seen = |k: usize| rec.frames.iter().any(|f| f[k].is_finite());
    let lacking = (0..rec.labels.len()).any(|k| seen(k) && index.get(&rec.labels[k]).is_none());
    if !(lacking || cfg.always) {
        return Ok((out, None));
    }
    let opts = CalibrationOptions {
        frames: cfg.frames,
        // Checked with the config: "auto" or a known table.
        marker_set: by_name(&cfg.marker_set),
        map: target.map,
        max_marker_distance_m: target.bind.max_marker_distance_m,
        ..CalibrationOptions::default()
    };
    let mut cal = calibrate(ch, target.roles, rec.as_take(), &opts).map_err(|source| {
        LiveCalibrationError::Calibrate {
            seconds,
            character: ch.name.clone(),
            source: Box::new(source),
        }
    })?;
    let params = (target.bind_for)(&cal.layout(ch));
    let rig = cal
        .bind(ch, &params, progress)
        .map_err(|source| LiveCalibrationError::Bind {
            character: ch.name.clone(),
            source,
        })?;
    if cal.verdict() == Verdict::Failed {
        return Err(LiveCalibrationError::Failed {
            seconds,
            character: ch.name.clone(),
            concerns: cal
                .concerns()
                .iter()
                .filter(|c| c.verdict() == Verdict::Failed)
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join("; "),
        });
    }
    if let (true, Some(path)) = (cfg.write, target.file) {
        write_layout(path, &cal)?;
        out.written = Some(path.to_path_buf());
    }
    out.calibration = Some(cal);
    Ok((out, Some(rig)))
}

/// Writes `cal` into the character file at `path`, keeping the old text as FILE.bak.
pub fn write_layout(path: &Path, cal: &Calibration) -> Result<(), LiveCalibrationError> {
    let shown = path.display().to_string();
    let io = |source| LiveCalibrationError::Io {
        path: shown.clone(),
        source,
    };
    let text = std::fs::read_to_string(path).map_err(io)?;
    let new = write_into(&text, &shown, cal).map_err(|source| LiveCalibrationError::Write {
        path: shown.clone(),
        source: Box::new(source),
    })?;
    // The new file is loaded as a stage would load it before it replaces the old one
    // (beside it, so its mesh path resolves alike): nothing the loader refuses is
    // written.
    let stem = path.file_stem().unwrap_or_default().to_string_lossy();
    let trial = path.with_file_name(format!(".{stem}.rigless-new.toml"));
    std::fs::write(&trial, &new).map_err(io)?;
    if let Err(source) = crate::character::file::load_character(&trial) {
        std::fs::remove_file(&trial).map_err(io)?;
        return Err(LiveCalibrationError::Refused {
            path: shown,
            source: Box::new(source),
        });
    }
    let mut bak = path.as_os_str().to_owned();
    bak.push(".bak");
    std::fs::write(PathBuf::from(bak), &text).map_err(io)?;
    std::fs::rename(&trial, path).map_err(io)
}
