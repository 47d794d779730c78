//! The RobotServer protocol, version 2 (docs/protocol.md is the reference).
//!
//! A persistent TCP connection per robot. Each message is a frame ([`crate::frame`]): a 4-byte
//! little-endian payload length, then that many bytes of UTF-8 JSON, one object with a `"type"`
//! field. The robot speaks first (`hello`, answered by `welcome` with the task's interface),
//! then alternates: it sends `start`, `step` or `abort`, the server answers `action` (or `ack`
//! after a finished or aborted episode). A request the server cannot use gets an `error` reply
//! with a machine-readable `code`; the connection stays open unless the error says `fatal`.

use serde::{Deserialize, Serialize};
use twinbots_api::{Space, TaskSpec};

/// The protocol version this crate speaks. Version 1 had no token, no `abort`, no error codes
/// and no task interface in `welcome`; a v1 `hello` is refused naming this version.
pub const VERSION: u32 = 2;
/// Frames larger than this are refused.
pub const MAX_FRAME: usize = 64 * 1024;
/// An oversized frame up to this size is skipped and the connection survives; a larger one
/// closes it (skipping gigabytes would hold the connection for minutes).
pub const MAX_SKIP: usize = 1024 * 1024;

/// Robot → server.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum RobotMessage {
    /// First message: who the robot is and what it observes and does.
    Hello {
        version: u32,
        robot: String,
        observation_space: Space,
        action_space: Space,
        /// The server's shared secret, if it has one (`serve --token`).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        token: Option<String>,
    },
    /// A new episode starts with this observation (a running one is dropped first); answered
    /// with an `action`.
    Start { obs: Vec<f32> },
    /// The result of the last action: the new observation (the episode's last, if it ended),
    /// the reward, and whether the episode ended. Answered with `action`, or `ack` if it ended.
    Step {
        obs: Vec<f32>,
        reward: f32,
        terminated: bool,
        truncated: bool,
        /// On an episode's last step, whether it reached its goal (Gymnasium's
        /// `info["is_success"]`); optional.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        success: Option<bool>,
        /// With `terminated`: the termination term that ended the episode (one of the task's
        /// `termination_terms`); optional. A learner that relabels goals (HER) recomputes the
        /// step's reward with it.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        ended_by: Option<String>,
    },
    /// The running episode is abandoned (an emergency stop, a fault, an operator's hand): its
    /// steps not yet learned from are dropped. Answered with `ack`, also when none was running.
    Abort,
    /// The robot leaves; nothing is answered.
    Bye,
}

/// Server → robot. (The welcome is larger than the rest; one is sent per connection, so it is
/// not boxed.)
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerMessage {
    /// The robot is accepted; `task` is what the server's model expects of it.
    Welcome { version: u32, robot_id: u64, task: TaskInterface },
    /// What to do next: a flat array (a discrete action is its index as a number, `[1.0]`).
    Action { action: Vec<f32> },
    /// The episode's end (or abort) was recorded; the robot may home and `start` again.
    Ack,
    /// Training is over: the robot should stop; the server closes the connection.
    Done { reason: String },
    /// The request was not used; with `fatal` the server closes the connection.
    Error { code: ErrorCode, message: String, fatal: bool },
}

/// Why a request was refused: what a client program branches on (the message is for people).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorCode {
    /// `hello.version` is not [`VERSION`] (fatal).
    UnsupportedVersion,
    /// The first message was not a `hello`, or a second `hello` came.
    HandshakeExpected,
    /// The token is missing or wrong (fatal).
    Unauthorized,
    /// This server trains another robot kind (fatal).
    WrongRobot,
    /// The robot's spaces differ from the model's (fatal).
    WrongSpaces,
    /// As many robots as `--max-robots` are connected (fatal).
    ServerFull,
    /// The server could not take the connection now (a thread could not start; fatal).
    Unavailable,
    /// A whole request did not arrive within the read (or handshake) timeout (fatal).
    Timeout,
    /// The frame is over [`MAX_FRAME`] bytes (fatal over [`MAX_SKIP`]).
    Oversized,
    /// Not UTF-8 JSON, an unknown `type`, a missing or mistyped field.
    Malformed,
    /// A number that is not finite as an f32 (NaN, ±inf, or beyond ±3.4e38 such as 1e39).
    NonFinite,
    /// An observation of the wrong length.
    WrongLength,
    /// An observation value outside the task's plausible range
    /// (`welcome.task.observation_plausible`): a faulty sensor, never fed to the learner.
    ObservationOutOfRange,
    /// A reward outside the task's declared range (`welcome.task.reward_range`).
    RewardOutOfRange,
    /// A `step` with no action awaiting its outcome (no `start` before it, or after `ack`).
    OutOfOrder,
    /// A `step`'s `ended_by` that names none of the task's termination terms
    /// (`welcome.task.termination_terms`), or comes on a step that did not terminate.
    UnknownTermination,
    /// The learner failed; training is over (fatal).
    LearnerFailed,
}

/// What a robot of a task sends and gets: the `welcome` reply's `task`, and what
/// `twinbots robots --json` prints for every task.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TaskInterface {
    pub robot: String,
    pub task: String,
    /// `obs` of `start` and `step`: a Box with bounds (see docs/protocol.md, Spaces).
    pub observation_space: Space,
    /// What each observation value is, in order (same length as the observation).
    pub observation_names: Vec<String>,
    /// Where each observation value of a working sensor lies (a Box); the server refuses
    /// others. Absent from servers before it was declared.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub observation_plausible: Option<Space>,
    /// `action` of the server's replies.
    pub action_space: Space,
    /// The lowest and highest reward one `step` may report; others are refused.
    pub reward_range: RewardRange,
    /// The reward's named terms (the task sums their weighted values).
    pub reward_terms: Vec<String>,
    /// How often a robot of the task acts, in seconds (its control step: 0.032 for the
    /// cart-pole). Informative: the server waits for each step, whenever it comes. Absent from
    /// servers before it was declared.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub control_period_s: Option<f64>,
    /// The task's termination terms: what a `step`'s `ended_by` may name. Absent from
    /// servers before it was declared.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub termination_terms: Vec<String>,
}

impl TaskInterface {
    pub fn of(robot: &str, spec: &TaskSpec) -> Self {
        Self {
            robot: robot.into(),
            task: spec.name.clone(),
            observation_space: spec.observation_space.clone(),
            observation_names: spec.observation_names.clone(),
            observation_plausible: Some(spec.observation_plausible.clone()),
            action_space: spec.action_space.clone(),
            reward_range: RewardRange { low: spec.reward_range.0, high: spec.reward_range.1 },
            reward_terms: spec.reward_terms.clone(),
            control_period_s: None,
            termination_terms: spec.termination_terms.clone(),
        }
    }

    /// The interface with the robot's control step (see [`TaskInterface::control_period_s`]),
    /// rounded to the microsecond (the f32 step's digits beyond it are noise).
    pub fn with_control_period(mut self, seconds: f64) -> Self {
        self.control_period_s = Some((seconds * 1e6).round() / 1e6);
        self
    }
}

/// A closed interval of rewards; infinite ends are written as the strings `"-inf"`/`"inf"`
/// (JSON has no infinity), as space bounds are.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RewardRange {
    pub low: f32,
    pub high: f32,
}

impl RewardRange {
    /// Whether `reward` lies in the range, allowing the rounding of summing f32 terms.
    pub fn contains(&self, reward: f32) -> bool {
        let slack = |bound: f32| 1e-5 * bound.abs().max(1.0);
        reward >= self.low - slack(self.low) && reward <= self.high + slack(self.high)
    }
}

impl Serialize for RewardRange {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        #[derive(Serialize)]
        struct Wire {
            low: serde_json::Value,
            high: serde_json::Value,
        }
        Wire { low: bound_to_json(self.low), high: bound_to_json(self.high) }.serialize(s)
    }
}

impl<'de> Deserialize<'de> for RewardRange {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct Wire {
            low: serde_json::Value,
            high: serde_json::Value,
        }
        let w = Wire::deserialize(d)?;
        let bound = |v: &serde_json::Value| {
            bound_from_json(v).ok_or_else(|| serde::de::Error::custom(format!("bad reward bound {v}")))
        };
        Ok(Self { low: bound(&w.low)?, high: bound(&w.high)? })
    }
}

fn bound_to_json(v: f32) -> serde_json::Value {
    match v {
        f32::INFINITY => "inf".into(),
        f32::NEG_INFINITY => "-inf".into(),
        v => serde_json::json!(v),
    }
}

fn bound_from_json(v: &serde_json::Value) -> Option<f32> {
    match v {
        serde_json::Value::String(s) if s == "inf" => Some(f32::INFINITY),
        serde_json::Value::String(s) if s == "-inf" => Some(f32::NEG_INFINITY),
        v => v.as_f64().map(|x| x as f32).filter(|x| x.is_finite()),
    }
}

/// An error reply.
pub fn error(code: ErrorCode, fatal: bool, message: impl Into<String>) -> ServerMessage {
    ServerMessage::Error { code, message: message.into(), fatal }
}
