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
    /// How much the reward of a step from `obs` to `next_obs` changes when its goal is `to`
    /// instead of `from`: the goal-dependent terms under `to` less under `from` (the other terms,
    /// effort and the like, do not depend on the goal).
    pub reward_change: fn(obs: &[f32], next_obs: &[f32], from: &[f32], to: &[f32]) -> f32,
}

impl GoalSpec {
    /// The reward a step from `obs` to `next_obs` that earned `reward` would have earned had its
    /// goal been `goal`.
    pub fn relabel_reward(&self, obs: &[f32], next_obs: &[f32], reward: f32, goal: &[f32]) -> f32 {
        reward + (self.reward_change)(obs, next_obs, &(self.desired)(obs), goal)
    }
}
