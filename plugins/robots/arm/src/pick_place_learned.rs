//! Pick-and-place learned end to end for any arm with a cell and a vacuum gripper (the UR5e's
//! `pick-place-learned`: Gymnasium-Robotics' FetchPickAndPlace in the assembly cell; the goal,
//! the reward and the scripted baseline are [`twinbots_task::cell::learned`]'s). The policy
//! moves the tool and switches the suction cup; the part starts anywhere on the free table
//! around the cell's fixtures and must be brought to a goal drawn per episode, on the table or
//! in the air.
//!
//! Action: Box([-1, 1]⁴): the tool's velocity (× `TOOL_SPEED`, the task's frame) and the suction
//! (on above 0). The controller turns the velocity into joint speeds with the tool kept
//! pointing down ([`Arm::tool_velocity`]) within safety planes around the work area
//! ([`crate::work_area`]), so the cup never presses into the table.
//!
//! Observation (the goal's terms first, at fixed places whatever the arm's joint count): the
//! tool and its velocity, the part's centre, its offset from the tool and its velocity (a cell
//! camera's reading; the twin reads the physics, so design patterns 1 and 2 only), the suction's
//! output and the vacuum sensor, the goal, then the joint positions. Positions are in the task's
//! frame: the base frame with its origin on the table top.

use std::sync::Arc;

use bevy::prelude::*;
use rand::Rng;
use twinbots_sim::{Motor, MotorCommand, SimSettings, Supervisor, VacuumGripper};
use twinbots_task::cell::learned::{
    ACTION_DIM, AIR_GOALS, AIR_HEIGHT, APPROACH_WEIGHT, EPISODE_STEPS, GoalTerms, Judged, PART_REST_Z, STOP_PENALTY,
    TOOL_SPEED, approach, flag, in_air, within_planes,
};
use twinbots_task::cell::parts::{PART_HEIGHT, part_seat};
use twinbots_task::cell::program::SpeedSlider;
use twinbots_task::{
    Action, Episode, GoalChange, GoalSpec, ObservationTerm, RewardTerm, SolvedCriterion, Space, StartEvent,
    TaskDefinition, TaskTerms, TerminationTerm,
};

use crate::ArmJoints;
use crate::arm::{Arm, START_SPREAD};
use crate::pick_place::ArmCell;
use crate::reach::{ReachState, STOP_TERM};
use crate::work_area::WorkArea;

/// Where the goal's terms lie in the observation.
pub const GOAL_TERMS: GoalTerms =
    GoalTerms { tcp_position: 0, part_position: 6, part_velocity: 12, suction: 15, holding: 16, goal_position: 17 };

/// What the goal's judge reads of the state.
fn judged(s: &ReachState) -> Judged {
    Judged { part: s.part, suction: s.suction, stopped: s.stopped }
}

/// The learned pick-and-place as a task of `arm` (which has a cell and a gripper, and so a
/// work area): a sparse −1 a step until the goal is met (which ends the episode, a success),
/// the cup's distance from the part, a protective stop's penalty (the stop ends it too, a
/// failure), `EPISODE_STEPS` at most. Solved when 95 % of 200 evaluation episodes succeed, as
/// the UR5e's.
pub fn pick_place_learned_task(arm: &Arc<Arm>) -> TaskDefinition<ReachState> {
    let area = arm.work_area.clone().expect("the learned pick-and-place is a task of arms with a cell");
    let n = arm.dof();
    let (lo, hi) = arm.file.ranges.iter().fold((0.0f64, 0.0f64), |(l, h), &(a, b)| (l.min(a), h.max(b)));
    let table = Vec3::Z * area.table;
    let tool = move |s: &ReachState| s.tool - table;
    let plausible = 5.0;
    TaskDefinition {
        name: format!("{}-pick-place-learned", arm.file.name),
        terms: TaskTerms {
            observations: vec![
                ObservationTerm::new("tool_position", 3, move |s: &ReachState, out: &mut Vec<f32>| {
                    out.extend(tool(s).to_array())
                })
                .plausible(-plausible, plausible),
                ObservationTerm::new("tool_velocity", 3, |s: &ReachState, out: &mut Vec<f32>| {
                    out.extend(s.tool_velocity.to_array())
                })
                .plausible(-20.0, 20.0),
                ObservationTerm::new("part_position", 3, |s: &ReachState, out: &mut Vec<f32>| {
                    out.extend(s.part.position.to_array())
                })
                .plausible(-plausible, plausible),
                ObservationTerm::new("part_offset", 3, move |s: &ReachState, out: &mut Vec<f32>| {
                    out.extend((s.part.position - tool(s)).to_array())
                })
                .plausible(-2.0 * plausible, 2.0 * plausible),
                // A part knocked off the table falls; 20 m/s bounds any fall in the cell.
                ObservationTerm::new("part_velocity", 3, |s: &ReachState, out: &mut Vec<f32>| {
                    out.extend(s.part.velocity.to_array())
                })
                .plausible(-20.0, 20.0),
                ObservationTerm::new("suction", 1, |s: &ReachState, out: &mut Vec<f32>| out.push(flag(s.suction)))
                    .bounded(0.0, 1.0),
                ObservationTerm::new("holding", 1, |s: &ReachState, out: &mut Vec<f32>| out.push(flag(s.part.held)))
                    .bounded(0.0, 1.0),
                ObservationTerm::new("goal_position", 3, |s: &ReachState, out: &mut Vec<f32>| {
                    out.extend(s.part_goal.to_array())
                })
                .plausible(-plausible, plausible),
                ObservationTerm::new("joint_positions", n, |s: &ReachState, out: &mut Vec<f32>| out.extend(&s.q))
                    .bounded(lo as f32 - 0.1, hi as f32 + 0.1),
            ],
            rewards: vec![
                RewardTerm::new("goal_missed", -1.0, |s: &ReachState| flag(!judged(s).meets(s.part_goal)))
                    .bounded(0.0, 1.0),
                RewardTerm::new(STOP_TERM, -STOP_PENALTY, |s: &ReachState| flag(s.stopped)).bounded(0.0, 1.0),
                // The cup's distance from the part's top: it leads exploration to the part (the
                // cup cannot push the part; it must seize it), and hindsight keeps it.
                RewardTerm::new("approach", -APPROACH_WEIGHT, move |s: &ReachState| approach(tool(s), s.part.position))
                    .bounded(0.0, 3.0),
            ],
            terminations: vec![
                TerminationTerm::goal("goal_met", |s: &ReachState| judged(s).meets(s.part_goal)),
                TerminationTerm::new(STOP_TERM, |s: &ReachState| s.stopped),
            ],
            time_limit: Some(EPISODE_STEPS),
            start_events: vec![new_pick(arm, area)],
        },
        action_space: Space::uniform_box(ACTION_DIM, -1.0, 1.0),
        solved: Some(SolvedCriterion::success_rate(200, 0.95)),
        goal: Some(GoalSpec { dim: 3, achieved, desired, substitute, change }),
    }
}

/// Start event: the arm near home, the part standing somewhere on the free table (any yaw), a
/// goal on the table or in the air.
fn new_pick(arm: &Arc<Arm>, area: WorkArea) -> StartEvent<ReachState> {
    let arm = arm.clone();
    let pick = arm.fixtures().expect("an arm with a work area stands in a cell").pick;
    StartEvent::new("new_pick", move |s: &mut ReachState, rng| {
        s.start_pose = arm.sample_around_home(rng, START_SPREAD);
        s.last_action.clear();
        s.previous_action.clear();
        s.suction = false;
        s.program = None;
        // The Supervisor seats the part at its pick seat plus this offset
        // (`pick_place::place_part`): here, on the table top.
        s.part_offset = area.sample(rng).extend(area.table) - part_seat(pick);
        s.part_yaw = rng.random_range(-std::f32::consts::PI..=std::f32::consts::PI);
        let goal = area.sample(rng);
        let lift = if rng.random_bool(AIR_GOALS) { rng.random_range(AIR_HEIGHT[0]..=AIR_HEIGHT[1]) } else { 0.0 };
        s.part_goal = goal.extend(PART_REST_Z + lift);
        // The base-frame point the live view marks.
        s.target = s.part_goal + Vec3::Z * area.table;
    })
}

/// The policy's action: the tool's velocity (within the safety planes, the tool turned down,
/// times the arena's speed slider) and the suction's output; an arm in a protective stop holds.
pub fn apply_action(
    arm: Res<Arm>,
    mut arenas: Query<(&ArmJoints, &Action, &mut ReachState, Option<&SpeedSlider>)>,
    mut motors: Query<&mut Motor>,
) {
    let Some(area) = &arm.work_area else { return };
    for (joints, action, mut state, slider) in &mut arenas {
        if action.0.is_empty() {
            continue;
        }
        let speeds = if state.stopped {
            vec![0.0; joints.0.len()]
        } else {
            let a = |i: usize| action.0.get(i).copied().unwrap_or(0.0).clamp(-1.0, 1.0);
            let tool = state.tool - Vec3::Z * area.table;
            let v = within_planes(&area.planes, tool, Vec3::new(a(0), a(1), a(2)) * TOOL_SPEED);
            state.suction = a(3) > 0.0;
            let scale = slider.map_or(1.0, |s| s.0);
            arm.tool_velocity(&state.q, |_| v.as_dvec3()).into_iter().map(|s| s * scale).collect()
        };
        for (&joint, speed) in joints.0.iter().zip(speeds) {
            if let Ok(mut m) = motors.get_mut(joint) {
                m.command = MotorCommand::Velocity(speed);
            }
        }
        state.push_action(&action.0);
    }
}

/// The part's reading: its centre and velocity in the task's frame (the cell camera's
/// stand-in: the physics).
pub fn read_part(arm: Res<Arm>, supervisor: Supervisor, mut arenas: Query<(&ArmCell, &mut ReachState)>) {
    let Some(area) = &arm.work_area else { return };
    let to_base = arm.base.inverse();
    for (cell, mut state) in &mut arenas {
        let Some(link) = supervisor.link_state(cell.part) else { continue };
        let pose = to_base * link.pose;
        let centre = pose.translation + pose.rotation * Vec3::Z * (PART_HEIGHT / 2.0);
        state.part.position = centre - Vec3::Z * area.table;
        state.part.velocity = to_base.rotation * link.linvel;
    }
}

/// The gripper's vacuum sensor: whether the cup holds the part. (Apart from [`read_part`]: the
/// Supervisor holds the grippers mutably.)
pub fn read_vacuum(grippers: Query<&VacuumGripper>, mut arenas: Query<(&ArmCell, &mut ReachState)>) {
    for (cell, mut state) in &mut arenas {
        state.part.held = grippers.get(cell.gripper).is_ok_and(|g| g.held().is_some());
    }
}

/// The figures of an episode that ended: how far the part ended from the goal, whether that
/// goal was in the air and the part lifted, the cycle time of a success, stops and energy.
pub fn report(settings: Res<SimSettings>, mut arenas: Query<(&ReachState, &mut Episode)>) {
    for (state, mut e) in &mut arenas {
        if !e.done() {
            continue;
        }
        let metrics = &mut e.running.metrics;
        metrics.insert("final_distance_mm".into(), 1e3 * (state.part.position - state.part_goal).length());
        metrics.insert("goal_in_air".into(), flag(in_air(state.part_goal)));
        metrics.insert("part_lifted".into(), flag(state.part.position.z > PART_REST_Z + 0.01));
        metrics.insert("protective_stops".into(), flag(state.stopped));
        metrics.insert("energy_j".into(), state.energy);
        if e.running.success == Some(true) {
            let cycle_time = (e.running.length + 1) as f32 * settings.control_dt();
            e.running.metrics.insert("cycle_time_s".into(), cycle_time);
        }
    }
}

/// The scripted pick-and-place over this task's observation ([`GoalTerms::scripted`]): what
/// `classic` names for it.
pub fn scripted(obs: &[f32]) -> Vec<f32> {
    GOAL_TERMS.scripted(obs)
}

fn achieved(obs: &[f32]) -> Vec<f32> {
    GOAL_TERMS.achieved(obs)
}

fn desired(obs: &[f32]) -> Vec<f32> {
    GOAL_TERMS.desired(obs)
}

fn substitute(obs: &mut [f32], goal: &[f32]) {
    GOAL_TERMS.substitute(obs, goal)
}

fn change(_obs: &[f32], next_obs: &[f32], ended_by: Option<&str>, from: &[f32], to: &[f32]) -> GoalChange {
    GOAL_TERMS.change(next_obs, ended_by == Some(STOP_TERM), from, to)
}
