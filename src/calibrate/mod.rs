//! Fitting a take's marker layout onto a character. So far: which humanoid part carries
//! each label of the common optical marker sets ([`marker_sets`]), and so which of the
//! character's joints (by their roles) may carry it.

pub mod marker_sets;
