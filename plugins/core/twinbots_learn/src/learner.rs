//! A model that learns (Stable-Baselines3's `BaseAlgorithm`): an [`Agent`] with `learn`. Every
//! algorithm of [`crate::algos::ALGOS`] is one, so training, resuming and the CLI handle any of
//! them the same way.

use std::path::Path;

use serde::Serialize;
use serde::de::DeserializeOwned;
use twinbots_api::{GoalSpec, TaskSpec, VecEnv};

use crate::agent::Agent;
use crate::callbacks::Callback;
use crate::model_io::ModelError;
use crate::served::ServedLearner;
use crate::stats::{TrainingEnd, TrainingTimes};

pub trait Learner: Agent + Send {
    /// Trains on `env` for `total_timesteps` more steps (summed over envs) or until a callback
    /// stops it; schedules run over the whole budget, earlier sessions included.
    fn learn(&mut self, env: &mut dyn VecEnv, total_timesteps: u64, callback: &mut dyn Callback) -> anyhow::Result<TrainingEnd>;
    /// Where its training time went, since it was made or loaded.
    fn times(&self) -> TrainingTimes;
    /// The task's goal (achieved and desired parts, and its reward), for algorithms that
    /// relabel experience with it (HER); the others need none.
    fn set_goal(&mut self, goal: Option<GoalSpec>) -> anyhow::Result<()> {
        let _ = goal;
        Ok(())
    }
    /// This model, learning from robots' steps as a RobotServer receives them, with batches
    /// (a rollout, a training iteration) sized for `robots` robots, until `total_timesteps`
    /// (the model's `timesteps`, earlier sessions included). Only algorithms whose line in
    /// `ALGOS` says `serves` can.
    fn serve(self: Box<Self>, robots: usize, total_timesteps: u64) -> anyhow::Result<Box<dyn ServedLearner>> {
        let _ = (robots, total_timesteps);
        anyhow::bail!("{} cannot learn from a RobotServer", self.algorithm())
    }
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

/// `T` (an algorithm's config) with `keys` over `T::default()`; a key that does not belong to
/// `T` or whose value does not fit is an error naming `<table>.<key>`.
pub fn config_from<T: Serialize + DeserializeOwned + Default>(keys: &toml::Table, table: &str) -> anyhow::Result<T> {
    let base = toml::Table::try_from(T::default())?;
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
