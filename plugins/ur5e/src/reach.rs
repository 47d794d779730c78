//! Reach: move the tool to a target sampled over the table, pointing down, and come to rest
//! there within 1 cm. The episode ends on arrival (success) or after [`EPISODE_STEPS`]; the
//! next starts near home or, after an arrival, half the time where that one ended.

use bevy::prelude::*;
use rand::Rng;
use twinbots_rl::Episode;
use twinbots_sim::{SimSettings, Supervisor};

use crate::arm::{ActionHistory, ArmState, reach_reward};
use crate::cell::{CellParts, FIXTURE_A, PART_HEIGHT, POCKET_FLOOR};
use crate::kinematics::HOME;
use crate::metrics::TwinMeter;

/// Control steps before a reach is given up (4 s).
pub const EPISODE_STEPS: u32 = 100;
/// Targets: this far from the base's axis (m)…
pub const TARGET_RADIUS: [f32; 2] = [0.35, 0.65];
/// …within this angle either side of the arm's front (−x), rad…
pub const TARGET_HALF_ANGLE: f32 = 0.8;
/// …and this high above the table (m).
pub const TARGET_HEIGHT: [f32; 2] = [0.05, 0.35];
/// Start poses: home with every joint off by up to this much (rad).
pub const START_SPREAD: f32 = 0.05;

/// Where the task sends the tool: a point in the base frame, the tool pointing down (Isaac
/// Lab's command term).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct ToolTarget(pub Vec3);

/// Where the last reach ended, when it succeeded: half the time the next one starts there, as a
/// cell's next move does, so the policy learns moves from anywhere it may have arrived (a
/// pick-and-place program chains them); otherwise it starts near home.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct LastArrival(pub Option<[f32; 6]>);

/// A target over the table, not inside the part waiting in fixture A.
pub fn sample_target(rng: &mut impl Rng) -> Vec3 {
    loop {
        let r = rng.random_range(TARGET_RADIUS[0]..=TARGET_RADIUS[1]);
        let a = std::f32::consts::PI + rng.random_range(-TARGET_HALF_ANGLE..=TARGET_HALF_ANGLE);
        let z = rng.random_range(TARGET_HEIGHT[0]..=TARGET_HEIGHT[1]);
        let target = Vec3::new(r * a.cos(), r * a.sin(), z);
        let over_part = (target.truncate() - FIXTURE_A.truncate()).length() < 0.06;
        if !(over_part && z < POCKET_FLOOR + PART_HEIGHT + 0.02) {
            return target;
        }
    }
}

/// A start pose near home.
pub fn sample_start(rng: &mut impl Rng) -> [f32; 6] {
    HOME.map(|q| q + rng.random_range(-START_SPREAD..=START_SPREAD))
}

/// Reset event: a new target, and the arm put (by the Supervisor) where the last successful
/// reach ended or near home (see [`LastArrival`]).
pub fn new_reach(
    mut supervisor: Supervisor,
    mut arenas: Query<(Entity, &Episode, &CellParts, &mut ToolTarget, &mut LastArrival)>,
) {
    for (arena, episode, parts, mut target, mut last) in &mut arenas {
        if !episode.needs_reset {
            continue;
        }
        let Some(mut a) = supervisor.arena_mut(arena) else { continue };
        target.0 = sample_target(&mut a.rng);
        let near_home = sample_start(&mut a.rng);
        let chain = a.rng.random::<bool>();
        let start = last.0.take().filter(|_| chain).unwrap_or(near_home);
        drop(a);
        for (&joint, q) in parts.joints.iter().zip(start) {
            supervisor.set_joint_position(joint, q);
        }
    }
}

pub fn reward(mut arenas: Query<(&ArmState, &ToolTarget, &ActionHistory, &mut Episode)>) {
    for (arm, target, actions, mut e) in &mut arenas {
        e.reward = reach_reward(arm, target.0, actions, arm.has_reached(target.0));
    }
}

pub fn terminate(settings: Res<SimSettings>, mut arenas: Query<(&ArmState, &ToolTarget, &TwinMeter, &mut LastArrival, &mut Episode)>) {
    for (arm, target, meter, mut last, mut e) in &mut arenas {
        let arrived = arm.has_reached(target.0);
        last.0 = arrived.then_some(arm.q);
        e.terminated = arrived;
        e.truncated = !arrived && e.length + 1 >= EPISODE_STEPS;
        if e.terminated || e.truncated {
            e.success = Some(arrived);
            let cycle_time = arrived.then(|| (e.length + 1) as f32 * settings.control_dt());
            e.metrics.insert("final_error_mm".into(), 1000.0 * arm.distance_to(target.0));
            meter.report(&mut e, cycle_time);
        }
    }
}
