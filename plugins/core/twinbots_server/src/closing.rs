//! Closing a connection after a fatal error reply so that the reply arrives. Closing a socket
//! with unread bytes in it makes the kernel send a reset, and a reset can overtake the reply
//! still in flight: the client would see "connection reset" instead of why. So: stop writing
//! (the client sees end-of-stream after the reply), read away what the client already sent for
//! a short while, then close.

use std::io::Read;
use std::net::{Shutdown, TcpStream};
use std::time::{Duration, Instant};

/// Bytes read away at most (a 4 GiB frame is not waited for).
const DRAIN_LIMIT: usize = 1024 * 1024;

pub fn close_after_reply(stream: &TcpStream, linger: Duration) {
    let _ = stream.shutdown(Shutdown::Write);
    let until = Instant::now() + linger;
    let mut reader = stream;
    let mut buf = [0u8; 8192];
    let mut drained = 0;
    while drained < DRAIN_LIMIT {
        let left = until.saturating_duration_since(Instant::now());
        if left.is_zero() || stream.set_read_timeout(Some(left)).is_err() {
            break;
        }
        match reader.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => drained += n,
        }
    }
}
