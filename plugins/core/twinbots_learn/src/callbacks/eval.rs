//! Periodic evaluation of the deterministic policy (SB3's `EvalCallback`, with
//! `StopTrainingOnRewardThreshold` as its stop criterion).

use super::{Callback, Flow, SolvedBy};
use crate::agent::Agent;
use crate::evaluation::{EvalResult, evaluate_against, evaluate_policy};
use crate::run_dir::RunDir;
use crate::stats::UpdateStats;
use crate::tensorboard::EventWriter;
use twinbots_api::SolvedCriterion;
use twinbots_api::env::VecEnv;

/// Builds a fresh env to evaluate on, its streams seeded with the given seed.
pub type EnvFactory = Box<dyn FnMut(u64) -> anyhow::Result<Box<dyn VecEnv>> + Send>;

/// Every `every` updates, runs `episodes` episodes of the deterministic policy on a fresh env
/// seeded for that evaluation ([`evaluation_seed`]: new targets and starts each time, so a
/// policy cannot pass by having learnt one fixed set; the same run seed draws the same ones,
/// also after a resume, which continues the update count), appends the result to the run's
/// `evaluations.csv` if given one, and stops training once an evaluation meets the solved
/// criterion if given one. Training episodes can lag far behind the deterministic policy
/// (exploration noise spoils a precise task), which is why SB3 judges on evaluations.
pub struct EvalCallback {
    task: String,
    make_env: EnvFactory,
    every: usize,
    episodes: usize,
    seed: u64,
    log: Option<RunDir>,
    events: Option<EventWriter>,
    stop_when: Option<SolvedCriterion>,
    /// The latest evaluation.
    pub last: Option<EvalResult>,
}

impl EvalCallback {
    /// Evaluates the task named `task` on envs from `make_env` every `every` updates (0:
    /// never), `episodes` episodes each, seeded with `seed`.
    pub fn new(
        task: &str,
        make_env: impl FnMut(u64) -> anyhow::Result<Box<dyn VecEnv>> + Send + 'static,
        every: usize,
        episodes: usize,
        seed: u64,
    ) -> Self {
        Self {
            task: task.to_string(),
            make_env: Box::new(make_env),
            every,
            episodes,
            seed,
            log: None,
            events: None,
            stop_when: None,
            last: None,
        }
    }

    /// Appends every evaluation to `run`'s `evaluations.csv`.
    pub fn log_to(mut self, run: RunDir) -> Self {
        self.log = Some(run);
        self
    }

    /// Writes every evaluation's `eval/` scalars into this TensorBoard event file.
    pub fn events_to(mut self, events: EventWriter) -> Self {
        self.events = Some(events);
        self
    }

    /// Stops training once an evaluation of at least `criterion.window` episodes meets it. An
    /// evaluation then ends early once its episodes rule the criterion out
    /// ([`evaluate_against`]): the stopping rule's cost falls, its decisions stay the same.
    pub fn stop_when_solved(mut self, criterion: SolvedCriterion) -> Self {
        self.stop_when = Some(criterion);
        self
    }
}

/// The seed of the `index`-th periodic evaluation of a run seeded `seed`: distinct for every
/// evaluation, a pure function of the two (SplitMix64's mixer over the pair).
pub fn evaluation_seed(seed: u64, index: u64) -> u64 {
    let mut z = seed ^ index.wrapping_add(1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Callback for EvalCallback {
    fn on_update(&mut self, stats: &UpdateStats, model: &dyn Agent) -> anyhow::Result<Flow> {
        if self.every == 0 || !stats.update.is_multiple_of(self.every) {
            return Ok(Flow::Continue);
        }
        let seed = evaluation_seed(self.seed, (stats.update / self.every) as u64);
        let mut env = (self.make_env)(seed)?;
        let result = match &self.stop_when {
            Some(criterion) => evaluate_against(&self.task, model, env.as_mut(), self.episodes, seed, criterion)?,
            None => evaluate_policy(&self.task, model, env.as_mut(), self.episodes, seed)?,
        };
        if let Some(run) = &self.log {
            run.append_evaluation(stats.timesteps, &result)?;
        }
        if let Some(events) = &self.events {
            events.scalars(stats.timesteps, &super::tensorboard::evaluation_scalars(&result))?;
        }
        let solved = self.stop_when.is_some_and(|c| result.meets(&c));
        self.last = Some(result);
        Ok(if solved { Flow::Solved(SolvedBy::Evaluation) } else { Flow::Continue })
    }
}

#[cfg(test)]
mod tests {
    use super::evaluation_seed;

    #[test]
    fn every_evaluation_draws_new_targets_the_same_for_the_same_run_seed() {
        let seeds: Vec<u64> = (1..=50).map(|i| evaluation_seed(7, i)).collect();
        let distinct: std::collections::HashSet<_> = seeds.iter().collect();
        assert_eq!(distinct.len(), seeds.len(), "two evaluations of one run share a seed");
        assert_eq!(seeds, (1..=50).map(|i| evaluation_seed(7, i)).collect::<Vec<_>>(), "not deterministic");
        assert!((1..=50).all(|i| evaluation_seed(8, i) != evaluation_seed(7, i)), "another run seed draws the same");
    }
}
