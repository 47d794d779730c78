//! PPO learning from robots (the RobotServer): each robot's transitions since the last update
//! go into its own one-env rollout buffer, filled with the pieces `learn` collects with
//! (`observe`, `policy_step`, `bootstrapped_reward`, `RolloutBuffer::push`). Once the robots
//! together hold a rollout (`n_steps` × robots), advantages are computed per robot, bootstrapped
//! from the value of the observation each one awaits the outcome of, and one update runs on all
//! of it.

use std::collections::HashMap;
use std::time::Instant;

use twinbots_api::EpisodeSummary;

use super::{PolicyStep, Ppo, RolloutBuffer};
use crate::agent::Agent;
use crate::learner::{Learner, RobotStep, ServedLearner};
use crate::normalize::RobotStatistics;
use crate::stats::UpdateStats;

/// One robot's experience since the last update.
struct Trajectory {
    buffer: RolloutBuffer,
    /// What the policy did on the observation awaiting its outcome.
    pending: Option<PolicyStep>,
    /// Index in `buffer` where the running episode began.
    episode_begin: usize,
    score: f32,
    length: u32,
    /// The running episode's discounted return, for `normalize_rewards`.
    discounted_return: f64,
    /// The robot left; its finished episodes wait for the next update, then it is forgotten.
    gone: bool,
}

pub(crate) struct ServedPpo {
    ppo: Ppo,
    /// Transitions per update, summed over robots.
    rollout: usize,
    /// The learning rate's schedule runs to this many steps.
    budget: u64,
    trajectories: HashMap<u64, Trajectory>,
    /// When collecting the next update's rollout began.
    collecting_since: Instant,
    /// Each robot's observation statistics, when the model normalises: the model's are the
    /// robots' consensus ([`RobotStatistics`]).
    statistics: Option<RobotStatistics>,
}

impl ServedPpo {
    pub fn new(ppo: Ppo, robots: usize, budget: u64) -> Self {
        let rollout = ppo.config.n_steps.saturating_mul(robots.max(1));
        let statistics = ppo.state.obs_rms.as_ref().map(RobotStatistics::new);
        Self { ppo, rollout, budget, trajectories: HashMap::new(), collecting_since: Instant::now(), statistics }
    }
}

impl ServedLearner for ServedPpo {
    fn agent(&self) -> &dyn Agent {
        &self.ppo
    }

    fn join(&mut self, robot: u64) {
        let (obs, act) = (self.ppo.state.observation_space.dim(), self.ppo.state.action_space.dim());
        let trajectory = Trajectory {
            buffer: RolloutBuffer::new(1, obs, act),
            pending: None,
            episode_begin: 0,
            score: 0.0,
            length: 0,
            discounted_return: 0.0,
            gone: false,
        };
        self.trajectories.insert(robot, trajectory);
    }

    fn drop_episode(&mut self, robot: u64) {
        if let Some(traj) = self.trajectories.get_mut(&robot) {
            traj.buffer.truncate(traj.episode_begin);
            traj.pending = None;
            traj.score = 0.0;
            traj.length = 0;
            traj.discounted_return = 0.0;
        }
    }

    /// A robot that ends its shift between updates loses nothing it completed.
    fn leave(&mut self, robot: u64) {
        self.drop_episode(robot);
        if let Some(statistics) = &mut self.statistics {
            statistics.leave(robot);
        }
        match self.trajectories.get_mut(&robot) {
            Some(t) if !t.buffer.is_empty() => t.gone = true,
            _ => {
                self.trajectories.remove(&robot);
            }
        }
    }

    fn awaits_outcome(&self, robot: u64) -> Option<bool> {
        self.trajectories.get(&robot).map(|t| t.pending.is_some())
    }

    fn act(&mut self, robot: u64, raw_obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        let obs = match (&mut self.statistics, &mut self.ppo.state.obs_rms) {
            (Some(statistics), Some(rms)) => {
                statistics.observe(robot, raw_obs);
                *rms = statistics.consensus();
                rms.normalize(raw_obs)
            }
            _ => self.ppo.observe(raw_obs),
        };
        let step = self.ppo.policy_step(obs)?;
        let action = step.env_actions.clone();
        if let Some(traj) = self.trajectories.get_mut(&robot) {
            traj.pending = Some(step);
        }
        Ok(action)
    }

    /// As `Ppo::collect_rollout` records a step; `obs` is the episode's last if it ended.
    fn record(&mut self, robot: u64, step: &RobotStep) -> anyhow::Result<()> {
        let traj = self.trajectories.get_mut(&robot).ok_or_else(|| anyhow::anyhow!("robot {robot} is not known"))?;
        let reward = match &mut self.ppo.reward_scale {
            Some(scale) => {
                scale.scale_one(&mut traj.discounted_return, step.reward, step.ended(), self.ppo.config.gamma)
            }
            None => step.reward,
        };
        let stored_reward = self.ppo.bootstrapped_reward(reward, step.terminated, step.truncated, Some(step.obs))?;
        let pending =
            traj.pending.take().ok_or_else(|| anyhow::anyhow!("robot {robot} has no action awaiting its outcome"))?;
        traj.buffer.push(&pending, &[stored_reward], &[step.ended()]);
        traj.score += step.reward;
        traj.length += 1;
        if step.ended() {
            let summary =
                EpisodeSummary { score: traj.score, length: traj.length, success: step.success, ..Default::default() };
            traj.episode_begin = traj.buffer.len();
            traj.score = 0.0;
            traj.length = 0;
            self.ppo.record_episode(&summary);
        }
        Ok(())
    }

    /// Once the robots together hold a rollout: advantages per robot, one PPO update on all of
    /// it.
    fn learn_if_due(&mut self) -> anyhow::Result<Option<UpdateStats>> {
        let held: usize = self.trajectories.values().map(|t| t.buffer.len()).sum();
        if held < self.rollout {
            return Ok(None);
        }
        let (gamma, lambda) = (self.ppo.config.gamma, self.ppo.config.gae_lambda);
        let mut batch =
            RolloutBuffer::new(1, self.ppo.state.observation_space.dim(), self.ppo.state.action_space.dim());
        for traj in self.trajectories.values_mut().filter(|t| !t.buffer.is_empty()) {
            // GAE bootstrapped from V(the observation awaiting its outcome); a segment that
            // ends with its episode needs no bootstrap (its last step is done).
            let last_value = match &traj.pending {
                Some(step) => self.ppo.values(&step.obs)?[0],
                None => 0.0,
            };
            traj.buffer.compute_advantages(&[last_value], gamma, lambda);
            batch.append(&traj.buffer);
            traj.buffer.clear();
            traj.episode_begin = 0;
        }
        self.trajectories.retain(|_, t| !t.gone);
        self.ppo.update_learning_rate(self.budget);
        // Counted once learned from: a robot's unfinished episode may still be dropped.
        self.ppo.state.timesteps += batch.len() as u64;
        let stats = self.ppo.train(&batch, self.collecting_since)?;
        self.collecting_since = Instant::now();
        Ok(Some(stats))
    }

    fn load(&self) -> (usize, usize) {
        let connected = self.trajectories.values().filter(|t| !t.gone).count();
        (connected, self.trajectories.values().map(|t| t.buffer.len()).sum())
    }

    fn into_learner(self: Box<Self>) -> Box<dyn Learner> {
        Box::new(self.ppo)
    }
}
