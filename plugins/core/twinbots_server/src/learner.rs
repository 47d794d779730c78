//! The learner behind the RobotServer: one PPO model trained on what every robot sends.
//!
//! Each connection keeps its transitions since the last update in a one-env rollout buffer,
//! filled with the pieces `Ppo::learn` collects with (`observe`, `policy_step`,
//! `bootstrapped_reward`, `RolloutBuffer::push`), one robot message at a time. Once all
//! connections together hold `rollout` transitions, the thread that completed the rollout runs
//! the PPO update while it holds the learner (the others wait, so every action is taken by a
//! known policy), then the callbacks, as `learn` does. A robot that disconnects or aborts
//! mid-episode loses the part of that episode not yet used in an update: it is never mixed
//! into training. Messages reach it only after `checks` passed them.

use std::collections::HashMap;
use std::time::Instant;

use twinbots_learn::ppo::{PolicyStep, RolloutBuffer};
use twinbots_api::EpisodeSummary;
use twinbots_learn::{Callback, Ppo, TrainingEnd};

use twinbots_link::protocol::{ErrorCode, RobotMessage, ServerMessage, error};

/// One robot's experience since the last update.
struct Trajectory {
    buffer: RolloutBuffer,
    /// What the policy did on the observation awaiting its outcome.
    pending: Option<PolicyStep>,
    /// Index in `buffer` where the running episode began.
    episode_begin: usize,
    score: f32,
    length: u32,
    /// The robot left; its finished episodes wait for the next update, then it is forgotten.
    gone: bool,
}

pub(crate) struct Learner {
    pub ppo: Ppo,
    /// Transitions per update, summed over robots.
    rollout: usize,
    /// Stop after this many transitions.
    timesteps: u64,
    trajectories: HashMap<u64, Trajectory>,
    pub callbacks: Box<dyn Callback + Send>,
    /// When collecting the next update's rollout began.
    collecting_since: Instant,
    pub end: Option<TrainingEnd>,
    /// Why the server must stop (a learner error, a panic anywhere in the server).
    pub error: Option<String>,
}

impl Learner {
    pub fn new(ppo: Ppo, rollout: usize, timesteps: u64, callbacks: Box<dyn Callback + Send>) -> Self {
        Self {
            ppo,
            rollout,
            timesteps,
            trajectories: HashMap::new(),
            callbacks,
            collecting_since: Instant::now(),
            end: None,
            error: None,
        }
    }

    /// Robots connected, and transitions held for the next update (left robots' included).
    pub fn load(&self) -> (usize, usize) {
        let connected = self.trajectories.values().filter(|t| !t.gone).count();
        (connected, self.trajectories.values().map(|t| t.buffer.len()).sum())
    }

    pub fn join(&mut self, id: u64) {
        let (obs, act) = (self.ppo.observation_space.dim(), self.ppo.action_space.dim());
        let trajectory =
            Trajectory { buffer: RolloutBuffer::new(1, obs, act), pending: None, episode_begin: 0, score: 0.0, length: 0, gone: false };
        self.trajectories.insert(id, trajectory);
    }

    /// Whatever the robot's running episode had not yet given to an update is dropped; its
    /// finished episodes still go into the next update (a robot that ends its shift between
    /// updates loses nothing it completed).
    pub fn leave(&mut self, id: u64) {
        self.drop_running_episode(id);
        match self.trajectories.get_mut(&id) {
            Some(t) if !t.buffer.is_empty() => t.gone = true,
            _ => {
                self.trajectories.remove(&id);
            }
        }
    }

    /// Whether the server must stop serving (training over or failed).
    pub fn stopped(&self) -> bool {
        self.end.is_some() || self.error.is_some()
    }

    /// The answer to one checked message; `None` ends the connection.
    pub fn handle(&mut self, id: u64, message: RobotMessage) -> Option<ServerMessage> {
        if let Some(end) = &self.end {
            return Some(ServerMessage::Done { reason: end.to_string() });
        }
        if let Some(e) = &self.error {
            return Some(error(ErrorCode::LearnerFailed, true, format!("learner failed: {e}")));
        }
        match message {
            RobotMessage::Hello { .. } => Some(error(ErrorCode::HandshakeExpected, false, "already introduced")),
            RobotMessage::Bye => {
                self.drop_running_episode(id);
                None
            }
            RobotMessage::Abort => {
                self.drop_running_episode(id);
                Some(ServerMessage::Ack)
            }
            RobotMessage::Start { obs } => {
                self.drop_running_episode(id);
                Some(self.act(id, &obs))
            }
            RobotMessage::Step { obs, reward, terminated, truncated, success } => {
                Some(self.record_step(id, obs, reward, terminated, truncated, success))
            }
        }
    }

    /// Records the outcome of the robot's pending action, as `Ppo::collect_rollout` records a
    /// step, and answers with the next action (or `ack` once the episode is over).
    fn record_step(&mut self, id: u64, obs: Vec<f32>, reward: f32, terminated: bool, truncated: bool, success: Option<bool>) -> ServerMessage {
        let Some(traj) = self.trajectories.get(&id) else {
            return error(ErrorCode::HandshakeExpected, true, "this robot is not known");
        };
        if traj.pending.is_none() {
            return error(ErrorCode::OutOfOrder, false, "'step' before 'start': no action is waiting for its outcome");
        }
        // `obs` is the episode's last observation if it ended.
        let stored_reward = match self.ppo.bootstrapped_reward(reward, terminated, truncated, Some(&obs)) {
            Ok(r) => r,
            Err(e) => return self.fail(e),
        };
        let traj = self.trajectories.get_mut(&id).expect("checked above");
        let step = traj.pending.take().expect("checked above");
        let ended = terminated || truncated;
        traj.buffer.push(&step, &[stored_reward], &[ended]);
        traj.score += reward;
        traj.length += 1;
        if ended {
            let summary = EpisodeSummary { score: traj.score, length: traj.length, success, ..Default::default() };
            traj.episode_begin = traj.buffer.len();
            traj.score = 0.0;
            traj.length = 0;
            self.ppo.record_episode(&summary);
        }
        let answer = if ended { ServerMessage::Ack } else { self.act(id, &obs) };
        if let Err(e) = self.maybe_update() {
            return self.fail(e);
        }
        answer
    }

    /// The policy's action on a fresh observation, which waits for its outcome.
    fn act(&mut self, id: u64, raw_obs: &[f32]) -> ServerMessage {
        let obs = self.ppo.observe(raw_obs);
        match self.ppo.policy_step(obs) {
            Ok(step) => {
                let action = step.env_actions.clone();
                if let Some(traj) = self.trajectories.get_mut(&id) {
                    traj.pending = Some(step);
                }
                ServerMessage::Action { action }
            }
            Err(e) => self.fail(e),
        }
    }

    /// A learner failure ends training: `RobotServer::wait` reports it.
    fn fail(&mut self, e: anyhow::Error) -> ServerMessage {
        self.error = Some(format!("{e:#}"));
        error(ErrorCode::LearnerFailed, true, format!("learner failed: {e:#}"))
    }

    fn drop_running_episode(&mut self, id: u64) {
        if let Some(traj) = self.trajectories.get_mut(&id) {
            let keep = traj.episode_begin;
            traj.buffer.truncate(keep);
            traj.pending = None;
            traj.score = 0.0;
            traj.length = 0;
        }
    }

    /// Once the robots together hold a rollout: advantages per robot, one PPO update on all of
    /// it, then the callbacks, which may end training, as may the budget.
    fn maybe_update(&mut self) -> anyhow::Result<()> {
        let held: usize = self.trajectories.values().map(|t| t.buffer.len()).sum();
        if held < self.rollout {
            return Ok(());
        }
        let (gamma, lambda) = (self.ppo.config.gamma, self.ppo.config.gae_lambda);
        let mut batch = RolloutBuffer::new(1, self.ppo.observation_space.dim(), self.ppo.action_space.dim());
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
        self.ppo.update_learning_rate(self.timesteps);
        // Counted once learned from: a robot's unfinished episode may still be dropped.
        self.ppo.timesteps += batch.len() as u64;
        let stats = self.ppo.train(&batch, self.collecting_since)?;
        self.collecting_since = Instant::now();
        let flow = self.callbacks.on_update(&stats, &self.ppo)?;
        let timesteps = self.ppo.timesteps;
        self.end = TrainingEnd::after(flow, timesteps)
            .or_else(|| (timesteps >= self.timesteps).then_some(TrainingEnd::BudgetSpent { timesteps }));
        Ok(())
    }
}
