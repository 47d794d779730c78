//! The RobotServer: accepts robots over TCP, serves each from its own thread, and trains one PPO
//! model on the experience they all send.
//!
//! Each connection keeps its transitions since the last update. Once all connections together
//! hold `rollout` transitions, the thread that completed the rollout runs the PPO update while
//! it holds the learner (the others wait, so every action is taken by a known policy). A robot
//! that disconnects mid-episode loses the part of that episode not yet used in an update: it is
//! never mixed into training.

use std::collections::HashMap;
use std::io::{BufReader, BufWriter};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};

use twinbots_rl::ppo::RolloutBuffer;
use twinbots_rl::{EpisodeSummary, Flow, Ppo, SolvedCriterion, UpdateStats};

use crate::protocol::{FrameError, RobotMessage, ServerMessage, VERSION, read_message, write_message};

/// Called after every update; `Flow::Stop` ends training.
pub type UpdateCallback = Box<dyn FnMut(&UpdateStats, &Ppo) -> anyhow::Result<Flow> + Send>;

/// What the server trains.
pub struct ServerSettings {
    /// The robot kind it accepts (`hello.robot` must match).
    pub robot: String,
    /// Transitions per PPO update, summed over robots.
    pub rollout: usize,
    /// Stop after this many transitions.
    pub timesteps: u64,
    pub solved: Option<SolvedCriterion>,
}

/// One robot's experience since the last update.
struct Trajectory {
    buffer: RolloutBuffer,
    /// The observation awaiting its outcome: (obs, sampled action, log-prob, value).
    pending: Option<(Vec<f32>, Vec<f32>, f32, f32)>,
    /// Index in `buffer` where the running episode began.
    episode_begin: usize,
    score: f32,
    length: u32,
}

struct Learner {
    ppo: Ppo,
    settings: ServerSettings,
    trajectories: HashMap<u64, Trajectory>,
    callback: UpdateCallback,
    finished: Option<String>,
    error: Option<String>,
}

/// A running server. `wait` blocks until training is over and returns the model.
pub struct RobotServer {
    pub addr: SocketAddr,
    learner: Arc<(Mutex<Learner>, Condvar)>,
}

impl RobotServer {
    /// Binds `listen` (port 0 picks a free port) and starts accepting robots.
    pub fn start(listen: SocketAddr, ppo: Ppo, settings: ServerSettings, callback: UpdateCallback) -> anyhow::Result<Self> {
        let listener = TcpListener::bind(listen).map_err(|e| anyhow::anyhow!("cannot listen on {listen}: {e}"))?;
        let addr = listener.local_addr()?;
        let learner = Arc::new((
            Mutex::new(Learner { ppo, settings, trajectories: HashMap::new(), callback, finished: None, error: None }),
            Condvar::new(),
        ));
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

    /// Blocks until training ends (budget spent, solved, or a learner error); returns the model
    /// and why it ended.
    pub fn wait(self) -> anyhow::Result<(Ppo, String)> {
        let (lock, done) = &*self.learner;
        let mut learner = lock.lock().map_err(|_| anyhow::anyhow!("learner lock poisoned"))?;
        while learner.finished.is_none() && learner.error.is_none() {
            learner = done.wait(learner).map_err(|_| anyhow::anyhow!("learner lock poisoned"))?;
        }
        if let Some(e) = learner.error.take() {
            anyhow::bail!("training failed: {e}");
        }
        let reason = learner.finished.clone().unwrap_or_default();
        // Robots still connected get `done` on their next message; the model is cloned out
        // through a save/load round trip (candle variables are shared handles).
        let dir = std::env::temp_dir().join(format!("twinbots-server-model-{}", std::process::id()));
        learner.ppo.save(&dir)?;
        let model = Ppo::load(&dir)?;
        let _ = std::fs::remove_dir_all(&dir);
        Ok((model, reason))
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
    let (obs_dim, act_dim) = match read_message::<RobotMessage>(&mut reader) {
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
            let dims = (observation_space.dim(), action_space.dim());
            learner.trajectories.insert(id, Trajectory {
                buffer: RolloutBuffer::new(1, dims.0, dims.1),
                pending: None,
                episode_begin: 0,
                score: 0.0,
                length: 0,
            });
            drop(learner);
            if !reply(&mut writer, &ServerMessage::Welcome { version: VERSION, robot_id: id }) {
                return;
            }
            dims
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
            let answer = learner.handle(id, message, obs_dim, act_dim);
            if learner.finished.is_some() || learner.error.is_some() {
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
    fn handle(&mut self, id: u64, message: RobotMessage, obs_dim: usize, act_dim: usize) -> Option<ServerMessage> {
        if let Some(reason) = &self.finished {
            return Some(ServerMessage::Done { reason: reason.clone() });
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
                Some(self.act(id, obs))
            }
            RobotMessage::Step { obs, reward, terminated, truncated, success } => {
                if let Some(e) = check(&obs) {
                    return Some(e);
                }
                let gamma = self.ppo.config.gamma;
                // A truncated episode's last reward is bootstrapped with γ V(final observation).
                let bootstrap = if truncated && !terminated { self.ppo.value_of(&obs).unwrap_or(0.0) * gamma } else { 0.0 };
                let traj = self.trajectories.get_mut(&id)?;
                let Some((prev_obs, action, log_prob, value)) = traj.pending.take() else {
                    return Some(error("'step' before 'start': no action is waiting for its outcome", false));
                };
                let b = &mut traj.buffer;
                b.obs.extend(prev_obs);
                b.actions.extend(action.iter().copied().take(act_dim));
                b.log_probs.push(log_prob);
                b.values.push(value);
                b.rewards.push(reward + bootstrap);
                b.dones.push(terminated || truncated);
                traj.score += reward;
                traj.length += 1;
                let ended = terminated || truncated;
                if ended {
                    let summary = EpisodeSummary { score: traj.score, length: traj.length, success, ..Default::default() };
                    traj.episode_begin = traj.buffer.len();
                    traj.score = 0.0;
                    traj.length = 0;
                    self.ppo.record_episode(&summary);
                }
                let answer = if ended { ServerMessage::Ack } else { self.act(id, obs) };
                if let Err(e) = self.maybe_update() {
                    self.error = Some(e.to_string());
                    return Some(error(format!("learner failed: {e}"), true));
                }
                Some(answer)
            }
        }
    }

    fn act(&mut self, id: u64, obs: Vec<f32>) -> ServerMessage {
        match self.ppo.act_one(&obs) {
            Ok((sampled, clipped, log_prob, value)) => {
                if let Some(traj) = self.trajectories.get_mut(&id) {
                    traj.pending = Some((obs, sampled, log_prob, value));
                }
                ServerMessage::Action { action: clipped }
            }
            Err(e) => error(format!("policy failed: {e}"), true),
        }
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

    /// Runs a PPO update once the robots together hold a rollout.
    fn maybe_update(&mut self) -> anyhow::Result<()> {
        let held: usize = self.trajectories.values().map(|t| t.buffer.len()).sum();
        if held < self.settings.rollout {
            return Ok(());
        }
        let (gamma, lambda) = (self.ppo.config.gamma, self.ppo.config.gae_lambda);
        let mut batch: Option<RolloutBuffer> = None;
        let mut values = HashMap::new();
        for (&id, traj) in &self.trajectories {
            // Bootstrap from the observation awaiting its outcome (if the episode goes on).
            let last = match &traj.pending {
                Some((obs, ..)) => self.ppo.value_of(obs)?,
                None => 0.0,
            };
            values.insert(id, last);
        }
        for (id, traj) in self.trajectories.iter_mut() {
            if traj.buffer.is_empty() {
                continue;
            }
            traj.buffer.compute_advantages(&[values[id]], gamma, lambda);
            match &mut batch {
                Some(b) => b.append(&traj.buffer),
                None => batch = Some(std::mem::replace(&mut traj.buffer, RolloutBuffer::new(1, 0, 0))),
            }
            let (o, a) = (batch.as_ref().map_or(0, |b| b.obs_dim), batch.as_ref().map_or(0, |b| b.act_dim));
            traj.buffer = RolloutBuffer::new(1, o, a);
            traj.episode_begin = 0;
        }
        let Some(batch) = batch else { return Ok(()) };
        let fraction = self.ppo.timesteps as f64 / self.settings.timesteps.max(1) as f64;
        let stats = self.ppo.train_on(&batch, fraction)?;
        if (self.callback)(&stats, &self.ppo)? == Flow::Stop {
            self.finished = Some("stopped by the callback".into());
        } else if self.settings.solved.is_some_and(|c| self.ppo.is_solved(&c)) {
            self.finished = Some(format!("solved after {} steps", self.ppo.timesteps));
        } else if self.ppo.timesteps >= self.settings.timesteps {
            self.finished = Some(format!("budget of {} steps spent", self.settings.timesteps));
        }
        Ok(())
    }
}
