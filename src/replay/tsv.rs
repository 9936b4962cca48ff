//! Qualisys Track Manager TSV exports (3D data): the header (`NO_OF_FRAMES`,
//! `FREQUENCY`, `MARKER_NAMES`, ...), an optional `Frame Time ...` column line, then one
//! line per frame with X Y Z per marker in millimetres, Z up. Read into metres, Y up
//! (right-handed: `(x, y, z)` becomes `(x, z, -y)`). Missing samples (`NaN`, empty fields,
//! or an exact `0 0 0` as older exports write) become NaN.
//!
//! Hostile files: `FREQUENCY` is held to `recording`'s rate limits and `MARKER_NAMES` to
//! [`MAX_MARKERS`]; a frame's positions (24 bytes each) come from its line's fields (at
//! least 3 bytes each), so the file's length bounds the frames. Lines are read field by
//! field, without a field table.

use super::recording::{rate_in_range, MAX_RATE_HZ, MIN_RATE_HZ};
use crate::geom::axes::y_up_from_z_up;
use glam::DVec3;

/// Most markers a file may declare (a bound on allocation before any frame is read).
pub const MAX_MARKERS: usize = 10_000;

/// A TSV recording.
#[derive(Clone, Debug)]
pub struct TsvRecording {
    pub rate_hz: f64,
    pub marker_names: Vec<String>,
    /// `frames[f][k]`, metres, world frame (Y up); NaN where missing.
    pub frames: Vec<Vec<DVec3>>,
}

/// Why a TSV file cannot be read, with its line (1-based).
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TsvError {
    #[error("line {line}: {field} {text:?} is not a number")]
    HeaderNumber {
        line: usize,
        field: &'static str,
        text: String,
    },
    #[error("line {line}: FREQUENCY {value:?} Hz is outside {MIN_RATE_HZ}..={MAX_RATE_HZ} Hz")]
    Rate { line: usize, value: f64 },
    #[error("line {line}: {count} MARKER_NAMES (1 to {MAX_MARKERS})")]
    MarkerCount { line: usize, count: usize },
    #[error("no MARKER_NAMES line before the data")]
    NoMarkerNames,
    #[error("no FREQUENCY line before the data")]
    NoFrequency,
    #[error("line {line}: expected {expected} values, found {found}")]
    Columns {
        line: usize,
        expected: usize,
        found: usize,
    },
    #[error("line {line}, column {column}: {text:?} is not a number")]
    Number {
        line: usize,
        column: usize,
        text: String,
    },
}

/// A header line's value (`FREQUENCY`, `MARKER_NAMES`) taken into `rate_hz` or `names`;
/// other header lines are ignored.
fn header_line<'a>(
    n: usize,
    first: &str,
    mut fields: impl Iterator<Item = &'a str> + Clone,
    rate_hz: &mut Option<f64>,
    names: &mut Option<Vec<String>>,
) -> Result<(), TsvError> {
    match first {
        "FREQUENCY" => {
            let v = fields.next().unwrap_or("").trim();
            let f: f64 = v.parse().map_err(|_| TsvError::HeaderNumber {
                line: n,
                field: "FREQUENCY",
                text: v.chars().take(32).collect(),
            })?;
            if !rate_in_range(f) {
                return Err(TsvError::Rate { line: n, value: f });
            }
            *rate_hz = Some(f);
        }
        "MARKER_NAMES" => {
            let count = fields.clone().count();
            if count == 0 || count > MAX_MARKERS {
                return Err(TsvError::MarkerCount { line: n, count });
            }
            *names = Some(fields.map(|s| s.trim().to_owned()).collect());
        }
        _ => {}
    }
    Ok(())
}

/// One frame line: 3 values per marker after `skip` leading columns, in metres, Y up.
fn frame_line(n: usize, line: &str, skip: usize, markers: usize) -> Result<Vec<DVec3>, TsvError> {
    let expected = skip + 3 * markers;
    let mut values = line.split('\t');
    let columns = || TsvError::Columns {
        line: n,
        expected,
        found: line.split('\t').count(),
    };
    let mut row = Vec::with_capacity(markers);
    for _ in 0..skip {
        values.next().ok_or_else(columns)?;
    }
    for k in 0..markers {
        let mut c = [0.0f64; 3];
        for (a, slot) in c.iter_mut().enumerate() {
            let s = values.next().ok_or_else(columns)?.trim();
            *slot = if s.is_empty() || s.eq_ignore_ascii_case("nan") {
                f64::NAN
            } else {
                s.parse().map_err(|_| TsvError::Number {
                    line: n,
                    column: skip + 3 * k + a + 1,
                    text: s.chars().take(32).collect(),
                })?
            };
        }
        let p = if c == [0.0; 3] || c.iter().any(|v| !v.is_finite()) {
            DVec3::NAN
        } else {
            y_up_from_z_up(DVec3::new(c[0], c[1], c[2])) * 1e-3
        };
        row.push(p);
    }
    // Trailing empty columns are allowed (some exports end lines with a tab).
    if values.any(|v| !v.trim().is_empty()) {
        return Err(columns());
    }
    Ok(row)
}

/// Parses a TSV export from its text.
pub fn parse_tsv(text: &str) -> Result<TsvRecording, TsvError> {
    let mut rate_hz = None;
    let mut names: Option<Vec<String>> = None;
    let mut frames = Vec::new();
    let mut has_frame_time = false;
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let line = line.trim_end_matches('\r');
        if line.trim().is_empty() {
            continue;
        }
        let mut fields = line.split('\t');
        let first = fields.next().unwrap_or("");
        let starts_numeric = first
            .trim()
            .chars()
            .next()
            .is_some_and(|c| c.is_ascii_digit() || c == '-' || c == '.');
        if !starts_numeric && frames.is_empty() {
            if first == "Frame" {
                has_frame_time = true;
            } else {
                header_line(n, first, fields, &mut rate_hz, &mut names)?;
            }
            continue;
        }
        let names = names.as_ref().ok_or(TsvError::NoMarkerNames)?;
        if rate_hz.is_none() {
            return Err(TsvError::NoFrequency);
        }
        let skip = if has_frame_time { 2 } else { 0 };
        frames.push(frame_line(n, line, skip, names.len())?);
    }
    Ok(TsvRecording {
        rate_hz: rate_hz.ok_or(TsvError::NoFrequency)?,
        marker_names: names.ok_or(TsvError::NoMarkerNames)?,
        frames,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const SMALL: &str = "NO_OF_FRAMES\t2\nFREQUENCY\t100\nMARKER_NAMES\ta\tb\n\
        Frame\tTime\ta X\ta Y\ta Z\tb X\tb Y\tb Z\n\
        1\t0.000\t1000.0\t2000.0\t3000.0\t0.000\t0.000\t0.000\n\
        2\t0.010\t1000.0\t2000.0\t3000.0\tNaN\t\t5\n";

    #[test]
    fn reads_metres_y_up_and_missing_samples() {
        let r = parse_tsv(SMALL).unwrap();
        assert_eq!(r.rate_hz, 100.0);
        assert_eq!(r.marker_names, ["a", "b"]);
        assert_eq!(r.frames.len(), 2);
        assert_eq!(r.frames[0][0], DVec3::new(1.0, 3.0, -2.0));
        assert!(!r.frames[0][1].is_finite());
        assert!(!r.frames[1][1].is_finite());
    }

    #[test]
    fn errors_name_the_line() {
        let bad = SMALL.replace("1000.0\t2000.0\t3000.0\tNaN", "1000.0\tx\t3000.0\tNaN");
        assert_eq!(
            parse_tsv(&bad).unwrap_err(),
            TsvError::Number {
                line: 6,
                column: 4,
                text: "x".into()
            }
        );
        let short = SMALL.replace("\tNaN\t\t5", "");
        assert!(matches!(
            parse_tsv(&short),
            Err(TsvError::Columns { line: 6, .. })
        ));
    }

    #[test]
    fn header_values_out_of_range_are_named() {
        for (text, value) in [
            ("0", 0.0),
            ("-100", -100.0),
            ("1e-300", 1e-300),
            ("1e9", 1e9),
        ] {
            let t = SMALL.replace("FREQUENCY\t100", &format!("FREQUENCY\t{text}"));
            assert_eq!(
                parse_tsv(&t).unwrap_err(),
                TsvError::Rate { line: 2, value }
            );
        }
        let t = SMALL.replace("FREQUENCY\t100", "FREQUENCY\tfast");
        assert_eq!(
            parse_tsv(&t).unwrap_err(),
            TsvError::HeaderNumber {
                line: 2,
                field: "FREQUENCY",
                text: "fast".into()
            }
        );
        let many = "\tm".repeat(MAX_MARKERS + 1);
        let t = SMALL.replace("MARKER_NAMES\ta\tb", &format!("MARKER_NAMES{many}"));
        assert_eq!(
            parse_tsv(&t).unwrap_err(),
            TsvError::MarkerCount {
                line: 3,
                count: MAX_MARKERS + 1
            }
        );
        let t = SMALL.replace("MARKER_NAMES\ta\tb", "MARKER_NAMES");
        assert_eq!(
            parse_tsv(&t).unwrap_err(),
            TsvError::MarkerCount { line: 3, count: 0 }
        );
        // Trailing tabs are allowed, a value past the last marker is not.
        let t = SMALL.replace("\t5\n", "\t5\t\t\n");
        assert_eq!(parse_tsv(&t).unwrap().frames.len(), 2);
        let t = SMALL.replace("\t5\n", "\t5\t\t7\n");
        assert_eq!(
            parse_tsv(&t).unwrap_err(),
            TsvError::Columns {
                line: 6,
                expected: 8,
                found: 10
            }
        );
    }

    proptest! {
        #[test]
        fn arbitrary_text_never_panics(s in "(?s).{0,400}") {
            let _ = parse_tsv(&s);
        }

        #[test]
        fn arbitrary_bytes_never_panic(b in proptest::collection::vec(any::<u8>(), 0..400)) {
            let _ = parse_tsv(&String::from_utf8_lossy(&b));
        }
    }
}
