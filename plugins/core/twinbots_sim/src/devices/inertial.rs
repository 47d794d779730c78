//! Body-state sensors in the manner of Webots: InertialUnit (roll, pitch, yaw), Gyro (angular
//! velocity), Accelerometer (proper acceleration, so it reads +g at rest), GPS (position and
//! speed) and TouchSensor (contact force). All read in the mount's frame unless said otherwise.

use bevy::math::{EulerRot, Vec3};
use bevy::prelude::*;

use super::due::{samples_now, world_changed, world_restored};
use super::mount::{Mount, MountState, SamplingPeriod, gaussian};
use crate::arena::{Arena, InArena};
use crate::physics::{SimClock, SimSettings};
use crate::robot::Link;

/// Roll, pitch and yaw (rad) of the mount frame in the arena (Z up), with Gaussian noise.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct InertialUnit {
    pub noise: f32,
    pub roll_pitch_yaw: [f32; 3],
}

/// Angular velocity (rad/s) in the mount frame.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct Gyro {
    pub noise: f32,
    pub value: Vec3,
}

/// Proper acceleration (m/s²) in the mount frame: (dv/dt − g), so +9.81 along up at rest.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct Accelerometer {
    pub noise: f32,
    pub value: Vec3,
    previous_velocity: Option<Vec3>,
}

/// Position (m) in the arena, speed (m/s) and velocity (m/s, in the arena's frame: Webots'
/// `getSpeedVector`) of the mount point.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct Gps {
    pub noise: f32,
    pub position: Vec3,
    pub speed: f32,
    pub velocity: Vec3,
}

/// Webots' TouchSensor: `touching` as the bumper type reports it, and `force` (N), the contact
/// force on the mount's link body in the last physics step, from rapier's contact impulses.
/// The force reads m·g for a body resting freely; where joints share the load, rapier's solver
/// impulses over-report it (measured: about +20 % for a box carrying a jointed flywheel).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct TouchSensor {
    pub noise: f32,
    pub touching: bool,
    pub force: f32,
}

type Sampled<'a, T> = (&'a mut T, &'a Mount, &'a InArena, Option<&'a SamplingPeriod>);

/// The loop every mounted sensor shares: find its arena and mount state, then let `read`
/// update the sensor; `due` says whether its sampling period falls on this step (a sensor that
/// must track every step, like the accelerometer, decides for itself what to do when not due).
fn sample_each<T: Component<Mutability = bevy::ecs::component::Mutable>>(
    step: u64,
    links: &Query<&Link>,
    arenas: &mut Query<&mut Arena>,
    sensors: &mut Query<Sampled<T>>,
    always: bool,
    mut read: impl FnMut(&mut T, &MountState, &mut Arena, bool),
) {
    for (mut sensor, mount, in_arena, period) in sensors.iter_mut() {
        let Ok(mut arena) = arenas.get_mut(in_arena.0) else { continue };
        let due = samples_now(&arena, period, step);
        if !(due || always && world_changed(&arena)) {
            continue;
        }
        let Some(state) = mount.state(links, &arena.world) else { continue };
        read(&mut sensor, &state, &mut arena, due);
    }
}

fn noise3(arena: &mut Arena, std: f32) -> Vec3 {
    Vec3::from_array([0.0; 3].map(|_| gaussian(&mut arena.rng, std)))
}

pub(crate) fn sample_inertial_units(
    clock: Res<SimClock>,
    links: Query<&Link>,
    mut arenas: Query<&mut Arena>,
    mut sensors: Query<Sampled<InertialUnit>>,
) {
    sample_each(clock.control_steps, &links, &mut arenas, &mut sensors, false, |s, state, arena, _| {
        let (yaw, pitch, roll) = state.pose.rotation.to_euler(EulerRot::ZYX);
        let n = s.noise;
        s.roll_pitch_yaw = [roll, pitch, yaw].map(|a| a + gaussian(&mut arena.rng, n));
    });
}

pub(crate) fn sample_gyros(
    clock: Res<SimClock>,
    links: Query<&Link>,
    mut arenas: Query<&mut Arena>,
    mut sensors: Query<Sampled<Gyro>>,
) {
    sample_each(clock.control_steps, &links, &mut arenas, &mut sensors, false, |s, state, arena, _| {
        s.value = state.pose.rotation.inverse() * state.angvel + noise3(arena, s.noise);
    });
}

/// Differentiates velocity over the control step, so it runs every step whatever the period.
pub(crate) fn sample_accelerometers(
    clock: Res<SimClock>,
    settings: Res<SimSettings>,
    links: Query<&Link>,
    mut arenas: Query<&mut Arena>,
    mut sensors: Query<Sampled<Accelerometer>>,
) {
    let dt = settings.control_dt();
    sample_each(clock.control_steps, &links, &mut arenas, &mut sensors, true, |s, state, arena, due| {
        if world_restored(arena) {
            // The world jumped to a new episode: no acceleration is read across the jump.
            s.previous_velocity = None;
        }
        let accel = s.previous_velocity.map_or(Vec3::ZERO, |v| (state.linvel - v) / dt);
        s.previous_velocity = Some(state.linvel);
        if due {
            s.value = state.pose.rotation.inverse() * (accel - settings.gravity) + noise3(arena, s.noise);
        }
    });
}

pub(crate) fn sample_gps(
    clock: Res<SimClock>,
    links: Query<&Link>,
    mut arenas: Query<&mut Arena>,
    mut sensors: Query<Sampled<Gps>>,
) {
    sample_each(clock.control_steps, &links, &mut arenas, &mut sensors, false, |s, state, arena, _| {
        s.position = state.pose.translation + noise3(arena, s.noise);
        s.speed = state.linvel.length();
        s.velocity = state.linvel;
    });
}

pub(crate) fn sample_touch_sensors(
    clock: Res<SimClock>,
    settings: Res<SimSettings>,
    links: Query<&Link>,
    mut arenas: Query<&mut Arena>,
    mut sensors: Query<Sampled<TouchSensor>>,
) {
    sample_each(clock.control_steps, &links, &mut arenas, &mut sensors, false, |s, state, arena, _| {
        let world = &arena.world;
        let Some(body) = world.bodies.get(state.body) else { return };
        let pairs = || body.colliders().iter().flat_map(|&c| world.contact_pairs_with(c));
        let touching = pairs().any(|pair| pair.has_any_active_contact());
        let impulse: f32 = pairs().map(|pair| pair.total_impulse_magnitude()).sum();
        // Rapier's stored contact impulse over a step of n solver substeps is (1 + 1/n) times
        // the impulse that supports a resting body (measured: 2×, 1.5×, 1.25× m·g·dt for n = 1,
        // 2, 4), so it is scaled by n / (n + 1) to read m·g at rest.
        let n = world.integration_parameters.num_solver_iterations.max(1) as f32;
        let force = impulse / settings.dt * n / (n + 1.0);
        s.touching = touching;
        s.force = if touching { (force + gaussian(&mut arena.rng, s.noise)).max(0.0) } else { 0.0 };
    });
}
