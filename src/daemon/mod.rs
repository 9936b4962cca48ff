//! The live daemon in the library: [`stage::Stage`] builds a whole stage from its config
//! (inputs, recorder, solver thread, sinks) and runs it on a clock; [`pipeline`] is the
//! fixed-rate loop the solver thread runs.

pub mod pipeline;
pub mod stage;

pub use stage::Stage;
