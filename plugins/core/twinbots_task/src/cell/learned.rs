//! Pick-and-place learned end to end, every arm's (Gymnasium-Robotics' FetchPickAndPlace in the
//! assembly cell): what meets a goal, the safety planes the tool keeps within, the scripted
//! baseline and the goal interface's judgement. Positions are in the task's frame: the arm's
//! base frame with its origin on the table top (z: height above the table), so the part
//! standing on the table has its centre at [`PART_REST_Z`] whatever the arm.
//!
//! The policy moves the tool and switches the suction cup; the part starts anywhere on the free
//! table and must be brought within [`GOAL_TOLERANCE`] of a goal drawn per episode — on the
//! table (then let go there, at rest) or, half the time, in the air (then held there). The
//! reward is sparse (−1 a step until the goal is met, which ends the episode) plus the cup's
//! distance from the part (goal-free, so hindsight relabelling keeps it).

use crate::GoalChange;
use bevy::prelude::*;

use super::parts::PART_HEIGHT;

/// Control steps before an episode is given up (4 s at 40 ms).
pub const EPISODE_STEPS: u32 = 100;
/// Tool speed (m/s) of a full-scale action: 2 cm a control step of 40 ms.
pub const TOOL_SPEED: f32 = 0.5;
/// The part's centre within this distance (m) of the goal meets it.
pub const GOAL_TOLERANCE: f32 = 0.02;
/// A part let go on the table counts only once at rest: slower than this (m/s).
pub const REST_SPEED: f32 = 0.05;
/// A part standing on the table has its centre this high.
pub const PART_REST_Z: f32 = PART_HEIGHT / 2.0;
/// The share of goals in the air, and how high above its resting height (m) such a goal holds
/// the part's centre.
pub const AIR_GOALS: f64 = 0.5;
pub const AIR_HEIGHT: [f32; 2] = [0.03, 0.20];
/// Gain (1/s) of the safety planes: within d of one the tool may close on it at most this × d
/// a second.
pub const PLANE_GAIN: f32 = 8.0;
/// A protective stop costs this many steps' −1: more than a failing episode's discounted rest
/// for γ ≤ 0.98 (1 / (1 − 0.98)), so stopping on purpose never pays.
pub const STOP_PENALTY: f32 = 50.0;
/// Weight (per m) of the cost of the cup's distance from the part's top.
pub const APPROACH_WEIGHT: f32 = 1.0;
/// The action: the tool's velocity (× [`TOOL_SPEED`]) and the suction (on above 0).
pub const ACTION_DIM: usize = 4;
/// The safety planes' floor above the table: a grip gap above a standing part's top, where the
/// cup seizes it and a part it holds hangs just clear of the table.
pub const TOOL_FLOOR: f32 = PART_HEIGHT + 0.003;
/// …and their ceiling above the table (m), unless an arm's home lies higher.
pub const PLANE_CEILING: f32 = 0.40;

/// SAC + HER settings of the learned pick-and-place (`train ARM --task pick-place-learned`, keys
/// of `[sac]`): RL Zoo's for FetchPickAndPlace (τ 0.05, 4 future goals per sample) with SB3's
/// learning rate 3e-4 (RL Zoo's 1e-3 solved 3 of 5 UR5e seeds: two learnt and then unlearnt;
/// at 3e-4 all 5 solve, median 380 k steps), the HER paper's γ 0.98 (a pick-and-place takes
/// ≈ 50 steps; measured on the UR5e, seed 0, with the approach cost: 31.5 % success at 260 k
/// steps where γ 0.95 with the dense part distance too had 0 % at 120 k), 128-unit layers
/// (RL Zoo's TQC uses 3 × 512, too slow a gradient step for two cores), observation
/// normalisation, and half a gradient step per env step of the 4 arenas (the HER paper's 40
/// batches per 100 steps of 2 episodes).
pub const SAC_HYPERPARAMS: &str = "learning_rate = 3e-4
gamma = 0.98
tau = 0.05
hidden = [128, 128]
batch_size = 256
her_goals = 4
normalize_observations = true
learning_starts = 1000
gradient_steps = 2
log_interval = 1000";

/// How the learned pick-and-place trains: SAC + HER, 4 arenas, a million steps at most,
/// evaluated on 200 episodes every 5 rows (20,000 steps).
pub fn training() -> crate::robot::TrainingDefaults {
    crate::robot::TrainingDefaults {
        algo: "sac",
        eval_episodes: 200,
        algos: vec![crate::robot::AlgoDefaults {
            algo: "sac",
            arenas: 4,
            timesteps: 1_000_000,
            eval_every: 5,
            hyperparams: SAC_HYPERPARAMS,
        }],
    }
}

/// The part as the cell measures it: its centre and velocity in the task's frame — a cell
/// camera's reading on a real cell, the physics' in the twin — and whether the cup holds it
/// (the gripper's vacuum sensor).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PartReading {
    pub position: Vec3,
    pub velocity: Vec3,
    pub held: bool,
}

/// What the judge of a goal needs: where the part is, how it moves, whether the cup holds it or
/// sucks, whether the arm stands in a protective stop.
#[derive(Clone, Copy, Debug)]
pub struct Judged {
    pub part: PartReading,
    pub suction: bool,
    pub stopped: bool,
}

impl Judged {
    /// Whether the goal is met: the part's centre within [`GOAL_TOLERANCE`] — held there for a
    /// goal in the air; for one on the table, let go (suction off, nothing held) and at rest.
    pub fn meets(&self, goal: Vec3) -> bool {
        let close = (self.part.position - goal).length() < GOAL_TOLERANCE;
        let released = !self.part.held && !self.suction && self.part.velocity.length() < REST_SPEED;
        !self.stopped && close && if in_air(goal) { self.part.held } else { released }
    }
}

/// Whether a goal lies in the air (the part must be held there) rather than on the table.
pub fn in_air(goal: Vec3) -> bool {
    goal.z > PART_REST_Z + 0.01
}

/// The cup's distance from the top of the part centred at `part` (m), within its bounds.
pub fn approach(tcp: Vec3, part: Vec3) -> f32 {
    (part + Vec3::Z * (PART_HEIGHT / 2.0) - tcp).length().min(3.0)
}

/// 1 or 0.
pub fn flag(on: bool) -> f32 {
    f32::from(u8::from(on))
}

/// The tool velocity `v` (m/s) held within the safety planes `planes` (`[min, max]` per axis):
/// towards a plane at most [`PLANE_GAIN`] × the distance left (a tool outside is sent back).
pub fn within_planes(planes: &[[f32; 2]; 3], tcp: Vec3, v: Vec3) -> Vec3 {
    let axis = |i: usize| {
        let [lo, hi] = planes[i];
        v[i].clamp(PLANE_GAIN * (lo - tcp[i]), PLANE_GAIN * (hi - tcp[i]))
    };
    Vec3::new(axis(0), axis(1), axis(2))
}

/// Where a task's observation holds what the goal is judged by (and the scripted policy reads).
#[derive(Clone, Copy, Debug)]
pub struct GoalTerms {
    pub tcp_position: usize,
    pub part_position: usize,
    pub part_velocity: usize,
    pub suction: usize,
    pub holding: usize,
    pub goal_position: usize,
}

fn point(values: &[f32]) -> Vec3 {
    Vec3::new(values[0], values[1], values[2])
}

impl GoalTerms {
    /// The goal an observation has achieved: the part's centre.
    pub fn achieved(&self, obs: &[f32]) -> Vec<f32> {
        obs[self.part_position..self.part_position + 3].to_vec()
    }

    /// The goal an observation asks for.
    pub fn desired(&self, obs: &[f32]) -> Vec<f32> {
        obs[self.goal_position..self.goal_position + 3].to_vec()
    }

    /// Rewrites `obs` so that it asks for `goal`.
    pub fn substitute(&self, obs: &mut [f32], goal: &[f32]) {
        obs[self.goal_position..self.goal_position + 3].copy_from_slice(&goal[..3]);
    }

    /// The step's reward and end under another goal, judged from the observation it led to as
    /// the task's terms judge the state: whether the goal is met (the stop's penalty and the
    /// approach do not depend on the goal). `stopped`: the step ended in a protective stop.
    pub fn change(&self, next_obs: &[f32], stopped: bool, from: &[f32], to: &[f32]) -> GoalChange {
        let judged = Judged {
            part: PartReading {
                position: point(&next_obs[self.part_position..]),
                velocity: point(&next_obs[self.part_velocity..]),
                held: next_obs[self.holding] > 0.5,
            },
            suction: next_obs[self.suction] > 0.5,
            stopped,
        };
        let (at_from, at_to) = (judged.meets(point(from)), judged.meets(point(to)));
        GoalChange { reward: flag(at_to) - flag(at_from), ends_at_from: at_from, ends_at_to: at_to }
    }

    /// A scripted pick-and-place over the task's observation, the baseline a learned policy is
    /// measured against (Fetch's scripted demonstrations do the same): over the part, down onto
    /// it with the suction on, up and over the goal, then down and let go (a goal on the table)
    /// or hold the part there (in the air). It steers the part, not the tool, once it holds it:
    /// the cup seizes a part wherever under its face it is.
    pub fn scripted(&self, obs: &[f32]) -> Vec<f32> {
        let tcp = point(&obs[self.tcp_position..]);
        let part = point(&obs[self.part_position..]);
        let goal = point(&obs[self.goal_position..]);
        let held = obs[self.holding] > 0.5;
        let top = Vec3::Z * (PART_HEIGHT / 2.0);
        let carry = 0.06;
        let flat = |v: Vec3| v.truncate().length();
        let (target, suction) = if held {
            // The tool where it would put the part at `at`.
            let tool_for = |at: Vec3| tcp + (at - part);
            if in_air(goal) {
                (tool_for(goal), true)
            } else if flat(goal - part) > 0.005 {
                (tool_for(goal + Vec3::Z * carry).with_z(tcp.z.max(goal.z + top.z + carry)), true)
            } else {
                let above = part.z - goal.z;
                (tool_for(goal), above > 0.004)
            }
        } else if flat(goal - part) < GOAL_TOLERANCE / 2.0 && !in_air(goal) {
            // Placed: let go and stay clear.
            (tcp, false)
        } else if flat(part - tcp) > 0.005 {
            ((part + top).with_z(tcp.z.max(part.z + top.z + carry)), false)
        } else {
            (part + top, true)
        };
        let v = ((target - tcp) * 8.0).clamp_length_max(TOOL_SPEED) / TOOL_SPEED;
        vec![v.x, v.y, v.z, if suction { 1.0 } else { -1.0 }]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_goal_on_the_table_is_met_by_a_part_let_go_at_rest_and_one_in_the_air_by_a_part_held_there() {
        let on_table = Vec3::new(-0.45, 0.0, PART_REST_Z);
        let in_the_air = on_table + Vec3::Z * 0.1;
        let part = |position: Vec3, held: bool| PartReading { position, velocity: Vec3::ZERO, held };
        let judged = |part, suction, stopped| Judged { part, suction, stopped };
        assert!(judged(part(on_table + Vec3::X * 0.015, false), false, false).meets(on_table));
        assert!(!judged(part(on_table + Vec3::X * 0.025, false), false, false).meets(on_table), "2 cm");
        assert!(!judged(part(on_table, true), true, false).meets(on_table), "still held");
        assert!(!judged(part(on_table, false), true, false).meets(on_table), "still sucking");
        let moving = PartReading { velocity: Vec3::X * 0.2, ..part(on_table, false) };
        assert!(!judged(moving, false, false).meets(on_table), "rolling");
        assert!(judged(part(in_the_air, true), true, false).meets(in_the_air));
        assert!(!judged(part(in_the_air, false), false, false).meets(in_the_air), "let go in the air");
        assert!(!judged(part(in_the_air, true), true, true).meets(in_the_air), "in a protective stop");
    }

    #[test]
    fn the_safety_planes_slow_the_tool_towards_them_and_send_it_back_from_outside() {
        let planes = [[-0.72, -0.18], [-0.32, 0.18], [TOOL_FLOOR, 0.40]];
        let near = Vec3::new(-0.45, 0.0, TOOL_FLOOR + 0.01);
        let v = within_planes(&planes, near, Vec3::new(0.3, 0.0, -0.5));
        assert_eq!(v.x, 0.3);
        assert!((v.z + PLANE_GAIN * 0.01).abs() < 1e-5, "{v}");
        let below = Vec3::new(-0.45, 0.0, TOOL_FLOOR - 0.01);
        assert!(within_planes(&planes, below, Vec3::new(0.0, 0.0, -0.5)).z > 0.0);
    }
}
