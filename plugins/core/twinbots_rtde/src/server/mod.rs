//! The controller's side of RTDE, for a stand-in: it accepts clients, answers their setup
//! (protocol version, controller version, recipes, start and pause), keeps the inputs each
//! client sets (one client per input: `IN_USE` for the next), and streams each started
//! client's output recipe at its frequency from the state the stand-in publishes every control
//! cycle. A malformed package gets an error text message and the session goes on, unless its
//! framing is lost (then it ends). The stand-in owns the cycle: it reads [`RtdeServer::inputs`],
//! computes, and [`RtdeServer::publish`]es.

use std::io::Write;
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_channel::Sender;

mod session;
use session::Session;

use crate::RtdeError;
use crate::package::{ControllerVersion, MessageLevel, Package, TextMessage, kind};
use crate::types::Value;
use crate::variables::{input_index, inputs, output_index, outputs};

/// The controller's outputs: one value per [`outputs`] entry, in its order.
#[derive(Clone, Debug)]
pub struct OutputState(pub Vec<Value>);

impl Default for OutputState {
    fn default() -> Self {
        Self(outputs().iter().map(|v| v.data_type.zero()).collect())
    }
}

impl OutputState {
    /// The index of output `name` (for setting it every cycle without a lookup); panics on a
    /// name the guide does not have, which is a bug in the stand-in.
    pub fn slot(name: &str) -> usize {
        output_index(name).unwrap_or_else(|| panic!("'{name}' is no RTDE output"))
    }

    /// The value of output `name`; panics on a name the guide does not have.
    pub fn get(&self, name: &str) -> Value {
        self.0[Self::slot(name)]
    }

    /// Sets output `slot`; the value must have the variable's type.
    pub fn set(&mut self, slot: usize, value: Value) {
        debug_assert_eq!(self.0[slot].data_type(), value.data_type(), "{}", outputs()[slot].name);
        self.0[slot] = value;
    }
}

/// The inputs clients have set: one value per [`inputs`] entry, in its order.
#[derive(Clone, Debug)]
pub struct InputState {
    pub values: Vec<Value>,
    /// Which session set each input (0: none).
    owners: Vec<u64>,
}

impl Default for InputState {
    fn default() -> Self {
        Self::new()
    }
}

impl InputState {
    /// Every input at zero, none held by a client.
    pub fn new() -> Self {
        let values: Vec<Value> = inputs().iter().map(|v| v.data_type.zero()).collect();
        let owners = vec![0; values.len()];
        Self { values, owners }
    }

    /// The value of input `name`; panics on a name the guide does not have.
    pub fn get(&self, name: &str) -> Value {
        self.values[input_index(name).unwrap_or_else(|| panic!("'{name}' is no RTDE input"))]
    }

    /// Sets input `name` (a stand-in's own tests drive its program this way); panics on a name
    /// the guide does not have or a value of another type.
    pub fn set(&mut self, name: &str, value: Value) {
        let i = input_index(name).unwrap_or_else(|| panic!("'{name}' is no RTDE input"));
        assert_eq!(inputs()[i].data_type, value.data_type(), "{name}");
        self.values[i] = value;
    }
}

/// What a stand-in tells its clients about itself.
#[derive(Clone, Debug)]
pub struct ControllerInfo {
    pub version: ControllerVersion,
    /// Control cycles per second: how often [`RtdeServer::publish`] is called.
    pub cycle_hz: f64,
    /// The source of its text messages.
    pub source: String,
}

/// What the stand-in allows its clients.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Clients at once; one more is closed at once (a UR controller serves a handful).
    pub max_clients: usize,
    /// How long a client that has not started its stream may stay silent.
    pub idle: Duration,
}

impl Default for Limits {
    fn default() -> Self {
        Self { max_clients: 16, idle: Duration::from_secs(30) }
    }
}

/// Events kept between two [`RtdeServer::take_events`]; older ones give way.
pub const MAX_EVENTS: usize = 1000;

struct Shared {
    info: ControllerInfo,
    limits: Limits,
    /// Sessions accepted and not yet closed.
    active: std::sync::atomic::AtomicUsize,
    inputs: Mutex<InputState>,
    sessions: Mutex<Vec<SessionHandle>>,
    events: Mutex<Vec<String>>,
    stop: AtomicBool,
    next_session: AtomicU64,
}

struct SessionHandle {
    id: u64,
    writer: Arc<Mutex<TcpStream>>,
    /// The streamer's channel while the session is started.
    stream: Option<Sender<Arc<OutputState>>>,
}

/// A listening stand-in controller.
pub struct RtdeServer {
    shared: Arc<Shared>,
    address: SocketAddr,
    accept: Option<JoinHandle<()>>,
}

impl RtdeServer {
    /// Listens on `address` (e.g. `127.0.0.1:30004`; port 0 picks a free one).
    pub fn bind(address: &str, info: ControllerInfo) -> Result<Self, RtdeError> {
        Self::bind_with(address, info, Limits::default())
    }

    /// [`RtdeServer::bind`] with other [`Limits`].
    pub fn bind_with(address: &str, info: ControllerInfo, limits: Limits) -> Result<Self, RtdeError> {
        let listener =
            TcpListener::bind(address).map_err(|error| RtdeError::Listen { address: address.to_string(), error })?;
        let local = listener.local_addr()?;
        listener.set_nonblocking(true)?;
        let shared = Arc::new(Shared {
            info,
            limits,
            active: std::sync::atomic::AtomicUsize::new(0),
            inputs: Mutex::new(InputState::new()),
            sessions: Mutex::new(Vec::new()),
            events: Mutex::new(Vec::new()),
            stop: AtomicBool::new(false),
            next_session: AtomicU64::new(1),
        });
        let accept_shared = shared.clone();
        let accept = std::thread::Builder::new()
            .name("rtde-accept".into())
            .spawn(move || accept_loop(listener, accept_shared))?;
        Ok(Self { shared, address: local, accept: Some(accept) })
    }

    pub fn local_addr(&self) -> SocketAddr {
        self.address
    }

    /// The inputs as clients have set them.
    pub fn inputs(&self) -> InputState {
        lock(&self.shared.inputs).clone()
    }

    /// One control cycle's outputs: each started client gets them if its frequency is due.
    /// A client whose streamer is four cycles behind misses this one (as a busy controller
    /// skips packages).
    pub fn publish(&self, state: Arc<OutputState>) {
        for session in lock(&self.shared.sessions).iter() {
            if let Some(tx) = &session.stream {
                let _ = tx.try_send(state.clone());
            }
        }
    }

    /// A text message to every client.
    pub fn broadcast(&self, level: MessageLevel, message: &str) {
        let text = TextMessage { level, message: message.to_string(), source: self.shared.info.source.clone() };
        let Ok(bytes) = Package::new(kind::TEXT_MESSAGE, text.encode()).encode() else { return };
        for session in lock(&self.shared.sessions).iter() {
            let _ = lock(&session.writer).write_all(&bytes);
        }
    }

    /// Clients connected now.
    pub fn clients(&self) -> usize {
        lock(&self.shared.sessions).len()
    }

    /// What happened since the last call: connections, refusals, client messages.
    pub fn take_events(&self) -> Vec<String> {
        std::mem::take(&mut *lock(&self.shared.events))
    }

    /// Stops accepting and closes every session.
    pub fn shutdown(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        for session in lock(&self.shared.sessions).iter() {
            let _ = lock(&session.writer).shutdown(Shutdown::Both);
        }
        if let Some(accept) = self.accept.take() {
            let _ = accept.join();
        }
    }
}

impl Drop for RtdeServer {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// Keeps an event, the oldest giving way past [`MAX_EVENTS`] (a hostile client must not grow
/// the list without bound).
fn push_event(shared: &Shared, event: String) {
    let mut events = lock(&shared.events);
    if events.len() >= MAX_EVENTS {
        events.drain(..MAX_EVENTS / 10);
    }
    events.push(event);
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

fn accept_loop(listener: TcpListener, shared: Arc<Shared>) {
    while !shared.stop.load(Ordering::SeqCst) {
        match listener.accept() {
            Ok((stream, peer)) => {
                if shared.active.load(Ordering::SeqCst) >= shared.limits.max_clients {
                    push_event(
                        &shared,
                        format!("{peer}: refused ({} clients connected already)", shared.limits.max_clients),
                    );
                    let _ = stream.shutdown(Shutdown::Both);
                    continue;
                }
                shared.active.fetch_add(1, Ordering::SeqCst);
                let session_shared = shared.clone();
                let spawned = std::thread::Builder::new()
                    .name(format!("rtde-{peer}"))
                    .spawn(move || Session::run(stream, peer, session_shared));
                if spawned.is_err() {
                    shared.active.fetch_sub(1, Ordering::SeqCst);
                }
            }
            // Nothing to accept (or a failed accept): look again shortly, so `stop` is seen.
            Err(_) => std::thread::sleep(Duration::from_millis(5)),
        }
    }
}
