//! The `[recorder]` table of a stage config: where the session recorder writes every
//! incoming sample, with the section's own checks ([`RecorderConfig::problems`]).

use std::path::PathBuf;

/// `[recorder]`: record every incoming sample to a session file (off unless `path` is
/// set).
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecorderConfig {
    /// Session file to write (`.rlsession`), relative to the stage config's folder;
    /// `{time}` is replaced by the start time (UTC, `YYYYmmdd-HHMMSS`).
    pub path: Option<PathBuf>,
    /// Longest time between writes to the file, seconds: a killed daemon loses at most
    /// this much.
    pub flush_interval_secs: f64,
}

impl Default for RecorderConfig {
    fn default() -> Self {
        Self {
            path: None,
            flush_interval_secs: 0.5,
        }
    }
}

impl RecorderConfig {
    /// What is wrong, as `(key, message)` with keys relative to `[recorder]`.
    pub fn problems(&self) -> Vec<(String, String)> {
        let f = self.flush_interval_secs;
        if f.is_finite() && f > 0.0 && f <= 60.0 {
            Vec::new()
        } else {
            vec![(
                "flush_interval_secs".into(),
                format!("must be in (0, 60] seconds, got {f}"),
            )]
        }
    }

    /// The session file for a run started at `unix_s`: `path` under `base_dir`, with
    /// `{time}` replaced by that time (UTC, `YYYYmmdd-HHMMSS`).
    pub fn path_at(&self, base_dir: &std::path::Path, unix_s: f64) -> Option<PathBuf> {
        let p = base_dir.join(self.path.as_ref()?);
        Some(PathBuf::from(
            p.to_string_lossy().replace("{time}", &utc_stamp(unix_s)),
        ))
    }
}

/// `YYYYmmdd-HHMMSS` (UTC) of a Unix time.
pub fn utc_stamp(unix_s: f64) -> String {
    let secs = unix_s.max(0.0) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + (m <= 2) as i64;
    format!(
        "{y:04}{m:02}{d:02}-{:02}{:02}{:02}",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamps_are_utc_calendar_times() {
        assert_eq!(utc_stamp(0.0), "19700101-000000");
        // 2000-02-29 (a leap day of a century divisible by 400) 12:34:56 UTC.
        assert_eq!(utc_stamp(951_827_696.0), "20000229-123456");
        assert_eq!(utc_stamp(1_798_761_599.0), "20261231-235959");
        let cfg = RecorderConfig {
            path: Some("takes/{time}.rlsession".into()),
            ..RecorderConfig::default()
        };
        assert_eq!(
            cfg.path_at(std::path::Path::new("/stage"), 0.0),
            Some(PathBuf::from("/stage/takes/19700101-000000.rlsession"))
        );
    }
}
