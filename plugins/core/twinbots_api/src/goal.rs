//! Goal-conditioned tasks (Gymnasium-Robotics' `GoalEnv`): where an observation holds the goal
//! it achieved and the goal it asks for, and how a step's reward changes for another goal. What
//! hindsight experience replay (HER) needs to relabel stored steps.

/// A task's goal interface, over its flat observations.
#[derive(Clone, Copy, Debug)]
pub struct GoalSpec {
    /// Size of a goal (the UR5e reach: a point, 3).
    pub dim: usize,
    /// The goal an observation has achieved (the tool's position).
    pub achieved: fn(obs: &[f32]) -> Vec<f32>,
    /// The goal an observation asks for (the target).
    pub desired: fn(obs: &[f32]) -> Vec<f32>,
    /// Rewrites `obs` so that it asks for `goal`.
    pub substitute: fn(obs: &mut [f32], goal: &[f32]),
    /// What becomes of a step from `obs` to `next_obs`, which the termination term `ended_by`
    /// ended (or none), when its goal is `to` instead of `from` (SB3's `compute_reward(achieved,
    /// desired, info)`, with the stored step's information).
    pub change: fn(obs: &[f32], next_obs: &[f32], ended_by: Option<&str>, from: &[f32], to: &[f32]) -> GoalChange,
}

/// A step under another goal: how its reward changes (the goal-dependent terms under the new
/// goal less under the old; effort and the like do not depend on the goal), and whether it
/// reaches either goal in a way that ends the episode (a reach ends on arrival).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GoalChange {
    pub reward: f32,
    pub ends_at_from: bool,
    pub ends_at_to: bool,
}

impl GoalSpec {
    /// The reward and `done` a step from `obs` to `next_obs` that earned `reward`, ended the
    /// MDP or not (`done`) and was ended by the termination term `ended_by`, would have had
    /// with the goal `goal`: an end the old goal caused is undone, one the new goal causes is
    /// added, any other end stays.
    pub fn relabel(
        &self,
        obs: &[f32],
        next_obs: &[f32],
        reward: f32,
        done: bool,
        ended_by: Option<&str>,
        goal: &[f32],
    ) -> (f32, bool) {
        let change = (self.change)(obs, next_obs, ended_by, &(self.desired)(obs), goal);
        (reward + change.reward, (done && !change.ends_at_from) || change.ends_at_to)
    }
}
