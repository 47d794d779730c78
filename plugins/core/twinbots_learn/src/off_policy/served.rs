//! SAC and TD3 learning from robots (the RobotServer). Each robot's running episode is kept
//! apart as (s, a, r, s', done) transitions and goes into the replay buffer whole when it ends,
//! so that its steps lie one after another there, as hindsight experience replay needs (the
//! buffer has one lane). Training keeps `learn`'s pace with `robots` envs: an iteration is
//! `robots` transitions stored, gradient steps every `train_freq` iterations from
//! `learning_starts` on, a row every `log_interval` iterations; an episode that completes
//! several at once takes all their gradient steps then (one row for them).

use std::collections::HashMap;

use twinbots_api::EpisodeSummary;

use super::{OffPolicy, Row};
use crate::agent::Agent;
use crate::learner::{Learner, RobotStep, ServedLearner};
use crate::normalize::RobotStatistics;
use crate::stats::UpdateStats;

/// One step of a robot's running episode.
struct Transition {
    obs: Vec<f32>,
    /// As the actor gave it, in [−1, 1].
    action: Vec<f32>,
    reward: f32,
    next_obs: Vec<f32>,
    terminated: bool,
    ended_by: Option<String>,
}

#[derive(Default)]
struct RunningEpisode {
    /// The observation and (unit) action awaiting their outcome.
    pending: Option<(Vec<f32>, Vec<f32>)>,
    steps: Vec<Transition>,
    score: f32,
}

pub(crate) struct ServedOffPolicy<M: OffPolicy> {
    model: M,
    /// Transitions per iteration.
    robots: u64,
    episodes: HashMap<u64, RunningEpisode>,
    /// Transitions stored since learning was last looked at.
    unseen: u64,
    row: Row,
    /// Each robot's observation statistics, when the model normalises: the model's are the
    /// robots' consensus ([`RobotStatistics`]).
    statistics: Option<RobotStatistics>,
}

impl<M: OffPolicy> ServedOffPolicy<M> {
    pub fn new(mut model: M, robots: usize) -> anyhow::Result<Self> {
        let lanes = super::replay_buffer(&mut model, 1);
        anyhow::ensure!(
            lanes == 1,
            "this model's replay buffer was filled by {lanes} envs stepped together; a RobotServer continues only a model it trained (or a new one)"
        );
        let statistics = model.parts().obs_rms.as_ref().map(RobotStatistics::new);
        Ok(Self {
            model,
            robots: robots.max(1) as u64,
            episodes: HashMap::new(),
            unseen: 0,
            row: Row::default(),
            statistics,
        })
    }

    /// Stores a finished episode's transitions, in order, and counts them.
    fn store(&mut self, steps: Vec<Transition>) {
        let last = steps.len().saturating_sub(1);
        let parts = self.model.parts();
        let buffer = parts.buffer.as_mut().expect("made in new");
        for (i, t) in steps.into_iter().enumerate() {
            buffer.push(&t.obs, &t.action, &[t.reward], &t.next_obs, &[t.terminated], &[i == last], &[t.ended_by]);
            *parts.timesteps += 1;
        }
        self.unseen += last as u64 + 1;
    }
}

impl<M: OffPolicy + Send> ServedLearner for ServedOffPolicy<M> {
    fn agent(&self) -> &dyn Agent {
        &self.model
    }

    fn join(&mut self, robot: u64) {
        self.episodes.insert(robot, RunningEpisode::default());
    }

    fn drop_episode(&mut self, robot: u64) {
        if let Some(episode) = self.episodes.get_mut(&robot) {
            *episode = RunningEpisode::default();
        }
    }

    fn leave(&mut self, robot: u64) {
        self.episodes.remove(&robot);
        if let Some(statistics) = &mut self.statistics {
            statistics.leave(robot);
        }
    }

    fn awaits_outcome(&self, robot: u64) -> Option<bool> {
        self.episodes.get(&robot).map(|e| e.pending.is_some())
    }

    /// The observation counts into the normalisation statistics first, as `learn` counts each
    /// observation it acts on: into its robot's, and the model's are the robots' consensus.
    fn act(&mut self, robot: u64, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        if let (Some(statistics), Some(rms)) = (&mut self.statistics, self.model.parts().obs_rms.as_mut()) {
            statistics.observe(robot, obs);
            *rms = statistics.consensus();
        }
        let unit = self.model.explore(obs)?;
        let action = super::to_env(self.model.action_space(), &unit);
        if let Some(episode) = self.episodes.get_mut(&robot) {
            episode.pending = Some((obs.to_vec(), unit));
        }
        Ok(action)
    }

    fn record(&mut self, robot: u64, step: &RobotStep) -> anyhow::Result<()> {
        let episode = self.episodes.get_mut(&robot).ok_or_else(|| anyhow::anyhow!("robot {robot} is not known"))?;
        let (obs, action) = episode
            .pending
            .take()
            .ok_or_else(|| anyhow::anyhow!("robot {robot} has no action awaiting its outcome"))?;
        episode.score += step.reward;
        episode.steps.push(Transition {
            obs,
            action,
            reward: step.reward,
            next_obs: step.obs.to_vec(),
            terminated: step.terminated,
            ended_by: step.ended_by.map(str::to_string),
        });
        if step.ended() {
            let finished = std::mem::take(episode);
            let summary = EpisodeSummary {
                score: finished.score,
                length: finished.steps.len() as u32,
                success: step.success,
                ..Default::default()
            };
            self.store(finished.steps);
            let parts = self.model.parts();
            *parts.episodes += 1;
            parts.history.record(&summary);
        }
        Ok(())
    }

    fn learn_if_due(&mut self) -> anyhow::Result<Option<UpdateStats>> {
        let schedule = self.model.schedule();
        let stored = std::mem::take(&mut self.unseen);
        if stored == 0 {
            return Ok(None);
        }
        self.row.transitions += stored;
        let now = *self.model.parts().timesteps;
        let before = now - stored;
        // Iterations and their multiples crossed since the last call; `learn` trains on the
        // iterations that end at `learning_starts` steps or later.
        let iterations = |t: u64| t / self.robots;
        let first_training = schedule.learning_starts.div_ceil(self.robots).max(1);
        let from = iterations(before).max(first_training - 1);
        let trains =
            if iterations(now) > from { crossed(from, iterations(now), schedule.train_freq as u64) } else { 0 };
        self.row.train(&mut self.model, trains as usize * schedule.gradient_steps)?;
        if crossed(iterations(before), iterations(now), schedule.log_interval as u64) == 0 {
            return Ok(None);
        }
        Ok(Some(std::mem::take(&mut self.row).finish(&mut self.model)?))
    }

    fn load(&self) -> (usize, usize) {
        (self.episodes.len(), self.episodes.values().map(|e| e.steps.len()).sum())
    }

    fn into_learner(self: Box<Self>) -> Box<dyn Learner> {
        Box::new(self.model)
    }
}

/// Rows of `n` per `every` crossed by a count going from `before` to `after` (a batch of
/// transitions may cross several at once).
fn crossed(before: u64, after: u64, every: u64) -> u64 {
    let every = every.max(1);
    after / every - before / every
}
