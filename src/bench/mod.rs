//! Benchmark suites behind `rigless bench`: each yields one record per case with the stable
//! field names of DESIGN.md's quality table, and writes it as a table row or a JSON line
//! as soon as it is measured ([`run_suite`]). Timing uses the monotonic clock around the
//! measured step only; setup is excluded and reported separately (`factor_s`).

pub mod actors;
pub mod assets;
pub mod calibration;
pub mod capsules;
pub mod characters;
pub mod codecs;
pub mod exercise;
pub mod export;
pub mod gapfill;
pub mod live;
pub mod replay;
pub mod truth;

use crate::runtime::stats::percentile;
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

/// The suites (`rigless bench --suite NAME`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Suite {
    /// Plain ARAP on the benchmark tet meshes of the shared data folder.
    Capsules,
    /// The procedural hand and body playing their motions, both methods.
    Characters,
    /// The marker buffer's fill error by gap length.
    Gapfill,
    /// The whole pipeline in real time: latency from input to client, missed ticks.
    Live,
    /// Decode cost per packet of each input format, 50 markers.
    Codecs,
    /// Send-time jitter of `rigless replay` against the file's clock.
    Replay,
    /// `rigless calibrate`'s time and accuracy, on known truth and real takes.
    Calibration,
    /// `rigless replay --export`'s speed: takes solved off line into a point cache.
    Export,
    /// Known truth on real assets: their own animations through their own skinning,
    /// a marker set on the skin, calibrated and solved, held against the skinned mesh.
    Truth,
    /// Stages of several performers: 1 to 8 bodies in real time, a label swap between
    /// two, two real takes in one.
    Actors,
}

/// How the suites run.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// The shared data folder (holds `tetmesh/`, `hand/`, `c3d/`).
    pub data: PathBuf,
    /// Seconds per case of the `live` and `replay` suites.
    pub seconds: f64,
    /// One JSON object per line instead of a table.
    pub json: bool,
}

/// Why a suite could not run.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("writing the results: {0}")]
    Write(#[from] std::io::Error),
    #[error("encoding a record: {0}")]
    Json(#[from] serde_json::Error),
    #[error(
        "{dir} not found: the {suite} suite needs the shared benchmark data (pass --data DIR)"
    )]
    NoData { suite: &'static str, dir: String },
    #[error("{case}: {source}")]
    Case {
        case: String,
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

impl BenchError {
    /// A case's failure.
    pub fn case(
        case: impl Into<String>,
        source: impl std::error::Error + Send + Sync + 'static,
    ) -> Self {
        BenchError::Case {
            case: case.into(),
            source: Box::new(source),
        }
    }
}

/// Runs `suite`, writing a line per case to `out` as it is measured.
pub fn run_suite(suite: Suite, opts: &BenchOptions, out: &mut dyn Write) -> Result<(), BenchError> {
    match suite {
        Suite::Capsules => capsules::suite(&opts.data, opts.json, out),
        Suite::Characters => characters::suite(&opts.data, opts.json, out),
        Suite::Gapfill => gapfill::suite(&opts.data, opts.json, out),
        Suite::Live => live::suite(opts.seconds, opts.json, out),
        Suite::Codecs => codecs::suite(opts.json, out),
        Suite::Replay => replay::suite(opts.seconds, opts.json, out),
        Suite::Calibration => calibration::suite(&opts.data, opts.json, out),
        Suite::Export => export::suite(opts.json, out),
        Suite::Truth => truth::suite(&opts.data, opts.json, out),
        Suite::Actors => actors::suite(&opts.data, opts.seconds, opts.json, out),
    }
}

/// Writes `record` as one JSON line.
fn json_line(out: &mut dyn Write, record: &impl serde::Serialize) -> Result<(), BenchError> {
    writeln!(out, "{}", serde_json::to_string(record)?)?;
    Ok(())
}

/// Median and spread of a set of durations, in milliseconds.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Spread {
    pub median_ms: f64,
    pub p10_ms: f64,
    pub p90_ms: f64,
    pub p99_ms: f64,
    pub min_ms: f64,
    pub max_ms: f64,
}

impl Spread {
    pub fn of(samples: &[Duration]) -> Self {
        let mut ms: Vec<f64> = samples.iter().map(|d| d.as_secs_f64() * 1e3).collect();
        let mut q = |p: f64| percentile(&mut ms, p);
        Self {
            median_ms: q(0.5),
            p10_ms: q(0.1),
            p90_ms: q(0.9),
            p99_ms: q(0.99),
            min_ms: q(0.0),
            max_ms: q(1.0),
        }
    }
}
