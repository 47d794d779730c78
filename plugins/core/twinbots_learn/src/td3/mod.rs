//! Twin Delayed DDPG (Fujimoto et al. 2018), read top to bottom like CleanRL's `td3_continuous_
//! action.py`, with Stable-Baselines3's surface and defaults: a deterministic actor explored
//! with Gaussian noise, twin critics whose smaller estimate makes the target, noise on the
//! target actor's actions, and actor and target updates every `policy_delay` critic updates.
//! Its replay buffer and critics are SAC's (`crate::sac`), its training loop the one they share
//! (`crate::off_policy::learn`).

mod config;
mod model_file;

use candle_core::{Device, Tensor, Var};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use twinbots_api::spaces::Space;

pub use config::Td3Config;

use crate::agent::{Agent, LoadAgent};
use crate::learner::{Algorithm, Learner, checked_table, config_from, load_learner};
use crate::learner_state::LearnerState;
use crate::model_io::ModelError;
use crate::nn::{Adam, AdamConfig, Dense};
use crate::normalize::RunningMeanStd;
use crate::off_policy::OffPolicy;
use crate::off_policy::networks::{ReluMlp, TwinCritic, polyak_update};
use crate::policy_net::PolicyNet;
use crate::replay_buffer::ReplayBuffer;
use crate::stats::UpdateStats;

/// The name `--algo` and the settings' `[td3]` table use, and the one its models are saved
/// under (`model.json`'s `algorithm`).
pub const NAME: &str = "td3";
pub const SAVED_AS: &str = "TD3";
/// Its figures in `progress.csv` (`UpdateStats::train`), in order.
pub const TRAIN_FIGURES: &[&str] = &["actor_loss", "critic_loss"];

/// TD3's line in [`crate::algos::ALGOS`].
pub const ALGORITHM: Algorithm = Algorithm {
    name: NAME,
    saved_as: SAVED_AS,
    summary: "Twin Delayed DDPG: off-policy, deterministic policy, continuous actions; every design pattern",
    continuous_only: true,
    serves: true,
    config: |keys, _arenas| checked_table::<Td3Config>(keys, NAME),
    new: |config, spec, seed| {
        Ok(Box::new(Td3::new(
            config_from(config, NAME)?,
            spec.observation_space.clone(),
            spec.action_space.clone(),
            seed,
        )?))
    },
    load: load_learner::<Td3>,
};

/// What the last row's gradient steps did (SB3's `train/` figures for TD3).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Td3Losses {
    pub actor_loss: f32,
    pub critic_loss: f32,
    pub gradient_steps: u64,
}

/// A TD3 agent: actor and twin critics with their targets, the optimisers, the replay buffer
/// and the counters that make a run resumable.
pub struct Td3 {
    pub config: Td3Config,
    /// Spaces, normaliser, seed, counters, last episodes, env state and times, as every
    /// learner keeps them.
    pub state: LearnerState,
    /// μ(s) = tanh(actor(s)), in [−1, 1] per action.
    pub actor: ReluMlp,
    pub actor_target: ReluMlp,
    pub critic: TwinCritic,
    pub critic_target: TwinCritic,
    /// Critic updates taken.
    pub gradient_steps: u64,
    /// Iterations of `learn` (steps of each env).
    pub iterations: u64,
    pub buffer: Option<ReplayBuffer>,
    actor_optimizer: Adam,
    critic_optimizer: Adam,
    rng: ChaCha8Rng,
    pub last_losses: Td3Losses,
}

/// A copy of `mlp` sharing no variables (a target network starts as its network).
fn deep_copy(mlp: &ReluMlp) -> candle_core::Result<ReluMlp> {
    let copy = |v: &Var| Var::from_tensor(&v.as_tensor().copy()?);
    let layers = mlp
        .layers
        .iter()
        .map(|l| Ok(Dense { weight: copy(&l.weight)?, bias: copy(&l.bias)? }))
        .collect::<candle_core::Result<_>>()?;
    Ok(ReluMlp { layers, relu_last: mlp.relu_last })
}

impl Td3 {
    pub fn new(config: Td3Config, observation_space: Space, action_space: Space, seed: u64) -> anyhow::Result<Self> {
        crate::tuning::for_small_networks();
        let Space::Box { low, .. } = &action_space else {
            anyhow::bail!("TD3 needs continuous (Box) actions, not {action_space}: use PPO")
        };
        config.validate()?;
        anyhow::ensure!(
            observation_space.image_shape().is_none(),
            "TD3 does not read camera images ({observation_space}) yet: use ppo or sac, whose policy = \"cnn\" does"
        );
        let (obs_dim, act_dim) = (observation_space.dim(), low.len());
        let mut init = ChaCha8Rng::seed_from_u64(seed);
        let sizes: Vec<usize> =
            std::iter::once(obs_dim).chain(config.hidden.iter().copied()).chain(std::iter::once(act_dim)).collect();
        let actor = ReluMlp::new(&sizes, false, &mut init, &Device::Cpu)?;
        let critic = TwinCritic::new(crate::nn::Encoder::Flat { dim: obs_dim }, act_dim, &config.hidden, &mut init)?;
        let adam = |vars: Vec<(String, Var)>| {
            Adam::new(
                vars.into_iter().map(|(_, v)| v).collect(),
                AdamConfig { learning_rate: config.off_policy.learning_rate, eps: 1e-8, ..AdamConfig::default() },
            )
        };
        Ok(Self {
            state: LearnerState::new(
                observation_space,
                action_space,
                config.normalize_observations.then(|| RunningMeanStd::new(obs_dim)),
                seed,
            ),
            actor_optimizer: adam(actor.vars("actor")),
            critic_optimizer: adam(critic.named_vars("critic")),
            actor_target: deep_copy(&actor)?,
            critic_target: critic.deep_copy()?,
            actor,
            critic,
            gradient_steps: 0,
            iterations: 0,
            buffer: None,
            rng: ChaCha8Rng::seed_from_u64(seed ^ twinbots_api::seeds::TD3_NOISE),
            last_losses: Td3Losses::default(),
            config,
        })
    }

    fn act_dim(&self) -> usize {
        self.state.action_space.dim()
    }

    /// Gaussian noise of standard deviation `std`, clipped to ± `clip`, for `n` actions.
    fn noise(&mut self, n: usize, std: f32, clip: f32) -> Vec<f32> {
        (0..n)
            .map(|_| {
                let e: f32 = StandardNormal.sample(&mut self.rng);
                (e * std).clamp(-clip, clip)
            })
            .collect()
    }

    /// [-1, 1] → the action space's bounds.
    fn to_env(&self, unit: &[f32]) -> Vec<f32> {
        crate::off_policy::to_env(&self.state.action_space, unit)
    }

    /// μ(s) in [−1, 1] for each raw observation row.
    fn unit_actions(&self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        Ok(self.actor.forward(&self.state.batch(obs)?)?.tanh()?.flatten_all()?.to_vec1::<f32>()?)
    }

    /// Actions in [−1, 1] for each raw observation row: uniform random until learning starts,
    /// then μ(s) + exploration noise.
    fn explore(&mut self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        if self.state.timesteps < self.config.off_policy.learning_starts {
            let n = obs.len() / self.state.observation_space.dim().max(1) * self.act_dim();
            return Ok((0..n).map(|_| self.rng.random_range(-1.0f32..=1.0)).collect());
        }
        let mut unit = self.unit_actions(obs)?;
        let noise = self.noise(unit.len(), self.config.action_noise, f32::INFINITY);
        unit.iter_mut().zip(noise).for_each(|(a, n)| *a = (*a + n).clamp(-1.0, 1.0));
        Ok(unit)
    }

    /// μ(s) for each raw observation row, in the action space's bounds.
    pub fn predict_deterministic(&self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        Ok(self.to_env(&self.unit_actions(obs)?))
    }

    /// μ(s), plus the exploration noise unless `deterministic`.
    pub fn predict(&mut self, obs: &[f32], deterministic: bool) -> anyhow::Result<Vec<f32>> {
        let mut unit = self.unit_actions(obs)?;
        if !deterministic {
            let noise = self.noise(unit.len(), self.config.action_noise, f32::INFINITY);
            unit.iter_mut().zip(noise).for_each(|(a, n)| *a = (*a + n).clamp(-1.0, 1.0));
        }
        Ok(self.to_env(&unit))
    }

    /// One critic update, and every `policy_delay`-th one an actor and target update; `None`
    /// when a loss or gradient was not finite (those weights stay, the step counts as skipped).
    pub fn gradient_step(&mut self) -> anyhow::Result<Option<Td3Losses>> {
        let Some(buffer) = &self.buffer else { return Ok(None) };
        if buffer.is_empty() {
            return Ok(None);
        }
        let batch = buffer.sample(self.config.off_policy.batch_size, &mut self.rng, None);
        let (b, act_dim, dev) = (batch.rewards.len(), self.act_dim(), Device::Cpu);
        let (obs, next_obs) = (self.state.batch(&batch.obs)?, self.state.batch(&batch.next_obs)?);
        let actions = Tensor::from_vec(batch.actions, (b, act_dim), &dev)?;
        let rewards = Tensor::from_vec(batch.rewards, b, &dev)?;
        let not_done = (Tensor::from_vec(batch.dones, b, &dev)?.neg()? + 1.0)?;

        // Target policy smoothing: ã = clip(μ'(s') + clip(ε, −c, c), −1, 1), ε ~ N(0, σ̃).
        let smoothing = self.noise(b * act_dim, self.config.target_policy_noise, self.config.target_noise_clip);
        let next_actions = (self.actor_target.forward(&next_obs)?.tanh()?
            + Tensor::from_vec(smoothing, (b, act_dim), &dev)?)?
        .clamp(-1f32, 1f32)?;
        // Critics: y = r + γ (1 − done) min(Q'₁, Q'₂)(s', ã); loss Σᵢ MSE(Qᵢ(s, a), y), as SB3.
        let next_q = self.critic_target.min_q(&next_obs, &next_actions)?;
        let target = (rewards + (not_done * next_q)? * self.config.off_policy.gamma as f64)?.detach();
        let (q1, q2) = self.critic.q(&obs, &actions)?;
        let critic_loss = ((&q1 - &target)?.sqr()?.mean_all()? + (&q2 - &target)?.sqr()?.mean_all()?)?;
        let mut applied = self.critic_optimizer.step(&critic_loss.backward()?, None)?.applied;
        self.gradient_steps += 1;

        // Delayed: the actor ascends Q₁(s, μ(s)), then the targets follow by Polyak.
        let mut actor_loss = f32::NAN;
        if self.gradient_steps.is_multiple_of(self.config.policy_delay as u64) {
            let (q_pi, _) = self.critic.q(&obs, &self.actor.forward(&obs)?.tanh()?)?;
            let loss = q_pi.mean_all()?.neg()?;
            actor_loss = loss.to_scalar::<f32>()?;
            applied &= self.actor_optimizer.step(&loss.backward()?, None)?.applied;
            polyak_update(
                &self.critic_target.named_vars("target"),
                &self.critic.named_vars("critic"),
                self.config.off_policy.tau,
            )?;
            polyak_update(
                &self.actor_target.vars("actor_target"),
                &self.actor.vars("actor"),
                self.config.off_policy.tau,
            )?;
        }
        if !applied {
            return Ok(None);
        }
        Ok(Some(Td3Losses {
            actor_loss,
            critic_loss: critic_loss.to_scalar::<f32>()?,
            gradient_steps: self.gradient_steps,
        }))
    }
}

impl Agent for Td3 {
    crate::agent::agent_basics!(Td3);
    fn policy_net(&self) -> anyhow::Result<PolicyNet> {
        let layers = crate::nn::layer_values(&self.actor.layers, "actor")?;
        Ok(crate::off_policy::actor_net(&self.state, crate::policy_net::InputEncoding::Flat, layers))
    }
    /// SB3's TD3 tags.
    fn train_scalars(&self, _stats: &UpdateStats) -> Vec<(String, f32)> {
        let l = &self.last_losses;
        crate::off_policy::train_scalars(TRAIN_FIGURES, &[l.actor_loss, l.critic_loss], l.gradient_steps)
    }
}

impl Learner for Td3 {
    crate::off_policy::learn_and_serve!();
}

impl OffPolicy for Td3 {
    crate::off_policy::schedule_and_parts!();
    fn explore(&mut self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        Td3::explore(self, obs)
    }
    /// The actor's loss is NaN on the steps between its delayed updates.
    fn train_steps(&mut self, n: usize, each: &mut dyn FnMut(Option<Vec<f32>>)) -> anyhow::Result<()> {
        for _ in 0..n {
            each(self.gradient_step()?.map(|l| vec![l.actor_loss, l.critic_loss]));
        }
        Ok(())
    }
    fn end_row(&mut self, figures: Vec<f32>) -> anyhow::Result<Vec<f32>> {
        let [actor_loss, critic_loss] = figures[..] else {
            anyhow::bail!("TD3 has {} figures, not {}", TRAIN_FIGURES.len(), figures.len())
        };
        self.last_losses = Td3Losses { actor_loss, critic_loss, gradient_steps: self.gradient_steps };
        Ok(figures)
    }
}

impl LoadAgent for Td3 {
    fn load(dir: &std::path::Path) -> Result<Self, ModelError> {
        Td3::load(dir)
    }
}
