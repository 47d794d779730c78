//! The RobotServer: accepts robots over TCP, serves each from its own thread, and trains one PPO
//! model on the experience they all send.
//!
//! Each connection keeps its transitions since the last update in a one-env rollout buffer,
//! filled with the pieces `Ppo::learn` collects with (`observe`, `policy_step`,
//! `bootstrapped_reward`, `RolloutBuffer::push`), one robot message at a time. Once all
//! connections together hold `rollout` transitions, the thread that completed the rollout runs
//! the PPO update while it holds the learner (the others wait, so every action is taken by a
//! known policy), then the callbacks, as `learn` does. A robot that disconnects mid-episode
//! loses the part of that episode not yet used in an update: it is never mixed into training.

use std::collections::HashMap;
use std::io::{BufReader, BufWriter};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Instant;

use twinbots_rl::ppo::{PolicyStep, RolloutBuffer};
use twinbots_rl::{Callback, EpisodeSummary, Ppo, TrainingEnd};

use crate::protocol::{FrameError, RobotMessage, ServerMessage, VERSION, read_message, write_message};

/// What the server trains.
pub struct ServerSettings {
    /// The robot kind it accepts (`hello.robot` must match).
    pub robot: String,
    /// Transitions per PPO update, summed over robots.
    pub rollout: usize,
    /// Stop after this many transitions (the model's `timesteps`, earlier sessions included).
    pub timesteps: u64,
}

/// One robot's experience since the last update.
struct Trajectory {
    buffer: RolloutBuffer,
    /// What the policy did on the observation awaiting its outcome.
    pending: Option<PolicyStep>,
    /// Index in `buffer` where the running episode began.
    episode_begin: usize,
    score: f32,
    length: u32,
}

struct Learner {
    ppo: Ppo,
    settings: ServerSettings,
    trajectories: HashMap<u64, Trajectory>,
    callbacks: Box<dyn Callback + Send>,
    /// When collecting the next update's rollout began.
    collecting_since: Instant,
    end: Option<TrainingEnd>,
    error: Option<String>,
}

/// A running server. `wait` blocks until training is over and returns the model.
pub struct RobotServer {
    pub addr: SocketAddr,
    learner: Arc<(Mutex<Learner>, Condvar)>,
}

impl RobotServer {
    /// Binds `listen` (port 0 picks a free port) and starts accepting robots. `callbacks` hear
    /// the training as `Ppo::learn`'s do (a `twinbots_rl::CallbackList` composes several).
    pub fn start(listen: SocketAddr, ppo: Ppo, settings: ServerSettings, mut callbacks: Box<dyn Callback + Send>) -> anyhow::Result<Self> {
        let listener = TcpListener::bind(listen).map_err(|e| anyhow::anyhow!("cannot listen on {listen}: {e}"))?;
        let addr = listener.local_addr()?;
        callbacks.on_training_start(&ppo)?;
        let learner = Learner {
            ppo,
            settings,
            trajectories: HashMap::new(),
            callbacks,
            collecting_since: Instant::now(),
            end: None,
            error: None,
        };
        let learner = Arc::new((Mutex::new(learner), Condvar::new()));
        let shared = learner.clone();
        std::thread::spawn(move || {
            let ids = AtomicU64::new(1);
            for stream in listener.incoming().flatten() {
                let shared = shared.clone();
                let id = ids.fetch_add(1, Ordering::Relaxed);
                std::thread::spawn(move || serve_robot(stream, id, shared));
            }
        });
        Ok(Self { addr, learner })
    }

    /// Robots connected now, and transitions they hold for the next update.
    pub fn load(&self) -> (usize, usize) {
        let learner = self.learner.0.lock().expect("learner lock");
        let held = learner.trajectories.values().map(|t| t.buffer.len()).sum();
        (learner.trajectories.len(), held)
    }

    /// Blocks until training ends (budget spent, solved, stopped by a callback, or a learner
    /// error), tells the callbacks, and returns a snapshot of the model and why it ended.
    /// Robots still connected get `done` on their next message.
    pub fn wait(self) -> anyhow::Result<(Ppo, TrainingEnd)> {
        let (lock, done) = &*self.learner;
        let mut learner = lock.lock().map_err(|_| anyhow::anyhow!("learner lock poisoned"))?;
        loop {
            if let Some(e) = learner.error.take() {
                anyhow::bail!("training failed: {e}");
            }
            if let Some(end) = learner.end.clone() {
                let learner = &mut *learner;
                learner.callbacks.on_training_end(&learner.ppo)?;
                return Ok((learner.ppo.snapshot()?, end));
            }
            learner = done.wait(learner).map_err(|_| anyhow::anyhow!("learner lock poisoned"))?;
        }
    }
}

fn reply(w: &mut BufWriter<TcpStream>, message: &ServerMessage) -> bool {
    write_message(w, message).is_ok()
}

fn error(message: impl Into<String>, fatal: bool) -> ServerMessage {
    ServerMessage::Error { message: message.into(), fatal }
}

/// One robot's connection, from `hello` to disconnect.
fn serve_robot(stream: TcpStream, id: u64, shared: Arc<(Mutex<Learner>, Condvar)>) {
    let _ = stream.set_nodelay(true);
    let Ok(read_half) = stream.try_clone() else { return };
    let mut reader = BufReader::new(read_half);
    let mut writer = BufWriter::new(stream);
    let (lock, done) = &*shared;

    // Handshake: version, robot kind and spaces must match.
    let obs_dim = match read_message::<RobotMessage>(&mut reader) {
        Ok(RobotMessage::Hello { version, robot, observation_space, action_space }) => {
            let Ok(mut learner) = lock.lock() else { return };
            let problem = if version != VERSION {
                Some(format!("protocol version {version} is not supported (server speaks {VERSION})"))
            } else if robot != learner.settings.robot {
                Some(format!("this server trains '{}', not '{robot}'", learner.settings.robot))
            } else {
                learner.ppo.check_spaces(&observation_space, &action_space).err().map(|e| e.to_string())
            };
            if let Some(problem) = problem {
                reply(&mut writer, &error(problem, true));
                return;
            }
            learner.trajectories.insert(id, Trajectory {
                buffer: RolloutBuffer::new(1, observation_space.dim(), action_space.dim()),
                pending: None,
                episode_begin: 0,
                score: 0.0,
                length: 0,
            });
            drop(learner);
            if !reply(&mut writer, &ServerMessage::Welcome { version: VERSION, robot_id: id }) {
                return;
            }
            observation_space.dim()
        }
        Ok(_) => {
            reply(&mut writer, &error("the first message must be 'hello'", true));
            return;
        }
        Err(e) => {
            if e.recoverable() {
                reply(&mut writer, &error(e.to_string(), true));
            }
            return;
        }
    };

    loop {
        let message = match read_message::<RobotMessage>(&mut reader) {
            Ok(m) => m,
            Err(e) if e.recoverable() => {
                if reply(&mut writer, &error(e.to_string(), false)) {
                    continue;
                }
                break;
            }
            Err(FrameError::Io(_)) | Err(_) => break,
        };
        let answer = {
            let Ok(mut learner) = lock.lock() else { break };
            let answer = learner.handle(id, message, obs_dim);
            if learner.end.is_some() || learner.error.is_some() {
                done.notify_all();
            }
            answer
        };
        match answer {
            Some(message) => {
                let stop = matches!(message, ServerMessage::Done { .. });
                if !reply(&mut writer, &message) || stop {
                    break;
                }
            }
            None => break, // bye
        }
    }
    // Whatever the running episode had not yet given to an update is dropped.
    if let Ok(mut learner) = lock.lock() {
        learner.trajectories.remove(&id);
    }
}

impl Learner {
    /// The answer to one message; `None` ends the connection.
    fn handle(&mut self, id: u64, message: RobotMessage, obs_dim: usize) -> Option<ServerMessage> {
        if let Some(end) = &self.end {
            return Some(ServerMessage::Done { reason: end.to_string() });
        }
        let check = |obs: &[f32]| {
            (obs.len() != obs_dim).then(|| error(format!("observation has {} values, expected {obs_dim}", obs.len()), false))
        };
        match message {
            RobotMessage::Hello { .. } => Some(error("already introduced", false)),
            RobotMessage::Bye => {
                self.drop_running_episode(id);
                None
            }
            RobotMessage::Start { obs } => {
                if let Some(e) = check(&obs) {
                    return Some(e);
                }
                self.drop_running_episode(id);
                Some(self.act(id, &obs))
            }
            RobotMessage::Step { obs, reward, terminated, truncated, success } => {
                if let Some(e) = check(&obs) {
                    return Some(e);
                }
                Some(self.record_step(id, obs, reward, terminated, truncated, success))
            }
        }
    }

    /// Records the outcome of the robot's pending action, as `Ppo::collect_rollout` records a
    /// step, and answers with the next action (or `ack` once the episode is over).
    fn record_step(&mut self, id: u64, obs: Vec<f32>, reward: f32, terminated: bool, truncated: bool, success: Option<bool>) -> ServerMessage {
        // `obs` is the episode's last observation if it ended.
        let stored_reward = match self.ppo.bootstrapped_reward(reward, terminated, truncated, Some(&obs)) {
            Ok(r) => r,
            Err(e) => return self.fail(e),
        };
        let Some(traj) = self.trajectories.get_mut(&id) else {
            return error("this robot is not known", true);
        };
        let Some(step) = traj.pending.take() else {
            return error("'step' before 'start': no action is waiting for its outcome", false);
        };
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

    /// A learner failure ends training: `wait` reports it.
    fn fail(&mut self, e: anyhow::Error) -> ServerMessage {
        self.error = Some(e.to_string());
        error(format!("learner failed: {e}"), true)
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
        if held < self.settings.rollout {
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
        self.ppo.update_learning_rate(self.settings.timesteps);
        // Counted once learned from: a robot's unfinished episode may still be dropped.
        self.ppo.timesteps += batch.len() as u64;
        let stats = self.ppo.train(&batch, self.collecting_since)?;
        self.collecting_since = Instant::now();
        let flow = self.callbacks.on_update(&stats, &self.ppo)?;
        let timesteps = self.ppo.timesteps;
        self.end = TrainingEnd::after(flow, timesteps)
            .or_else(|| (timesteps >= self.settings.timesteps).then_some(TrainingEnd::BudgetSpent { timesteps }));
        Ok(())
    }
}
