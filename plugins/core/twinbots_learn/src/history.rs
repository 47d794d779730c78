//! The last finished training episodes a model keeps (SB3's `ep_info_buffer`), saved with it.

use std::collections::{BTreeMap, VecDeque};

use serde::{Deserialize, Serialize};
use twinbots_api::{EpisodeSummary, Measure, SolvedCriterion};

use crate::stats::UpdateStats;

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
