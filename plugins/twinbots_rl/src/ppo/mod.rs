//! Proximal Policy Optimization (Schulman et al. 2017), read top to bottom like CleanRL's
//! `ppo.py`, with Stable-Baselines3's surface: `learn`, `predict`, `save`, `load`.

mod buffer;
mod config;
mod model_file;
mod policy;

use std::collections::VecDeque;
use std::time::Instant;

use candle_core::{Device, Tensor, Var};
use candle_nn::{AdamW, Optimizer, ParamsAdamW};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

pub use buffer::RolloutBuffer;
pub use config::PpoConfig;
pub use model_file::{ModelError, write_atomic};
pub use policy::ActorCritic;

use crate::env::VecEnv;
use crate::normalize::RunningMeanStd;
use crate::spaces::Space;
use crate::task::{EpisodeSummary, Measure, SolvedCriterion};

/// One row of `progress.csv`: what an update saw and did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct UpdateStats {
    pub update: usize,
    pub timesteps: u64,
    pub episodes: u64,
    /// Over the last 100 finished episodes.
    pub mean_reward: f32,
    pub min_reward: f32,
    pub max_reward: f32,
    pub mean_length: f32,
    /// Share of the last 100 finished episodes that reported success (NaN: none reported).
    pub success_rate: f32,
    pub policy_loss: f32,
    pub value_loss: f32,
    pub entropy: f32,
    pub approx_kl: f32,
    pub clip_fraction: f32,
    pub learning_rate: f64,
    pub steps_per_s: f32,
}

/// What a callback tells `learn` after an update.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    Continue,
    Stop,
}

/// Called after every update with its statistics and the model; `Flow::Stop` ends training.
pub trait Callback {
    fn on_update(&mut self, stats: &UpdateStats, model: &Ppo) -> anyhow::Result<Flow>;
}

impl<F: FnMut(&UpdateStats, &Ppo) -> anyhow::Result<Flow>> Callback for F {
    fn on_update(&mut self, stats: &UpdateStats, model: &Ppo) -> anyhow::Result<Flow> {
        self(stats, model)
    }
}

/// A PPO agent: the policy, its optimiser state and the counters that make a run resumable.
pub struct Ppo {
    pub config: PpoConfig,
    pub observation_space: Space,
    pub action_space: Space,
    pub policy: ActorCritic,
    pub obs_rms: Option<RunningMeanStd>,
    pub seed: u64,
    pub timesteps: u64,
    pub episodes: u64,
    pub updates: u64,
    /// Scores of the last 100 finished episodes, oldest first.
    pub recent_scores: VecDeque<f32>,
    recent_lengths: VecDeque<f32>,
    /// 1 or 0 for each of the last 100 finished episodes that reported success or failure.
    pub recent_successes: VecDeque<f32>,
    optimizer: AdamW,
    rng: ChaCha8Rng,
}

const WINDOW: usize = 100;

impl std::fmt::Debug for Ppo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Ppo")
            .field("observation_space", &self.observation_space)
            .field("action_space", &self.action_space)
            .field("timesteps", &self.timesteps)
            .field("episodes", &self.episodes)
            .finish_non_exhaustive()
    }
}

impl Ppo {
    pub fn new(config: PpoConfig, observation_space: Space, action_space: Space, seed: u64) -> anyhow::Result<Self> {
        let obs_dim = observation_space.dim();
        let policy = ActorCritic::new(obs_dim, &action_space, &config.hidden, config.log_std_init, seed)?;
        let obs_rms = config.normalize_observations.then(|| RunningMeanStd::new(obs_dim));
        let optimizer = adam(&policy, config.learning_rate)?;
        Ok(Self {
            config,
            observation_space,
            action_space,
            policy,
            obs_rms,
            seed,
            timesteps: 0,
            episodes: 0,
            updates: 0,
            recent_scores: VecDeque::new(),
            recent_lengths: VecDeque::new(),
            recent_successes: VecDeque::new(),
            optimizer,
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_0f_a11),
        })
    }

    /// Observations as the network sees them (normalised if configured).
    fn prepare(&self, obs: &[f32]) -> anyhow::Result<Tensor> {
        let rows = obs.len() / self.observation_space.dim();
        let data = match &self.obs_rms {
            Some(rms) => rms.normalize(obs),
            None => obs.to_vec(),
        };
        Ok(Tensor::from_vec(data, (rows, self.observation_space.dim()), &Device::Cpu)?)
    }

    /// The action for each observation row (flat in, flat out), clipped to a box's bounds.
    pub fn predict(&mut self, obs: &[f32], deterministic: bool) -> anyhow::Result<Vec<f32>> {
        let x = self.prepare(obs)?;
        let (actions, _, _) = self.policy.act(&x, deterministic, &mut self.rng)?;
        Ok(self.clip_to_space(actions))
    }

    /// The policy's most likely action for each observation row; needs no random stream.
    pub fn predict_deterministic(&self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        let x = self.prepare(obs)?;
        let mut unused = ChaCha8Rng::seed_from_u64(0);
        let (actions, _, _) = self.policy.act(&x, true, &mut unused)?;
        Ok(self.clip_to_space(actions))
    }

    /// Boxes are clipped before they reach the env; the buffer keeps the unclipped sample so
    /// its log-probability stays right (as SB3).
    fn clip_to_space(&self, mut actions: Vec<f32>) -> Vec<f32> {
        if let Space::Box { low, high } = &self.action_space {
            for (i, a) in actions.iter_mut().enumerate() {
                let k = i % low.len();
                *a = a.clamp(low[k], high[k]);
            }
        }
        actions
    }

    /// One observation → (action as sampled, action clipped to the space, log-probability,
    /// value): what a rollout records, for learners that collect their own data (the RobotServer).
    pub fn act_one(&mut self, obs: &[f32]) -> anyhow::Result<(Vec<f32>, Vec<f32>, f32, f32)> {
        if let Some(rms) = &mut self.obs_rms {
            rms.update(obs);
        }
        let x = self.prepare(obs)?;
        let (action, log_prob, value) = self.policy.act(&x, false, &mut self.rng)?;
        Ok((action.clone(), self.clip_to_space(action), log_prob[0], value[0]))
    }

    /// V(obs) for one observation.
    pub fn value_of(&self, obs: &[f32]) -> anyhow::Result<f32> {
        Ok(self.policy.value(&self.prepare(obs)?)?.to_vec1::<f32>()?[0])
    }

    /// Counts a finished episode into the statistics.
    pub fn record_episode(&mut self, episode: &EpisodeSummary) {
        self.episodes += 1;
        push_window(&mut self.recent_scores, episode.score);
        push_window(&mut self.recent_lengths, episode.length as f32);
        if let Some(success) = episode.success {
            push_window(&mut self.recent_successes, if success { 1.0 } else { 0.0 });
        }
    }

    /// Success rate of the last 100 finished episodes that reported success, if any did.
    pub fn recent_success_rate(&self) -> Option<f32> {
        (!self.recent_successes.is_empty()).then(|| mean(&self.recent_successes))
    }

    /// Whether the recent episodes meet `criterion`.
    pub fn is_solved(&self, criterion: &SolvedCriterion) -> bool {
        let values = match criterion.measure {
            Measure::Score => &self.recent_scores,
            Measure::Success => &self.recent_successes,
        };
        let values: Vec<f32> = values.iter().copied().collect();
        criterion.is_met(&values)
    }

    /// One PPO update on a buffer whose advantages are computed; `timesteps` advances by its
    /// length. With a linear schedule, the learning rate follows `fraction_done`.
    pub fn train_on(&mut self, buffer: &RolloutBuffer, fraction_done: f64) -> anyhow::Result<UpdateStats> {
        let started = Instant::now();
        if self.config.linear_lr {
            self.optimizer.set_learning_rate(self.config.learning_rate * (1.0 - fraction_done).clamp(0.0, 1.0));
        }
        self.updates += 1;
        self.timesteps += buffer.len() as u64;
        let losses = self.optimize(buffer)?;
        Ok(self.update_stats(losses, buffer.len(), started))
    }

    /// Mean score of the last 100 finished episodes.
    pub fn mean_recent_score(&self) -> f32 {
        mean(&self.recent_scores)
    }

    /// Trains for `total_timesteps` more env steps (summed over envs), calling `callback` after
    /// each update. A linear learning rate decays over the whole budget, `timesteps` so far
    /// included, so a resumed run follows the schedule of an uninterrupted one.
    pub fn learn(
        &mut self,
        env: &mut dyn VecEnv,
        total_timesteps: u64,
        callback: &mut dyn Callback,
    ) -> anyhow::Result<()> {
        anyhow::ensure!(
            env.observation_space().dim() == self.observation_space.dim() && env.action_space() == &self.action_space,
            "the env's spaces ({} obs, {} actions) differ from the model's ({} obs, {} actions)",
            env.observation_space().dim(), env.action_space(), self.observation_space.dim(), self.action_space
        );
        let c = self.config.clone();
        let n_envs = env.num_envs();
        let (obs_dim, act_dim) = (self.observation_space.dim(), self.action_space.dim());
        let mut buffer = RolloutBuffer::new(n_envs, obs_dim, act_dim);
        let end = self.timesteps + total_timesteps;
        let mut obs = env.reset(Some(self.seed.wrapping_add(self.timesteps)))?;
        while self.timesteps < end {
            self.updates += 1;
            let started = Instant::now();
            if c.linear_lr {
                let progress = self.timesteps as f64 / end as f64;
                self.optimizer.set_learning_rate(c.learning_rate * (1.0 - progress).max(0.0));
            }

            // 1. Rollout: n_steps of every env with the current policy.
            buffer.clear();
            for _ in 0..c.n_steps {
                if let Some(rms) = &mut self.obs_rms {
                    rms.update(&obs);
                }
                let x = self.prepare(&obs)?;
                let (actions, log_probs, values) = self.policy.act(&x, false, &mut self.rng)?;
                let step = env.step(&self.clip_to_space(actions.clone()))?;
                let mut rewards = step.rewards.clone();
                // A truncated episode did not end in the MDP: bootstrap its last reward with
                // γ V(final observation), as SB3 does.
                for e in 0..n_envs {
                    if step.truncated[e] && !step.terminated[e]
                        && let Some(final_obs) = &step.final_obs[e]
                    {
                        let v = self.policy.value(&self.prepare(final_obs)?)?.to_vec1::<f32>()?[0];
                        rewards[e] += c.gamma * v;
                    }
                    if let Some(ep) = &step.episodes[e] {
                        self.record_episode(ep);
                    }
                }
                buffer.obs.extend_from_slice(&obs);
                buffer.actions.extend_from_slice(&actions);
                buffer.log_probs.extend_from_slice(&log_probs);
                buffer.values.extend_from_slice(&values);
                buffer.rewards.extend_from_slice(&rewards);
                buffer.dones.extend((0..n_envs).map(|e| step.terminated[e] || step.truncated[e]));
                obs = step.obs;
                self.timesteps += n_envs as u64;
            }

            // 2. Advantages by GAE, bootstrapped from V(s_T).
            let last_values = self.policy.value(&self.prepare(&obs)?)?.to_vec1::<f32>()?;
            buffer.compute_advantages(&last_values, c.gamma, c.gae_lambda);

            // 3. Optimise the clipped surrogate for n_epochs over shuffled minibatches.
            let losses = self.optimize(&buffer)?;

            let stats = self.update_stats(losses, c.n_steps * n_envs, started);
            if callback.on_update(&stats, self)? == Flow::Stop {
                break;
            }
        }
        Ok(())
    }

    /// An update's row: the losses from `optimize`, the counters and episode statistics now,
    /// and the throughput of the `samples` collected and learned from since `started`.
    fn update_stats(&self, losses: UpdateStats, samples: usize, started: Instant) -> UpdateStats {
        UpdateStats {
            update: self.updates as usize,
            timesteps: self.timesteps,
            episodes: self.episodes,
            mean_reward: mean(&self.recent_scores),
            min_reward: self.recent_scores.iter().copied().fold(f32::NAN, f32::min),
            max_reward: self.recent_scores.iter().copied().fold(f32::NAN, f32::max),
            mean_length: mean(&self.recent_lengths),
            success_rate: mean(&self.recent_successes),
            learning_rate: self.optimizer.learning_rate(),
            steps_per_s: samples as f32 / started.elapsed().as_secs_f32(),
            ..losses
        }
    }

    fn optimize(&mut self, buffer: &RolloutBuffer) -> anyhow::Result<UpdateStats> {
        let c = &self.config;
        let dev = Device::Cpu;
        let n = buffer.len();
        let (obs_dim, act_dim) = (buffer.obs_dim, buffer.act_dim);
        let obs_all = match &self.obs_rms {
            Some(rms) => rms.normalize(&buffer.obs),
            None => buffer.obs.clone(),
        };
        let mut indices: Vec<usize> = (0..n).collect();
        let (mut pg_sum, mut v_sum, mut ent_sum, mut kl_sum, mut clip_sum, mut batches) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        'epochs: for _ in 0..c.n_epochs {
            indices.shuffle(&mut self.rng);
            for chunk in indices.chunks(c.batch_size) {
                let b = chunk.len();
                let gather = |src: &[f32], width: usize| -> Vec<f32> {
                    chunk.iter().flat_map(|&i| src[i * width..(i + 1) * width].iter().copied()).collect()
                };
                let obs = Tensor::from_vec(gather(&obs_all, obs_dim), (b, obs_dim), &dev)?;
                let actions = Tensor::from_vec(gather(&buffer.actions, act_dim), (b, act_dim), &dev)?;
                let actions = if act_dim == 1 && matches!(self.action_space, Space::Discrete { .. }) {
                    actions.squeeze(1)?
                } else {
                    actions
                };
                let old_log_prob = Tensor::from_vec(gather(&buffer.log_probs, 1), b, &dev)?;
                let returns = Tensor::from_vec(gather(&buffer.returns, 1), b, &dev)?;
                let mut adv = gather(&buffer.advantages, 1);
                if c.normalize_advantage && b > 1 {
                    let m = adv.iter().sum::<f32>() / b as f32;
                    let s = (adv.iter().map(|a| (a - m).powi(2)).sum::<f32>() / (b - 1) as f32).sqrt();
                    adv.iter_mut().for_each(|a| *a = (*a - m) / (s + 1e-8));
                }
                let adv = Tensor::from_vec(adv, b, &dev)?;

                let eval = self.policy.evaluate(&obs, &actions)?;
                // ratio = π(a|s) / π_old(a|s)
                let log_ratio = (&eval.log_prob - &old_log_prob)?;
                let ratio = log_ratio.exp()?;
                // L_clip = E[min(r A, clip(r, 1-ε, 1+ε) A)]; we minimise its negative.
                let surr1 = (&ratio * &adv)?;
                let surr2 = (ratio.clamp(1.0 - c.clip_range, 1.0 + c.clip_range)? * &adv)?;
                let policy_loss = surr1.minimum(&surr2)?.mean_all()?.neg()?;
                // L_V = E[(V(s) - R)^2]   (SB3's MSE, no value clipping)
                let value_loss = (&eval.value - &returns)?.sqr()?.mean_all()?;
                let entropy = eval.entropy.mean_all()?;
                let loss = ((&policy_loss - (&entropy * c.ent_coef as f64)?)? + (&value_loss * c.vf_coef as f64)?)?;

                let mut grads = loss.backward()?;
                clip_grad_norm(&mut grads, &self.policy.named_vars(), c.max_grad_norm)?;
                self.optimizer.step(&grads)?;

                // approx KL (Schulman's k3 estimator): E[(r - 1) - log r]
                let approx_kl = ((&ratio - 1.0)? - &log_ratio)?.mean_all()?.to_scalar::<f32>()?;
                let clipped = ((&ratio - 1.0)?.abs()?.gt(c.clip_range as f64)?)
                    .to_dtype(candle_core::DType::F32)?.mean_all()?.to_scalar::<f32>()?;
                pg_sum += policy_loss.to_scalar::<f32>()?;
                v_sum += value_loss.to_scalar::<f32>()?;
                ent_sum += entropy.to_scalar::<f32>()?;
                kl_sum += approx_kl;
                clip_sum += clipped;
                batches += 1.0;
                if let Some(target) = c.target_kl
                    && approx_kl > 1.5 * target
                {
                    break 'epochs;
                }
            }
        }
        let batches = f32::max(batches, 1.0);
        Ok(UpdateStats {
            policy_loss: pg_sum / batches,
            value_loss: v_sum / batches,
            entropy: ent_sum / batches,
            approx_kl: kl_sum / batches,
            clip_fraction: clip_sum / batches,
            ..Default::default()
        })
    }
}

fn adam(policy: &ActorCritic, lr: f64) -> anyhow::Result<AdamW> {
    let vars: Vec<Var> = policy.named_vars().into_iter().map(|(_, v)| v).collect();
    // Plain Adam as in SB3 (eps 1e-5, no weight decay).
    Ok(AdamW::new(vars, ParamsAdamW { lr, beta1: 0.9, beta2: 0.999, eps: 1e-5, weight_decay: 0.0 })?)
}

/// Scales all gradients so their global L2 norm is at most `max_norm`.
fn clip_grad_norm(grads: &mut candle_core::backprop::GradStore, vars: &[(String, Var)], max_norm: f32) -> anyhow::Result<()> {
    let mut total = 0.0f32;
    for (_, v) in vars {
        if let Some(g) = grads.get(v.as_tensor()) {
            total += g.sqr()?.sum_all()?.to_scalar::<f32>()?;
        }
    }
    let norm = total.sqrt();
    if norm > max_norm {
        let scale = (max_norm / (norm + 1e-6)) as f64;
        for (_, v) in vars {
            if let Some(g) = grads.remove(v.as_tensor()) {
                grads.insert(v.as_tensor(), (g * scale)?);
            }
        }
    }
    Ok(())
}

fn push_window(window: &mut VecDeque<f32>, x: f32) {
    if window.len() == WINDOW {
        window.pop_front();
    }
    window.push_back(x);
}

fn mean(xs: &VecDeque<f32>) -> f32 {
    if xs.is_empty() { f32::NAN } else { xs.iter().sum::<f32>() / xs.len() as f32 }
}
