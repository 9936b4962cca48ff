//! The user's binding settings, as resolved from the `[bind]` section of a character file
//! (or a procedural character's defaults): what `rig` reads to build the control mesh and
//! its system.

/// Binding parameters.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BindParams {
    /// Lattice cell edge in metres.
    pub cell_size_m: f64,
    /// Spacing of skeleton samples along each segment, in metres.
    pub skeleton_step_m: f64,
    /// Shape weight `w_l`.
    pub w_shape: f64,
    /// Marker weight `w_u`.
    pub w_marker: f64,
    /// Skeleton weight `w_d`.
    pub w_skeleton: f64,
    /// A marker farther than this from every control tet is an error, in metres.
    pub max_marker_distance_m: f64,
}
