//! The off-policy learners' base (SAC, TD3; SB3's `OffPolicyAlgorithm`): their critics
//! ([`networks`]), their replay buffer on disk ([`replay_file`]), actions in [−1, 1] scaled to
//! the action box, a vectorised step stored as transitions, the training loop ([`learn`]) and
//! learning from robots ([`served`]), through the [`OffPolicy`] face each of them shows.

pub mod config;
pub mod networks;
pub(crate) mod replay_file;
pub(crate) mod served;

use std::time::Instant;

use twinbots_api::env::VecEnv;
use twinbots_api::env_state::EnvState;
use twinbots_api::{EpisodeSummary, Space, StepResult};

use crate::callbacks::Callback;
use crate::history::EpisodeHistory;
use crate::learner::Learner;
use crate::learner_state::LearnerState;
use crate::normalize::RunningMeanStd;
use crate::policy_net::{Activation, DenseLayer, InputEncoding, PolicyHead, PolicyNet};
use crate::replay_buffer::ReplayBuffer;
use crate::stats::{TrainingEnd, TrainingTimes, UpdateStats, figures};

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

/// The action space's bounds → [−1, 1], clipped there: [`to_env`]'s inverse, for actions a
/// demonstrator took.
pub fn to_unit(space: &Space, env: &[f32]) -> Vec<f32> {
    let Space::Box { low, high } = space else { return env.to_vec() };
    env.iter()
        .enumerate()
        .map(|(i, a)| {
            let k = i % low.len();
            (2.0 * (a - low[k]) / (high[k] - low[k]) - 1.0).clamp(-1.0, 1.0)
        })
        .collect()
}

/// The exported actor of an off-policy learner: ReLU layers, tanh squashed to the action box.
pub(crate) fn actor_net(state: &LearnerState, encoding: InputEncoding, layers: Vec<DenseLayer>) -> PolicyNet {
    PolicyNet {
        obs_rms: state.obs_rms.clone(),
        encoding,
        layers,
        hidden: Activation::Relu,
        head: PolicyHead::TanhToBox,
    }
}

/// SB3's `train/` tags: each of the row's figures under its name, then `train/n_updates`.
pub(crate) fn train_scalars(names: &[&str], figures: &[f32], gradient_steps: u64) -> Vec<(String, f32)> {
    let named = names.iter().zip(figures).map(|(name, &value)| (format!("train/{name}"), value));
    named.chain(std::iter::once(("train/n_updates".to_string(), gradient_steps as f32))).collect()
}

/// Stores the step from `obs` with the (unit) `actions` that gave `out` as transitions
/// (s, a, r, s', done): a finished episode's s' is its last observation, and a truncated one is
/// not done, so its value bootstraps. Each episode that ended is handed to `ended`.
pub fn store_step(
    buffer: Option<&mut ReplayBuffer>,
    obs: &[f32],
    actions: &[f32],
    out: &StepResult,
    mut ended: impl FnMut(&EpisodeSummary),
) {
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

/// How an off-policy learner's training runs (its config's numbers).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Schedule {
    pub learning_starts: u64,
    /// Gradient steps are taken every `train_freq` iterations (steps of every env).
    pub train_freq: usize,
    pub gradient_steps: usize,
    /// A row every `log_interval` iterations.
    pub log_interval: usize,
    pub buffer_size: usize,
    pub learning_rate: f64,
}

/// The counters and stores an off-policy learner keeps, lent to [`learn`] and its served form.
pub(crate) struct Parts<'a> {
    /// Where the envs' first reset draws from (with the steps taken before it).
    pub seed: u64,
    pub timesteps: &'a mut u64,
    /// Iterations of `learn` (steps of each env).
    pub iterations: &'a mut u64,
    pub episodes: &'a mut u64,
    pub updates: &'a mut u64,
    pub history: &'a mut EpisodeHistory,
    pub buffer: &'a mut Option<ReplayBuffer>,
    pub obs_rms: &'a mut Option<RunningMeanStd>,
    pub times: &'a mut TrainingTimes,
    /// Where the envs stood at the last row (see `Ppo::env_state`).
    pub env_state: &'a mut Option<EnvState>,
}

/// Gives `model` an empty replay buffer for `lanes` envs if it has none yet (image
/// observations kept as bytes, as they came); returns the lanes of the buffer it has.
pub(crate) fn replay_buffer<M: OffPolicy>(model: &mut M, lanes: usize) -> usize {
    if model.parts().buffer.is_none() {
        let ring = ReplayBuffer::new(
            model.schedule().buffer_size,
            lanes,
            model.observation_space().dim(),
            model.action_space().dim(),
        );
        let ring =
            if matches!(model.observation_space(), Space::Image { .. }) { ring.with_byte_observations() } else { ring };
        *model.parts().buffer = Some(ring);
    }
    model.parts().buffer.as_ref().map_or(lanes, |b| b.n_envs)
}

/// Trains `model` for `more_steps` more env steps (summed over envs), calling `callback`
/// after every row, and says why it stopped: SAC's and TD3's `learn`.
pub(crate) fn learn<M: OffPolicy>(
    model: &mut M,
    env: &mut dyn VecEnv,
    more_steps: u64,
    callback: &mut dyn Callback,
) -> anyhow::Result<TrainingEnd> {
    model.check_spaces(env.observation_space(), env.action_space())?;
    let n_envs = env.num_envs();
    let schedule = model.schedule();
    let lanes = replay_buffer(model, n_envs);
    anyhow::ensure!(lanes == n_envs, "the replay buffer was filled by {lanes} envs, this env has {n_envs}");
    let parts = model.parts();
    let end = *parts.timesteps + more_steps;
    // A model that learnt before continues its envs' episodes (replayed); a new one starts.
    let mut obs = match parts.env_state.take() {
        Some(state) => twinbots_api::restore(env, &state)?,
        None => {
            let first = env.reset(Some(parts.seed.wrapping_add(*parts.timesteps)))?;
            if let Some(rms) = parts.obs_rms {
                rms.update(&first);
            }
            first
        }
    };
    callback.on_training_start(&*model)?;
    let (mut ended, mut row) = (None, Row::default());
    while ended.is_none() && *model.parts().timesteps < end {
        // 1. Act: uniform random actions until learning starts, then the learner's exploring ones.
        let inference_started = Instant::now();
        let unit = model.explore(&obs)?;
        let env_started = Instant::now();
        let out = env.step(&to_env(model.action_space(), &unit))?;
        let parts = model.parts();
        parts.times.inference_s += (env_started - inference_started).as_secs_f64();
        parts.times.env_s += env_started.elapsed().as_secs_f64();

        // 2. Store (s, a, r, s', done).
        let (history, episodes) = (parts.history, parts.episodes);
        store_step(parts.buffer.as_mut(), &obs, &unit, &out, |episode| {
            *episodes += 1;
            history.record(episode);
        });
        if let Some(rms) = parts.obs_rms {
            rms.update(&out.obs);
        }
        obs = out.obs;
        *parts.timesteps += n_envs as u64;
        *parts.iterations += 1;
        let (timesteps, iterations) = (*parts.timesteps, *parts.iterations);

        // 3. Learn from the buffer.
        row.transitions += n_envs as u64;
        if timesteps >= schedule.learning_starts && iterations % schedule.train_freq as u64 == 0 {
            row.train(model, schedule.gradient_steps)?;
        }

        // 4. A row and the callbacks.
        if iterations % schedule.log_interval as u64 == 0 {
            let callbacks_started = Instant::now();
            *model.parts().env_state = env.state()?;
            let stats = std::mem::take(&mut row).finish(model)?;
            ended = TrainingEnd::after(callback.on_update(&stats, &*model)?, timesteps);
            // The next row's clock starts after the callbacks (an evaluation is not its time).
            row = Row::default();
            model.parts().times.callbacks_s += callbacks_started.elapsed().as_secs_f64();
        }
    }
    callback.on_training_end(&*model)?;
    let parts = model.parts();
    *parts.env_state = None;
    Ok(ended.unwrap_or(TrainingEnd::BudgetSpent { timesteps: *parts.timesteps }))
}

/// What an off-policy learner (SAC, TD3) shows [`served::ServedOffPolicy`].
pub(crate) trait OffPolicy: Learner + 'static {
    fn schedule(&self) -> Schedule;
    fn parts(&mut self) -> Parts<'_>;
    /// Actions in [−1, 1] for each raw observation row: uniform random until learning starts,
    /// then the learner's exploring ones (as `learn` acts).
    fn explore(&mut self, obs: &[f32]) -> anyhow::Result<Vec<f32>>;
    /// `n` gradient steps, each one's figures handed to `each` in turn: in its `TRAIN_FIGURES`
    /// order (NaN where the step has none), or `None` when it was skipped (a loss or gradient
    /// not finite).
    fn train_steps(&mut self, n: usize, each: &mut dyn FnMut(Option<Vec<f32>>)) -> anyhow::Result<()>;
    /// A row's figures (each the mean over the row's steps that gave it; NaN if none did)
    /// become the model's last losses; returns them as the row logs them.
    fn end_row(&mut self, figures: Vec<f32>) -> anyhow::Result<Vec<f32>>;
}

/// One row's gradient steps (a row every `log_interval` iterations, SB3's log interval): each
/// figure's sum and count over the steps that gave it (TD3's actor loss comes every
/// `policy_delay` steps only), the steps applied and skipped, the env steps taken, and when
/// the row began. `learn` and the served form both keep their rows with it.
pub(crate) struct Row {
    sums: Vec<f32>,
    counts: Vec<u32>,
    applied: usize,
    skipped: usize,
    /// Env steps (transitions) in the row, counted by the caller.
    pub transitions: u64,
    started: std::time::Instant,
}

impl Default for Row {
    fn default() -> Self {
        Self {
            sums: Vec::new(),
            counts: Vec::new(),
            applied: 0,
            skipped: 0,
            transitions: 0,
            started: std::time::Instant::now(),
        }
    }
}

impl Row {
    /// `n` gradient steps of `model`, timed as its updates.
    pub fn train<M: OffPolicy>(&mut self, model: &mut M, n: usize) -> anyhow::Result<()> {
        if n == 0 {
            return Ok(());
        }
        let started = std::time::Instant::now();
        model.train_steps(n, &mut |step| match step {
            Some(step) => self.add(&step),
            None => self.skipped += 1,
        })?;
        model.parts().times.update_s += started.elapsed().as_secs_f64();
        Ok(())
    }

    fn add(&mut self, step: &[f32]) {
        self.sums.resize(step.len(), 0.0);
        self.counts.resize(step.len(), 0);
        for (k, v) in step.iter().enumerate().filter(|(_, v)| v.is_finite()) {
            self.sums[k] += v;
            self.counts[k] += 1;
        }
        self.applied += 1;
    }

    /// Ends the row: its figures' means become `model`'s last losses, the row is counted in
    /// `model`'s updates, and its statistics are returned (skipped steps also said on stderr).
    pub fn finish<M: OffPolicy>(self, model: &mut M) -> anyhow::Result<UpdateStats> {
        let names = model.train_figures();
        let means = (0..names.len())
            .map(|k| match self.counts.get(k) {
                Some(&c) if c > 0 => self.sums[k] / c as f32,
                _ => f32::NAN,
            })
            .collect();
        let logged = model.end_row(means)?;
        let learning_rate = model.schedule().learning_rate;
        let parts = model.parts();
        *parts.updates += 1;
        if self.skipped > 0 {
            eprintln!(
                "row {}: {} gradient step(s) skipped: a loss or gradient was not finite",
                *parts.updates, self.skipped
            );
        }
        Ok(UpdateStats {
            train: figures(names, &logged),
            learning_rate,
            steps_per_s: self.transitions as f32 / self.started.elapsed().as_secs_f32(),
            skipped_steps: self.skipped,
            applied_steps: self.applied,
            ..parts.history.row(*parts.updates, *parts.timesteps, *parts.episodes)
        })
    }
}

/// [`OffPolicy::schedule`] and [`OffPolicy::parts`] of a learner whose fields and config keys
/// are named as SAC's and TD3's are.
macro_rules! schedule_and_parts {
    () => {
        fn schedule(&self) -> $crate::off_policy::Schedule {
            let c = &self.config.off_policy;
            $crate::off_policy::Schedule {
                learning_starts: c.learning_starts,
                train_freq: c.train_freq,
                gradient_steps: c.gradient_steps,
                log_interval: self.config.log_interval,
                buffer_size: c.buffer_size,
                learning_rate: c.learning_rate,
            }
        }
        fn parts(&mut self) -> $crate::off_policy::Parts<'_> {
            $crate::off_policy::Parts {
                seed: self.state.seed,
                timesteps: &mut self.state.timesteps,
                iterations: &mut self.iterations,
                episodes: &mut self.state.episodes,
                updates: &mut self.state.updates,
                history: &mut self.state.history,
                buffer: &mut self.buffer,
                obs_rms: &mut self.state.obs_rms,
                times: &mut self.state.times,
                env_state: &mut self.state.env_state,
            }
        }
    };
}
pub(crate) use schedule_and_parts;

/// The [`Learner`] methods SAC and TD3 share: `learn` is [`learn`], and served, each is a
/// [`served::ServedOffPolicy`] (it learns to no fixed budget, so it takes none).
macro_rules! learn_and_serve {
    () => {
        fn learn(
            &mut self,
            env: &mut dyn twinbots_api::VecEnv,
            more_steps: u64,
            callback: &mut dyn $crate::callbacks::Callback,
        ) -> anyhow::Result<$crate::stats::TrainingEnd> {
            $crate::off_policy::learn(self, env, more_steps, callback)
        }
        fn serve(
            self: Box<Self>,
            robots: usize,
            _budget: u64,
        ) -> anyhow::Result<Box<dyn $crate::learner::ServedLearner>> {
            Ok(Box::new($crate::off_policy::served::ServedOffPolicy::new(*self, robots)?))
        }
    };
}
pub(crate) use learn_and_serve;
