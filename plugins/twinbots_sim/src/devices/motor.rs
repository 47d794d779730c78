//! Motors in the manner of Webots' RotationalMotor / LinearMotor: velocity, position or torque
//! control, always within the motor's max velocity and max torque (force).

use bevy::prelude::*;

use super::joint::{Joint, JointState};
use crate::arena::{Arena, InArena};
use crate::physics::SimSettings;
use crate::rapier::prelude::*;

/// Gain of rapier's velocity motor: high, so the motor tracks its target as fast as its torque
/// limit allows (the torque limit, not this gain, is what bounds it).
const VELOCITY_MOTOR_GAIN: f32 = 1.0e4;

/// What the motor is asked to do. Values outside the motor's limits are clamped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MotorCommand {
    /// No torque: the joint turns freely.
    Off,
    /// Target velocity (rad/s or m/s).
    Velocity(f32),
    /// Target position (rad or m), reached with a P controller whose speed is bounded.
    Position(f32),
    /// Torque (N·m) or force (N).
    Torque(f32),
}

/// A motor on a joint.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct Motor {
    /// Max speed (rad/s or m/s): URDF `<limit velocity>`.
    pub max_velocity: f32,
    /// Max torque or force: URDF `<limit effort>`.
    pub max_effort: f32,
    /// Proportional gain of position control (1/s), Webots' default P = 10.
    pub position_gain: f32,
    /// Fraction of `max_effort` the motor actually delivers (1: as rated; domain
    /// randomization lowers it to model weak or worn motors).
    pub strength: f32,
    pub command: MotorCommand,
    /// The command restored when the arena is reset.
    pub initial_command: MotorCommand,
}

impl Motor {
    pub fn new(max_velocity: f32, max_effort: f32) -> Self {
        Self {
            max_velocity,
            max_effort,
            position_gain: 10.0,
            strength: 1.0,
            command: MotorCommand::Off,
            initial_command: MotorCommand::Off,
        }
    }

    /// The velocity the motor's controller asks for now, bounded by `max_velocity`.
    pub fn target_velocity(&self, state: &JointState) -> Option<f32> {
        let v = match self.command {
            MotorCommand::Velocity(v) => v,
            MotorCommand::Position(p) => self.position_gain * (p - state.position),
            MotorCommand::Off | MotorCommand::Torque(_) => return None,
        };
        Some(v.clamp(-self.max_velocity, self.max_velocity))
    }
}

pub(crate) fn drive_motors(
    settings: Res<SimSettings>,
    mut arenas: Query<&mut Arena>,
    motors: Query<(&Joint, &JointState, &Motor, &InArena)>,
) {
    for (joint, state, motor, in_arena) in &motors {
        let Ok(mut arena) = arenas.get_mut(in_arena.0) else { continue };
        let world = &mut arena.world;
        let axis = if joint.kind.is_rotational() { JointAxis::AngX } else { JointAxis::LinX };
        let target = motor.target_velocity(state);
        if let Some(j) = world.impulse_joints.get_mut(joint.handle, false) {
            match target {
                Some(v) => {
                    j.data.set_motor_velocity(axis, v, VELOCITY_MOTOR_GAIN);
                    j.data.set_motor_max_force(axis, motor.max_effort * motor.strength);
                }
                None => {
                    j.data.set_motor_velocity(axis, 0.0, 0.0);
                    j.data.set_motor_max_force(axis, 0.0);
                }
            }
        }
        if let MotorCommand::Torque(t) = motor.command {
            let limit = motor.max_effort * motor.strength;
            apply_effort(world, joint, t.clamp(-limit, limit), settings.dt);
        }
    }
}

/// Applies an effort between the joint's two bodies for one step, as equal and opposite impulses.
fn apply_effort(world: &mut PhysicsWorld, joint: &Joint, effort: f32, dt: f32) {
    let Some((axis, _, _)) = joint.measure(world) else { return };
    let impulse = axis * effort * dt;
    let rotational = joint.kind.is_rotational();
    let anchor = world
        .impulse_joints
        .get(joint.handle)
        .zip(world.bodies.get(joint.child_body))
        .map(|(j, b)| (*b.position() * j.data.local_frame2).translation);
    for (handle, sign) in [(joint.child_body, 1.0), (joint.parent_body, -1.0)] {
        let Some(body) = world.bodies.get_mut(handle) else { continue };
        if rotational {
            body.apply_torque_impulse(impulse * sign, true);
        } else if let Some(anchor) = anchor {
            body.apply_impulse_at_point(impulse * sign, anchor, true);
        }
    }
}
