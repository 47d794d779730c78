//! Webots' DistanceSensor (ray type): a ray along the mount's +X, a maximum range, and a
//! lookup table that turns distance into the value the sensor reports.

use bevy::prelude::*;

use super::due::samples_now;
use super::mount::{Mount, SamplingPeriod, gaussian};
use crate::arena::{Arena, InArena};
use crate::physics::SimClock;
use crate::rapier::prelude::*;
use crate::robot::Link;

/// A ray distance sensor. `lookup` rows are `[distance, value, noise]` as in Webots: the value
/// is interpolated linearly between rows, and `noise` is the standard deviation as a fraction
/// of the value. Beyond the range the sensor reads the last row's value.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct DistanceSensor {
    pub lookup: Vec<[f32; 3]>,
    /// The reported value.
    pub value: f32,
    /// The distance actually measured (m), `max_range` when nothing was hit.
    pub distance: f32,
}

impl DistanceSensor {
    /// A sensor that reports the distance itself, up to `max_range`, without noise.
    pub fn linear(max_range: f32) -> Self {
        Self::with_lookup(vec![[0.0, 0.0, 0.0], [max_range, max_range, 0.0]])
    }

    /// A sensor with a Webots lookup table (rows sorted by distance, at least two).
    pub fn with_lookup(lookup: Vec<[f32; 3]>) -> Self {
        let max = lookup.last().map_or(0.0, |r| r[0]);
        Self { value: lookup.last().map_or(0.0, |r| r[1]), distance: max, lookup }
    }

    pub fn max_range(&self) -> f32 {
        self.lookup.last().map_or(0.0, |r| r[0])
    }

    /// Value and noise fraction for a distance, interpolated in the table.
    pub fn look_up(&self, distance: f32) -> (f32, f32) {
        let rows = &self.lookup;
        if rows.is_empty() {
            return (distance, 0.0);
        }
        if distance <= rows[0][0] {
            return (rows[0][1], rows[0][2]);
        }
        for w in rows.windows(2) {
            let ([d0, v0, n0], [d1, v1, n1]) = (w[0], w[1]);
            if distance <= d1 {
                let t = if d1 > d0 { (distance - d0) / (d1 - d0) } else { 1.0 };
                return (v0 + t * (v1 - v0), n0 + t * (n1 - n0));
            }
        }
        let last = rows[rows.len() - 1];
        (last[1], last[2])
    }
}

pub(crate) fn sample_distance_sensors(
    clock: Res<SimClock>,
    links: Query<&Link>,
    mut arenas: Query<&mut Arena>,
    mut sensors: Query<(&mut DistanceSensor, &Mount, &InArena, Option<&SamplingPeriod>)>,
) {
    for (mut sensor, mount, in_arena, period) in &mut sensors {
        let Ok(mut arena) = arenas.get_mut(in_arena.0) else { continue };
        if !samples_now(&arena, period, clock.control_steps) {
            continue;
        }
        let Some(state) = mount.state(&links, &arena.world) else { continue };
        let Ok(link) = links.get(mount.link) else { continue };
        let robot = link.robot;
        // The robot does not see itself: its own links' bodies are excluded.
        let own_bodies: Vec<RigidBodyHandle> = links.iter().filter(|l| l.robot == robot).map(|l| l.body).collect();
        let is_other = |_: ColliderHandle, c: &Collider| c.parent().is_none_or(|b| !own_bodies.contains(&b));
        let ray = Ray::new(state.pose.translation, state.pose.rotation * Vec3::X);
        let max = sensor.max_range();
        let hit = arena.world.cast_ray(&ray, max, true, QueryFilter::new().predicate(&is_other));
        let distance = hit.map_or(max, |(_, toi)| toi.min(max));
        let (value, noise) = sensor.look_up(distance);
        let noisy = value + gaussian(&mut arena.rng, noise * value.abs());
        sensor.distance = distance;
        sensor.value = noisy;
    }
}
