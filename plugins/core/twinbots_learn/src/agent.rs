//! What every learner is to the rest of twinbots: an [`Agent`] acts deterministically, saves
//! itself, counts its steps and keeps the [`EpisodeHistory`] of its training episodes. The
//! callbacks, evaluation, run directories and commands work on `&dyn Agent`, so PPO and SAC
//! share them (Stable-Baselines3's `BaseAlgorithm`).

use std::collections::{BTreeMap, VecDeque};
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::model_io::{ModelError, file_error};
use crate::ppo::UpdateStats;
use twinbots_api::spaces::Space;
use twinbots_api::{EpisodeSummary, Measure, SolvedCriterion};

/// The window of finished episodes the training figures are taken over (SB3's `ep_info_buffer`).
pub const WINDOW: usize = 100;

/// The last 100 finished training episodes: scores, lengths, successes and the task's figures.
/// Saved with a model (its fields sit at the top level of `model.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EpisodeHistory {
    /// Scores, oldest first.
    pub recent_scores: VecDeque<f32>,
    #[serde(default)]
    pub recent_lengths: VecDeque<f32>,
    /// 1 or 0 for each episode that reported success or failure.
    #[serde(default)]
    pub recent_successes: VecDeque<f32>,
    /// Each figure the task reports (energy, cycle time…), over the episodes that reported it.
    #[serde(default)]
    pub recent_metrics: BTreeMap<String, VecDeque<f32>>,
}

impl EpisodeHistory {
    /// Counts a finished episode in.
    pub fn record(&mut self, episode: &EpisodeSummary) {
        push_window(&mut self.recent_scores, episode.score);
        push_window(&mut self.recent_lengths, episode.length as f32);
        if let Some(success) = episode.success {
            push_window(&mut self.recent_successes, if success { 1.0 } else { 0.0 });
        }
        for (name, value) in &episode.metrics {
            push_window(self.recent_metrics.entry(name.clone()).or_default(), *value);
        }
    }

    /// Mean score (NaN before any episode ended).
    pub fn mean_score(&self) -> f32 {
        mean(&self.recent_scores)
    }

    pub fn mean_length(&self) -> f32 {
        mean(&self.recent_lengths)
    }

    /// Success rate over the episodes that reported success, if any did.
    pub fn success_rate(&self) -> Option<f32> {
        (!self.recent_successes.is_empty()).then(|| mean(&self.recent_successes))
    }

    /// The mean of each figure.
    pub fn metric_means(&self) -> BTreeMap<String, f32> {
        self.recent_metrics.iter().map(|(name, values)| (name.clone(), mean(values))).collect()
    }

    /// Whether these episodes meet `criterion`.
    pub fn is_solved(&self, criterion: &SolvedCriterion) -> bool {
        let values = match criterion.measure {
            Measure::Score => &self.recent_scores,
            Measure::Success => &self.recent_successes,
        };
        let values: Vec<f32> = values.iter().copied().collect();
        criterion.is_met(&values)
    }

    /// The episode part of a `progress.csv` row (the learner fills in the rest).
    pub fn row(&self, update: u64, timesteps: u64, episodes: u64) -> UpdateStats {
        UpdateStats {
            update: update as usize,
            timesteps,
            episodes,
            mean_reward: self.mean_score(),
            min_reward: self.recent_scores.iter().copied().fold(f32::NAN, f32::min),
            max_reward: self.recent_scores.iter().copied().fold(f32::NAN, f32::max),
            mean_length: self.mean_length(),
            success_rate: mean(&self.recent_successes),
            ..Default::default()
        }
    }
}

fn push_window(window: &mut VecDeque<f32>, x: f32) {
    if window.len() == WINDOW {
        window.pop_front();
    }
    window.push_back(x);
}

pub(crate) fn mean(xs: &VecDeque<f32>) -> f32 {
    if xs.is_empty() { f32::NAN } else { xs.iter().sum::<f32>() / xs.len() as f32 }
}

/// A learner as the callbacks, evaluation and run directories see it.
pub trait Agent {
    /// `"PPO"` or `"SAC"`: the `algorithm` of its `model.json`.
    fn algorithm(&self) -> &'static str;
    fn observation_space(&self) -> &Space;
    fn action_space(&self) -> &Space;
    /// Env steps learnt from (summed over envs).
    fn timesteps(&self) -> u64;
    /// Training episodes finished.
    fn episodes(&self) -> u64;
    /// The last 100 finished training episodes.
    fn history(&self) -> &EpisodeHistory;
    /// The policy's most likely action for each raw observation row.
    fn predict_deterministic(&self, obs: &[f32]) -> anyhow::Result<Vec<f32>>;
    /// Saves into the directory `dir` (created if needed), every file atomically.
    fn save(&self, dir: &Path) -> Result<(), ModelError>;
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
            return Err(ModelError::SpaceMismatch { what: "actions", model: self.action_space().to_string(), robot: action.to_string() });
        }
        Ok(())
    }
}

/// A model that can be loaded from a directory one of its kind saved.
pub trait LoadAgent: Agent + Sized {
    fn load(dir: &Path) -> Result<Self, ModelError>;
}

/// The algorithm a saved model was trained with (its `model.json`'s `algorithm`).
pub fn saved_algorithm(dir: &Path) -> Result<String, ModelError> {
    #[derive(Deserialize)]
    struct Algorithm {
        algorithm: String,
    }
    let path = dir.join(crate::model_io::METADATA_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| file_error(&path, e))?;
    let a: Algorithm = serde_json::from_str(&text).map_err(|e| file_error(&path, e))?;
    Ok(a.algorithm)
}

/// Loads a model of whichever algorithm saved it.
pub fn load_agent(dir: &Path) -> Result<Box<dyn Agent + Send>, ModelError> {
    match saved_algorithm(dir)?.as_str() {
        "PPO" => Ok(Box::new(crate::ppo::Ppo::load(dir)?)),
        "SAC" => Ok(Box::new(crate::sac::Sac::load(dir)?)),
        other => Err(ModelError::File {
            path: dir.join(crate::ppo::METADATA_FILE),
            message: format!("algorithm '{other}' is unknown to this build (it reads PPO and SAC)"),
        }),
    }
}
