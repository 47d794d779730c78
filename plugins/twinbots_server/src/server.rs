//! The RobotServer: accepts robots over TCP, serves each from its own thread
//! ([`crate::connection`]), and trains one PPO model ([`crate::learner`]) on the experience they
//! all send.
//!
//! It fails rather than hangs: a panic in the learner, a connection thread or the accept loop,
//! or a learner error, ends [`RobotServer::wait`] with the reason. A client's mistakes never do:
//! they are answered, logged with the peer's address, and the other robots go on.

use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use twinbots_rl::{Callback, Ppo, TaskSpec, TrainingEnd};

use crate::checks::Rejection;
use crate::frame::write_message;
use crate::learner::Learner;
use crate::protocol::{ErrorCode, TaskInterface};

/// What the server trains.
pub struct ServerSettings {
    /// The robot and task it serves (`hello` must match its robot and spaces; `welcome`
    /// carries it; steps are checked against its observation length and reward range).
    pub task: TaskInterface,
    /// Transitions per PPO update, summed over robots.
    pub rollout: usize,
    /// Stop after this many transitions (the model's `timesteps`, earlier sessions included).
    pub timesteps: u64,
    pub limits: ServerLimits,
}

impl ServerSettings {
    /// Serving `robot`'s task `spec`, with the default limits.
    pub fn new(robot: &str, spec: &TaskSpec, rollout: usize, timesteps: u64) -> Self {
        Self { task: TaskInterface::of(robot, spec), rollout, timesteps, limits: ServerLimits::default() }
    }
}

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
            connection_stack: 2 * 1024 * 1024,
        }
    }
}

/// What every thread of the server shares.
pub(crate) struct Shared {
    learner: Mutex<Learner>,
    /// Signalled when training ends or fails.
    changed: Condvar,
    pub task: TaskInterface,
    pub limits: ServerLimits,
    connected: AtomicUsize,
    rejections: AtomicU64,
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
    fn take(shared: &Arc<Shared>) -> Option<Self> {
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

/// A running server. `wait` blocks until training is over and returns the model.
pub struct RobotServer {
    pub addr: SocketAddr,
    shared: Arc<Shared>,
}

impl RobotServer {
    /// Binds `listen` (port 0 picks a free port) and starts accepting robots. `callbacks` hear
    /// the training as `Ppo::learn`'s do (a `twinbots_rl::CallbackList` composes several).
    pub fn start(listen: SocketAddr, ppo: Ppo, settings: ServerSettings, mut callbacks: Box<dyn Callback + Send>) -> anyhow::Result<Self> {
        anyhow::ensure!(settings.limits.max_robots >= 1, "max_robots must be at least 1");
        anyhow::ensure!(
            !settings.limits.handshake_timeout.is_zero() && !settings.limits.read_timeout.is_zero(),
            "timeouts must be longer than zero"
        );
        let listener = TcpListener::bind(listen).map_err(|e| anyhow::anyhow!("cannot listen on {listen}: {e}"))?;
        let addr = listener.local_addr()?;
        callbacks.on_training_start(&ppo)?;
        let shared = Arc::new(Shared {
            learner: Mutex::new(Learner::new(ppo, settings.rollout, settings.timesteps, callbacks)),
            changed: Condvar::new(),
            task: settings.task,
            limits: settings.limits,
            connected: AtomicUsize::new(0),
            rejections: AtomicU64::new(0),
        });
        let accepting = shared.clone();
        std::thread::Builder::new()
            .name("robot-server-accept".into())
            .spawn(move || {
                let stopped = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| accept_robots(&listener, &accepting)));
                let why = match stopped {
                    Err(panic) => format!("the accept loop panicked: {}", panic_message(&*panic)),
                    Ok(never) => match never {},
                };
                accepting.fail(why);
            })
            .map_err(|e| anyhow::anyhow!("cannot start the accept loop: {e}"))?;
        Ok(Self { addr, shared })
    }

    /// Robots connected now, and transitions they hold for the next update.
    pub fn load(&self) -> (usize, usize) {
        self.shared.learner().load()
    }

    /// Messages and connections refused so far (each is logged to stderr with its peer).
    pub fn rejections(&self) -> u64 {
        self.shared.rejections.load(Ordering::Relaxed)
    }

    /// Blocks until training ends (budget spent, solved, stopped by a callback) or fails (a
    /// learner error, a panic in any server thread), tells the callbacks, and returns a
    /// snapshot of the model and why it ended. Robots still connected get `done` on their next
    /// message.
    pub fn wait(self) -> anyhow::Result<(Ppo, TrainingEnd)> {
        let mut learner = self.shared.learner();
        loop {
            if let Some(e) = &learner.error {
                anyhow::bail!("training failed: {e}");
            }
            if let Some(end) = learner.end.clone() {
                let learner = &mut *learner;
                learner.callbacks.on_training_end(&learner.ppo)?;
                return Ok((learner.ppo.snapshot()?, end));
            }
            learner = self.shared.changed.wait(learner).unwrap_or_else(PoisonError::into_inner);
        }
    }
}

/// Accepts connections for as long as the process lives; never returns.
fn accept_robots(listener: &TcpListener, shared: &Arc<Shared>) -> std::convert::Infallible {
    let mut next_id = 1u64;
    loop {
        match listener.accept() {
            Ok((stream, peer)) => {
                admit(stream, peer, next_id, shared);
                next_id += 1;
            }
            Err(e) => {
                // Out of file descriptors and the like: the condition passes when connections
                // close. Pause instead of spinning on it.
                eprintln!("robot server: cannot accept a connection: {e}");
                std::thread::sleep(Duration::from_millis(50));
            }
        }
    }
}

/// Serves a new connection on its own thread, or refuses it with a reason when the server is
/// full or no thread can be started for it.
fn admit(stream: TcpStream, peer: SocketAddr, id: u64, shared: &Arc<Shared>) {
    let Some(slot) = Slot::take(shared) else {
        let max = shared.limits.max_robots;
        let why = format!("the server is full: {max} robots are connected (serve --max-robots {max})");
        refuse(stream, peer, shared, Rejection::new(ErrorCode::ServerFull, true, why));
        return;
    };
    // A handle to answer through if the thread cannot start (the stream moves into it).
    let answer = stream.try_clone();
    let serving = shared.clone();
    let spawned = std::thread::Builder::new()
        .name(format!("robot-{id}"))
        .stack_size(shared.limits.connection_stack)
        .spawn(move || {
            let _slot = slot;
            let served = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| crate::connection::serve(stream, peer, id, &serving)));
            if let Err(panic) = served {
                serving.fail(format!("the connection thread of {peer} panicked: {}", panic_message(&*panic)));
            }
        });
    if let Err(e) = spawned {
        let why = format!("the server cannot serve another robot now (no thread: {e}); try again later");
        match answer {
            Ok(stream) => refuse(stream, peer, shared, Rejection::new(ErrorCode::Unavailable, true, why)),
            Err(_) => shared.log_rejection(peer, "new connection", &Rejection::new(ErrorCode::Unavailable, true, why)),
        }
    }
}

/// Answers a connection the server will not serve, from the accepting thread (a short write
/// timeout: a peer that does not read cannot hold up accepting).
fn refuse(stream: TcpStream, peer: SocketAddr, shared: &Shared, rejection: Rejection) {
    shared.log_rejection(peer, "new connection", &rejection);
    let _ = stream.set_write_timeout(Some(Duration::from_secs(1)));
    let mut stream = stream;
    let _ = write_message(&mut stream, &rejection.reply());
}

/// The text of a panic's payload.
pub(crate) fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "(no message)".into())
}
