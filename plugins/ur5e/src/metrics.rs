//! The digital-twin figures of paper §4, per episode: energy the joint motors spend
//! (∫ Σ|τ·ω| dt, integrated every physics step), joint-limit events and collision events (each
//! counted once when it begins), and the cycle time of a successful episode.

use bevy::prelude::*;
use twinbots_sim::rapier::prelude::*;
use twinbots_sim::{Arena, JointState, Link, SimSettings, VacuumGripper};
use twinbots_rl::Episode;

use crate::cell::CellParts;
use crate::state::CellState;

/// Per arena: what the running episode has cost so far.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct TwinMeter {
    /// Energy delivered by the motors (J).
    pub energy: f32,
    pub joint_limit_events: u32,
    pub collision_events: u32,
    at_limit: bool,
    in_collision: bool,
}

impl TwinMeter {
    /// Counts the beginnings of limit and collision contacts from this step's state.
    pub fn observe(&mut self, at_limit: bool, in_collision: bool) {
        self.joint_limit_events += u32::from(at_limit && !self.at_limit);
        self.collision_events += u32::from(in_collision && !self.in_collision);
        self.at_limit = at_limit;
        self.in_collision = in_collision;
    }

    /// Writes the episode's figures into its log; `cycle_time` only for a successful one.
    pub fn report(&self, episode: &mut Episode, cycle_time: Option<f32>) {
        let m = &mut episode.metrics;
        m.insert("energy_j".into(), self.energy);
        m.insert("joint_limit_events".into(), self.joint_limit_events as f32);
        m.insert("collision_events".into(), self.collision_events as f32);
        if let Some(t) = cycle_time {
            m.insert("cycle_time_s".into(), t);
        }
    }
}

/// Adds Σ|τ·ω|·dt of the last physics step (runs every physics step).
pub fn meter_energy(settings: Res<SimSettings>, joints: Query<&JointState>, mut arenas: Query<(&CellParts, &mut TwinMeter)>) {
    for (parts, mut meter) in &mut arenas {
        let power: f32 = joints.iter_many(parts.joints).map(|s| (s.effort * s.velocity).abs()).sum();
        meter.energy += power * settings.dt;
    }
}

/// Whether any link of the arm touches the cell (table, fixtures, parts), not counting the
/// gripper's body touching the part it is meant to pick.
pub fn arm_touches_cell(world: &PhysicsWorld, arm_bodies: &[RigidBodyHandle], gripper_body: Option<RigidBodyHandle>, part_body: RigidBodyHandle) -> bool {
    arm_bodies.iter().filter_map(|&b| Some((b, world.bodies.get(b)?))).any(|(handle, body)| {
        body.colliders().iter().any(|&own| {
            world.contact_pairs_with(own).any(|pair| {
                let other = if pair.collider1 == own { pair.collider2 } else { pair.collider1 };
                let other_body = world.colliders.get(other).and_then(|c| c.parent());
                let intended = Some(handle) == gripper_body && other_body == Some(part_body);
                pair.has_any_active_contact() && !intended
            })
        })
    })
}

/// Counts joint-limit and collision events of this control step.
pub fn count_events(
    links: Query<&Link>,
    grippers: Query<&twinbots_sim::Mount, With<VacuumGripper>>,
    mut arenas: Query<(&Arena, &CellParts, &CellState, &mut TwinMeter)>,
) {
    for (arena, parts, state, mut meter) in &mut arenas {
        let arm_bodies: Vec<RigidBodyHandle> = links.iter().filter(|l| l.robot == parts.robot).map(|l| l.body).collect();
        let gripper_body = grippers.get(parts.gripper).ok().and_then(|m| links.get(m.link).ok()).map(|l| l.body);
        let Ok(part) = links.get(parts.part) else { continue };
        let touching = arm_touches_cell(&arena.world, &arm_bodies, gripper_body, part.body);
        meter.observe(state.arm.at_joint_limit(), touching);
    }
}
