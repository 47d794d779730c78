//! Finished episodes as every learner and report sees them, and when a task counts as solved.

use std::collections::BTreeMap;

/// Solved when the mean of the last `window` episodes' `measure` exceeds `threshold`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolvedCriterion {
    pub window: usize,
    pub threshold: f32,
    pub measure: Measure,
}

/// What a solved criterion averages over episodes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Measure {
    /// The episode's score (summed reward).
    #[default]
    Score,
    /// 1 for an episode that reached its goal, 0 otherwise: the mean is the success rate.
    Success,
}

impl SolvedCriterion {
    /// Mean score of the last `window` episodes above `threshold`.
    pub fn mean_score(window: usize, threshold: f32) -> Self {
        Self { window, threshold, measure: Measure::Score }
    }

    /// Success rate of the last `window` episodes at least `rate`.
    pub fn success_rate(window: usize, rate: f32) -> Self {
        // Rates are multiples of 1/window: a hair below makes "at least" exact.
        Self { window, threshold: rate - 0.5 / window as f32, measure: Measure::Success }
    }

    /// Whether `values` of `measure`, the first of `episodes` episodes whose mean is judged,
    /// already rule the criterion out: even if every episode left reached the best value there
    /// is (success, for a success rate), their mean could not exceed the threshold. Scores have
    /// no such bound: never for them.
    pub fn out_of_reach(&self, values: &[f32], episodes: usize) -> bool {
        let best = match self.measure {
            Measure::Success => 1.0,
            Measure::Score => return false,
        };
        let left = episodes.saturating_sub(values.len()) as f64;
        let highest = (values.iter().map(|&v| v as f64).sum::<f64>() + left * best) / episodes.max(1) as f64;
        highest <= self.threshold as f64
    }

    /// Whether these episodes' values of `measure` (oldest first) meet the criterion.
    pub fn is_met(&self, values: &[f32]) -> bool {
        if values.len() < self.window {
            return false;
        }
        let last = &values[values.len() - self.window..];
        last.iter().sum::<f32>() / self.window as f32 > self.threshold
    }
}

/// The score and length of a finished episode, and what the task reported of it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EpisodeSummary {
    pub score: f32,
    pub length: u32,
    /// Whether it reached the task's goal (Stable-Baselines3's `info["is_success"]`); `None`
    /// for tasks without a goal.
    pub success: Option<bool>,
    /// Named figures of the episode (Isaac Lab's episode log), e.g. energy or cycle time.
    pub metrics: BTreeMap<String, f32>,
    /// The episode's sum of each reward term (weighted), by term name (Isaac Lab's
    /// `Episode_Reward/<term>`): they add up to `score`.
    pub rewards: BTreeMap<String, f32>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_success_rate_criterion_needs_its_window_and_at_least_its_rate() {
        let c = SolvedCriterion::success_rate(20, 0.95);
        let mut values = vec![1.0; 19];
        assert!(!c.is_met(&values), "19 episodes are not a window of 20");
        values.push(0.0);
        assert!(c.is_met(&values), "19 of 20 is 95 %");
        values.push(0.0);
        assert!(!c.is_met(&values), "18 of the last 20 is 90 %");
    }

    #[test]
    fn a_success_rate_is_out_of_reach_once_more_episodes_failed_than_it_allows() {
        // 98 % of 200: 196 successes, so at most 4 failures.
        let c = SolvedCriterion::success_rate(200, 0.98);
        let mut values = vec![1.0, 0.0, 0.0, 1.0, 0.0, 0.0];
        assert!(!c.out_of_reach(&values, 200), "4 failures: 196 of 200 is still possible");
        values.push(0.0);
        assert!(c.out_of_reach(&values, 200), "5 failures: at most 195 of 200");
        assert!(!c.out_of_reach(&[], 200));
        // A mean score has no best value to bound what is left.
        assert!(!SolvedCriterion::mean_score(100, 1950.0).out_of_reach(&[0.0; 99], 100));
    }
}
