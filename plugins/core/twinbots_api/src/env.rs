//! The vectorised env API (Gymnasium / Stable-Baselines3 VecEnv semantics) and Gymnasium's
//! single-env surface over it.

use crate::env_state::{EnvState, StreamState};
use crate::episode::EpisodeSummary;
use crate::spaces::Space;

/// What one vectorised step returns. Vectors are flat: env `i`'s observation is
/// `obs[i * obs_dim..(i + 1) * obs_dim]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepResult {
    pub obs: Vec<f32>,
    pub rewards: Vec<f32>,
    pub terminated: Vec<bool>,
    pub truncated: Vec<bool>,
    /// For envs whose episode ended this step: the last observation of that episode (the
    /// `obs` entry is already the first of the next one).
    pub final_obs: Vec<Option<Vec<f32>>>,
    pub episodes: Vec<Option<EpisodeSummary>>,
    /// For envs whose episode terminated this step: the termination term that ended it (a
    /// step's `info`, which a goal's reward may depend on: `GoalSpec::change`). Empty where the
    /// env does not say.
    pub ended_by: Vec<Option<String>>,
}

/// What [`StepResult::way_ended`] calls an episode truncated by its time limit.
pub const TIME_LIMIT: &str = "time_limit";

impl StepResult {
    /// How env `i`'s episode ended this step: its termination term, else [`TIME_LIMIT`] where
    /// it was truncated; `None` where it did not end or the env does not say.
    pub fn way_ended(&self, i: usize) -> Option<String> {
        match self.ended_by.get(i).cloned().flatten() {
            Some(term) => Some(term),
            None if self.truncated.get(i) == Some(&true) && self.terminated.get(i) != Some(&true) => {
                Some(TIME_LIMIT.to_string())
            }
            None => None,
        }
    }
}

/// N environments stepped together, with auto-reset. Errors mean the simulation is gone
/// (its thread ended or panicked), never bad luck: callers stop.
pub trait VecEnv {
    fn num_envs(&self) -> usize;
    fn observation_space(&self) -> &Space;
    fn action_space(&self) -> &Space;
    /// Resets every env; `seed` restarts their random streams (env `i` gets stream `i`).
    fn reset(&mut self, seed: Option<u64>) -> anyhow::Result<Vec<f32>>;
    /// Applies `actions` (flat, `num_envs * action_dim`) and advances one control step.
    fn step(&mut self, actions: &[f32]) -> anyhow::Result<StepResult>;
    /// The envs' state as their running episodes ([`crate::replay`]), for a checkpoint; `None`
    /// for envs that cannot be replayed (a resumed run then starts fresh episodes).
    fn state(&mut self) -> anyhow::Result<Option<EnvState>> {
        Ok(None)
    }
    /// Starts new episodes in the envs of `starts`, each from its stream state, after setting
    /// the control-step clock to `clock` if given; returns every env's observation. What
    /// [`crate::replay::replay`] is made of.
    fn begin_episodes(&mut self, starts: &[(usize, StreamState)], clock: Option<u64>) -> anyhow::Result<Vec<f32>> {
        let _ = (starts, clock);
        anyhow::bail!("this env cannot replay episodes")
    }
}

/// Gymnasium's `info` for one env: set on the step an episode ended (auto-reset happened).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Info {
    pub final_observation: Option<Vec<f32>>,
    pub episode: Option<EpisodeSummary>,
}

/// One transition, Gymnasium's `(obs, reward, terminated, truncated, info)`.
pub type Transition = (Vec<f32>, f32, bool, bool, Info);

/// Gymnasium's single-env surface over a one-env [`VecEnv`]. Finished episodes auto-reset
/// (the vectorised semantics); the finished episode's last observation is in `info`.
pub struct SingleEnv<V: VecEnv>(pub V);

impl<V: VecEnv> SingleEnv<V> {
    pub fn new(env: V) -> anyhow::Result<Self> {
        anyhow::ensure!(env.num_envs() == 1, "SingleEnv wraps exactly one env, got {}", env.num_envs());
        Ok(Self(env))
    }

    /// `reset(seed) -> (obs, info)`
    pub fn reset(&mut self, seed: Option<u64>) -> anyhow::Result<(Vec<f32>, Info)> {
        Ok((self.0.reset(seed)?, Info::default()))
    }

    /// `step(action) -> (obs, reward, terminated, truncated, info)`; the action must lie in the
    /// action space.
    pub fn step(&mut self, action: &[f32]) -> anyhow::Result<Transition> {
        anyhow::ensure!(
            self.0.action_space().contains(action),
            "action {action:?} is not in the action space {}",
            self.0.action_space()
        );
        let mut r = self.0.step(action)?;
        let info = Info { final_observation: r.final_obs.pop().flatten(), episode: r.episodes.pop().flatten() };
        Ok((r.obs, r.rewards[0], r.terminated[0], r.truncated[0], info))
    }
}
