//! Physics is Z up (URDF); Bevy is Y up: every pose and point is turned by −90° about X on the
//! way into a render world.

use std::f32::consts::FRAC_PI_2;

use bevy::prelude::*;
use twinbots_sim::rapier::math::Pose;

/// The rotation taking Z-up physics coordinates to Bevy's Y-up.
pub fn z_up_to_y_up() -> Quat {
    Quat::from_rotation_x(-FRAC_PI_2)
}

/// A physics pose as a Bevy transform.
pub fn to_bevy(pose: Pose) -> Transform {
    let r = z_up_to_y_up();
    Transform { translation: r * pose.translation, rotation: r * pose.rotation, scale: Vec3::ONE }
}

/// A physics point in Bevy coordinates.
pub fn point_to_bevy(p: Vec3) -> Vec3 {
    z_up_to_y_up() * p
}
