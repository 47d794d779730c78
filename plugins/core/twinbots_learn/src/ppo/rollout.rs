//! Collecting experience with the current policy: normalising observations as they arrive,
//! sampling actions, bootstrapping truncated episodes, and filling the rollout buffer. `learn`
//! drives it over a `VecEnv`; the RobotServer uses the same pieces one robot message at a time.

use std::time::Instant;

use candle_core::{Device, Tensor};

use super::fused::Inference;
use super::{Ppo, RolloutBuffer};
use twinbots_api::env::VecEnv;
use twinbots_api::spaces::Space;

/// What the policy did on a batch of observations, one row per env: everything a rollout
/// records about the step before its outcome is known.
#[derive(Clone, Debug, PartialEq)]
pub struct PolicyStep {
    /// The observations acted on, as the network saw them (normalised with the statistics in
    /// force when they arrived).
    pub obs: Vec<f32>,
    /// The actions as sampled: what `log_probs` are the log-probabilities of.
    pub actions: Vec<f32>,
    /// The actions clipped to a box's bounds: what the env applies. SB3 keeps the unclipped
    /// sample in the buffer so its log-probability stays right.
    pub env_actions: Vec<f32>,
    pub log_probs: Vec<f32>,
    /// V(obs).
    pub values: Vec<f32>,
    /// Under frozen encoders (`freeze_features`), the features the policy acted on (and the
    /// value's own, where it has an encoder of its own), one row per env, for the update to
    /// reuse; empty otherwise.
    pub features: Vec<f32>,
    pub value_features: Vec<f32>,
}

impl Ppo {
    /// Observations fresh from the env: folded into the running statistics (when the model
    /// normalises), then normalised with the statistics now in force. This is the only place
    /// the statistics move, once per observation, as SB3's VecNormalize does in `step`/`reset`.
    pub fn observe(&mut self, raw: &[f32]) -> Vec<f32> {
        match &mut self.state.obs_rms {
            Some(rms) => {
                rms.update(raw);
                rms.normalize(raw)
            }
            None => raw.to_vec(),
        }
    }

    /// Observations normalised with the current statistics, which they do not change (a
    /// finished episode's last observation, inference).
    pub fn normalize(&self, raw: &[f32]) -> Vec<f32> {
        crate::normalize::normalized(self.state.obs_rms.as_ref(), raw)
    }

    /// Rows of normalised observations as a tensor for the networks.
    pub(super) fn batch(&self, obs: &[f32]) -> anyhow::Result<Tensor> {
        let dim = self.state.observation_space.dim();
        Ok(Tensor::from_vec(obs.to_vec(), (obs.len() / dim, dim), &Device::Cpu)?)
    }

    /// Samples an action for each row of `obs` (normalised, from [`Ppo::observe`]).
    pub fn policy_step(&mut self, obs: Vec<f32>) -> anyhow::Result<PolicyStep> {
        self.policy_step_with(obs, None)
    }

    /// [`Ppo::policy_step`], through `inference` when given (read from the current policy).
    fn policy_step_with(&mut self, obs: Vec<f32>, inference: Option<&Inference>) -> anyhow::Result<PolicyStep> {
        let (mut features, mut value_features) = (Vec::new(), Vec::new());
        let (actions, log_probs, values) = match inference {
            Some(inference) => {
                inference.act(&self.policy.head, &obs, obs.len() / self.state.observation_space.dim(), &mut self.rng)
            }
            None => {
                let (f, v) = self.policy.features(&self.batch(&obs)?)?;
                if self.config.freeze_features {
                    features = f.flatten_all()?.to_vec1::<f32>()?;
                    value_features =
                        v.as_ref().map(|v| v.flatten_all()?.to_vec1::<f32>()).transpose()?.unwrap_or_default();
                }
                self.policy.act_from(&f, v.as_ref(), false, &mut self.rng)?
            }
        };
        let env_actions = self.clip_to_space(actions.clone());
        Ok(PolicyStep { obs, actions, env_actions, log_probs, values, features, value_features })
    }

    /// V(s) for each row of `obs` (normalised).
    pub fn values(&self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        Ok(self.policy.value(&self.batch(obs)?)?.to_vec1::<f32>()?)
    }

    /// Rewards of one step of every env as the learner stores them: scaled with
    /// `normalize_rewards` (the statistics move), else as they came.
    pub fn scale_rewards(&mut self, rewards: &[f32], dones: &[bool]) -> Vec<f32> {
        match &mut self.reward_scale {
            Some(scale) => scale.scale(rewards, dones, self.config.gamma),
            None => rewards.to_vec(),
        }
    }

    /// The reward a step stores (already scaled): a truncated episode did not end in the MDP, so its last
    /// reward is bootstrapped with γ V(final observation), as SB3 does. `final_obs` is raw.
    pub fn bootstrapped_reward(
        &self,
        reward: f32,
        terminated: bool,
        truncated: bool,
        final_obs: Option<&[f32]>,
    ) -> anyhow::Result<f32> {
        match final_obs {
            Some(last) if truncated && !terminated => {
                Ok(reward + self.config.gamma * self.values(&self.normalize(last))?[0])
            }
            _ => Ok(reward),
        }
    }

    /// Boxes are clipped before they reach the env.
    pub fn clip_to_space(&self, mut actions: Vec<f32>) -> Vec<f32> {
        if let Space::Box { low, high } = &self.state.action_space {
            for (i, a) in actions.iter_mut().enumerate() {
                let k = i % low.len();
                *a = a.clamp(low[k], high[k]);
            }
        }
        actions
    }

    /// Fills `buffer` (cleared first) with `n_steps` steps of every env of `env`, starting
    /// from `obs` (normalised) and leaving there the observations to continue from.
    pub fn collect_rollout(
        &mut self,
        env: &mut dyn VecEnv,
        obs: &mut Vec<f32>,
        buffer: &mut RolloutBuffer,
    ) -> anyhow::Result<()> {
        let n_envs = env.num_envs();
        buffer.clear();
        // The policy is the same for the whole rollout: its numbers are read once.
        let inference = Inference::read(&self.policy)?;
        for _ in 0..self.config.n_steps {
            let inference_started = Instant::now();
            let step = self.policy_step_with(std::mem::take(obs), inference.as_ref())?;
            let env_started = Instant::now();
            let outcome = env.step(&step.env_actions)?;
            let env_done = Instant::now();
            self.state.times.inference_s += (env_started - inference_started).as_secs_f64();
            self.state.times.env_s += (env_done - env_started).as_secs_f64();
            let dones: Vec<bool> = (0..n_envs).map(|e| outcome.terminated[e] || outcome.truncated[e]).collect();
            let scaled = self.scale_rewards(&outcome.rewards, &dones);
            let mut rewards = Vec::with_capacity(n_envs);
            for e in 0..n_envs {
                let (terminated, truncated) = (outcome.terminated[e], outcome.truncated[e]);
                rewards.push(self.bootstrapped_reward(
                    scaled[e],
                    terminated,
                    truncated,
                    outcome.final_obs[e].as_deref(),
                )?);
                if let Some(episode) = &outcome.episodes[e] {
                    self.record_episode(episode);
                }
            }
            buffer.push(&step, &rewards, &dones);
            *obs = self.observe(&outcome.obs);
            self.state.timesteps += n_envs as u64;
            // Bootstrap values of truncated episodes and normalising are inference too.
            self.state.times.inference_s += env_done.elapsed().as_secs_f64();
        }
        Ok(())
    }
}
