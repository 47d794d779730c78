//! Webots' PositionSensor: the joint position, sampled once per control step, with optional
//! Gaussian noise (rad or m).

use bevy::prelude::*;

use super::joint::JointState;
use super::mount::gaussian;
use crate::arena::{Arena, InArena};

/// The latest reading of a joint's position sensor (rad or m).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct PositionSensor {
    pub value: f32,
    /// Standard deviation of the reading's noise.
    pub noise: f32,
}

pub fn sample_position_sensors(
    mut arenas: Query<&mut Arena>,
    mut sensors: Query<(&JointState, &mut PositionSensor, &InArena)>,
) {
    for (state, mut sensor, in_arena) in &mut sensors {
        let noise = match arenas.get_mut(in_arena.0) {
            Ok(mut arena) if sensor.noise > 0.0 => gaussian(&mut arena.rng, sensor.noise),
            _ => 0.0,
        };
        sensor.value = state.position + noise;
    }
}
