//! The RobotServer: accepts robots over TCP, serves each from its own thread
//! ([`crate::connection`]), and trains one model of any algorithm that can be served
//! ([`crate::learner`]) on the experience they all send.
//!
//! It fails rather than hangs: a panic in the learner, a connection thread or the accept loop,
//! or a learner error, ends [`RobotServer::wait`] with the reason. A client's mistakes never do:
//! they are answered, logged with the peer's address, and the other robots go on.

use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::Duration;

use twinbots_api::TaskSpec;
use twinbots_learn::{Callback, Learner as Model, TrainingEnd};

use crate::learner::Learner;
pub use crate::shared::ServerLimits;
use crate::shared::{Shared, Slot, panic_message};
use twinbots_link::checks::Rejection;
use twinbots_link::frame::write_message;
use twinbots_link::protocol::{ErrorCode, TaskInterface};

/// What the server trains.
pub struct ServerSettings {
    /// The robot and task it serves (`hello` must match its robot and spaces; `welcome`
    /// carries it; steps are checked against its observation length and reward range).
    pub task: TaskInterface,
    /// Robots the learner's batches are sized for (PPO's rollout is `n_steps` × robots;
    /// SAC's and TD3's iteration is one step of each).
    pub robots: usize,
    /// Stop after this many transitions (the model's `timesteps`, earlier sessions included).
    pub timesteps: u64,
    pub limits: ServerLimits,
}

impl ServerSettings {
    /// Serving `robot`'s task `spec`, with the default limits.
    pub fn new(robot: &str, spec: &TaskSpec, robots: usize, timesteps: u64) -> Self {
        Self { task: TaskInterface::of(robot, spec), robots, timesteps, limits: ServerLimits::default() }
    }
}

/// A running server. `wait` blocks until training is over and returns the model.
pub struct RobotServer {
    pub addr: SocketAddr,
    shared: Arc<Shared>,
}

impl RobotServer {
    /// Binds `listen` (port 0 picks a free port) and starts accepting robots. `callbacks` hear
    /// the training as `learn`'s do (a `twinbots_learn::CallbackList` composes several). A
    /// model whose algorithm cannot be served is an error.
    pub fn start(
        listen: SocketAddr,
        model: Box<dyn Model>,
        settings: ServerSettings,
        mut callbacks: Box<dyn Callback + Send>,
    ) -> anyhow::Result<Self> {
        anyhow::ensure!(settings.limits.max_robots >= 1, "max_robots must be at least 1");
        anyhow::ensure!(
            !settings.limits.handshake_timeout.is_zero() && !settings.limits.read_timeout.is_zero(),
            "timeouts must be longer than zero"
        );
        let listener = TcpListener::bind(listen).map_err(|e| anyhow::anyhow!("cannot listen on {listen}: {e}"))?;
        let addr = listener.local_addr()?;
        let model = model.serve(settings.robots, settings.timesteps)?;
        callbacks.on_training_start(model.agent())?;
        let shared = Arc::new(Shared {
            learner: Mutex::new(Learner::new(model, settings.timesteps, callbacks)),
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
                let stopped =
                    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| accept_robots(&listener, &accepting)));
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
    /// learner error, a panic in any server thread), tells the callbacks, and returns the model
    /// and why it ended. Robots still connected get `done` on their next message.
    pub fn wait(self) -> anyhow::Result<(Box<dyn Model>, TrainingEnd)> {
        let mut learner = self.shared.learner();
        loop {
            if let Some(e) = &learner.error {
                anyhow::bail!("training failed: {e}");
            }
            if let Some(end) = learner.end.clone() {
                return Ok((learner.finish()?, end));
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
            let served = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                crate::connection::serve(stream, peer, id, &serving)
            }));
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
    // Under TLS a plain reply would read as a broken handshake: close, and the robot retries
    // as it does after any lost connection.
    if shared.limits.tls.is_some() {
        return;
    }
    let _ = stream.set_write_timeout(Some(Duration::from_secs(1)));
    let mut stream = stream;
    let _ = write_message(&mut stream, &rejection.reply());
}
