//! A model that learns (Stable-Baselines3's `BaseAlgorithm`): an [`Agent`] with `learn`. Every
//! algorithm of [`crate::algos::ALGOS`] is one, so training, resuming and the CLI handle any of
//! them the same way; one that can be served also learns from robots' steps as a RobotServer
//! receives them ([`ServedLearner`]).

use std::path::Path;

use serde::Serialize;
use serde::de::DeserializeOwned;
use twinbots_api::{GoalSpec, TaskSpec, VecEnv};

use crate::agent::Agent;
use crate::callbacks::Callback;
use crate::model_io::ModelError;
use crate::stats::{TrainingEnd, TrainingTimes, UpdateStats};

pub trait Learner: Agent + Send {
    /// Trains on `env` for `more_steps` env steps beyond its `timesteps` (summed over envs), or
    /// until a callback stops it (SB3's `learn(total_timesteps, reset_num_timesteps=False)`);
    /// schedules run over the whole budget, earlier training included.
    fn learn(
        &mut self,
        env: &mut dyn VecEnv,
        more_steps: u64,
        callback: &mut dyn Callback,
    ) -> anyhow::Result<TrainingEnd>;
    /// Where its training time went, since it was made or loaded.
    fn times(&self) -> TrainingTimes {
        self.state().times
    }
    /// The task's goal (achieved and desired parts, and its reward), for algorithms that
    /// relabel experience with it (HER); the others need none.
    fn set_goal(&mut self, goal: Option<GoalSpec>) -> anyhow::Result<()> {
        let _ = goal;
        Ok(())
    }
    /// This model, learning from robots' steps as a RobotServer receives them, with batches
    /// (a rollout, a training iteration) sized for `robots` robots, until its `timesteps`
    /// (earlier training included) reach `budget` — an absolute count, unlike `learn`'s. Only
    /// algorithms whose line in `ALGOS` says `serves` can.
    fn serve(self: Box<Self>, robots: usize, budget: u64) -> anyhow::Result<Box<dyn ServedLearner>> {
        let _ = (robots, budget);
        anyhow::bail!("{} cannot learn from a RobotServer", self.algorithm())
    }
}

/// The outcome of a robot's last action, as its `step` message reports it.
#[derive(Clone, Copy, Debug)]
pub struct RobotStep<'a> {
    /// The observation after the action (the episode's last when it ended).
    pub obs: &'a [f32],
    pub reward: f32,
    pub terminated: bool,
    pub truncated: bool,
    /// Whether the episode reached its goal (on its last step).
    pub success: Option<bool>,
    /// The termination term that ended it (with `terminated`): what a goal's reward is
    /// recomputed with when HER relabels the step.
    pub ended_by: Option<&'a str>,
}

impl RobotStep<'_> {
    pub fn ended(&self) -> bool {
        self.terminated || self.truncated
    }
}

/// A model learning from robots' steps as they arrive (design pattern 3's RobotServer): every
/// robot runs its own episodes at its own pace, one message at a time, and the learner keeps
/// each robot's running episode apart until it can learn from it. An algorithm that can be served says so in
/// its line of `ALGOS` (`serves`) and turns its model into one with `Learner::serve`: PPO
/// (`ppo/served.rs`), SAC and TD3 (`off_policy/served.rs`). The server calls these with the
/// learner's lock held: a robot's request is answered once any learning it made due is done,
/// so every action comes from a known policy.
pub trait ServedLearner: Send {
    /// The model, for the callbacks.
    fn agent(&self) -> &dyn Agent;
    /// A robot connected; its id is the server's for that connection.
    fn join(&mut self, robot: u64);
    /// The robot's running episode is dropped unlearnt (an abort, a new start, the robot
    /// left): a part of an episode is never mixed into training. Its finished episodes stay.
    fn drop_episode(&mut self, robot: u64);
    /// The robot left (its running episode is dropped first).
    fn leave(&mut self, robot: u64);
    /// Whether the robot has an action waiting for its outcome; `None`: no such robot.
    fn awaits_outcome(&self, robot: u64) -> Option<bool>;
    /// The action for the robot's fresh observation (an episode's first, or the one after a
    /// step), which then waits for its outcome.
    fn act(&mut self, robot: u64, obs: &[f32]) -> anyhow::Result<Vec<f32>>;
    /// The outcome of the robot's waiting action (see [`Self::awaits_outcome`]).
    fn record(&mut self, robot: u64, step: &RobotStep) -> anyhow::Result<()>;
    /// Learns if enough has arrived; the row for the callbacks when one is due.
    fn learn_if_due(&mut self) -> anyhow::Result<Option<UpdateStats>>;
    /// Robots connected, and their transitions not yet learnt from.
    fn load(&self) -> (usize, usize);
    /// The model, once serving is over.
    fn into_learner(self: Box<Self>) -> Box<dyn Learner>;
}

/// One algorithm as the rest of twinbots knows it: a line of [`crate::algos::ALGOS`], the one
/// place an algorithm is named (RL Zoo's `ALGOS`). Each algorithm's folder defines its own.
pub struct Algorithm {
    /// Lower case: `--algo`, the settings' `[<name>]` table, a robot's training defaults.
    pub name: &'static str,
    /// Its models' `model.json` `algorithm` (`"PPO"`).
    pub saved_as: &'static str,
    /// One line: what it is.
    pub summary: &'static str,
    /// Whether it learns continuous (Box) actions only.
    pub continuous_only: bool,
    /// Whether a RobotServer (design pattern 3) can train it from robots' steps.
    pub serves: bool,
    /// Its hyperparameters: `keys` over its defaults, checked (an unknown key, a wrong type or
    /// a value out of range is an error naming `<name>.<key>`), returned whole as
    /// `config.toml` keeps them. `arenas`: the envs it will train on.
    pub config: fn(keys: &toml::Table, arenas: usize) -> anyhow::Result<toml::Table>,
    /// A fresh model for the task `spec`, from a table `config` returned, seeded with `seed`.
    pub new: fn(config: &toml::Table, spec: &TaskSpec, seed: u64) -> anyhow::Result<Box<dyn Learner>>,
    /// The model saved in a directory.
    pub load: fn(dir: &Path) -> Result<Box<dyn Learner>, ModelError>,
}

/// An algorithm's hyperparameters, as its settings table holds them.
pub trait LearnerConfig: Serialize + DeserializeOwned + Default {
    /// The first setting outside its range, as an error naming `<name>.<key>`.
    fn check(&self) -> anyhow::Result<()>;
}

/// [`Algorithm::config`] of an algorithm whose settings need no check beyond their own.
pub fn checked_table<T: LearnerConfig>(keys: &toml::Table, table: &str) -> anyhow::Result<toml::Table> {
    let config: T = config_from(keys, table)?;
    config.check()?;
    Ok(toml::Table::try_from(&config)?)
}

/// [`Algorithm::load`] of a learner that loads as itself.
pub fn load_learner<L: crate::agent::LoadAgent + Learner + 'static>(
    dir: &Path,
) -> Result<Box<dyn Learner>, ModelError> {
    Ok(Box::new(L::load(dir)?))
}

/// `T` (an algorithm's config) with `keys` over `T::default()`; a key that does not belong to
/// `T` or whose value does not fit is an error naming `<table>.<key>`.
pub fn config_from<T: Serialize + DeserializeOwned + Default>(keys: &toml::Table, table: &str) -> anyhow::Result<T> {
    let base = toml::Table::try_from(T::default())?;
    // Every key a table may hold, `None`s included (TOML leaves those out); serde's own check
    // cannot be used where a config flattens another's keys into its table.
    let known = match serde_json::to_value(T::default())? {
        serde_json::Value::Object(fields) => fields.into_iter().map(|(key, _)| key).collect::<Vec<_>>(),
        _ => Vec::new(),
    };
    if let Some((key, value)) = keys.iter().find(|(key, _)| !known.contains(key)) {
        let expected = known.iter().map(|k| format!("`{k}`")).collect::<Vec<_>>().join(", ");
        anyhow::bail!("{table}.{key} = {value}: unknown field `{key}`, expected one of {expected}");
    }
    // Key by key first, so an error names the key (serde's message for a wrong type does not).
    for (key, value) in keys {
        let mut one = base.clone();
        one.insert(key.clone(), value.clone());
        if let Err(e) = one.try_into::<T>() {
            anyhow::bail!("{table}.{key} = {value}: {}", e.message());
        }
    }
    let mut merged = base;
    merged.extend(keys.clone());
    merged.try_into().map_err(|e: toml::de::Error| anyhow::anyhow!("[{table}]: {}", e.message()))
}
