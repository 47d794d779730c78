//! Reach for any arm: move the tool link to a target and come to rest there within 1 cm, a
//! goal-conditioned task (Gymnasium-Robotics' FetchReach: the position only, as a 5-DoF arm
//! cannot take every orientation). The UR5e reach's terms less its tilt and its stop forfeit:
//! motion costs, an arrival bonus that ends the episode, a protective stop at a joint's limit
//! that ends it as a failure; and a cost of a joint's approach to its stop.
//!
//! The observation starts with the tool (3), target − tool (3) and the tool's velocity (3), so
//! the goal interface reads them at fixed places whatever the arm's joint count; then the
//! joints' positions, speeds and the last action (one per joint each).

use std::sync::Arc;

use bevy::prelude::*;
use twinbots_task::{
    GoalChange, GoalSpec, ObservationTerm, RewardTerm, SolvedCriterion, Space, StartEvent, TaskDefinition, TaskTerms,
    TerminationTerm,
};

use twinbots_sim::rapier::na::{DMatrix, DVector};
use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_task::cell::learned::PartReading;
use twinbots_task::cell::program::{Program, ToolReading};

use crate::arm::{Arm, START_SPREAD};

/// The name of the termination term a protective stop ends an episode with.
pub const STOP_TERM: &str = "protective_stop";
/// Control steps before a reach is given up.
pub const EPISODE_STEPS: u32 = 100;
/// A reach succeeds when the tool is this close to the target (m)…
pub use crate::arm::REACH_TOLERANCE;
/// …and has come to rest: slower than this (m/s).
pub const SETTLED_SPEED: f32 = 0.05;
/// The bonus for arriving (which ends the reach).
pub const ARRIVAL_BONUS: f32 = 10.0;
/// A protective stop's penalty in steps of the pose cost where it tripped: the UR5e reach's (see
/// its `STOP_PENALTY_STEPS`). The UR5e's reach also forfeits the arrival bonus in a stop; this
/// one does not (its figures were measured without it).
pub const STOP_PENALTY_STEPS: f32 = 64.0;
const DISTANCE_WEIGHT: f32 = 1.0;
/// Cost per rad (or m) past the soft limits, per step.
const JOINT_LIMIT_WEIGHT: f32 = 5.0;
const PRECISION_WEIGHT: f32 = 0.1;
/// Distances beyond this (m) are no reach: the range a RobotServer checks rewards against.
const MAX_DISTANCE: f32 = 5.0;

/// What the arm's controller knows at a step (one per arena): its joints from the encoders,
/// the tool from its own kinematics, the target, the actions, whether its safety system
/// stopped it, and the start the next episode drew.
#[derive(Component, Clone, Debug, Default)]
pub struct ReachState {
    pub q: Vec<f32>,
    pub qd: Vec<f32>,
    /// The tool link's position, velocity and z axis (its gripper's) in the base frame.
    pub tool: Vec3,
    pub tool_velocity: Vec3,
    pub tool_axis: Vec3,
    pub target: Vec3,
    pub last_action: Vec<f32>,
    pub previous_action: Vec<f32>,
    /// The protective stop, latched until it is unlocked: a joint entering the last
    /// [`crate::arm::LIMIT_MARGIN`] of its range, or the safety system's (`safety`).
    pub stopped: bool,
    /// The controller's safety system: a joint beyond its URDF velocity or effort limit
    /// ([`twinbots_task::safety`], as the UR5e's) stops the arm.
    pub safety: twinbots_task::safety::Safety,
    /// How far the joints are past their soft limits, summed (rad or m).
    pub limit_depth: f32,
    /// Whether a joint was within the stop's margin at the last reading: the stop trips as a
    /// joint enters the margin, so an arm stopped there can be unlocked and home out of it.
    pub at_limit: bool,
    pub start_pose: Vec<f32>,
    /// The energy the joint motors delivered this episode (J): ∫ Σ|τ·ω| dt.
    pub energy: f32,
    /// Pick-and-place ([`crate::pick_place`]): the cell program's progress (none in a reach),
    /// whether it wants the suction on, and where the start drew the part in its pocket.
    pub program: Option<Program>,
    pub suction: bool,
    pub part_offset: Vec3,
    pub part_yaw: f32,
    /// Learned pick-and-place ([`crate::pick_place_learned`]): the part as the cell measures it
    /// and where the task wants it, in the task's frame (the base frame from the table top).
    pub part: PartReading,
    pub part_goal: Vec3,
}

/// A straight move has brought the tool down only once its axis is within this of the
/// vertical (rad): [`crate::arm::TILT_TOLERANCE`].
pub use crate::arm::TILT_TOLERANCE;

/// The cell program reads the tool as the controller does: close, at rest, not stopped; level
/// (pointing down) where a straight move must leave it. A free move is the reach policy's,
/// which does not steer the tool's axis.
impl ToolReading for ReachState {
    fn tool(&self) -> Vec3 {
        self.tool
    }

    fn has_reached_within(&self, target: Vec3, tolerance: f32, level: bool) -> bool {
        let tilt = self.tool_axis.angle_between(-Vec3::Z);
        !self.stopped
            && (target - self.tool).length() < tolerance
            && self.tool_velocity.length() < SETTLED_SPEED
            && (!level || tilt < TILT_TOLERANCE)
    }
}

impl ReachState {
    /// Takes the joints' readings (the controller's order) and what the controller's kinematics
    /// make of them: the tool, the soft limits' depth. Returns whether a joint is within the
    /// stop's margin (the caller decides what the stop does).
    pub fn read(&mut self, arm: &Arm, q: Vec<f32>, qd: Vec<f32>) -> bool {
        let (tool, velocity, axis) = arm.tool_motion(&q, &qd);
        self.tool = tool.as_vec3();
        self.tool_velocity = velocity.as_vec3();
        self.tool_axis = axis.as_vec3();
        self.limit_depth = arm.limit_depth(&q);
        let at_limit = arm.at_limit(&q);
        self.q = q;
        self.qd = qd;
        at_limit
    }

    pub fn distance(&self) -> f32 {
        (self.target - self.tool).length()
    }

    /// Close and at rest, not stopped.
    pub fn arrived(&self) -> bool {
        !self.stopped && arrived_at(self.tool, self.tool_velocity, self.target)
    }

    /// Records the action the arm was given (the policy observes the last).
    pub fn push_action(&mut self, action: &[f32]) {
        self.previous_action = std::mem::take(&mut self.last_action);
        self.last_action = action.iter().map(|a| a.clamp(-1.0, 1.0)).collect();
        self.previous_action.resize(self.last_action.len(), 0.0);
    }
}

fn arrived_at(tool: Vec3, velocity: Vec3, target: Vec3) -> bool {
    (target - tool).length() < REACH_TOLERANCE && velocity.length() < SETTLED_SPEED
}

fn precision(distance: f32) -> f32 {
    1.0 - (-(distance / 0.02).powi(2)).exp()
}

/// The cost of one step with the tool `distance` from the target.
fn pose_cost(distance: f32) -> f32 {
    DISTANCE_WEIGHT * distance.min(MAX_DISTANCE) + PRECISION_WEIGHT * precision(distance)
}

/// The reward terms that depend on the target, as one number (what hindsight relabelling
/// recomputes for another goal): distance, precision, arrival, the stop's penalty.
fn target_reward(distance: f32, arrived: bool, stopped: bool) -> f32 {
    let mut r = -pose_cost(distance) + if arrived { ARRIVAL_BONUS } else { 0.0 };
    if stopped {
        r -= STOP_PENALTY_STEPS * pose_cost(distance);
    }
    r
}

/// The reach task of `arm`.
pub fn reach_task(arm: &Arc<Arm>) -> TaskDefinition<ReachState> {
    let n = arm.dof();
    let (lo, hi) = arm.file.ranges.iter().fold((0.0f64, 0.0f64), |(l, h), &(a, b)| (l.min(a), h.max(b)));
    let top_speed = arm.file.speed_limits.iter().fold(0.0f64, |m, &s| m.max(s)) as f32;
    let max_pose_cost = pose_cost(MAX_DISTANCE);
    TaskDefinition {
        name: arm.file.name.clone(),
        terms: TaskTerms {
            observations: vec![
                // Plausible: 5 m around the base (an arm's reach is under 2 m).
                ObservationTerm::new("tool_position", 3, |s: &ReachState, out: &mut Vec<f32>| {
                    out.extend(s.tool.to_array())
                })
                .plausible(-5.0, 5.0),
                ObservationTerm::new("target_offset", 3, |s: &ReachState, out: &mut Vec<f32>| {
                    out.extend((s.target - s.tool).to_array())
                })
                .plausible(-10.0, 10.0),
                ObservationTerm::new("tool_velocity", 3, |s: &ReachState, out: &mut Vec<f32>| {
                    out.extend(s.tool_velocity.to_array())
                })
                .plausible(-20.0, 20.0),
                ObservationTerm::new("joint_positions", n, |s: &ReachState, out: &mut Vec<f32>| out.extend(&s.q))
                    .bounded(lo as f32 - 0.1, hi as f32 + 0.1),
                // Four times the fastest joint's task speed: what a working encoder can report.
                ObservationTerm::new("joint_velocities", n, |s: &ReachState, out: &mut Vec<f32>| out.extend(&s.qd))
                    .plausible(-4.0 * top_speed, 4.0 * top_speed),
                ObservationTerm::new("last_action", n, move |s: &ReachState, out: &mut Vec<f32>| {
                    out.extend((0..n).map(|k| s.last_action.get(k).copied().unwrap_or(0.0)))
                })
                .bounded(-1.0, 1.0),
            ],
            rewards: vec![
                RewardTerm::new("distance", -DISTANCE_WEIGHT, |s: &ReachState| s.distance().min(MAX_DISTANCE))
                    .bounded(0.0, MAX_DISTANCE),
                RewardTerm::new("precision", -PRECISION_WEIGHT, |s: &ReachState| precision(s.distance()))
                    .bounded(0.0, 1.0),
                RewardTerm::new("effort", -0.01, |s: &ReachState| s.last_action.iter().map(|a| a * a).sum())
                    .bounded(0.0, n as f32),
                RewardTerm::new("action_rate", -0.02, |s: &ReachState| {
                    s.last_action.iter().zip(&s.previous_action).map(|(a, b)| (a - b).powi(2)).sum()
                })
                .bounded(0.0, 4.0 * n as f32),
                // A joint's approach to its stop costs before the stop does: SAC otherwise drives
                // a joint that barely moves the tool (the xArm7's wrist pitch) into its stop at
                // full speed (measured: 90 % of its reaches ended so at 90,000 steps).
                RewardTerm::new("joint_limits", -JOINT_LIMIT_WEIGHT, |s: &ReachState| s.limit_depth)
                    .bounded(0.0, n as f32 * crate::arm::SOFT_LIMIT_ZONE as f32),
                RewardTerm::new("arrival", ARRIVAL_BONUS, |s: &ReachState| f32::from(u8::from(s.arrived())))
                    .bounded(0.0, 1.0),
                RewardTerm::new(
                    STOP_TERM,
                    -STOP_PENALTY_STEPS,
                    |s: &ReachState| {
                        if s.stopped { pose_cost(s.distance()) } else { 0.0 }
                    },
                )
                .bounded(0.0, max_pose_cost),
            ],
            terminations: vec![
                TerminationTerm::goal("arrived", |s: &ReachState| s.arrived()),
                TerminationTerm::new(STOP_TERM, |s: &ReachState| s.stopped),
            ],
            time_limit: Some(EPISODE_STEPS),
            start_events: vec![new_reach(arm)],
        },
        action_space: Space::uniform_box(n, -1.0, 1.0),
        // The UR5e reach's margin over the 95 % a twin must reach.
        solved: Some(SolvedCriterion::success_rate(200, 0.98)),
        goal: Some(reach_goal()),
    }
}

/// Start event: a new target and a start near home. The stop stays locked: the Supervisor's
/// reset unlocks it (patterns 1 and 2), or the arm's homing once braked to rest (pattern 3).
fn new_reach(arm: &Arc<Arm>) -> StartEvent<ReachState> {
    let arm = arm.clone();
    StartEvent::new("new_reach", move |s: &mut ReachState, rng| {
        s.target = arm.sample_target(rng);
        s.start_pose = arm.sample_around_home(rng, START_SPREAD);
        s.last_action.clear();
        s.previous_action.clear();
    })
}

fn point(values: &[f32]) -> Vec3 {
    Vec3::new(values[0], values[1], values[2])
}

/// Where the tool, target offset, tool velocity and joint positions are in the observation.
const TOOL: usize = 0;
const OFFSET: usize = 3;
const VELOCITY: usize = 6;
const JOINT_POSITIONS: usize = 9;

/// Gain of the classical controller (1/s): the tool's speed towards the target per metre away…
const RESOLVED_RATE_GAIN: f64 = 4.0;
/// …up to this tool speed (m/s): the UR5e controller's.
const RESOLVED_RATE_MAX_SPEED: f64 = 0.5;
/// Its damping (m²): keeps the least-squares step finite near a singularity.
const RESOLVED_RATE_DAMPING: f64 = 1e-4;

/// The reach's classical controller (what `classic` names for a robot file's arm in `demos`,
/// `study` and `eval`): joint speeds, as actions, that move the tool towards the target by
/// damped least squares on the position rows of the chain's Jacobian (resolved-rate control),
/// the tool at most 0.5 m/s, scaled as a whole so that no joint exceeds its task speed (the
/// motion keeps its direction). From the observation alone, as a policy acts.
pub fn resolved_rate(file: &RobotFile, obs: &[f32]) -> Vec<f32> {
    let n = file.joints.len();
    let q: Vec<f64> = obs[JOINT_POSITIONS..JOINT_POSITIONS + n].iter().map(|&v| v as f64).collect();
    let columns = file.chain.jacobian(&file.chain_order(&q));
    let j = DMatrix::from_fn(3, n, |r, c| columns[c][r]);
    let offset = point(&obs[OFFSET..]).as_dvec3();
    let v = (offset * RESOLVED_RATE_GAIN).clamp_length_max(RESOLVED_RATE_MAX_SPEED);
    let Some(damped) = (&j * j.transpose() + DMatrix::identity(3, 3) * RESOLVED_RATE_DAMPING).cholesky() else {
        return vec![0.0; n];
    };
    let chain_speeds = j.transpose() * damped.solve(&DVector::from_row_slice(&[v.x, v.y, v.z]));
    // The Jacobian's columns are the chain's order; actions are the controller's.
    let mut actions = vec![0.0; n];
    for (c, k) in file.controller_index().into_iter().enumerate() {
        actions[k] = chain_speeds[c] / file.speed_limits[k];
    }
    let top = actions.iter().fold(1.0f64, |m, a| m.max(a.abs()));
    actions.iter().map(|a| (a / top) as f32).collect()
}

fn achieved(obs: &[f32]) -> Vec<f32> {
    obs[TOOL..TOOL + 3].to_vec()
}

fn desired(obs: &[f32]) -> Vec<f32> {
    (point(&obs[TOOL..]) + point(&obs[OFFSET..])).to_array().to_vec()
}

fn substitute(obs: &mut [f32], goal: &[f32]) {
    let offset = point(goal) - point(&obs[TOOL..]);
    obs[OFFSET..OFFSET + 3].copy_from_slice(&offset.to_array());
}

/// The target terms under each goal, and arrival at each; a step the protective stop ended
/// keeps its stop (its penalty follows the goal) and arrives nowhere.
fn change(_obs: &[f32], next_obs: &[f32], ended_by: Option<&str>, from: &[f32], to: &[f32]) -> GoalChange {
    let (tool, velocity) = (point(&next_obs[TOOL..]), point(&next_obs[VELOCITY..]));
    let stopped = ended_by == Some(STOP_TERM);
    let terms = |goal: &[f32]| {
        let target = point(goal);
        let arrived = !stopped && arrived_at(tool, velocity, target);
        (target_reward((target - tool).length(), arrived, stopped), arrived)
    };
    let ((before, ends_at_from), (after, ends_at_to)) = (terms(from), terms(to));
    GoalChange { reward: after - before, ends_at_from, ends_at_to }
}

/// The reach's goal interface: the goal achieved is the tool's position, the goal desired the target.
pub fn reach_goal() -> GoalSpec {
    GoalSpec { dim: 3, achieved, desired, substitute, change }
}
