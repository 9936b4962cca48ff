//! Qualisys Track Manager TSV exports (3D data): the header (`NO_OF_FRAMES`,
//! `FREQUENCY`, `MARKER_NAMES`, ...), an optional `Frame Time ...` column line, then one
//! line per frame with X Y Z per marker in millimetres, Z up. Read into metres, Y up
//! (right-handed: `(x, y, z)` becomes `(x, z, -y)`). Missing samples (`NaN`, empty fields,
//! or an exact `0 0 0` as older exports write) become NaN.

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
    #[error("line {line}: {what}")]
    Header { line: usize, what: String },
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
            match first {
                "FREQUENCY" => {
                    let v = fields.next().unwrap_or("").trim();
                    let f: f64 = v.parse().map_err(|_| TsvError::Header {
                        line: n,
                        what: format!("FREQUENCY {v:?} is not a number"),
                    })?;
                    if !(f.is_finite() && f > 0.0 && f <= 100_000.0) {
                        return Err(TsvError::Header {
                            line: n,
                            what: format!("FREQUENCY {f} is not a rate in Hz"),
                        });
                    }
                    rate_hz = Some(f);
                }
                "MARKER_NAMES" => {
                    let v: Vec<String> = fields.map(|s| s.trim().to_owned()).collect();
                    if v.is_empty() || v.len() > MAX_MARKERS {
                        return Err(TsvError::Header {
                            line: n,
                            what: format!("{} marker names (1 to {MAX_MARKERS})", v.len()),
                        });
                    }
                    names = Some(v);
                }
                "Frame" => has_frame_time = true,
                _ => {}
            }
            continue;
        }
        let names = names.as_ref().ok_or(TsvError::NoMarkerNames)?;
        if rate_hz.is_none() {
            return Err(TsvError::NoFrequency);
        }
        let skip = if has_frame_time { 2 } else { 0 };
        let expected = skip + 3 * names.len();
        let values: Vec<&str> = line.split('\t').collect();
        // Trailing empty columns are allowed (some exports end lines with a tab).
        let found = values.len();
        if found < expected || values[expected..].iter().any(|v| !v.trim().is_empty()) {
            return Err(TsvError::Columns {
                line: n,
                expected,
                found,
            });
        }
        let mut row = Vec::with_capacity(names.len());
        for k in 0..names.len() {
            let mut c = [0.0f64; 3];
            for (a, slot) in c.iter_mut().enumerate() {
                let col = skip + 3 * k + a;
                let s = values[col].trim();
                *slot = if s.is_empty() || s.eq_ignore_ascii_case("nan") {
                    f64::NAN
                } else {
                    s.parse().map_err(|_| TsvError::Number {
                        line: n,
                        column: col + 1,
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
        frames.push(row);
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
