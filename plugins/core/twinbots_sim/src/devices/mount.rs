//! Where a device sits: a link and an offset from the link frame. Shared by every mounted
//! device (distance sensors, IMU, GPS, touch sensors, emitters, receivers, cameras).

use bevy::math::Vec3;
use bevy::prelude::*;
use rand::Rng;
use rand_distr::StandardNormal;

use crate::rapier::prelude::*;
use crate::robot::Link;

/// A device mounted on `link` at `offset` (in the link frame). The device's forward axis is
/// its local +X, as in Webots.
#[derive(Component, Clone, Copy, Debug)]
pub struct Mount {
    pub link: Entity,
    pub offset: Pose,
}

/// How often a device samples, in control steps (1 = every step), as Webots' sampling period.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct SamplingPeriod(pub u32);

impl Default for SamplingPeriod {
    fn default() -> Self {
        Self(1)
    }
}

impl SamplingPeriod {
    /// Whether a device with this period samples on control step `step`.
    pub fn due(period: Option<&SamplingPeriod>, step: u64) -> bool {
        period.is_none_or(|p| p.0 <= 1 || step.is_multiple_of(p.0 as u64))
    }
}

/// World pose, linear velocity (of the mount point) and angular velocity of a mount.
#[derive(Clone, Copy, Debug)]
pub struct MountState {
    pub pose: Pose,
    pub linvel: Vec3,
    pub angvel: Vec3,
    pub body: RigidBodyHandle,
}

impl Mount {
    pub fn state(&self, links: &Query<&Link>, world: &PhysicsWorld) -> Option<MountState> {
        let link = links.get(self.link).ok()?;
        let body = world.bodies.get(link.body)?;
        let pose = *body.position() * link.offset * self.offset;
        Some(MountState {
            pose,
            linvel: body.velocity_at_point(pose.translation),
            angvel: body.angvel(),
            body: link.body,
        })
    }
}

/// Gaussian noise with standard deviation `std` (0: none).
pub fn gaussian(rng: &mut impl Rng, std: f32) -> f32 {
    if std > 0.0 { std * rng.sample::<f32, _>(StandardNormal) } else { 0.0 }
}
