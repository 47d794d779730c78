//! When devices sample. One rule for every device and every schedule: a device reads a world
//! that changed since the devices last sampled. After a control step's physics it samples if
//! its [`SamplingPeriod`] is due; after an arena was restored (an episode reset) every device of
//! that arena samples, whatever its period, so the reset observation reads the new episode's
//! first state. An arena that did not change does not sample again, so sampling at a reset
//! neither draws noise from, nor disturbs differentiating sensors of, arenas that were not
//! reset: each arena's trajectory stays a function of its own seed and actions only.

use bevy::ecs::schedule::ScheduleConfigs;
use bevy::ecs::system::ScheduleSystem;
use bevy::prelude::*;

use super::{contact_sensor, distance_sensor, inertial, position_sensor};
use crate::arena::{Arena, WorldChanges};

/// The device-sampling systems (position, distance, inertial, gyro, accelerometer, GPS, touch
/// and contact sensors), in the order [`sample_devices`] fixes.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub struct DeviceSampling;

/// Every device-sampling system, then the bookkeeping that records the arenas as sampled.
/// `SimSet::Sense` runs them every control step; a reset schedule adds them to its sensing set
/// so a reset arena's devices read its new state:
/// `app.add_systems(EnvReset, twinbots_sim::devices::sample_devices().in_set(ResetSet::Sense))`.
/// They run in a fixed order, not side by side: all draw noise from the arena's one random
/// stream, so their order is part of the trajectory a seed gives.
pub fn sample_devices() -> ScheduleConfigs<ScheduleSystem> {
    (
        (
            position_sensor::sample_position_sensors,
            distance_sensor::sample_distance_sensors,
            inertial::sample_inertial_units,
            inertial::sample_gyros,
            inertial::sample_accelerometers,
            inertial::sample_gps,
            inertial::sample_touch_sensors,
            contact_sensor::sample_contact_sensors,
        )
            .chain()
            .in_set(DeviceSampling),
        devices_sampled.after(DeviceSampling),
    )
        .into_configs()
}

fn devices_sampled(mut arenas: Query<&mut Arena>) {
    for mut arena in &mut arenas {
        arena.unsampled = WorldChanges::default();
    }
}
