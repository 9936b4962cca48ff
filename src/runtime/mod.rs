//! Ground floor: what every layer uses at run time: the clock, latest-value slots, a
//! seeded random generator, percentiles of measurements.

pub mod rng;
pub mod stats;
