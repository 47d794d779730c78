//! Soft Actor-Critic (Haarnoja et al. 2018, with the automatic entropy tuning of the follow-up
//! paper), read top to bottom like CleanRL's `sac_continuous_action.py`, with
//! Stable-Baselines3's surface and defaults: `learn`, `predict`, `save`, `load`, callbacks,
//! and hindsight experience replay (Andrychowicz et al. 2017) for goal-conditioned tasks.
//!
//! `learn` (the loop it shares with TD3, `crate::off_policy::learn`) steps every env once per
//! iteration: random actions until `learning_starts`, then the actor's samples; each step goes
//! into the replay buffer (`crate::replay_buffer`, shared with TD3); every `train_freq`
//! iterations it takes `gradient_steps` gradient steps (`update.rs`); every `log_interval`
//! iterations it writes a row and calls the callbacks (the "update" they count).

mod config;
mod fused;
mod model_file;
mod networks;
mod update;

use candle_core::{Device, Tensor, Var};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

pub use crate::off_policy::networks::{ReluMlp, TwinCritic, polyak_update};
pub use crate::replay_buffer::{Batch, ReplayBuffer};
pub use config::SacConfig;
pub use networks::Actor;

use crate::agent::{Agent, LoadAgent};
use crate::learner::{Algorithm, Learner, checked_table, config_from, load_learner};
use crate::learner_state::LearnerState;
use crate::model_io::ModelError;
use crate::nn::Encoder;
use crate::nn::{Adam, AdamConfig};
use crate::normalize::RunningMeanStd;
use crate::off_policy::OffPolicy;
use crate::policy_net::PolicyNet;
use crate::stats::UpdateStats;
use twinbots_api::GoalSpec;
use twinbots_api::spaces::Space;

/// The name `--algo` and the settings' `[sac]` table use, and the one its models are saved
/// under (`model.json`'s `algorithm`).
pub const NAME: &str = "sac";
pub const SAVED_AS: &str = "SAC";
/// Its figures in `progress.csv` (`UpdateStats::train`), in order.
pub const TRAIN_FIGURES: &[&str] = &["actor_loss", "critic_loss", "ent_coef", "ent_coef_loss", "entropy"];

/// SAC's line in [`crate::algos::ALGOS`].
pub const ALGORITHM: Algorithm = Algorithm {
    name: NAME,
    saved_as: SAVED_AS,
    summary: "Soft Actor-Critic: off-policy, continuous actions, with HER for goal-conditioned tasks; every design pattern",
    continuous_only: true,
    serves: true,
    config: |keys, _arenas| checked_table::<SacConfig>(keys, NAME),
    new: |config, spec, seed| {
        let sac =
            Sac::new(config_from(config, NAME)?, spec.observation_space.clone(), spec.action_space.clone(), seed)?;
        Ok(Box::new(sac.with_goal(spec.goal)?))
    },
    load: load_learner::<Sac>,
};

/// What the last row's gradient steps did (SB3's `train/` figures for SAC).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SacLosses {
    pub actor_loss: f32,
    pub critic_loss: f32,
    /// α, the entropy coefficient.
    pub ent_coef: f32,
    pub ent_coef_loss: f32,
    /// −log π(a|s) of the actor's samples: an estimate of the policy's entropy.
    pub entropy: f32,
    pub gradient_steps: u64,
}

const GIB: f64 = (1u64 << 30) as f64;
/// The most memory a replay buffer may ask for.
const MAX_BUFFER_BYTES: f64 = 16.0 * GIB;

/// A SAC agent: actor, twin critics and their targets, α, the optimisers, the replay buffer
/// and the counters that make a run resumable.
pub struct Sac {
    pub config: SacConfig,
    /// Spaces, normaliser, seed, counters, last episodes, env state and times, as every
    /// learner keeps them.
    pub state: LearnerState,
    pub actor: Actor,
    pub critic: TwinCritic,
    pub critic_target: TwinCritic,
    /// log α (learnt when `learn_ent_coef`).
    pub log_ent_coef: Var,
    /// Gradient steps taken.
    pub gradient_steps: u64,
    /// Iterations of `learn` (steps of each env).
    pub iterations: u64,
    pub buffer: Option<ReplayBuffer>,
    /// Relabels goals (HER) when the config asks for it; not saved: the caller gives it again.
    pub goal: Option<GoalSpec>,
    actor_optimizer: Adam,
    critic_optimizer: Adam,
    ent_optimizer: Adam,
    rng: ChaCha8Rng,
    pub last_losses: SacLosses,
}

impl std::fmt::Debug for Sac {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Sac")
            .field("observation_space", &self.state.observation_space)
            .field("action_space", &self.state.action_space)
            .field("timesteps", &self.state.timesteps)
            .finish_non_exhaustive()
    }
}

impl Sac {
    pub fn new(config: SacConfig, observation_space: Space, action_space: Space, seed: u64) -> anyhow::Result<Self> {
        crate::tuning::for_small_networks();
        config.validate()?;
        let Space::Box { low, .. } = &action_space else {
            anyhow::bail!("SAC needs continuous (Box) actions, not {action_space}: use PPO")
        };
        let (obs_dim, act_dim) = (observation_space.dim(), low.len());
        crate::nn::check_normalization(&observation_space, config.normalize_observations, NAME)?;
        // The ring keeps observation and next observation: bytes for camera images, else f32.
        let value_bytes = if matches!(observation_space, Space::Image { .. }) { 1.0 } else { 4.0 };
        let buffer_bytes = config.off_policy.buffer_size as f64 * obs_dim as f64 * 2.0 * value_bytes;
        anyhow::ensure!(
            buffer_bytes <= MAX_BUFFER_BYTES,
            "sac.buffer_size = {}: {} transitions of {observation_space} observations take {:.0} GiB; at most {:.0} GiB: \
             use buffer_size = {} or less",
            config.off_policy.buffer_size,
            config.off_policy.buffer_size,
            buffer_bytes / GIB,
            MAX_BUFFER_BYTES / GIB,
            (MAX_BUFFER_BYTES / (obs_dim as f64 * 2.0 * value_bytes)) as u64
        );
        let mut init = ChaCha8Rng::seed_from_u64(seed);
        let encoder = |rng: &mut ChaCha8Rng| {
            Encoder::new(config.policy, &observation_space, config.features_dim, NAME, rng, &Device::Cpu)
        };
        let actor = Actor::new(encoder(&mut init)?, act_dim, &config.hidden, &mut init)?;
        let critic = TwinCritic::new(encoder(&mut init)?, act_dim, &config.hidden, &mut init)?;
        let critic_target = critic.deep_copy()?;
        let log_ent_coef = Var::from_tensor(&Tensor::new(&[config.ent_coef_init.ln()], &Device::Cpu)?)?;
        let adam = |vars: Vec<Var>| {
            Adam::new(
                vars,
                AdamConfig { learning_rate: config.off_policy.learning_rate, eps: 1e-8, ..AdamConfig::default() },
            )
        };
        let vars = |named: Vec<(String, Var)>| named.into_iter().map(|(_, v)| v).collect::<Vec<_>>();
        Ok(Self {
            state: LearnerState::new(
                observation_space,
                action_space,
                config.normalize_observations.then(|| RunningMeanStd::new(obs_dim)),
                seed,
            ),
            actor_optimizer: adam(vars(actor.named_vars())),
            critic_optimizer: adam(vars(critic.named_vars("critic"))),
            ent_optimizer: adam(vec![log_ent_coef.clone()]),
            config,
            actor,
            critic,
            critic_target,
            log_ent_coef,
            gradient_steps: 0,
            iterations: 0,
            buffer: None,
            goal: None,
            rng: ChaCha8Rng::seed_from_u64(seed ^ twinbots_api::seeds::SAC_SAMPLING),
            last_losses: SacLosses::default(),
        })
    }

    /// Relabels goals with `goal` (when `her_goals` > 0); a task without one cannot use HER.
    pub fn with_goal(mut self, goal: Option<GoalSpec>) -> anyhow::Result<Self> {
        Learner::set_goal(&mut self, goal)?;
        Ok(self)
    }

    fn act_dim(&self) -> usize {
        self.state.action_space.dim()
    }

    /// Standard normal noise for `rows` actions, from the agent's own stream.
    fn noise(&mut self, rows: usize) -> Vec<f32> {
        (0..rows * self.act_dim()).map(|_| StandardNormal.sample(&mut self.rng)).collect()
    }

    /// [-1, 1] → the action space's bounds.
    fn to_env(&self, unit: &[f32]) -> Vec<f32> {
        crate::off_policy::to_env(&self.state.action_space, unit)
    }

    /// The action for each raw observation row: tanh(μ) when `deterministic`, else a sample.
    pub fn predict(&mut self, obs: &[f32], deterministic: bool) -> anyhow::Result<Vec<f32>> {
        if deterministic {
            return self.predict_deterministic(obs);
        }
        let x = self.state.batch(obs)?;
        let rows = x.dim(0)?;
        let eps = Tensor::from_vec(self.noise(rows), (rows, self.act_dim()), &Device::Cpu)?;
        let (a, _) = self.actor.sample(&x, &eps)?;
        Ok(self.to_env(&a.flatten_all()?.to_vec1::<f32>()?))
    }

    /// tanh(μ(s)) for each raw observation row, in the action space's bounds.
    pub fn predict_deterministic(&self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        let a = self.actor.mode(&self.state.batch(obs)?)?;
        Ok(self.to_env(&a.flatten_all()?.to_vec1::<f32>()?))
    }

    /// Actions in [−1, 1] for each raw observation row: uniform random until learning starts,
    /// then samples of the actor.
    fn explore(&mut self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        let rows = obs.len() / self.state.observation_space.dim().max(1);
        if self.state.timesteps < self.config.off_policy.learning_starts {
            return Ok((0..rows * self.act_dim()).map(|_| self.rng.random_range(-1.0f32..=1.0)).collect());
        }
        let x = self.state.batch(obs)?;
        let eps = Tensor::from_vec(self.noise(rows), (rows, self.act_dim()), &Device::Cpu)?;
        Ok(self.actor.sample(&x, &eps)?.0.flatten_all()?.to_vec1::<f32>()?)
    }

    /// α now.
    pub fn ent_coef(&self) -> anyhow::Result<f32> {
        Ok(self.log_ent_coef.as_tensor().exp()?.to_vec1::<f32>()?[0])
    }
}

impl Agent for Sac {
    crate::agent::agent_basics!(Sac);
    fn policy_net(&self) -> anyhow::Result<PolicyNet> {
        let encoding = self.actor.encoder.export("actor.")?;
        Ok(crate::off_policy::actor_net(&self.state, encoding, self.actor.mode_layers()?))
    }
    /// SB3's SAC tags.
    fn train_scalars(&self, _stats: &UpdateStats) -> Vec<(String, f32)> {
        let l = &self.last_losses;
        let figures = [l.actor_loss, l.critic_loss, l.ent_coef, l.ent_coef_loss, l.entropy];
        crate::off_policy::train_scalars(TRAIN_FIGURES, &figures, l.gradient_steps)
    }
}

impl Learner for Sac {
    crate::off_policy::learn_and_serve!();
    fn set_goal(&mut self, goal: Option<GoalSpec>) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.config.her_goals == 0 || goal.is_some(),
            "sac.her_goals = {}: this task is not goal-conditioned (it declares no achieved and desired goal)",
            self.config.her_goals
        );
        self.goal = goal;
        Ok(())
    }
}

impl OffPolicy for Sac {
    crate::off_policy::schedule_and_parts!();
    fn explore(&mut self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        Sac::explore(self, obs)
    }
    fn train_steps(&mut self, n: usize, each: &mut dyn FnMut(Option<Vec<f32>>)) -> anyhow::Result<()> {
        self.run_gradient_steps(n, &mut |losses| {
            each(losses.map(|l| vec![l.actor_loss, l.critic_loss, l.ent_coef, l.ent_coef_loss, l.entropy]))
        })
    }
    /// α is the one in force now, as `learn` logs it.
    fn end_row(&mut self, figures: Vec<f32>) -> anyhow::Result<Vec<f32>> {
        let [actor_loss, critic_loss, _, ent_coef_loss, entropy] = figures[..] else {
            anyhow::bail!("SAC has {} figures, not {}", TRAIN_FIGURES.len(), figures.len())
        };
        let ent_coef = self.ent_coef()?;
        self.last_losses = SacLosses {
            actor_loss,
            critic_loss,
            ent_coef,
            ent_coef_loss,
            entropy,
            gradient_steps: self.gradient_steps,
        };
        Ok(vec![actor_loss, critic_loss, ent_coef, ent_coef_loss, entropy])
    }
}

impl LoadAgent for Sac {
    fn load(dir: &std::path::Path) -> Result<Self, ModelError> {
        Sac::load(dir)
    }
}
