//! The rollout buffer and Generalised Advantage Estimation (Schulman et al. 2016):
//!   δ_t = r_t + γ V(s_{t+1}) (1 − done_t) − V(s_t),   A_t = δ_t + γλ (1 − done_t) A_{t+1},
//!   R_t = A_t + V(s_t)  (the value target).

use super::rollout::PolicyStep;

/// `n_steps` steps of `n_envs` envs, flat and step-major: index `t * n_envs + e`.
pub struct RolloutBuffer {
    pub n_envs: usize,
    pub obs_dim: usize,
    pub act_dim: usize,
    /// Observations as the policy saw them: normalised with the statistics in force when they
    /// were collected (SB3's VecNormalize), so an update's first ratio π/π_old is exactly 1.
    pub obs: Vec<f32>,
    pub actions: Vec<f32>,
    pub log_probs: Vec<f32>,
    pub rewards: Vec<f32>,
    /// Whether the episode ended *after* this step.
    pub dones: Vec<bool>,
    pub values: Vec<f32>,
    pub advantages: Vec<f32>,
    pub returns: Vec<f32>,
    /// Under frozen encoders, each sample's features as the rollout computed them
    /// ([`PolicyStep::features`]), for the update to reuse; empty otherwise.
    pub features: Vec<f32>,
    pub value_features: Vec<f32>,
}

impl RolloutBuffer {
    pub fn new(n_envs: usize, obs_dim: usize, act_dim: usize) -> Self {
        Self {
            n_envs,
            obs_dim,
            act_dim,
            obs: Vec::new(),
            actions: Vec::new(),
            log_probs: Vec::new(),
            rewards: Vec::new(),
            dones: Vec::new(),
            values: Vec::new(),
            advantages: Vec::new(),
            returns: Vec::new(),
            features: Vec::new(),
            value_features: Vec::new(),
        }
    }

    pub fn clear(&mut self) {
        for v in [
            &mut self.obs,
            &mut self.actions,
            &mut self.log_probs,
            &mut self.rewards,
            &mut self.values,
            &mut self.advantages,
            &mut self.returns,
            &mut self.features,
            &mut self.value_features,
        ] {
            v.clear();
        }
        self.dones.clear();
    }

    /// Records one step of every env: what the policy did on its observations (`step`), and
    /// the rewards and episode ends that followed.
    pub fn push(&mut self, step: &PolicyStep, rewards: &[f32], dones: &[bool]) {
        self.obs.extend_from_slice(&step.obs);
        self.actions.extend_from_slice(&step.actions);
        self.log_probs.extend_from_slice(&step.log_probs);
        self.values.extend_from_slice(&step.values);
        self.rewards.extend_from_slice(rewards);
        self.dones.extend_from_slice(dones);
        self.features.extend_from_slice(&step.features);
        self.value_features.extend_from_slice(&step.value_features);
    }

    pub fn len(&self) -> usize {
        self.rewards.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rewards.is_empty()
    }

    /// The width of a row of cached features (`features` or `value_features`): 0 when there
    /// are none for every sample.
    pub fn cached_width(&self, cached: &[f32]) -> usize {
        match self.len() {
            n if n > 0 && !cached.is_empty() && cached.len().is_multiple_of(n) => cached.len() / n,
            _ => 0,
        }
    }

    /// Appends a single-env buffer whose advantages are computed (segments of several robots
    /// become one training batch).
    pub fn append(&mut self, other: &RolloutBuffer) {
        self.obs.extend_from_slice(&other.obs);
        self.actions.extend_from_slice(&other.actions);
        self.log_probs.extend_from_slice(&other.log_probs);
        self.rewards.extend_from_slice(&other.rewards);
        self.dones.extend_from_slice(&other.dones);
        self.values.extend_from_slice(&other.values);
        self.advantages.extend_from_slice(&other.advantages);
        self.returns.extend_from_slice(&other.returns);
        self.features.extend_from_slice(&other.features);
        self.value_features.extend_from_slice(&other.value_features);
    }

    /// Keeps only the first `n` steps (a single-env buffer).
    pub fn truncate(&mut self, n: usize) {
        let (o, a) = (self.obs_dim, self.act_dim);
        let (f, vf) = (self.cached_width(&self.features), self.cached_width(&self.value_features));
        self.obs.truncate(n * o);
        self.actions.truncate(n * a);
        self.features.truncate(n * f);
        self.value_features.truncate(n * vf);
        for v in [&mut self.log_probs, &mut self.rewards, &mut self.values] {
            v.truncate(n);
        }
        self.dones.truncate(n);
        self.advantages.clear();
        self.returns.clear();
    }

    /// GAE over the stored steps; `last_values` are V(s) of the observations after the last step.
    pub fn compute_advantages(&mut self, last_values: &[f32], gamma: f32, lambda: f32) {
        let n = self.n_envs;
        let steps = self.len() / n;
        self.advantages = vec![0.0; self.len()];
        for e in 0..n {
            let mut next_adv = 0.0;
            let mut next_value = last_values[e];
            for t in (0..steps).rev() {
                let i = t * n + e;
                let live = if self.dones[i] { 0.0 } else { 1.0 };
                let delta = self.rewards[i] + gamma * next_value * live - self.values[i];
                next_adv = delta + gamma * lambda * live * next_adv;
                self.advantages[i] = next_adv;
                next_value = self.values[i];
            }
        }
        self.returns = self.advantages.iter().zip(&self.values).map(|(a, v)| a + v).collect();
    }
}
