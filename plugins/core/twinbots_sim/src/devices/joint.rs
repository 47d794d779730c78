//! Joints as entities: the rapier joint they stand for, and their measured state.

use bevy::math::{Quat, Vec3};
use bevy::prelude::*;

use crate::arena::{Arena, InArena};
use crate::physics::SimSettings;
use crate::rapier::prelude::*;
use crate::urdf::JointKind;

/// A movable joint of a robot, simulated as a rapier impulse joint whose free axis is the
/// local X axis of both joint frames.
#[derive(Component, Clone, Debug)]
pub struct Joint {
    pub name: String,
    pub kind: JointKind,
    pub robot: Entity,
    pub handle: ImpulseJointHandle,
    pub parent_body: RigidBodyHandle,
    pub child_body: RigidBodyHandle,
    /// Position stops, if any.
    pub limits: Option<[f32; 2]>,
}

/// Width (rad) of the window of a rotational joint's range that rapier enforces at a time:
/// rapier measures angles within one turn and takes a range of 2π or more for "free", so a
/// wider range (the UR5e's ±2π) is enforced as a window just under a turn wide that follows
/// the joint and reaches a real stop only when the joint is near it. Its other edge stays
/// about π from the joint, further than a joint turns in one physics step.
const STOP_WINDOW: f32 = std::f32::consts::TAU - 0.2;

/// The position stops rapier should enforce while the joint is at `position` (unwrapped):
/// its range if rapier can hold that range, else the window of it nearest to centred on
/// `position` (see [`STOP_WINDOW`]). A rotational range of exactly one turn (±π) becomes a
/// window too: to rapier it would be free.
pub(crate) fn stop_window(kind: JointKind, limits: Option<[f32; 2]>, position: f32) -> Option<[f32; 2]> {
    let [lo, hi] = limits?;
    if !kind.is_rotational() || hi - lo < STOP_WINDOW {
        return Some([lo, hi]);
    }
    let start = (position - STOP_WINDOW / 2.0).clamp(lo, hi - STOP_WINDOW);
    Some([start, start + STOP_WINDOW])
}

/// Position (unwrapped, so continuous joints count turns), speed and motor effort of a
/// joint, measured after every physics step. Privileged-free: it is what an encoder and the
/// motor's current sensing report on a real joint. The joint measures position and speed; its
/// [`Motor`](super::Motor), if any, measures the effort.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct JointState {
    pub position: f32,
    pub velocity: f32,
    /// Torque (N·m) or force (N) the joint's motor exerted on the child over the last physics
    /// step, as Webots' torque feedback (0 for a joint without a motor or with it off). Written
    /// by the motor module after the joint's position and speed.
    pub effort: f32,
    wrapped: f32,
}

impl Joint {
    /// The rapier axis the joint moves along.
    pub fn axis(&self) -> JointAxis {
        if self.kind.is_rotational() { JointAxis::AngX } else { JointAxis::LinX }
    }

    /// World-frame free axis, and (wrapped) position and velocity along it.
    pub fn measure(&self, world: &PhysicsWorld) -> Option<(Vec3, f32, f32)> {
        let joint = world.impulse_joints.get(self.handle)?;
        let b1 = world.bodies.get(self.parent_body)?;
        let b2 = world.bodies.get(self.child_body)?;
        let f1 = *b1.position() * joint.data.local_frame1;
        let f2 = *b2.position() * joint.data.local_frame2;
        let axis = f1.rotation * Vec3::X;
        if self.kind.is_rotational() {
            let rel: Quat = f1.rotation.inverse() * f2.rotation;
            // Twist about X, with the sign of the shorter way round.
            let sign = if rel.w < 0.0 { -1.0 } else { 1.0 };
            let angle = 2.0 * (sign * rel.x).atan2(sign * rel.w);
            let vel = (b2.angvel() - b1.angvel()).dot(axis);
            Some((axis, angle, vel))
        } else {
            let offset = (f2.translation - f1.translation).dot(axis);
            let vel = (b2.velocity_at_point(f2.translation) - b1.velocity_at_point(f2.translation)).dot(axis);
            Some((axis, offset, vel))
        }
    }
}

impl JointState {
    /// A state measured from scratch (no turn history): used at spawn and after resets.
    pub fn measured(joint: &Joint, world: &PhysicsWorld) -> Self {
        let (_, pos, vel) = joint.measure(world).unwrap_or_default();
        Self { position: pos, velocity: vel, effort: 0.0, wrapped: pos }
    }

    /// Advances the state over a physics step of `dt`. The speed is the position's change over
    /// the step, as an encoder measures it: rapier reports body velocities without the position
    /// correction its solver applied, so under a holding motor's load they show a creep the
    /// joint does not make.
    fn update(&mut self, joint: &Joint, world: &PhysicsWorld, dt: f32) {
        let Some((_, pos, _)) = joint.measure(world) else { return };
        let previous = self.position;
        if joint.kind.is_rotational() {
            self.position += wrap_angle(pos - self.wrapped);
        } else {
            self.position = pos;
        }
        self.wrapped = pos;
        self.velocity = (self.position - previous) / dt;
    }
}

/// Moves each joint's rapier stops with it (see [`stop_window`]), before the physics step:
/// rapier's limit constraint, not only the motor, holds a joint at its URDF stops, so a
/// contact or a load beyond the motor's strength cannot push it through.
pub(crate) fn place_stops(mut arenas: Query<&mut Arena>, joints: Query<(&Joint, &JointState, &InArena)>) {
    for (joint, state, in_arena) in &joints {
        let Some(window) = stop_window(joint.kind, joint.limits, state.position) else { continue };
        let Ok(mut arena) = arenas.get_mut(in_arena.0) else { continue };
        if let Some(j) = arena.world.impulse_joints.get_mut(joint.handle, false) {
            let axis = joint.axis();
            if j.data.limits(axis).is_none_or(|l| [l.min, l.max] != window) {
                j.data.set_limits(axis, window);
            }
        }
    }
}

/// An angle brought into [−π, π] by whole turns.
pub(crate) fn wrap_angle(angle: f32) -> f32 {
    angle - std::f32::consts::TAU * (angle / std::f32::consts::TAU).round()
}

pub(crate) fn measure_joints(
    settings: Res<SimSettings>,
    arenas: Query<&Arena>,
    mut joints: Query<(&Joint, &InArena, &mut JointState)>,
) {
    for (joint, in_arena, mut state) in &mut joints {
        if let Ok(arena) = arenas.get(in_arena.0) {
            state.update(joint, &arena.world, settings.dt);
        }
    }
}
