//! Per-frame math: ARAP local and global steps, the skeleton step, the frame solver and
//! its quality figures, and the `[solver]` config. No I/O, no locks, no logging: results
//! come back in a report.

pub mod arap;
pub mod config;
pub mod frame;
pub mod harmonic;
pub mod ik;
