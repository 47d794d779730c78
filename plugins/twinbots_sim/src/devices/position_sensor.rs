//! Webots' PositionSensor: the joint position, sampled once per control step.

use bevy::prelude::*;

use super::joint::JointState;

/// The latest reading of a joint's position sensor (rad or m).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct PositionSensor {
    pub value: f32,
}

pub fn sample_position_sensors(mut sensors: Query<(&JointState, &mut PositionSensor)>) {
    for (state, mut sensor) in &mut sensors {
        sensor.value = state.position;
    }
}
