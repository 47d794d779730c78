//! Design pattern 3 for the UR5e: no Supervisor anywhere in the app. The controller knows the
//! arm from its encoders and its own kinematics, takes reach targets from the cell's work
//! orders (the task's start event, from its own random stream), and talks to a RobotServer
//! through its Communicator (the generic cycle of `twinbots_link::robot`, with the reach
//! task's own terms). Episodes restart the way a real cell's do: the arm homes with its own
//! motors (after a protective stop, once braked to rest and unlocked), and if the part has
//! been knocked out of fixture A, the lab operator puts it back before the next episode
//! starts. (The start pose the start event also draws is for the Supervisor of pattern 1; a
//! homing arm starts at home.) The twin's figures of an episode (energy, events) count from its
//! start, not from its homing.

use bevy::prelude::*;
use twinbots_link::robot::{AtHome, Controller, Phase, RobotCycleSet, ServerRobotPlugin};
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::{Motor, Operator};

use crate::arm;
use crate::cell::{CellParts, part_seat};
use crate::metrics::TwinMeter;
use crate::state::CellState;

/// The operator re-seats the part when it is this far from its seat (m).
const PART_OUT_OF_PLACE: f32 = 0.005;

pub(crate) fn build(app: &mut App) {
    app.add_plugins(ServerRobotPlugin::<CellState>::new("ur5e"))
        .add_systems(Update, (home.in_set(RobotCycleSet::Home), (operate, reset_meter).in_set(RobotCycleSet::Operate)));
}

/// Homing with the arm's own motors, to the episode's drawn start pose (near home, or where
/// the last reach arrived: the reach's start event, as the Supervisor places the arm under
/// patterns 1 and 2) at up to [`arm::HOMING_SPEED`]; once there and still, the robot is
/// "home" and the next step starts an episode. An arm in a protective stop
/// first brakes to rest; then the stop is unlocked (as an operator or the cell's PLC does
/// through UR's dashboard) and it homes.
fn home(mut robots: Query<(&CellParts, &mut CellState, &Controller, &mut AtHome)>, mut motors: Query<&mut Motor>) {
    for (parts, mut state, controller, mut at_home) in &mut robots {
        if controller.phase() != Phase::Homing || !state.read {
            continue;
        }
        if state.safety.stopped() {
            if !state.safety.stop_ended(&state.arm.qd) {
                continue;
            }
            state.safety.unlock();
        }
        at_home.0 = state.arm.is_at(&state.start_pose);
        if at_home.0 {
            arm::drive(parts, [0.0; 6], &mut motors);
        } else {
            arm::drive(parts, arm::speeds_towards(&state.arm.q, &state.start_pose), &mut motors);
        }
    }
}

/// The lab operator: when an episode is about to start and the part is out of fixture A, puts
/// it back.
fn operate(mut operator: Operator, robots: Query<(Entity, &CellParts, &CellState, &Controller)>) {
    for (arena, parts, state, controller) in &robots {
        if controller.phase() != Phase::Starting {
            continue;
        }
        let seat = parts.base * Pose::from_translation(part_seat(state.fixtures.pick));
        let out_of_place = operator.object_pose(arena, parts.part).is_none_or(|p| {
            (p.translation - seat.translation).length() > PART_OUT_OF_PLACE
                || p.rotation.angle_between(seat.rotation) > 0.05
        });
        if out_of_place {
            operator.place_object(arena, parts.part, seat);
        }
    }
}

/// An episode's figures start from nothing when it starts (homing is not part of it).
fn reset_meter(mut robots: Query<(&Controller, &mut TwinMeter)>) {
    for (controller, mut meter) in &mut robots {
        if controller.phase() == Phase::Starting {
            *meter = TwinMeter::default();
        }
    }
}
