//! Learning from robots' steps as they arrive (design pattern 3's RobotServer): every robot runs
//! its own episodes at its own pace, one message at a time, and the learner keeps each robot's
//! running episode apart until it can learn from it. An algorithm that can be served says so
//! in its line of [`crate::algos::ALGOS`] and turns its model into one with
//! [`crate::Learner::serve`]: PPO (`ppo::served`), SAC and TD3 (`off_policy::served`).
//!
//! The server calls these with the learner's lock held: a robot's request is answered once
//! any learning it made due is done, so every action comes from a known policy.

use crate::agent::Agent;
use crate::learner::Learner;
use crate::stats::UpdateStats;

/// The outcome of a robot's last action, as its `step` message reports it.
#[derive(Clone, Copy, Debug)]
pub struct RobotStep<'a> {
    /// The observation after the action (the episode's last when it ended).
    pub obs: &'a [f32],
    pub reward: f32,
    pub terminated: bool,
    pub truncated: bool,
    /// Whether the episode reached its goal (on its last step).
    pub success: Option<bool>,
    /// The termination term that ended it (with `terminated`): what a goal's reward is
    /// recomputed with when HER relabels the step.
    pub ended_by: Option<&'a str>,
}

impl RobotStep<'_> {
    pub fn ended(&self) -> bool {
        self.terminated || self.truncated
    }
}

/// A model learning from robots (see the module's description).
pub trait ServedLearner: Send {
    /// The model, for the callbacks.
    fn agent(&self) -> &dyn Agent;
    /// A robot connected; its id is the server's for that connection.
    fn join(&mut self, robot: u64);
    /// The robot's running episode is dropped unlearnt (an abort, a new start, the robot
    /// left): a part of an episode is never mixed into training. Its finished episodes stay.
    fn drop_episode(&mut self, robot: u64);
    /// The robot left (its running episode is dropped first).
    fn leave(&mut self, robot: u64);
    /// Whether the robot has an action waiting for its outcome; `None`: no such robot.
    fn awaits_outcome(&self, robot: u64) -> Option<bool>;
    /// The action for the robot's fresh observation (an episode's first, or the one after a
    /// step), which then waits for its outcome.
    fn act(&mut self, robot: u64, obs: &[f32]) -> anyhow::Result<Vec<f32>>;
    /// The outcome of the robot's waiting action (see [`Self::awaits_outcome`]).
    fn record(&mut self, robot: u64, step: &RobotStep) -> anyhow::Result<()>;
    /// Learns if enough has arrived; the row for the callbacks when one is due.
    fn learn_if_due(&mut self) -> anyhow::Result<Option<UpdateStats>>;
    /// Robots connected, and their transitions not yet learnt from.
    fn load(&self) -> (usize, usize);
    /// The model, once serving is over.
    fn into_learner(self: Box<Self>) -> Box<dyn Learner>;
}

/// Rows of `n` per `every` crossed by a count going from `before` to `after` (a batch of
/// transitions may cross several at once).
pub(crate) fn crossed(before: u64, after: u64, every: u64) -> u64 {
    let every = every.max(1);
    after / every - before / every
}
