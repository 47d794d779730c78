//! What the off-policy learners (SAC, TD3) share around their replay buffer: actions in
//! [−1, 1] scaled to the action box, and a vectorised step stored as transitions.

use twinbots_api::{EpisodeSummary, Space, StepResult};

use crate::replay_buffer::ReplayBuffer;

/// Actions in [−1, 1] (clipped) → the action box's bounds: `low + (a + 1) · (high − low) / 2`.
pub fn to_env(space: &Space, unit: &[f32]) -> Vec<f32> {
    let Space::Box { low, high } = space else { return unit.to_vec() };
    unit.iter()
        .enumerate()
        .map(|(i, u)| {
            let k = i % low.len();
            low[k] + (u.clamp(-1.0, 1.0) + 1.0) * 0.5 * (high[k] - low[k])
        })
        .collect()
}

/// Stores the step from `obs` with the (unit) `actions` that gave `out` as transitions
/// (s, a, r, s', done): a finished episode's s' is its last observation, and a truncated one is
/// not done, so its value bootstraps. Each episode that ended is handed to `ended`.
pub fn store_step(buffer: Option<&mut ReplayBuffer>, obs: &[f32], actions: &[f32], out: &StepResult, mut ended: impl FnMut(&EpisodeSummary)) {
    let n_envs = out.rewards.len();
    let obs_dim = obs.len() / n_envs.max(1);
    let mut next_obs = out.obs.clone();
    let mut ends = vec![false; n_envs];
    for e in 0..n_envs {
        ends[e] = out.terminated[e] || out.truncated[e];
        if let Some(last) = &out.final_obs[e] {
            next_obs[e * obs_dim..(e + 1) * obs_dim].copy_from_slice(last);
        }
        if let Some(episode) = &out.episodes[e] {
            ended(episode);
        }
    }
    if let Some(buffer) = buffer {
        buffer.push(obs, actions, &out.rewards, &next_obs, &out.terminated, &ends, &out.ended_by);
    }
}
