//! What every learner is to the rest of twinbots: an [`Agent`] acts deterministically, saves
//! itself, counts its steps and keeps the [`EpisodeHistory`] of its training episodes. The
//! callbacks, evaluation, run directories and commands work on `&dyn Agent`, so PPO and SAC
//! share them (Stable-Baselines3's `BaseAlgorithm`).

use std::path::Path;

use twinbots_api::spaces::Space;

pub use crate::history::{EpisodeHistory, WINDOW};
use crate::learner_state::LearnerState;
use crate::model_io::ModelError;
use crate::policy_net::PolicyNet;
use crate::stats::UpdateStats;

/// A learner as the callbacks, evaluation and run directories see it.
pub trait Agent {
    /// The `algorithm` of its `model.json` (`"PPO"`): its entry's `saved_as` in
    /// [`crate::algos::ALGOS`].
    fn algorithm(&self) -> &'static str;
    /// What it keeps as every learner does: spaces, counters, history.
    fn state(&self) -> &LearnerState;
    fn observation_space(&self) -> &Space {
        &self.state().observation_space
    }
    fn action_space(&self) -> &Space {
        &self.state().action_space
    }
    /// Env steps learnt from (summed over envs).
    fn timesteps(&self) -> u64 {
        self.state().timesteps
    }
    /// Training episodes finished.
    fn episodes(&self) -> u64 {
        self.state().episodes
    }
    /// The last 100 finished training episodes.
    fn history(&self) -> &EpisodeHistory {
        &self.state().history
    }
    /// The policy's most likely action for each raw observation row.
    fn predict_deterministic(&self, obs: &[f32]) -> anyhow::Result<Vec<f32>>;
    /// The action for each raw observation row: the most likely one when `deterministic`,
    /// else a sample from the policy's own random stream (SB3's `predict`).
    fn predict(&mut self, obs: &[f32], deterministic: bool) -> anyhow::Result<Vec<f32>>;
    /// The deterministic policy as plain numbers, for export.
    fn policy_net(&self) -> anyhow::Result<PolicyNet>;
    /// Saves into the directory `dir` (created if needed), every file atomically.
    fn save(&self, dir: &Path) -> Result<(), ModelError>;
    /// The names of its `UpdateStats::train` figures, in the order it gives them (its columns
    /// of `progress.csv`).
    fn train_figures(&self) -> &'static [&'static str];
    /// The algorithm's own `train/` TensorBoard scalars for an update's row.
    fn train_scalars(&self, stats: &UpdateStats) -> Vec<(String, f32)>;

    /// A clear error when this model cannot drive a robot with these spaces.
    fn check_spaces(&self, observation: &Space, action: &Space) -> Result<(), ModelError> {
        if observation.dim() != self.observation_space().dim() {
            return Err(ModelError::SpaceMismatch {
                what: "observations of dimension",
                model: self.observation_space().dim().to_string(),
                robot: observation.dim().to_string(),
            });
        }
        if action != self.action_space() {
            return Err(ModelError::SpaceMismatch {
                what: "actions",
                model: self.action_space().to_string(),
                robot: action.to_string(),
            });
        }
        Ok(())
    }
}

/// A model that can be loaded from a directory one of its kind saved.
pub trait LoadAgent: Agent + Sized {
    fn load(dir: &Path) -> Result<Self, ModelError>;
}

/// The [`Agent`] methods a learner `$ty` writes as every learner does: its `SAVED_AS` name and
/// `TRAIN_FIGURES`, its `state` field, and its own `predict`, `predict_deterministic` and `save`.
macro_rules! agent_basics {
    ($ty:ident) => {
        fn algorithm(&self) -> &'static str {
            SAVED_AS
        }
        fn train_figures(&self) -> &'static [&'static str] {
            TRAIN_FIGURES
        }
        fn state(&self) -> &$crate::learner_state::LearnerState {
            &self.state
        }
        fn predict_deterministic(&self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
            $ty::predict_deterministic(self, obs)
        }
        fn predict(&mut self, obs: &[f32], deterministic: bool) -> anyhow::Result<Vec<f32>> {
            $ty::predict(self, obs, deterministic)
        }
        fn save(&self, dir: &std::path::Path) -> Result<(), $crate::model_io::ModelError> {
            $ty::save(self, dir)
        }
    };
}
pub(crate) use agent_basics;
