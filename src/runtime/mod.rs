//! Ground floor: what every layer uses at run time. The clock (system or manual, time
//! passed in so tests drive it), the latest-value slots between threads, the socket
//! waits of the network inputs and senders (and how often they say what went wrong), a
//! seeded random generator, percentiles of measurements, TOML documents read with every
//! problem at its line, and files a user named read within a size bound.

pub mod clock;
pub mod files;
#[cfg(test)]
pub mod logs;
pub mod net;
pub mod rng;
pub mod said;
pub mod slot;
pub mod stats;
pub mod toml_doc;
