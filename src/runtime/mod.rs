//! Ground floor: what every layer uses at run time. The clock (system or manual, time
//! passed in so tests drive it), the latest-value slots between threads, the socket
//! waits of the network inputs and senders, a seeded random generator, and percentiles
//! of measurements.

pub mod clock;
#[cfg(test)]
pub mod logs;
pub mod net;
pub mod rng;
pub mod slot;
pub mod stats;
