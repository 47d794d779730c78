//! How a robot's cell is framed by cameras: plain data a robot plugin declares, so the renderer
//! (and anything else that shows the cell) needs nothing robot-specific.

use bevy::math::{Quat, Vec3};

/// The point cameras look at, how far away they stand (m), and which way the robot faces (yaw
/// of its front, rad), so `front` and `iso` see its working side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Framing {
    pub target: Vec3,
    pub distance: f32,
    pub facing: f32,
}

impl Default for Framing {
    /// A robot on the floor about a metre tall facing +x (the cart-pole, the Pioneer).
    fn default() -> Self {
        Self { target: Vec3::new(0.0, 0.0, 0.5), distance: 2.6, facing: 0.0 }
    }
}

impl Framing {
    /// Names of the cell's cameras.
    pub const CAMERAS: [&str; 4] = ["side", "front", "iso", "top"];

    /// Where a named camera of the cell stands (physics coordinates, Z up): `side` (from −y),
    /// `front` (from +x), `iso` or `top`; it looks at [`Framing::target`].
    pub fn eye(&self, name: &str) -> Option<Vec3> {
        let d = self.distance;
        let offset = match name {
            "side" => Vec3::new(0.0, -d, 0.08 * d),
            "front" => Vec3::new(d, 0.0, 0.08 * d),
            "iso" => Vec3::new(0.7 * d, -0.7 * d, 0.35 * d),
            "top" => Vec3::new(0.0, -0.004 * d, d),
            _ => return None,
        };
        Some(self.target + Quat::from_rotation_z(self.facing) * offset)
    }
}
