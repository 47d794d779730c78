//! The RobotServer protocol, version 1 (see docs/protocol.md).
//!
//! A persistent TCP connection per robot. Each message is a frame: a 4-byte little-endian
//! payload length, then that many bytes of UTF-8 JSON, one object with a `"type"` field.
//! The robot speaks first (`hello`), then alternates: it sends `start` or `step`, the server
//! answers `action` (or `ack` after a finished episode). Any request the server cannot use gets
//! an `error` reply; the connection stays open unless the error says `fatal`.

use std::io::{self, Read, Write};

use serde::{Deserialize, Serialize};
use twinbots_rl::Space;

pub const VERSION: u32 = 1;
/// Frames larger than this are refused (their bytes are skipped, the connection survives).
pub const MAX_FRAME: usize = 64 * 1024;

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
    },
    /// A new episode starts with this observation; answered with an `action`.
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
    },
    /// The robot leaves; nothing is answered.
    Bye,
}

/// Server → robot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerMessage {
    Welcome { version: u32, robot_id: u64 },
    Action { action: Vec<f32> },
    Ack,
    /// Training is over: the robot should stop.
    Done { reason: String },
    /// The request was not usable; with `fatal` the server closes the connection.
    Error { message: String, fatal: bool },
}

#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    #[error("connection: {0}")]
    Io(#[from] io::Error),
    #[error("frame of {0} bytes exceeds the {MAX_FRAME}-byte limit")]
    Oversized(usize),
    #[error("malformed message: {0}")]
    Malformed(String),
}

impl FrameError {
    /// Whether the connection can go on after this error.
    pub fn recoverable(&self) -> bool {
        !matches!(self, FrameError::Io(_))
    }
}

/// Writes one message as a frame.
pub fn write_message<T: Serialize>(w: &mut impl Write, message: &T) -> io::Result<()> {
    let payload = serde_json::to_vec(message).map_err(io::Error::other)?;
    let mut frame = Vec::with_capacity(4 + payload.len());
    frame.extend((payload.len() as u32).to_le_bytes());
    frame.extend(payload);
    w.write_all(&frame)?;
    w.flush()
}

/// Reads one frame and parses it. An oversized frame is skipped whole, so the next frame can
/// still be read; a malformed one was read whole too.
pub fn read_message<T: for<'de> Deserialize<'de>>(r: &mut impl Read) -> Result<T, FrameError> {
    let mut len = [0u8; 4];
    r.read_exact(&mut len)?;
    let len = u32::from_le_bytes(len) as usize;
    if len > MAX_FRAME {
        io::copy(&mut r.take(len as u64), &mut io::sink())?;
        return Err(FrameError::Oversized(len));
    }
    let mut payload = vec![0u8; len];
    r.read_exact(&mut payload)?;
    serde_json::from_slice(&payload).map_err(|e| FrameError::Malformed(e.to_string()))
}
