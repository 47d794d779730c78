//! Evaluating a policy (SB3's `evaluate_policy`): the deterministic policy on a vectorised env
//! until a number of episodes end, with their scores, success and the task's figures.

use std::collections::BTreeMap;

use serde::Serialize;

use crate::agent::Agent;
use twinbots_api::env::VecEnv;
use twinbots_api::{EpisodeSummary, Measure, SolvedCriterion};

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EvalResult {
    /// The task evaluated, as the caller names it (a robot's own, or a variant such as the
    /// UR5e's pick-place).
    pub task: String,
    pub episodes: usize,
    pub mean_score: f32,
    pub std_score: f32,
    pub min_score: f32,
    pub max_score: f32,
    pub mean_length: f32,
    /// Share of episodes that reached their goal, for tasks that report success.
    pub success_rate: Option<f32>,
    /// Each figure the task reports (energy, events, cycle time…), averaged over the episodes
    /// that report it: cycle time over the successful ones.
    pub metrics: BTreeMap<String, f32>,
    /// Each reward term's sum per episode, averaged: how the mean score divides among the
    /// task's terms.
    pub rewards: BTreeMap<String, f32>,
    /// How many episodes each way ended: the termination term's name, [`TIME_LIMIT`] for a
    /// truncated one. Empty where the episodes came without it (a robot's own run).
    pub ended_by: BTreeMap<String, usize>,
    pub scores: Vec<f32>,
}

/// What [`EvalResult::ended_by`] calls an episode truncated by its time limit.
pub use twinbots_api::env::TIME_LIMIT;

impl EvalResult {
    /// Whether these episodes meet a solved criterion: at least its window of them, whose
    /// mean score (or success rate) exceeds its threshold.
    pub fn meets(&self, criterion: &SolvedCriterion) -> bool {
        let value = match criterion.measure {
            Measure::Score => self.mean_score,
            Measure::Success => self.success_rate.unwrap_or(0.0),
        };
        self.episodes >= criterion.window && value > criterion.threshold
    }

    /// One line per figure, for people.
    pub fn describe(&self) -> String {
        let mut out = format!(
            "{}: {} episodes, score {:.1} ± {:.1} (min {:.0}, max {:.0}), mean length {:.1}",
            self.task, self.episodes, self.mean_score, self.std_score, self.min_score, self.max_score, self.mean_length
        );
        if let Some(rate) = self.success_rate {
            out += &format!("\n  success rate {:.1} %", 100.0 * rate);
        }
        for (name, value) in &self.metrics {
            out += &format!("\n  {name}: {value:.3}");
        }
        if !self.ended_by.is_empty() {
            let ways: Vec<String> = self.ended_by.iter().map(|(way, n)| format!("{way} {n}")).collect();
            out += &format!("\n  ended by: {}", ways.join(", "));
        }
        out
    }
}

/// Runs `model`'s deterministic policy on `env` (reset with `seed`) until `episodes` episodes
/// have ended, and reports them under the name `task`.
pub fn evaluate_policy(
    task: &str,
    model: &dyn Agent,
    env: &mut dyn VecEnv,
    episodes: usize,
    seed: u64,
) -> anyhow::Result<EvalResult> {
    run_episodes(task, model, env, episodes, seed, |_| false)
}

/// [`evaluate_policy`] judged against `criterion`: it stops as soon as the episodes so far rule
/// the criterion out ([`SolvedCriterion::out_of_reach`]), so an evaluation that cannot pass
/// costs a few episodes, not all of them. Whether it meets the criterion is the same as
/// with every episode run; its figures are those of the episodes it ran (`episodes` says how many).
pub fn evaluate_against(
    task: &str,
    model: &dyn Agent,
    env: &mut dyn VecEnv,
    episodes: usize,
    seed: u64,
    criterion: &SolvedCriterion,
) -> anyhow::Result<EvalResult> {
    let value = |e: &EpisodeSummary| match criterion.measure {
        Measure::Score => Some(e.score),
        Measure::Success => e.success.map(f32::from),
    };
    run_episodes(task, model, env, episodes, seed, |finished| {
        let values: Vec<f32> = finished.iter().filter_map(value).collect();
        criterion.out_of_reach(&values, episodes)
    })
}

/// Steps the deterministic policy until `episodes` episodes ended or `enough` says so after a
/// step; the episodes of that step beyond `episodes` are dropped.
fn run_episodes(
    task: &str,
    model: &dyn Agent,
    env: &mut dyn VecEnv,
    episodes: usize,
    seed: u64,
    enough: impl Fn(&[EpisodeSummary]) -> bool,
) -> anyhow::Result<EvalResult> {
    anyhow::ensure!(episodes > 0, "an evaluation needs at least 1 episode");
    model.check_spaces(env.observation_space(), env.action_space())?;
    let mut obs = env.reset(Some(seed))?;
    let mut finished = Vec::with_capacity(episodes);
    let mut ended_by: BTreeMap<String, usize> = BTreeMap::new();
    while finished.len() < episodes {
        let mut step = env.step(&model.predict_deterministic(&obs)?)?;
        let before = finished.len();
        for (i, ep) in std::mem::take(&mut step.episodes).into_iter().enumerate() {
            let Some(ep) = ep else { continue };
            if finished.len() < episodes {
                finished.push(ep);
                if let Some(way) = step.way_ended(i) {
                    *ended_by.entry(way).or_default() += 1;
                }
            }
        }
        if finished.len() > before && enough(&finished) {
            break;
        }
        obs = step.obs;
    }
    Ok(EvalResult { ended_by, ..EvalResult::of_episodes(task, &finished) })
}

impl EvalResult {
    /// The figures of these finished episodes (at least one), under the name `task`: however
    /// they were run (an env, a robot running an exported policy on its own).
    pub fn of_episodes(task: &str, episodes: &[EpisodeSummary]) -> Self {
        let scores: Vec<f32> = episodes.iter().map(|e| e.score).collect();
        let successes: Vec<f32> = episodes.iter().filter_map(|e| e.success.map(f32::from)).collect();
        let mut figures: BTreeMap<String, Vec<f32>> = BTreeMap::new();
        let mut rewards: BTreeMap<String, f32> = BTreeMap::new();
        for ep in episodes {
            for (name, value) in &ep.metrics {
                figures.entry(name.clone()).or_default().push(*value);
            }
            for (name, value) in &ep.rewards {
                *rewards.entry(name.clone()).or_default() += *value;
            }
        }
        let n = scores.len() as f32;
        let mean = scores.iter().sum::<f32>() / n;
        let average = |xs: &[f32]| xs.iter().sum::<f32>() / xs.len() as f32;
        EvalResult {
            task: task.to_string(),
            success_rate: (!successes.is_empty()).then(|| average(&successes)),
            metrics: figures.iter().map(|(name, xs)| (name.clone(), average(xs))).collect(),
            rewards: rewards.into_iter().map(|(name, sum)| (name, sum / n)).collect(),
            ended_by: BTreeMap::new(),
            episodes: scores.len(),
            mean_score: mean,
            std_score: (scores.iter().map(|s| (s - mean).powi(2)).sum::<f32>() / n).sqrt(),
            min_score: scores.iter().copied().fold(f32::INFINITY, f32::min),
            max_score: scores.iter().copied().fold(f32::NEG_INFINITY, f32::max),
            mean_length: episodes.iter().map(|e| e.length as f32).sum::<f32>() / n,
            scores,
        }
    }
}
