//! The learner behind the RobotServer: one model, of any algorithm that can be served
//! (`twinbots_learn::ServedLearner`: PPO, SAC, TD3), trained on what every robot sends.
//!
//! This side speaks the protocol: it turns each checked message into the model's `act` and
//! `record`, lets the model learn once the message made that due (the thread that sent it holds
//! the learner meanwhile, so the others wait and every action is taken by a known policy),
//! then runs the callbacks and ends training on their word or the budget. Messages reach it
//! only after `checks` passed them.

use twinbots_learn::{Callback, Learner as Model, RobotStep, ServedLearner, TrainingEnd};

use twinbots_link::protocol::{ErrorCode, RobotMessage, ServerMessage, error};

pub(crate) struct Learner {
    /// The model; taken by `RobotServer::wait` once training is over.
    model: Option<Box<dyn ServedLearner>>,
    /// Stop after this many transitions.
    timesteps: u64,
    pub callbacks: Box<dyn Callback + Send>,
    pub end: Option<TrainingEnd>,
    /// Why the server must stop (a learner error, a panic anywhere in the server).
    pub error: Option<String>,
}

impl Learner {
    pub fn new(model: Box<dyn ServedLearner>, timesteps: u64, callbacks: Box<dyn Callback + Send>) -> Self {
        Self { model: Some(model), timesteps, callbacks, end: None, error: None }
    }

    /// Robots connected, and transitions held not yet learnt from.
    pub fn load(&self) -> (usize, usize) {
        self.model.as_ref().map_or((0, 0), |m| m.load())
    }

    pub fn join(&mut self, id: u64) {
        if let Some(model) = &mut self.model {
            model.join(id);
        }
    }

    /// Whatever the robot's running episode had not yet given to learning is dropped; its
    /// finished episodes are kept.
    pub fn leave(&mut self, id: u64) {
        if let Some(model) = &mut self.model {
            model.leave(id);
        }
    }

    /// Whether the server must stop serving (training over or failed).
    pub fn stopped(&self) -> bool {
        self.end.is_some() || self.error.is_some()
    }

    /// Tells the callbacks training ended and hands the model over (once).
    pub fn finish(&mut self) -> anyhow::Result<Box<dyn Model>> {
        let model = self.model.take().ok_or_else(|| anyhow::anyhow!("the model was handed over already"))?;
        self.callbacks.on_training_end(model.agent())?;
        Ok(model.into_learner())
    }

    /// The answer to one checked message; `None` ends the connection.
    pub fn handle(&mut self, id: u64, message: RobotMessage) -> Option<ServerMessage> {
        if let Some(end) = &self.end {
            return Some(ServerMessage::Done { reason: end.to_string() });
        }
        if let Some(e) = &self.error {
            return Some(error(ErrorCode::LearnerFailed, true, format!("learner failed: {e}")));
        }
        let model = self.model.as_mut()?;
        match message {
            RobotMessage::Hello { .. } => Some(error(ErrorCode::HandshakeExpected, false, "already introduced")),
            RobotMessage::Bye => {
                model.drop_episode(id);
                None
            }
            RobotMessage::Abort => {
                model.drop_episode(id);
                Some(ServerMessage::Ack)
            }
            RobotMessage::Start { obs } => {
                model.drop_episode(id);
                Some(self.act(id, &obs))
            }
            RobotMessage::Step { obs, reward, terminated, truncated, success, ended_by } => {
                let step =
                    RobotStep { obs: &obs, reward, terminated, truncated, success, ended_by: ended_by.as_deref() };
                Some(self.record_step(id, &step))
            }
        }
    }

    /// Records the outcome of the robot's waiting action and answers with the next action (or
    /// `ack` once the episode is over), after any learning it made due.
    fn record_step(&mut self, id: u64, step: &RobotStep) -> ServerMessage {
        let model = self.model.as_mut().expect("checked by handle");
        match model.awaits_outcome(id) {
            None => return error(ErrorCode::HandshakeExpected, true, "this robot is not known"),
            Some(false) => {
                return error(
                    ErrorCode::OutOfOrder,
                    false,
                    "'step' before 'start': no action is waiting for its outcome",
                );
            }
            Some(true) => {}
        }
        if let Err(e) = model.record(id, step) {
            return self.fail(e);
        }
        let answer = if step.ended() { ServerMessage::Ack } else { self.act(id, step.obs) };
        if let Err(e) = self.learn_if_due() {
            return self.fail(e);
        }
        answer
    }

    /// The policy's action on a fresh observation, which waits for its outcome.
    fn act(&mut self, id: u64, obs: &[f32]) -> ServerMessage {
        let model = self.model.as_mut().expect("checked by handle");
        match model.act(id, obs) {
            Ok(action) => ServerMessage::Action { action },
            Err(e) => self.fail(e),
        }
    }

    /// A learner failure ends training: `RobotServer::wait` reports it.
    fn fail(&mut self, e: anyhow::Error) -> ServerMessage {
        self.error = Some(format!("{e:#}"));
        error(ErrorCode::LearnerFailed, true, format!("learner failed: {e:#}"))
    }

    /// The model learns if it is due, the callbacks hear of each row, and training ends on
    /// their word or once the budget is spent.
    fn learn_if_due(&mut self) -> anyhow::Result<()> {
        let model = self.model.as_mut().expect("checked by handle");
        let flow = match model.learn_if_due()? {
            Some(stats) => Some(self.callbacks.on_update(&stats, model.agent())?),
            None => None,
        };
        let timesteps = model.agent().timesteps();
        self.end = flow
            .and_then(|flow| TrainingEnd::after(flow, timesteps))
            .or_else(|| (timesteps >= self.timesteps).then_some(TrainingEnd::BudgetSpent { timesteps }));
        Ok(())
    }
}
