//! The reach task as a goal-conditioned task (Gymnasium-Robotics' `GoalEnv`), for hindsight
//! experience replay: the goal achieved is the TCP, the goal desired is the target, and the
//! reward for another target recomputes the reach task's own target terms from the observation
//! (the joints' angles and speeds give the controller's TCP, tilt and speed, exactly as
//! `ArmState::read` does) and the step's record (whether the protective stop ended it).

use std::sync::OnceLock;

use bevy::math::Vec3;
use twinbots_task::{GoalChange, GoalSpec, RewardTerm, TaskDefinition, TaskTerms};

use crate::arm::ArmState;
use crate::safety::StopCause;
use crate::state::CellState;

/// Where the observation terms the goal is made of start, from the reach task's own terms.
struct Offsets {
    joint_positions: usize,
    joint_velocities: usize,
    tcp_position: usize,
    target_offset: usize,
}

fn offsets() -> &'static Offsets {
    static OFFSETS: OnceLock<Offsets> = OnceLock::new();
    OFFSETS.get_or_init(|| {
        let terms = TaskTerms { observations: crate::reach::observations(), ..Default::default() };
        let at =
            |name: &str| terms.observation_offset(name).unwrap_or_else(|| panic!("the reach task observes no {name}"));
        Offsets {
            joint_positions: at("joint_positions"),
            joint_velocities: at("joint_velocities"),
            tcp_position: at("tcp_position"),
            target_offset: at("target_offset"),
        }
    })
}

/// The reach task's reward terms that depend on the target (the protective stop's penalty is
/// a multiple of the pose cost where the stop tripped); the others (tilt, effort, action rate) do not.
const TARGET_TERMS: [&str; 4] = ["distance", "precision", "arrival", "protective_stop"];

fn target_terms() -> &'static [RewardTerm<CellState>] {
    static TERMS: OnceLock<Vec<RewardTerm<CellState>>> = OnceLock::new();
    TERMS.get_or_init(|| {
        crate::reach::reach_task().terms.rewards.into_iter().filter(|t| TARGET_TERMS.contains(&t.name)).collect()
    })
}

fn point(values: &[f32]) -> Vec3 {
    Vec3::new(values[0], values[1], values[2])
}

fn achieved(obs: &[f32]) -> Vec<f32> {
    let tcp = offsets().tcp_position;
    obs[tcp..tcp + 3].to_vec()
}

fn desired(obs: &[f32]) -> Vec<f32> {
    let o = offsets();
    (point(&obs[o.tcp_position..]) + point(&obs[o.target_offset..])).to_array().to_vec()
}

fn substitute(obs: &mut [f32], goal: &[f32]) {
    let o = offsets();
    let offset = point(goal) - point(&obs[o.tcp_position..]);
    obs[o.target_offset..o.target_offset + 3].copy_from_slice(&offset.to_array());
}

/// The target terms under each goal, and arrival at each (which ends a reach). A step its
/// record says the protective stop ended keeps the stop: its penalty (a multiple of the pose
/// cost where it tripped) is recomputed for `to`, and it arrives nowhere.
fn change(_obs: &[f32], next_obs: &[f32], ended_by: Option<&str>, from: &[f32], to: &[f32]) -> GoalChange {
    let joints = |at: usize| -> [f32; 6] { std::array::from_fn(|i| next_obs[at + i]) };
    // The kinematics once for both goals: it is most of a relabelling's cost.
    let o = offsets();
    let mut state = CellState {
        arm: ArmState::from_joints(joints(o.joint_positions), joints(o.joint_velocities)),
        ..Default::default()
    };
    if ended_by == Some(crate::reach::STOP_TERM) {
        state.safety.stop = Some(StopCause::Recorded);
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

/// The reach task with its goal interface: what the cell trains and what its spec says.
pub fn reach_with_goal() -> TaskDefinition<CellState> {
    TaskDefinition { goal: Some(reach_goal()), ..crate::reach::reach_task() }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The target terms' reward for the arm of `next_obs` with the target at `goal`.
    fn goal_reward(next_obs: &[f32], goal: &[f32]) -> f32 {
        let joints = |at: usize| -> [f32; 6] { std::array::from_fn(|i| next_obs[at + i]) };
        let o = offsets();
        let state = CellState {
            arm: ArmState::from_joints(joints(o.joint_positions), joints(o.joint_velocities)),
            target: point(goal),
            ..Default::default()
        };
        target_terms().iter().map(|t| t.weighted(&state)).sum()
    }

    #[test]
    fn the_goal_is_read_where_the_spec_names_its_values_and_the_spec_carries_the_goal() {
        let spec = reach_with_goal().spec();
        assert!(spec.goal.is_some(), "the task's spec is its only source, goal included");
        let o = offsets();
        for (name, at) in [
            ("joint_positions[0]", o.joint_positions),
            ("joint_velocities[0]", o.joint_velocities),
            ("tcp_position[0]", o.tcp_position),
            ("target_offset[0]", o.target_offset),
        ] {
            assert_eq!(spec.observation_names[at], name);
        }
    }

    #[test]
    fn a_substituted_goal_is_desired_and_rewarded_as_the_task_rewards_it() {
        let arm = ArmState::from_joints(crate::kinematics::HOME, [0.0; 6]);
        let tcp = arm.tcp.translation;
        let mut obs = vec![0.0; 26];
        obs[..6].copy_from_slice(&crate::kinematics::HOME);
        let tcp_at = offsets().tcp_position;
        obs[tcp_at..tcp_at + 3].copy_from_slice(&tcp.to_array());
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
        let change = (goal.change)(&obs, &obs, None, &target.to_array(), &tcp.to_array());
        assert!((change.reward - (here - far)).abs() < 1e-4, "{change:?}");
        assert!(!change.ends_at_from);
        let down = crate::kinematics::tilt(&arm.tcp) < crate::arm::TILT_TOLERANCE;
        assert!((here - if down { 10.0 } else { 0.0 }).abs() < 1e-3, "{here} (pointing down: {down})");
        assert_eq!(
            change.ends_at_to, down,
            "arrival at the TCP itself (at rest) ends the reach iff the tool points down"
        );
        // A step the protective stop ended (its record says so): its penalty (a multiple of
        // the pose cost where the stop tripped) follows the goal, and nothing arrives.
        let stopped = (goal.change)(&obs, &obs, Some(crate::reach::STOP_TERM), &target.to_array(), &tcp.to_array());
        assert!(!stopped.ends_at_to && !stopped.ends_at_from);
        assert!(
            stopped.reward > change.reward + 1.0,
            "the stop's penalty did not shrink with the distance: {stopped:?} vs {change:?}"
        );
    }
}
