//! Design pattern 3 for the cart-pole: no Supervisor anywhere in the app. The robot knows
//! itself from its own devices only (wheel encoders for position and speed, the pole's position
//! sensor, the angle's change per step for its rate), talks to a RobotServer through its
//! Communicator (the generic cycle of `twinbots_link::robot`, with the task's own terms), and
//! restarts episodes the way a real cell would: it drives itself back to the centre with its
//! own motors while the lab operator holds the pole upright, then the operator lets go at the
//! drawn tilt.

use bevy::prelude::*;
use twinbots_link::robot::{AtHome, Controller, Phase, RobotCycleSet, ServerRobotPlugin};
use twinbots_sim::{JointState, Motor, MotorCommand, Operator, PositionSensor, SimSettings};
use twinbots_task::task::TaskSet;

use crate::{CartPoleParts, CartPoleState, WHEEL_SPEED};

const WHEEL_RADIUS: f32 = 0.04;

/// The pole angle the controller read last step, for the rate.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct PreviousAngle(f32);

pub(crate) fn build(app: &mut App) {
    app.add_plugins(ServerRobotPlugin::<CartPoleState>::new("cartpole"))
        .add_systems(PostStartup, add_previous_angle)
        .add_systems(Update, (home.in_set(RobotCycleSet::Home), operate.in_set(RobotCycleSet::Operate)))
        .add_systems(Update, read_devices.in_set(TaskSet::Read));
}

fn add_previous_angle(mut commands: Commands, arenas: Query<Entity, With<CartPoleParts>>) {
    for arena in &arenas {
        commands.entity(arena).insert(PreviousAngle::default());
    }
}

/// Encoders and the pole sensor → x, v, angle, rate.
fn read_devices(
    settings: Res<SimSettings>,
    sensors: Query<&PositionSensor>,
    encoders: Query<&JointState>,
    mut robots: Query<(&CartPoleParts, &mut CartPoleState, &mut PreviousAngle)>,
) {
    for (parts, mut state, mut previous) in &mut robots {
        let wheels: Vec<&JointState> = parts.wheels.iter().filter_map(|&w| encoders.get(w).ok()).collect();
        let n = wheels.len().max(1) as f32;
        state.x = wheels.iter().map(|s| s.position).sum::<f32>() / n * WHEEL_RADIUS;
        state.v = wheels.iter().map(|s| s.velocity).sum::<f32>() / n * WHEEL_RADIUS;
        state.angle = sensors.get(parts.pole_joint).map_or(0.0, |s| s.value);
        state.rate = (state.angle - previous.0) / settings.control_dt();
        previous.0 = state.angle;
    }
}

/// Homing with the robot's own motors: a P controller on the odometry drives back to x = 0.
fn home(mut robots: Query<(&CartPoleParts, &CartPoleState, &Controller, &mut AtHome)>, mut motors: Query<&mut Motor>) {
    for (parts, state, controller, mut at_home) in &mut robots {
        if controller.phase() != Phase::Homing {
            continue;
        }
        at_home.0 = state.x.abs() < 0.005 && state.v.abs() < 0.02;
        if at_home.0 {
            continue;
        }
        let speed = (-4.0 * state.x / WHEEL_RADIUS).clamp(-WHEEL_SPEED, WHEEL_SPEED);
        for wheel in parts.wheels {
            if let Ok(mut m) = motors.get_mut(wheel) {
                m.command = MotorCommand::Velocity(speed);
            }
        }
    }
}

/// The lab operator: holds the pole upright while the robot homes, and lets go at the drawn
/// tilt when the episode starts.
fn operate(
    mut operator: Operator,
    mut robots: Query<(Entity, &CartPoleParts, &CartPoleState, &Controller, &mut PreviousAngle)>,
) {
    for (arena, parts, state, controller, mut previous) in &mut robots {
        let angle = match controller.phase() {
            Phase::Homing => 0.0,
            Phase::Starting => state.start_tilt,
            Phase::Running => continue,
        };
        operator.place_joint(arena, parts.pole_joint, angle);
        previous.0 = angle;
    }
}
