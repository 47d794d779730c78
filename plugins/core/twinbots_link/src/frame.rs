//! Frames on the wire: a 4-byte little-endian payload length, then that many bytes of UTF-8
//! JSON. Reading never trusts the length: an oversized frame is refused before any of it is
//! allocated, and a stalled one ends at the reader's deadline ([`crate::deadline`]).

use std::io::{self, Read, Write};

use serde::{Deserialize, Serialize};

use crate::protocol::{ErrorCode, MAX_FRAME, MAX_SKIP};

#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    /// The connection closed or broke; nothing can be answered.
    #[error("connection: {0}")]
    Io(io::Error),
    /// A whole frame did not arrive in time; part of it may have been read, so the stream
    /// cannot be resynchronised.
    #[error("no whole message within the timeout")]
    TimedOut,
    /// Over [`MAX_FRAME`] bytes; `skipped` when its bytes were read past, so the next frame
    /// can still be read.
    #[error("frame of {len} bytes exceeds the {MAX_FRAME}-byte limit")]
    Oversized { len: usize, skipped: bool },
    /// Read whole, but not a message of this protocol.
    #[error("malformed message: {0}")]
    Malformed(String),
}

impl From<io::Error> for FrameError {
    fn from(e: io::Error) -> Self {
        match e.kind() {
            // What a socket read timeout gives (WouldBlock on Unix, TimedOut on Windows).
            io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut => FrameError::TimedOut,
            _ => FrameError::Io(e),
        }
    }
}

impl FrameError {
    /// Whether the connection cannot go on after this error.
    pub fn fatal(&self) -> bool {
        match self {
            FrameError::Io(_) | FrameError::TimedOut => true,
            FrameError::Oversized { skipped, .. } => !skipped,
            FrameError::Malformed(_) => false,
        }
    }

    /// The code of the error reply; `None` when the peer is gone.
    pub fn code(&self) -> Option<ErrorCode> {
        match self {
            FrameError::Io(_) => None,
            FrameError::TimedOut => Some(ErrorCode::Timeout),
            FrameError::Oversized { .. } => Some(ErrorCode::Oversized),
            FrameError::Malformed(_) => Some(ErrorCode::Malformed),
        }
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

/// Reads one frame's payload. An oversized frame up to [`MAX_SKIP`] bytes is read past (the
/// connection goes on); a larger one is not read at all.
pub fn read_frame(r: &mut impl Read) -> Result<Vec<u8>, FrameError> {
    let mut len = [0u8; 4];
    r.read_exact(&mut len)?;
    let len = u32::from_le_bytes(len) as usize;
    if len > MAX_FRAME {
        if len > MAX_SKIP {
            return Err(FrameError::Oversized { len, skipped: false });
        }
        let skipped = io::copy(&mut r.take(len as u64), &mut io::sink())?;
        if skipped < len as u64 {
            return Err(FrameError::Io(io::ErrorKind::UnexpectedEof.into()));
        }
        return Err(FrameError::Oversized { len, skipped: true });
    }
    let mut payload = vec![0u8; len];
    r.read_exact(&mut payload)?;
    Ok(payload)
}

/// Parses a payload. serde_json refuses nesting deeper than 128 levels and numbers beyond
/// f64, so no input can exhaust the stack; f32 overflow is [`crate::checks`]' business.
pub fn decode<T: for<'de> Deserialize<'de>>(payload: &[u8]) -> Result<T, FrameError> {
    serde_json::from_slice(payload).map_err(|e| FrameError::Malformed(e.to_string()))
}

/// Reads one frame and parses it.
pub fn read_message<T: for<'de> Deserialize<'de>>(r: &mut impl Read) -> Result<T, FrameError> {
    decode(&read_frame(r)?)
}
