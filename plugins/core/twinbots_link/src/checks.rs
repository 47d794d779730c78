//! What the server checks of every message before the learner sees it: the handshake
//! (version first, so a client of another version learns which one to speak, then token,
//! robot kind and spaces) and each request's numbers (finite as f32, the observation's length,
//! the reward within the task's declared range). A message that fails is answered with an
//! error and never reaches the learner.

use crate::frame::{FrameError, decode};
use crate::protocol::{ErrorCode, RobotMessage, ServerMessage, TaskInterface, VERSION, error};

/// A refused message: the error reply it gets.
#[derive(Clone, Debug, PartialEq)]
pub struct Rejection {
    pub code: ErrorCode,
    pub fatal: bool,
    pub message: String,
}

impl Rejection {
    pub fn new(code: ErrorCode, fatal: bool, message: impl Into<String>) -> Self {
        Self { code, fatal, message: message.into() }
    }

    pub fn reply(&self) -> ServerMessage {
        error(self.code, self.fatal, self.message.clone())
    }

    /// The reply to a frame that could not be read or parsed; `None` when the peer is gone.
    pub fn of_frame(e: &FrameError) -> Option<Self> {
        Some(Self::new(e.code()?, e.fatal(), e.to_string()))
    }
}

/// What a `hello` must match.
pub struct Admission<'a> {
    pub task: &'a TaskInterface,
    pub token: Option<&'a str>,
}

/// Checks a first frame's payload. Every refusal is fatal: a client that cannot introduce
/// itself has nothing else to say.
pub fn check_hello(payload: &[u8], admission: &Admission) -> Result<RobotMessage, Rejection> {
    let fatal = |code, message: String| Rejection::new(code, true, message);
    // The version is read before the rest, so a client of another version (whose hello may
    // have other fields) is told which version to speak rather than what field it lacks.
    let value: serde_json::Value =
        decode(payload).map_err(|e| fatal(ErrorCode::Malformed, format!("{e}; the first message must be 'hello'")))?;
    if value.get("type").and_then(|t| t.as_str()) != Some("hello") {
        return Err(fatal(ErrorCode::HandshakeExpected, "the first message must be 'hello'".into()));
    }
    match value.get("version").and_then(|v| v.as_u64()) {
        Some(v) if v == u64::from(VERSION) => {}
        other => {
            let theirs = other.map_or_else(|| "without a version".to_string(), |v| format!("version {v}"));
            return Err(fatal(
                ErrorCode::UnsupportedVersion,
                format!("protocol {theirs} is not supported: this server speaks version {VERSION} only (docs/protocol.md)"),
            ));
        }
    }
    let hello: RobotMessage = serde_json::from_value(value).map_err(|e| fatal(ErrorCode::Malformed, format!("malformed hello: {e}")))?;
    let RobotMessage::Hello { robot, observation_space, action_space, token, .. } = &hello else {
        unreachable!("the type was checked to be hello");
    };
    if let Some(expected) = admission.token
        && !same_secret(token.as_deref().unwrap_or(""), expected)
    {
        let why = if token.is_some() { "wrong token" } else { "this server needs a token (hello.token)" };
        return Err(fatal(ErrorCode::Unauthorized, why.into()));
    }
    let task = admission.task;
    if *robot != task.robot {
        return Err(fatal(ErrorCode::WrongRobot, format!("this server trains '{}', not '{robot}'", task.robot)));
    }
    if *observation_space != task.observation_space || *action_space != task.action_space {
        return Err(fatal(
            ErrorCode::WrongSpaces,
            format!(
                "spaces differ: the robot has observation {observation_space} and action {action_space}, the model observation {} and action {} (with bounds: welcome.task of `twinbots robots --json`)",
                task.observation_space, task.action_space
            ),
        ));
    }
    Ok(hello)
}

/// Compares secrets in time independent of where they differ (no timing oracle for guessing
/// a token byte by byte).
fn same_secret(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    let mut diff = a.len() ^ b.len();
    for i in 0..a.len().max(b.len()) {
        diff |= usize::from(a.get(i).copied().unwrap_or(0) ^ b.get(i).copied().unwrap_or(0));
    }
    diff == 0
}

/// Checks a request after the handshake: numbers finite, observation of the task's length,
/// reward within its range. Refusals are not fatal: the robot may send a corrected request.
pub fn check_request(message: &RobotMessage, task: &TaskInterface) -> Result<(), Rejection> {
    let refuse = |code, message: String| Err(Rejection::new(code, false, message));
    let obs = match message {
        RobotMessage::Start { obs } | RobotMessage::Step { obs, .. } => obs,
        RobotMessage::Hello { .. } => return refuse(ErrorCode::HandshakeExpected, "already introduced: 'hello' comes once".into()),
        RobotMessage::Abort | RobotMessage::Bye => return Ok(()),
    };
    let dim = task.observation_space.dim();
    if obs.len() != dim {
        return refuse(ErrorCode::WrongLength, format!("observation has {} values, expected {dim}", obs.len()));
    }
    if let Some(i) = obs.iter().position(|v| !v.is_finite()) {
        let name = task.observation_names.get(i).map_or(String::new(), |n| format!(" ({n})"));
        return refuse(ErrorCode::NonFinite, format!("observation value {i}{name} is {}: not a finite f32", obs[i]));
    }
    if let RobotMessage::Step { reward, .. } = message {
        if !reward.is_finite() {
            return refuse(ErrorCode::NonFinite, format!("reward is {reward}: not a finite f32 (|x| ≤ 3.4e38)"));
        }
        let range = task.reward_range;
        if !range.contains(*reward) {
            return refuse(
                ErrorCode::RewardOutOfRange,
                format!("reward {reward} is outside the task's range [{}, {}] per step", range.low, range.high),
            );
        }
    }
    Ok(())
}
