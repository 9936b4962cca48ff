//! Wiring of the live daemon: the clock, the latest-value slots between the solver thread
//! and the sinks, and the fixed-rate loop (see the data flow in the crate docs).

pub mod clock;
pub mod pipeline;
pub mod slot;
