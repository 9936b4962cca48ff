//! Up-axis conversions: the world frame is right-handed with Y up; sources that put Z up
//! (C3D and Qualisys exports, CAD meshes, some OSC senders) are turned into it once at the
//! edge, here.

use glam::DVec3;

/// A Z-up point or direction in the world's Y-up frame: the rotation of −90° about X,
/// `(x, y, z) → (x, z, −y)` (right-handed in, right-handed out; lengths, angles and
/// handedness are kept, and no rounding happens).
#[inline]
pub fn y_up_from_z_up(p: DVec3) -> DVec3 {
    DVec3::new(p.x, p.z, -p.y)
}

/// The inverse of [`y_up_from_z_up`]: a world (Y-up) point or direction in a Z-up frame,
/// `(x, y, z) → (x, −z, y)` (the rotation of +90° about X).
#[inline]
pub fn z_up_from_y_up(p: DVec3) -> DVec3 {
    DVec3::new(p.x, -p.z, p.y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;

    #[test]
    fn z_up_is_a_rotation_of_minus_90_degrees_about_x() {
        let q = DQuat::from_rotation_x(-std::f64::consts::FRAC_PI_2);
        for p in [DVec3::X, DVec3::Y, DVec3::Z, DVec3::new(0.3, -1.2, 2.5)] {
            assert!((y_up_from_z_up(p) - q * p).length() < 1e-15, "{p}");
        }
        // Z up becomes Y up.
        assert_eq!(y_up_from_z_up(DVec3::Z), DVec3::Y);
    }

    #[test]
    fn the_two_conversions_are_exact_inverses() {
        let p = DVec3::new(0.1, -2.3, 4.56);
        assert_eq!(z_up_from_y_up(y_up_from_z_up(p)), p);
        assert_eq!(y_up_from_z_up(z_up_from_y_up(p)), p);
    }
}
