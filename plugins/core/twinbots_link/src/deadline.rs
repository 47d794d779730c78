//! A TCP stream whose reads end at a deadline. A socket read timeout alone bounds each read,
//! not a message: a client trickling one byte every few seconds would hold its connection
//! thread forever. The server sets a deadline before each request; every read waits only for
//! what is left of it.

use std::io::{self, Read};
use std::net::TcpStream;
use std::time::{Duration, Instant};

pub struct DeadlineStream {
    stream: TcpStream,
    deadline: Option<Instant>,
}

impl DeadlineStream {
    pub fn new(stream: TcpStream) -> Self {
        Self { stream, deadline: None }
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
            self.stream.set_read_timeout(Some(left))?;
        }
        self.stream.read(buf)
    }
}
