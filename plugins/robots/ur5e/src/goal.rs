//! The reach task as a goal-conditioned task (Gymnasium-Robotics' `GoalEnv`), for hindsight
//! experience replay: the goal achieved is the TCP, the goal desired is the target, and the
//! reward for another target recomputes the reach task's own target terms from the observation
//! (the joints' angles and speeds give the controller's TCP, tilt and speed, exactly as
//! `ArmState::read` does).

use std::sync::OnceLock;

use bevy::math::Vec3;
use twinbots_task::{GoalChange, GoalSpec, RewardTerm};

use crate::arm::ArmState;
use crate::safety::StopCause;
use crate::state::CellState;

/// Where the observation terms put the values the goal is made of (checked against the terms'
/// names by a test).
pub const JOINT_POSITIONS: usize = 0;
pub const JOINT_VELOCITIES: usize = 6;
pub const TCP_POSITION: usize = 12;
pub const TARGET_OFFSET: usize = 15;

/// The reach task's reward terms that depend on the target (the protective stop's penalty is
/// a multiple of the pose cost where the stop tripped); the others (tilt, effort, action rate) do not.
const TARGET_TERMS: [&str; 4] = ["distance", "precision", "arrival", "protective_stop"];

fn target_terms() -> &'static [RewardTerm<CellState>] {
    static TERMS: OnceLock<Vec<RewardTerm<CellState>>> = OnceLock::new();
    TERMS.get_or_init(|| crate::reach::reach_task().terms.rewards.into_iter().filter(|t| TARGET_TERMS.contains(&t.name)).collect())
}

fn point(values: &[f32]) -> Vec3 {
    Vec3::new(values[0], values[1], values[2])
}

fn achieved(obs: &[f32]) -> Vec<f32> {
    obs[TCP_POSITION..TCP_POSITION + 3].to_vec()
}

fn desired(obs: &[f32]) -> Vec<f32> {
    (point(&obs[TCP_POSITION..]) + point(&obs[TARGET_OFFSET..])).to_array().to_vec()
}

fn substitute(obs: &mut [f32], goal: &[f32]) {
    let offset = point(goal) - point(&obs[TCP_POSITION..]);
    obs[TARGET_OFFSET..TARGET_OFFSET + 3].copy_from_slice(&offset.to_array());
}

/// The target terms under each goal, and arrival at each (which ends a reach). A reach ends
/// only on arrival or in a protective stop, so a step that ended without arriving at `from`
/// ended in a stop: its penalty is recomputed for `to`, and it arrives nowhere.
fn change(_obs: &[f32], next_obs: &[f32], done: bool, from: &[f32], to: &[f32]) -> GoalChange {
    let joints = |at: usize| -> [f32; 6] { std::array::from_fn(|i| next_obs[at + i]) };
    // The kinematics once for both goals: it is most of a relabelling's cost.
    let mut state = CellState { arm: ArmState::from_joints(joints(JOINT_POSITIONS), joints(JOINT_VELOCITIES)), ..Default::default() };
    if done && !state.arm.has_reached(point(from)) {
        state.safety.stop = Some(StopCause::Speed { joint: 0, ratio: f32::NAN });
    }
    let mut terms = |goal: &[f32]| {
        state.target = point(goal);
        (target_terms().iter().map(|t| t.weighted(&state)).sum::<f32>(), state.arrived())
    };
    let ((before, ends_at_from), (after, ends_at_to)) = (terms(from), terms(to));
    GoalChange { reward: after - before, ends_at_from, ends_at_to }
}

/// The reach task's goal interface.
pub fn reach_goal() -> GoalSpec {
    GoalSpec { dim: 3, achieved, desired, substitute, change }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The target terms' reward for the arm of `next_obs` with the target at `goal`.
    fn goal_reward(next_obs: &[f32], goal: &[f32]) -> f32 {
        let joints = |at: usize| -> [f32; 6] { std::array::from_fn(|i| next_obs[at + i]) };
        let state = CellState { arm: ArmState::from_joints(joints(JOINT_POSITIONS), joints(JOINT_VELOCITIES)), target: point(goal), ..Default::default() };
        target_terms().iter().map(|t| t.weighted(&state)).sum()
    }

    #[test]
    fn the_goal_offsets_match_the_observation_terms() {
        let names = crate::reach::reach_task().spec().observation_names;
        let at = |prefix: &str| names.iter().position(|n| n.starts_with(prefix)).unwrap();
        assert_eq!(at("joint_positions"), JOINT_POSITIONS);
        assert_eq!(at("joint_velocities"), JOINT_VELOCITIES);
        assert_eq!(at("tcp_position"), TCP_POSITION);
        assert_eq!(at("target_offset"), TARGET_OFFSET);
    }

    #[test]
    fn a_substituted_goal_is_desired_and_rewarded_as_the_task_rewards_it() {
        let arm = ArmState::from_joints(crate::kinematics::HOME, [0.0; 6]);
        let tcp = arm.tcp.translation;
        let mut obs = vec![0.0; 26];
        obs[..6].copy_from_slice(&crate::kinematics::HOME);
        obs[TCP_POSITION..TCP_POSITION + 3].copy_from_slice(&tcp.to_array());
        let goal = reach_goal();
        let target = tcp + Vec3::new(0.1, 0.0, 0.0);
        (goal.substitute)(&mut obs, &target.to_array());
        let back = (goal.desired)(&obs);
        assert!((point(&back) - target).length() < 1e-6);
        assert_eq!((goal.achieved)(&obs), tcp.to_array().to_vec());
        // 10 cm away: −1 × 0.1 − 0.1 × (1 − e^{−25}), no arrival; at the TCP itself the
        // distance terms vanish and the arrival bonus is paid only if the tool points down.
        let far = goal_reward(&obs, &target.to_array());
        assert!((far - (-0.1 - 0.1)).abs() < 1e-3, "{far}");
        let here = goal_reward(&obs, &tcp.to_array());
        let change = (goal.change)(&obs, &obs, false, &target.to_array(), &tcp.to_array());
        assert!((change.reward - (here - far)).abs() < 1e-4, "{change:?}");
        assert!(!change.ends_at_from);
        let down = crate::kinematics::tilt(&arm.tcp) < crate::arm::TILT_TOLERANCE;
        assert!((here - if down { 10.0 } else { 0.0 }).abs() < 1e-3, "{here} (pointing down: {down})");
        assert_eq!(change.ends_at_to, down, "arrival at the TCP itself (at rest) ends the reach iff the tool points down");
        // A step that ended without arriving ended in a protective stop: its penalty (a
        // multiple of the pose cost where the stop tripped) follows the goal, and nothing arrives.
        let stopped = (goal.change)(&obs, &obs, true, &target.to_array(), &tcp.to_array());
        assert!(!stopped.ends_at_to && !stopped.ends_at_from);
        assert!(stopped.reward > change.reward + 1.0, "the stop's penalty did not shrink with the distance: {stopped:?} vs {change:?}");
    }
}
