//! Proximal Policy Optimization (Schulman et al. 2017), read top to bottom like CleanRL's
//! `ppo.py`, with Stable-Baselines3's surface: `learn`, `predict`, `save`, `load`, callbacks.
//!
//! `learn` is the loop: collect a rollout (`rollout.rs`), compute advantages (`buffer.rs`), and
//! update (`update.rs`). Served by a RobotServer (`served.rs`), it collects robots' steps with
//! the same pieces: `observe`, `policy_step`, `bootstrapped_reward`, `RolloutBuffer::push`,
//! `values`, `update_learning_rate`, `train`.

mod buffer;
mod config;
mod fused;
mod model_file;
mod part;
pub(crate) mod policy;
mod reward_scale;
mod rollout;
mod served;
mod update;

use std::collections::BTreeMap;
use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

pub use crate::model_io::{METADATA_FILE, ModelError, WEIGHTS_FILE, write_atomic};
pub use crate::stats::{TrainingTimes, UpdateStats};
pub use buffer::RolloutBuffer;
pub use config::{MAX_ROLLOUT, PpoConfig};
pub use policy::{ActorCritic, Head};
pub use reward_scale::RewardScale;
pub use rollout::PolicyStep;

use crate::callbacks::Callback;
use crate::learner::{Algorithm, config_from, load_learner};
use crate::learner_state::LearnerState;
use crate::nn::Adam;
use crate::normalize::RunningMeanStd;
use crate::policy_net::{Activation, PolicyHead, PolicyNet};
use crate::stats::TrainingEnd;
use twinbots_api::env::VecEnv;
use twinbots_api::spaces::Space;
use twinbots_api::{EpisodeSummary, SolvedCriterion};

/// The name `--algo` and the settings' `[ppo]` table use, and the one its models are saved
/// under (`model.json`'s `algorithm`).
pub const NAME: &str = "ppo";
pub const SAVED_AS: &str = "PPO";
/// Its figures in `progress.csv` (`UpdateStats::train`), in order.
pub const TRAIN_FIGURES: &[&str] = &["policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction"];

/// PPO's line in [`crate::algos::ALGOS`].
pub const ALGORITHM: Algorithm = Algorithm {
    name: NAME,
    saved_as: SAVED_AS,
    summary: "Proximal Policy Optimization: on-policy, discrete or continuous actions, every design pattern",
    continuous_only: false,
    serves: true,
    config: |keys, arenas| {
        let config: PpoConfig = config_from(keys, NAME)?;
        config.validate()?;
        let rollout = config.n_steps.saturating_mul(arenas);
        anyhow::ensure!(
            rollout <= MAX_ROLLOUT,
            "ppo.n_steps × arenas = {} × {arenas} = {rollout}: a rollout must hold at most {MAX_ROLLOUT} samples",
            config.n_steps
        );
        Ok(toml::Table::try_from(&config)?)
    },
    new: |config, spec, seed| {
        let model =
            Ppo::new(config_from(config, NAME)?, spec.observation_space.clone(), spec.action_space.clone(), seed)?;
        anyhow::ensure!(
            !model.config.freeze_features || !fused::applies(&model.policy),
            "ppo.freeze_features = true: there is no image encoder to freeze (observations {}, policy {:?}); it applies to camera images with policy cnn or keypoints",
            spec.observation_space,
            model.config.policy
        );
        if let Some(path) = &model.config.features_from {
            // A fresh model only: a saved one has its own weights (and needs the file no more).
            for encoder in [Some(&model.policy.encoder), model.policy.value_encoder.as_ref()].into_iter().flatten() {
                crate::model_io::set_encoder_from_file(encoder, path)
                    .map_err(|e| anyhow::anyhow!("ppo.features_from = {e:#}"))?;
            }
        }
        Ok(Box::new(model))
    },
    load: load_learner::<Ppo>,
};

/// A PPO agent: the policy, its optimiser state and the counters that make a run resumable.
pub struct Ppo {
    pub config: PpoConfig,
    /// Spaces, normaliser, seed, counters, last episodes, env state and times, as every
    /// learner keeps them.
    pub state: LearnerState,
    pub policy: ActorCritic,
    /// With `normalize_rewards`: how rewards are scaled before they are stored.
    pub reward_scale: Option<RewardScale>,
    optimizer: Adam,
    rng: ChaCha8Rng,
}

impl std::fmt::Debug for Ppo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Ppo")
            .field("observation_space", &self.state.observation_space)
            .field("action_space", &self.state.action_space)
            .field("timesteps", &self.state.timesteps)
            .field("episodes", &self.state.episodes)
            .finish_non_exhaustive()
    }
}

impl Ppo {
    pub fn new(config: PpoConfig, observation_space: Space, action_space: Space, seed: u64) -> anyhow::Result<Self> {
        crate::tuning::for_small_networks();
        config.validate()?;
        let obs_dim = observation_space.dim();
        let encoder = (config.policy, config.features_dim, config.share_features_extractor);
        let policy =
            ActorCritic::new(&observation_space, &action_space, encoder, &config.hidden, config.log_std_init, seed)?;
        crate::nn::check_normalization(&observation_space, config.normalize_observations, NAME)?;
        let obs_rms = config.normalize_observations.then(|| RunningMeanStd::new(obs_dim));
        let reward_scale = config.normalize_rewards.then(RewardScale::default);
        let optimizer = update::adam(&policy, config.learning_rate);
        Ok(Self {
            state: LearnerState::new(observation_space, action_space, obs_rms, seed),
            config,
            policy,
            reward_scale,
            optimizer,
            rng: ChaCha8Rng::seed_from_u64(seed ^ twinbots_api::seeds::PPO_ACTIONS),
        })
    }

    /// An independent copy (weights, optimiser state, normalisation, counters, random stream)
    /// to evaluate or save while the original trains on.
    pub fn snapshot(&self) -> anyhow::Result<Ppo> {
        let policy = self.policy.deep_copy()?;
        let optimizer = self.optimizer.for_copies(policy.named_vars().into_iter().map(|(_, v)| v).collect())?;
        Ok(Self {
            state: self.state.clone(),
            config: self.config.clone(),
            policy,
            reward_scale: self.reward_scale.clone(),
            optimizer,
            rng: self.rng.clone(),
        })
    }

    /// The action for each raw observation row (flat in, flat out), clipped to a box's bounds.
    pub fn predict(&mut self, obs: &[f32], deterministic: bool) -> anyhow::Result<Vec<f32>> {
        let x = self.batch(&self.normalize(obs))?;
        let (actions, _, _) = self.policy.act(&x, deterministic, &mut self.rng)?;
        Ok(self.clip_to_space(actions))
    }

    /// The policy's most likely action for each raw observation row; needs no random stream.
    pub fn predict_deterministic(&self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        let x = self.batch(&self.normalize(obs))?;
        let mut unused = ChaCha8Rng::seed_from_u64(0);
        let (actions, _, _) = self.policy.act(&x, true, &mut unused)?;
        Ok(self.clip_to_space(actions))
    }

    /// Counts a finished episode into the statistics.
    pub fn record_episode(&mut self, episode: &EpisodeSummary) {
        self.state.episodes += 1;
        self.state.history.record(episode);
    }

    /// The mean of each figure over the last 100 finished episodes that reported it.
    pub fn recent_metric_means(&self) -> BTreeMap<String, f32> {
        self.state.history.metric_means()
    }

    /// Success rate of the last 100 finished episodes that reported success, if any did.
    pub fn recent_success_rate(&self) -> Option<f32> {
        self.state.history.success_rate()
    }

    /// Whether the recent episodes meet `criterion`.
    pub fn is_solved(&self, criterion: &SolvedCriterion) -> bool {
        self.state.history.is_solved(criterion)
    }

    /// Mean score of the last 100 finished episodes.
    pub fn mean_recent_score(&self) -> f32 {
        self.state.history.mean_score()
    }

    /// Trains for `more_steps` more env steps (summed over envs), calling `callback`
    /// after each update, and says why it stopped. A linear learning rate decays over the
    /// whole budget, `timesteps` so far included, so a resumed run follows the schedule of an
    /// uninterrupted one.
    pub fn learn(
        &mut self,
        env: &mut dyn VecEnv,
        more_steps: u64,
        callback: &mut dyn Callback,
    ) -> anyhow::Result<TrainingEnd> {
        anyhow::ensure!(
            env.observation_space().dim() == self.state.observation_space.dim()
                && env.action_space() == &self.state.action_space,
            "the env's spaces ({} obs, {} actions) differ from the model's ({} obs, {} actions)",
            env.observation_space().dim(),
            env.action_space(),
            self.state.observation_space.dim(),
            self.state.action_space
        );
        let end = self.state.timesteps + more_steps;
        let mut buffer =
            RolloutBuffer::new(env.num_envs(), self.state.observation_space.dim(), self.state.action_space.dim());
        // A model that learnt before continues its envs' episodes (replayed: their observations
        // are already in the statistics); a new one starts them.
        let mut obs = match self.state.env_state.take() {
            Some(state) => {
                let raw = twinbots_api::restore(env, &state)?;
                self.normalize(&raw)
            }
            None => {
                let first = env.reset(Some(self.state.seed.wrapping_add(self.state.timesteps)))?;
                self.observe(&first)
            }
        };
        callback.on_training_start(self)?;
        let mut ended = None;
        while ended.is_none() && self.state.timesteps < end {
            let started = Instant::now();
            self.update_learning_rate(end);

            // 1. Rollout: n_steps of every env with the current policy.
            self.collect_rollout(env, &mut obs, &mut buffer)?;
            // Where the envs stand for a checkpoint after this update (the update leaves them
            // alone): env time, not update time.
            let recording_started = Instant::now();
            self.state.env_state = env.state()?;
            self.state.times.env_s += recording_started.elapsed().as_secs_f64();

            // 2. Advantages by GAE, bootstrapped from V(s_T).
            let update_started = Instant::now();
            let last_values = self.values(&obs)?;
            buffer.compute_advantages(&last_values, self.config.gamma, self.config.gae_lambda);

            // 3. Optimise the clipped surrogate for n_epochs over shuffled minibatches.
            let stats = self.train(&buffer, started)?;
            let callbacks_started = Instant::now();
            self.state.times.update_s += (callbacks_started - update_started).as_secs_f64();

            ended = TrainingEnd::after(callback.on_update(&stats, self)?, self.state.timesteps);
            self.state.times.callbacks_s += callbacks_started.elapsed().as_secs_f64();
        }
        callback.on_training_end(self)?;
        self.state.env_state = None;
        Ok(ended.unwrap_or(TrainingEnd::BudgetSpent { timesteps: self.state.timesteps }))
    }
}

impl crate::agent::Agent for Ppo {
    crate::agent::agent_basics!(Ppo);
    fn policy_net(&self) -> anyhow::Result<PolicyNet> {
        let layers = crate::nn::layer_values(&self.policy.pi.layers, "pi")?;
        let head = match &self.state.action_space {
            Space::Discrete { .. } => PolicyHead::ArgMax,
            Space::Box { .. } => PolicyHead::ClipToBox,
            other => anyhow::bail!("{other} actions cannot be exported"),
        };
        Ok(PolicyNet {
            obs_rms: self.state.obs_rms.clone(),
            encoding: self.policy.encoder.export("")?,
            layers,
            hidden: Activation::Tanh,
            head,
        })
    }

    /// SB3's PPO tags: the loss L_clip − c_ent·H + c_V·L_V (here averaged over the update's
    /// minibatches; SB3 logs its last minibatch's), its parts, KL, clip fraction, σ.
    fn train_scalars(&self, s: &UpdateStats) -> Vec<(String, f32)> {
        let c = &self.config;
        let (policy_loss, value_loss, entropy) = (s.train("policy_loss"), s.train("value_loss"), s.train("entropy"));
        let loss = policy_loss - c.ent_coef * entropy + c.vf_coef * value_loss;
        let mut out: Vec<(String, f32)> = vec![
            ("train/loss".into(), loss),
            ("train/policy_gradient_loss".into(), policy_loss),
            ("train/value_loss".into(), value_loss),
            ("train/entropy_loss".into(), -entropy),
            ("train/approx_kl".into(), s.train("approx_kl")),
            ("train/clip_fraction".into(), s.train("clip_fraction")),
        ];
        if let policy::Head::Gaussian { log_std, .. } = &self.policy.head
            && let Ok(values) = log_std.as_tensor().to_vec1::<f32>()
        {
            out.push(("train/std".into(), values.iter().map(|l| l.exp()).sum::<f32>() / values.len().max(1) as f32));
        }
        out
    }
}

impl crate::learner::Learner for Ppo {
    fn learn(
        &mut self,
        env: &mut dyn VecEnv,
        more_steps: u64,
        callback: &mut dyn Callback,
    ) -> anyhow::Result<TrainingEnd> {
        Ppo::learn(self, env, more_steps, callback)
    }
    fn serve(self: Box<Self>, robots: usize, budget: u64) -> anyhow::Result<Box<dyn crate::learner::ServedLearner>> {
        Ok(Box::new(served::ServedPpo::new(*self, robots, budget)))
    }
}

impl crate::agent::LoadAgent for Ppo {
    fn load(dir: &std::path::Path) -> Result<Self, ModelError> {
        Ppo::load(dir)
    }
}

impl Ppo {
    /// A clear error when this model cannot drive a robot with these spaces.
    pub fn check_spaces(&self, observation: &Space, action: &Space) -> Result<(), ModelError> {
        crate::agent::Agent::check_spaces(self, observation, action)
    }
}
