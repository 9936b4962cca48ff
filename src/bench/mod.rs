//! Benchmark suites behind `rigless bench`: each yields one record per case with the stable
//! field names of DESIGN.md's quality table. Timing uses the monotonic clock around the
//! measured step only; setup is excluded and reported separately (`factor_s`).

pub mod capsules;
pub mod characters;
pub mod codecs;
pub mod gapfill;
pub mod live;

use crate::runtime::stats::percentile;
use std::time::Duration;

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
