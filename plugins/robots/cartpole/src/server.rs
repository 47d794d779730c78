//! Design pattern 3 for the cart-pole: no Supervisor anywhere in the app. The robot knows
//! itself from its own devices only (a GPS and an inertial unit on the cart for where it is and
//! how fast it goes, the pole's position sensor, a gyro on the pole for its rate), talks to a
//! RobotServer through its Communicator (the generic cycle of `twinbots_link::robot`, with the
//! task's own terms), and restarts episodes the way a real cell would: it drives itself back to
//! the centre with its own motors while the lab operator holds the pole upright, then the
//! operator lets go at the drawn tilt.
//!
//! Not the wheels' encoders: the wheels reach a new speed within a step and slip under the
//! cart's inertia, so they read the speed commanded, not the cart's (at a reversal +0.18 m/s
//! while the cart still moves backwards). A policy that saw its last action where the cart's
//! speed belongs, and the wheels' travel as its position, stalled at ≈ 190 steps in most seeds
//! (docs/benchmarks.md, "Cart-pole, pattern 3"). On a real cell the GPS is a motion-capture
//! marker or a track encoder.

use bevy::prelude::*;
use twinbots_link::robot::{AtHome, Controller, Phase, RobotCycleSet, ServerRobotPlugin};
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::{Gps, Gyro, InArena, InertialUnit, Motor, MotorCommand, Mount, Operator, PositionSensor};
use twinbots_task::task::TaskSet;

use crate::{CartPoleParts, CartPoleState, WHEEL_RADIUS, WHEEL_SPEED};

/// The robot's devices beyond its URDF's (mounted when the app starts), and its dead
/// reckoning: how far the cart went along its heading since it was switched on. A cart on the
/// floor turns a little as its wheels slip, so its position on the world's x is not the
/// position along its track.
#[derive(Component, Clone, Copy, Debug)]
pub struct CartDevices {
    gps: Entity,
    inertial_unit: Entity,
    /// On the pole, its y axis the hinge's.
    gyro: Entity,
    last_position: Option<Vec3>,
    travelled: f32,
}

pub(crate) fn build(app: &mut App) {
    app.add_plugins(ServerRobotPlugin::<CartPoleState>::new("cartpole"))
        .add_systems(PostStartup, mount_devices)
        .add_systems(Update, (home.in_set(RobotCycleSet::Home), operate.in_set(RobotCycleSet::Operate)))
        .add_systems(Update, read_devices.in_set(TaskSet::Read));
}

fn mount_devices(mut commands: Commands, arenas: Query<(Entity, &CartPoleParts)>) {
    for (arena, parts) in &arenas {
        let on = |link| (Mount { link, offset: Pose::IDENTITY }, InArena(arena));
        let devices = CartDevices {
            gps: commands.spawn((Gps::default(), on(parts.cart))).id(),
            inertial_unit: commands.spawn((InertialUnit::default(), on(parts.cart))).id(),
            gyro: commands.spawn((Gyro::default(), on(parts.pole_link))).id(),
            last_position: None,
            travelled: 0.0,
        };
        commands.entity(arena).insert(devices);
    }
}

/// GPS and inertial unit → x (the distance travelled along the heading) and v (the speed along
/// it); the pole's sensor and gyro → angle and rate.
fn read_devices(
    sensors: Query<&PositionSensor>,
    gps_sensors: Query<&Gps>,
    inertial_units: Query<&InertialUnit>,
    gyros: Query<&Gyro>,
    mut robots: Query<(&CartPoleParts, &mut CartPoleState, &mut CartDevices)>,
) {
    for (parts, mut state, mut devices) in &mut robots {
        let (Ok(gps), Ok(inertial_unit), Ok(gyro)) =
            (gps_sensors.get(devices.gps), inertial_units.get(devices.inertial_unit), gyros.get(devices.gyro))
        else {
            continue;
        };
        let yaw = inertial_unit.roll_pitch_yaw[2];
        let heading = Vec3::new(yaw.cos(), yaw.sin(), 0.0);
        if let Some(last) = devices.last_position {
            devices.travelled += (gps.position - last).dot(heading);
        }
        devices.last_position = Some(gps.position);
        state.x = devices.travelled;
        state.v = gps.velocity.dot(heading);
        state.angle = sensors.get(parts.pole_joint).map_or(0.0, |s| s.value);
        state.rate = gyro.value.y;
    }
}

/// Homing with the robot's own motors: a P controller on the distance travelled drives back to
/// x = 0.
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
fn operate(mut operator: Operator, robots: Query<(Entity, &CartPoleParts, &CartPoleState, &Controller)>) {
    for (arena, parts, state, controller) in &robots {
        let angle = match controller.phase() {
            Phase::Homing => 0.0,
            Phase::Starting => state.start_tilt,
            Phase::Running => continue,
        };
        operator.place_joint(arena, parts.pole_joint, angle);
    }
}
