//! Input sources that feed marker samples into the daemon's bounded channel.

pub mod synthetic;
