//! A connection whose reads end at a deadline. A socket read timeout alone bounds each read,
//! not a message: a client trickling one byte every few seconds would hold its connection
//! thread forever. The server sets a deadline before each request (a robot before each reply);
//! every read waits only for what is left of it. Writes pass through (a frame is written whole
//! and flushed, so no write buffer is needed beside the read buffer).

use std::io::{self, Read, Write};
use std::time::{Duration, Instant};

use crate::tls::Transport;

pub struct DeadlineStream {
    stream: Transport,
    deadline: Option<Instant>,
}

impl DeadlineStream {
    pub fn new(stream: impl Into<Transport>) -> Self {
        Self { stream: stream.into(), deadline: None }
    }

    /// The next reads must be done within `timeout` from now.
    pub fn expire_in(&mut self, timeout: Duration) {
        self.deadline = Some(Instant::now() + timeout);
    }
}

impl Read for DeadlineStream {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if let Some(deadline) = self.deadline {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(io::ErrorKind::TimedOut.into());
            }
            self.stream.tcp().set_read_timeout(Some(left))?;
        }
        self.stream.read(buf)
    }
}

impl Write for DeadlineStream {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.stream.write(buf)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.stream.flush()
    }
}
