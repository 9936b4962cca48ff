//! The `[solver]` table of a stage config: the fixed-rate loop's rate and deadline and
//! the frame solver's method and settings, each key documented, unknown keys refused,
//! with the section's own checks ([`SolverConfig::problems`]).

use super::frame::Method;

/// `[solver]`: the fixed-rate loop and the frame solver.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SolverConfig {
    /// Deformation method: `"arap"` (volumetric ARAP and Green coordinates, the default)
    /// or `"harmonic"` (harmonic rotation fields and a Poisson rebuild, de Aguiar et al.).
    pub method: Method,
    /// Harmonic method: share of each bone's length, at each end, left free of
    /// correspondences (larger: softer bends).
    pub harmonic_margin: f64,
    /// Frames per second of the solver thread, Hz.
    pub rate_hz: f64,
    /// ARAP iteration cap per frame.
    pub max_iterations: usize,
    /// Relative change of `0.5·rrms + 0.5·bone_length_error` that ends a frame.
    pub tolerance: f64,
    /// Share of the frame period a solve may use before it stops at its deadline.
    pub deadline_fraction: f64,
    /// Capacity of the input channel, samples (inputs drop and count samples beyond it).
    pub channel_capacity: usize,
    /// Posture fit weight towards the rest pose: metres of marker misfit per metre of
    /// height that one radian away from rest is worth (higher: stiffer, less noise).
    pub rest_prior: f64,
    /// The same towards the previous frame's posture (higher: smoother, more lag).
    pub prev_prior: f64,
    /// ARAP: gain of the volume restoration (0: off; 1: the default, which gives
    /// compressed flesh at creases back its volume within a few frames; above 2 it may
    /// oscillate).
    pub volume_gain: f64,
    /// Solver threads of a stage of several actors (each actor is solved on one of
    /// them); default: the machine's cores. One actor always takes one thread.
    pub threads: Option<usize>,
}

impl Default for SolverConfig {
    fn default() -> Self {
        Self {
            method: Method::Arap,
            harmonic_margin: super::harmonic::HarmonicParams::default().margin,
            rate_hz: 120.0,
            max_iterations: 30,
            tolerance: 1e-3,
            deadline_fraction: 0.8,
            channel_capacity: 4096,
            rest_prior: super::ik::IkParams::default().rest_prior,
            prev_prior: super::ik::IkParams::default().prev_prior,
            volume_gain: super::frame::SolverParams::default().volume_gain,
            threads: None,
        }
    }
}

/// Most solver threads a stage asks for.
pub const MAX_THREADS: usize = 256;

impl SolverConfig {
    /// Solver threads for `actors` actors: [`Self::threads`], else the machine's cores;
    /// never more than the actors.
    pub fn threads_for(&self, actors: usize) -> usize {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        self.threads.unwrap_or(cores).clamp(1, actors.max(1))
    }

    /// The frame solver's settings.
    pub fn params(&self) -> super::frame::SolverParams {
        super::frame::SolverParams {
            method: self.method,
            harmonic: super::harmonic::HarmonicParams {
                margin: self.harmonic_margin,
            },
            max_iterations: self.max_iterations,
            tolerance: self.tolerance,
            ik: super::ik::IkParams {
                rest_prior: self.rest_prior,
                prev_prior: self.prev_prior,
                ..super::ik::IkParams::default()
            },
            volume_gain: self.volume_gain,
        }
    }

    /// What is wrong, as `(key, message)` with keys relative to `[solver]`.
    pub fn problems(&self) -> Vec<(String, String)> {
        let mut out = Vec::new();
        let mut push = |key: &str, msg: String| out.push((key.to_owned(), msg));
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !(positive(self.rate_hz) && self.rate_hz <= 2000.0) {
            push(
                "rate_hz",
                format!("must be in (0, 2000] Hz, got {:?}", self.rate_hz),
            );
        }
        if self.max_iterations == 0 || self.max_iterations > 10_000 {
            push(
                "max_iterations",
                format!("must be 1 to 10000, got {:?}", self.max_iterations),
            );
        }
        if !positive(self.tolerance) {
            push(
                "tolerance",
                format!("must be positive, got {:?}", self.tolerance),
            );
        }
        if !(positive(self.deadline_fraction) && self.deadline_fraction <= 1.0) {
            push(
                "deadline_fraction",
                format!("must be in (0, 1], got {:?}", self.deadline_fraction),
            );
        }
        for (key, v) in [
            ("rest_prior", self.rest_prior),
            ("prev_prior", self.prev_prior),
        ] {
            if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
                push(key, format!("must be in [0, 1], got {v}"));
            }
        }
        if !(self.volume_gain.is_finite() && (0.0..=2.0).contains(&self.volume_gain)) {
            push(
                "volume_gain",
                format!("must be in [0, 2], got {:?}", self.volume_gain),
            );
        }
        if !(self.harmonic_margin.is_finite() && (0.0..0.5).contains(&self.harmonic_margin)) {
            push(
                "harmonic_margin",
                format!("must be in [0, 0.5), got {:?}", self.harmonic_margin),
            );
        }
        if let Some(t) = self.threads.filter(|t| !(1..=MAX_THREADS).contains(t)) {
            push("threads", format!("must be 1 to {MAX_THREADS}, got {t}"));
        }
        if !(16..=1 << 24).contains(&self.channel_capacity) {
            push(
                "channel_capacity",
                format!(
                    "must be 16 to 16777216 samples, got {:?}",
                    self.channel_capacity
                ),
            );
        }
        out
    }
}
