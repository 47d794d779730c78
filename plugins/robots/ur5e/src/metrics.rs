//! The digital-twin figures of paper §4, per episode: energy the joint motors spend
//! (∫ Σ|τ·ω| dt, integrated every physics step), joint-limit events, collision events and
//! protective stops (each counted once when it begins), and the cycle time of a successful
//! episode.

use bevy::prelude::*;
use twinbots_sim::{ContactSensor, JointState, SimSettings, Touched};
use twinbots_task::Episode;

use crate::cell::CellParts;
use crate::state::CellState;

/// Per arena: what the running episode has cost so far.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct TwinMeter {
    /// Energy delivered by the motors (J).
    pub energy: f32,
    pub joint_limit_events: u32,
    pub collision_events: u32,
    pub protective_stops: u32,
    at_limit: bool,
    in_collision: bool,
    stopped: bool,
}

impl TwinMeter {
    /// Counts the beginnings of limit contacts, collisions and protective stops from this
    /// step's state.
    pub fn observe(&mut self, at_limit: bool, in_collision: bool, stopped: bool) {
        self.joint_limit_events += u32::from(at_limit && !self.at_limit);
        self.collision_events += u32::from(in_collision && !self.in_collision);
        self.protective_stops += u32::from(stopped && !self.stopped);
        self.at_limit = at_limit;
        self.in_collision = in_collision;
        self.stopped = stopped;
    }

    /// Writes the episode's figures into its log; `cycle_time` only for a successful one.
    pub fn report(&self, episode: &mut Episode, cycle_time: Option<f32>) {
        let m = &mut episode.running.metrics;
        m.insert("energy_j".into(), self.energy);
        m.insert("joint_limit_events".into(), self.joint_limit_events as f32);
        m.insert("collision_events".into(), self.collision_events as f32);
        m.insert("protective_stops".into(), self.protective_stops as f32);
        if let Some(t) = cycle_time {
            m.insert("cycle_time_s".into(), t);
        }
    }
}

/// Adds Σ|τ·ω|·dt of the last physics step (runs every physics step).
pub fn meter_energy(
    settings: Res<SimSettings>,
    joints: Query<&JointState>,
    mut arenas: Query<(&CellParts, &mut TwinMeter)>,
) {
    for (parts, mut meter) in &mut arenas {
        let power: f32 = joints.iter_many(parts.joints).map(|s| (s.effort * s.velocity).abs()).sum();
        meter.energy += power * settings.dt;
    }
}

/// Whether any link of the arm touches the cell (table, fixtures, parts), as its contact
/// sensors report, not counting the cup's body touching the part it is meant to pick.
pub fn arm_in_collision(parts: &CellParts, sensors: &Query<&ContactSensor>) -> bool {
    let cup = parts.contact_sensors[parts.contact_sensors.len() - 1];
    parts.contact_sensors.iter().filter_map(|&s| Some((s, sensors.get(s).ok()?))).any(|(s, sensor)| {
        if s == cup { sensor.touches_other_than(Touched::Link(parts.part)) } else { sensor.touching() }
    })
}

/// Counts joint-limit and collision events and protective stops of this control step, from
/// the arm's encoders, contact sensors and safety system (devices and the controller: no
/// physics world is read, under any design pattern).
pub fn count_events(sensors: Query<&ContactSensor>, mut arenas: Query<(&CellParts, &CellState, &mut TwinMeter)>) {
    for (parts, state, mut meter) in &mut arenas {
        meter.observe(state.arm.at_joint_limit(), arm_in_collision(parts, &sensors), state.safety.stopped());
    }
}
