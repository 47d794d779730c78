//! What every thread of a RobotServer shares: its limits, the learner behind its lock, and the
//! count of connections.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use twinbots_link::checks::Rejection;
use twinbots_link::protocol::TaskInterface;

use crate::learner::Learner;

/// What the server allows a client (docs/protocol.md, Limits).
#[derive(Clone, Debug)]
pub struct ServerLimits {
    /// Connections at once, handshaking ones included; the next is refused (`server_full`).
    pub max_robots: usize,
    /// Time for a new connection's whole `hello` to arrive.
    pub handshake_timeout: Duration,
    /// Time for each whole request to arrive once the previous one was answered (a robot
    /// homing or waiting longer is disconnected; the Communicator reconnects).
    pub read_timeout: Duration,
    /// A shared secret `hello.token` must equal; `None`: no token needed.
    pub token: Option<String>,
    /// TLS (`serve --tls-cert/--tls-key`): every connection is encrypted; `None`: plain TCP.
    pub tls: Option<twinbots_link::tls::ServerTls>,
    /// Stack size of connection threads in bytes. Tests set an impossible one to show that a
    /// connection that cannot get a thread is refused while the server goes on.
    pub connection_stack: usize,
}

impl Default for ServerLimits {
    fn default() -> Self {
        Self {
            max_robots: 64,
            handshake_timeout: Duration::from_secs(10),
            read_timeout: Duration::from_secs(60),
            token: None,
            tls: None,
            connection_stack: 2 * 1024 * 1024,
        }
    }
}

/// What every thread of the server shares.
pub(crate) struct Shared {
    pub learner: Mutex<Learner>,
    /// Signalled when training ends or fails.
    pub changed: Condvar,
    pub task: TaskInterface,
    pub limits: ServerLimits,
    pub connected: AtomicUsize,
    pub rejections: AtomicU64,
}

impl Shared {
    /// The learner. A panic while it was held is caught where it happens and recorded as the
    /// learner's error, so a poisoned lock only means that: go on to report it.
    pub fn learner(&self) -> MutexGuard<'_, Learner> {
        self.learner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Wakes `wait` if training is over or failed.
    pub fn notify_if_stopped(&self, learner: &Learner) {
        if learner.stopped() {
            self.changed.notify_all();
        }
    }

    /// The server must stop: `wait` returns this reason (the first one, if several).
    pub fn fail(&self, reason: String) {
        let mut learner = self.learner();
        learner.error.get_or_insert(reason);
        self.changed.notify_all();
    }

    /// Logs a refused message with its peer and counts it.
    pub fn log_rejection(&self, peer: SocketAddr, who: &str, rejection: &Rejection) {
        self.rejections.fetch_add(1, Ordering::Relaxed);
        let fatal = if rejection.fatal { ", connection closed" } else { "" };
        eprintln!("robot server: refused {peer} ({who}): {:?}{fatal}: {}", rejection.code, rejection.message);
    }
}

/// A connection's place under `max_robots`, given back when dropped.
pub(crate) struct Slot(Arc<Shared>);

impl Slot {
    pub fn take(shared: &Arc<Shared>) -> Option<Self> {
        let max = shared.limits.max_robots;
        shared.connected.fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| (n < max).then_some(n + 1)).ok()?;
        Some(Self(shared.clone()))
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        self.0.connected.fetch_sub(1, Ordering::AcqRel);
    }
}

/// The text of a panic's payload.
pub(crate) fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "(no message)".into())
}
