//! What the server checks of every message before the learner sees it: the handshake
//! (version first, so a client of another version learns which one to speak, then token,
//! robot kind and spaces) and each request's numbers (finite as f32, the observation's length,
//! the reward within the task's declared range). A message that fails is answered with an
//! error and never reaches the learner.
//!
//! And what a robot checks of the server's replies ([`check_welcome`], [`check_action`]): a
//! robot moves on what it is told, so a reply of another protocol version, for another robot
//! or other spaces, or an action outside the robot's action space stops it with the reason.

use crate::frame::{FrameError, decode};
use twinbots_api::Space;

use crate::protocol::{ErrorCode, RobotMessage, ServerMessage, TaskInterface, VERSION, error};

/// A refused message: the error reply it gets.
#[derive(Clone, Debug, PartialEq)]
pub struct Rejection {
    pub code: ErrorCode,
    pub fatal: bool,
    pub message: String,
}

/// The longest refusal message, in characters: messages quote what a peer sent (a robot name,
/// serde's view of a malformed field), so a 60 KiB name cannot become a 60 KiB reply or log line.
pub const MAX_MESSAGE: usize = 300;

/// The longest server text (an error message, a `done` reason) a robot keeps, in characters.
pub const MAX_SERVER_TEXT: usize = 200;

impl Rejection {
    pub fn new(code: ErrorCode, fatal: bool, message: impl Into<String>) -> Self {
        Self { code, fatal, message: truncated(&message.into(), MAX_MESSAGE) }
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
                format!(
                    "protocol {theirs} is not supported: this server speaks version {VERSION} only (docs/protocol.md)"
                ),
            ));
        }
    }
    let hello: RobotMessage =
        serde_json::from_value(value).map_err(|e| fatal(ErrorCode::Malformed, format!("malformed hello: {e}")))?;
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
        RobotMessage::Hello { .. } => {
            return refuse(ErrorCode::HandshakeExpected, "already introduced: 'hello' comes once".into());
        }
        RobotMessage::Abort | RobotMessage::Bye => return Ok(()),
    };
    let dim = task.observation_space.dim();
    if obs.len() != dim {
        return refuse(ErrorCode::WrongLength, format!("observation has {} values, expected {dim}", obs.len()));
    }
    // " (its name)" of observation value i, where the task names it.
    let name = |i: usize| task.observation_names.get(i).map_or(String::new(), |n| format!(" ({n})"));
    if let Some(i) = obs.iter().position(|v| !v.is_finite()) {
        return refuse(
            ErrorCode::NonFinite,
            format!("observation value {i}{} is {}: not a finite f32", name(i), obs[i]),
        );
    }
    if let Some(Space::Box { low, high }) = &task.observation_plausible
        && let Some(i) = (0..obs.len().min(low.len()).min(high.len())).find(|&i| obs[i] < low[i] || obs[i] > high[i])
    {
        return refuse(
            ErrorCode::ObservationOutOfRange,
            format!(
                "observation value {i}{} is {}, outside its plausible range [{}, {}]: a faulty sensor?",
                name(i),
                obs[i],
                low[i],
                high[i]
            ),
        );
    }
    if let RobotMessage::Step { reward, terminated, ended_by, .. } = message {
        if let Some(term) = ended_by {
            let shown = truncated(term, 64);
            if !terminated {
                return refuse(
                    ErrorCode::UnknownTermination,
                    format!("ended_by '{shown}' on a step that did not terminate"),
                );
            }
            if !task.termination_terms.iter().any(|t| t == term) {
                let known = if task.termination_terms.is_empty() {
                    "none".to_string()
                } else {
                    task.termination_terms.join(", ")
                };
                return refuse(
                    ErrorCode::UnknownTermination,
                    format!("ended_by '{shown}' is not one of this task's termination terms ({known})"),
                );
            }
        }
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

/// Checks the server's first reply on the robot's side: a `welcome` of this protocol's version
/// for this robot kind and its spaces (version first, as the server does for `hello`), or an
/// error reply (returned as it is, for the caller to tell retryable from fatal). Anything else
/// is the problem, in words.
pub fn check_welcome(
    payload: &[u8],
    robot: &str,
    observation_space: &Space,
    action_space: &Space,
) -> Result<ServerMessage, String> {
    let value: serde_json::Value = decode(payload).map_err(|e| format!("its reply to hello is not a message: {e}"))?;
    let kind = value.get("type").and_then(|t| t.as_str()).unwrap_or("").to_string();
    if kind == "error" {
        return serde_json::from_value(value).map_err(|e| format!("malformed error reply to hello: {e}"));
    }
    if kind != "welcome" {
        return Err(format!("it answered hello with {:?}, not \"welcome\"", truncated(&kind, 40)));
    }
    match value.get("version").and_then(|v| v.as_u64()) {
        Some(v) if v == u64::from(VERSION) => {}
        Some(v) => return Err(format!("it speaks protocol version {v}; this robot speaks version {VERSION}")),
        None => return Err(format!("its welcome has no protocol version; this robot speaks version {VERSION}")),
    }
    let welcome: ServerMessage = serde_json::from_value(value).map_err(|e| format!("malformed welcome: {e}"))?;
    let ServerMessage::Welcome { task, .. } = &welcome else { unreachable!("the type was checked to be welcome") };
    if task.robot != robot {
        return Err(format!("it welcomed a {:?}, not this {robot:?}", truncated(&task.robot, 40)));
    }
    if task.observation_space != *observation_space || task.action_space != *action_space {
        return Err(format!(
            "its model has observation {} and action {}, this robot observation {observation_space} and action {action_space} (with bounds: `twinbots robots --json`)",
            task.observation_space, task.action_space
        ));
    }
    Ok(welcome)
}

/// Checks an action the server sent against the robot's action space.
pub fn check_action(action: &[f32], space: &Space) -> Result<(), String> {
    if space.contains(action) {
        return Ok(());
    }
    let shown: Vec<String> = action.iter().take(8).map(|v| v.to_string()).collect();
    let more = if action.len() > 8 { ", …" } else { "" };
    let bounds = match space {
        Space::Box { low, high } => format!(" (low {low:?}, high {high:?})"),
        _ => String::new(),
    };
    Err(format!("it sent the action [{}{more}], outside this robot's action space {space}{bounds}", shown.join(", ")))
}

/// At most `max` characters of a peer-supplied string, marked when cut.
pub fn truncated(text: &str, max: usize) -> String {
    match text.char_indices().nth(max) {
        Some((cut, _)) => format!("{}…", &text[..cut]),
        None => text.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn task() -> TaskInterface {
        TaskInterface {
            robot: "cartpole".into(),
            task: "cartpole".into(),
            observation_space: Space::uniform_box(1, -1.0, 1.0),
            observation_names: vec!["x".into()],
            observation_plausible: None,
            action_space: Space::Discrete { n: 2 },
            reward_range: crate::protocol::RewardRange { low: 0.0, high: 1.0 },
            reward_terms: vec![],
            control_period_s: None,
            termination_terms: vec!["fallen".into()],
        }
    }

    #[test]
    fn a_long_peer_supplied_name_is_cut_in_the_refusal() {
        let task = task();
        let name = "r".repeat(60_000);
        let hello = serde_json::json!({"type": "hello", "version": VERSION, "robot": name, "observation_space": task.observation_space, "action_space": task.action_space});
        let refused = check_hello(hello.to_string().as_bytes(), &Admission { task: &task, token: None }).unwrap_err();
        assert_eq!(refused.code, ErrorCode::WrongRobot);
        assert!(
            refused.message.chars().count() <= MAX_MESSAGE + 1 && refused.message.ends_with('…'),
            "{} chars",
            refused.message.len()
        );
        assert_eq!(truncated("short", 10), "short");
    }

    #[test]
    fn a_step_names_only_a_termination_term_of_the_task_and_only_when_it_terminated() {
        let task = task();
        let step = |terminated, ended_by: &str| RobotMessage::Step {
            obs: vec![0.5],
            reward: 1.0,
            terminated,
            truncated: false,
            success: None,
            ended_by: Some(ended_by.into()),
        };
        assert!(check_request(&step(true, "fallen"), &task).is_ok());
        let unknown = check_request(&step(true, "tipped"), &task).unwrap_err();
        assert_eq!(unknown.code, ErrorCode::UnknownTermination);
        assert!(
            unknown.message.contains("'tipped'") && unknown.message.contains("(fallen)") && !unknown.fatal,
            "{}",
            unknown.message
        );
        let running = check_request(&step(false, "fallen"), &task).unwrap_err();
        assert_eq!(running.code, ErrorCode::UnknownTermination);
        assert!(running.message.contains("did not terminate"), "{}", running.message);
    }
}
