//! The live daemon in the library: [`stage::Stage`] builds a whole stage from its config
//! (inputs, recorder, solver thread, sinks) and runs it on a clock; [`pipeline`] is the
//! fixed-rate loop the solver thread runs ([`input_rates`] measures the inputs for it); [`offline`] plays a recording through that loop
//! on a manual clock, as fast as it goes; [`capture`] gathers live input into a take, and
//! [`live_calibration`] calibrates a stage's character from its first seconds.

pub mod capture;
pub mod input_rates;
pub mod live_calibration;
pub mod offline;
pub mod pipeline;
pub mod stage;

pub use stage::Stage;
