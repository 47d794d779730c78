//! Webots' PositionSensor: the joint position, sampled once per control step, with optional
//! Gaussian noise (rad or m).

use bevy::prelude::*;

use super::due::samples_now;
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

/// Samples every control step (position sensors have no period).
pub(crate) fn sample_position_sensors(
    mut arenas: Query<&mut Arena>,
    mut sensors: Query<(&JointState, &mut PositionSensor, &InArena)>,
) {
    for (state, mut sensor, in_arena) in &mut sensors {
        let Ok(mut arena) = arenas.get_mut(in_arena.0) else { continue };
        if !samples_now(&arena, None, 0) {
            continue;
        }
        let noise = gaussian(&mut arena.rng, sensor.noise);
        sensor.value = state.position + noise;
    }
}
