//! The robot's end of the RobotServer protocol: the Communicator device's connection. It
//! introduces itself, exchanges one request and reply per control step, and when the server
//! goes away it reconnects with exponential backoff.
//!
//! One bound on every wait, the `patience`: a reply (the `welcome` too) that does not come within
//! it, a send the server does not take within it, and reconnections that get no request answered
//! within it each stop the robot with the reason. Reconnections back off (20 ms doubling to 1 s)
//! until a request is answered, so a server that welcomes and closes sees about one connection a
//! second, not thousands. The server's replies are checked: its protocol version, robot and
//! spaces in `welcome`, and every action against the robot's action space.

use std::io::{self, BufReader};
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

use twinbots_api::Space;

use crate::checks::{MAX_SERVER_TEXT, check_action, check_welcome, truncated};
use crate::deadline::DeadlineStream;
use crate::frame::{FrameError, read_frame, read_message, write_message};
use crate::protocol::{ErrorCode, RobotMessage, ServerMessage, TaskInterface, VERSION};
use crate::tls::{ClientTls, Transport, is_tls_refusal};

/// The first pause between reconnections, and the longest.
const FIRST_BACKOFF: Duration = Duration::from_millis(20);
const MAX_BACKOFF: Duration = Duration::from_secs(1);

#[derive(Debug, thiserror::Error)]
pub enum CommunicatorError {
    #[error("lost the server at {0}")]
    Disconnected(SocketAddr),
    #[error("no server at {addr} after trying for {waited:.1?}")]
    Unreachable { addr: SocketAddr, waited: Duration },
    #[error("the server refused: {0}")]
    Refused(String),
    /// Reached, but it did not answer (or take what was sent) in time.
    #[error("the server at {addr} sent no {what} within {waited:.1?} (--patience)")]
    Silent { addr: SocketAddr, what: &'static str, waited: Duration },
    /// Reached, but what it sent is not this protocol, or not for this robot.
    #[error("the server at {addr} broke the protocol: {problem}")]
    Protocol { addr: SocketAddr, problem: String },
    /// TLS refused the server (a certificate this robot does not trust, a server without TLS).
    #[error("TLS with the server at {addr} failed: {problem}")]
    Tls { addr: SocketAddr, problem: String },
    /// It keeps taking connections and dropping them before answering a request.
    #[error(
        "the server at {addr} took {connections} connections in {waited:.1?} but answered no request on them (it closes them)"
    )]
    Unresponsive { addr: SocketAddr, connections: u32, waited: Duration },
    /// It takes connections and closes them before any `welcome`: often TLS on one side only.
    #[error(
        "the server at {addr} closed {connections} connections in {waited:.1?} before its welcome (does it speak TLS? `--tls-ca` must match how it serves)"
    )]
    Unwelcoming { addr: SocketAddr, connections: u32, waited: Duration },
}

/// Who this robot is, for the `hello` message.
#[derive(Clone, Debug)]
pub struct Identity {
    pub robot: String,
    pub observation_space: Space,
    pub action_space: Space,
    /// The server's shared secret, if it wants one (`serve --token`).
    pub token: Option<String>,
}

/// The Communicator: a persistent connection to a RobotServer.
pub struct Communicator {
    addr: SocketAddr,
    identity: Identity,
    /// The longest wait: for a reply, for a send, and for a connection that answers.
    pub patience: Duration,
    /// Replies are read through the buffer; requests are written whole to the stream under it.
    link: Option<BufReader<DeadlineStream>>,
    /// TLS to speak, and the name the server's certificate must bear (`None`: plain TCP).
    tls: Option<(ClientTls, rustls::pki_types::ServerName<'static>)>,
    pub robot_id: Option<u64>,
    /// What the server expects of this robot (its `welcome`).
    pub task: Option<TaskInterface>,
    /// Reconnections after the first connection.
    pub reconnects: u32,
    /// Since when, over how many connections and welcomes, no request has been answered
    /// (`None` once one is).
    unanswered: Option<(Instant, u32, u32)>,
    /// The pause before the next connection attempt (`None`: connect at once).
    backoff: Option<Duration>,
}

impl Communicator {
    pub fn new(addr: SocketAddr, identity: Identity, patience: Duration) -> Self {
        Self {
            addr,
            identity,
            patience,
            link: None,
            tls: None,
            robot_id: None,
            task: None,
            reconnects: 0,
            unanswered: None,
            backoff: None,
        }
    }

    /// Speaks TLS, trusting `tls`'s authorities for a certificate that bears `name`.
    pub fn with_tls(mut self, tls: ClientTls, name: rustls::pki_types::ServerName<'static>) -> Self {
        self.tls = Some((tls, name));
        self
    }

    pub fn is_connected(&self) -> bool {
        self.link.is_some()
    }

    /// Connects (or reconnects) and says hello, retrying with backoff until a connection is
    /// welcomed, or `patience` has passed since the last answered request (or since the
    /// first attempt).
    pub fn connect(&mut self) -> Result<(), CommunicatorError> {
        let (since, _, _) = *self.unanswered.get_or_insert((Instant::now(), 0, 0));
        loop {
            if let Some(pause) = self.backoff {
                if since.elapsed() + pause >= self.patience {
                    return Err(self.gave_up(since.elapsed()));
                }
                std::thread::sleep(pause);
            }
            self.backoff = Some(self.backoff.map_or(FIRST_BACKOFF, |b| (b * 2).min(MAX_BACKOFF)));
            match self.try_connect() {
                Ok(()) => {
                    if self.robot_id.is_some() {
                        self.reconnects += 1;
                    }
                    return Ok(());
                }
                Err(CommunicatorError::Disconnected(_)) => {}
                Err(fatal) => return Err(fatal),
            }
        }
    }

    /// Why the connection attempts ended.
    fn gave_up(&self, waited: Duration) -> CommunicatorError {
        match self.unanswered {
            Some((_, connections, 0)) if connections > 0 => {
                CommunicatorError::Unwelcoming { addr: self.addr, connections, waited }
            }
            Some((_, connections, _)) if connections > 0 => {
                CommunicatorError::Unresponsive { addr: self.addr, connections, waited }
            }
            _ => CommunicatorError::Unreachable { addr: self.addr, waited },
        }
    }

    fn try_connect(&mut self) -> Result<(), CommunicatorError> {
        let gone = |_| CommunicatorError::Disconnected(self.addr);
        let timeout = self.patience.clamp(Duration::from_millis(1), Duration::from_secs(1));
        let stream = TcpStream::connect_timeout(&self.addr, timeout).map_err(gone)?;
        let _ = stream.set_nodelay(true);
        stream.set_write_timeout(Some(self.patience.max(Duration::from_millis(1)))).map_err(gone)?;
        if let Some((_, connections, _)) = &mut self.unanswered {
            *connections += 1;
        }
        let tls = self.tls.as_ref().map(|(tls, name)| (tls, name.clone()));
        let mut link = BufReader::new(DeadlineStream::new(Transport::connect(stream, tls).map_err(gone)?));
        let hello = RobotMessage::Hello {
            version: VERSION,
            robot: self.identity.robot.clone(),
            observation_space: self.identity.observation_space.clone(),
            action_space: self.identity.action_space.clone(),
            token: self.identity.token.clone(),
        };
        // Under TLS the handshake happens here, within the patience (the write's and read's).
        link.get_mut().expire_in(self.patience);
        write_message(link.get_mut(), &hello).map_err(|e| self.send_failed(e))?;
        let payload = read_frame(&mut link).map_err(|e| self.read_failed(e, "welcome"))?;
        let id = &self.identity;
        let welcome = check_welcome(&payload, &id.robot, &id.observation_space, &id.action_space)
            .map_err(|problem| CommunicatorError::Protocol { addr: self.addr, problem })?;
        match welcome {
            ServerMessage::Welcome { robot_id, task, .. } => {
                if let Some((_, _, welcomes)) = &mut self.unanswered {
                    *welcomes += 1;
                }
                self.robot_id = Some(robot_id);
                self.task = Some(task);
                self.link = Some(link);
                Ok(())
            }
            // A full or busy server may have room later: keep trying within the patience.
            ServerMessage::Error { code: ErrorCode::ServerFull | ErrorCode::Unavailable, .. } => {
                Err(CommunicatorError::Disconnected(self.addr))
            }
            ServerMessage::Error { message, .. } => {
                Err(CommunicatorError::Refused(truncated(&message, MAX_SERVER_TEXT)))
            }
            other => unreachable!("check_welcome passes a welcome or an error only, not {other:?}"),
        }
    }

    /// A send that failed: the server is gone, or took nothing within the patience.
    fn send_failed(&self, e: io::Error) -> CommunicatorError {
        if is_tls_refusal(&e) {
            return CommunicatorError::Tls { addr: self.addr, problem: e.to_string() };
        }
        match e.kind() {
            io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut => CommunicatorError::Silent {
                addr: self.addr,
                what: "room for a request (it reads nothing)",
                waited: self.patience,
            },
            _ => CommunicatorError::Disconnected(self.addr),
        }
    }

    /// A reply that could not be read: gone (reconnect), silent, or not a frame of this protocol.
    fn read_failed(&self, e: FrameError, what: &'static str) -> CommunicatorError {
        match e {
            FrameError::Io(e) if is_tls_refusal(&e) => {
                CommunicatorError::Tls { addr: self.addr, problem: e.to_string() }
            }
            FrameError::Io(_) => CommunicatorError::Disconnected(self.addr),
            FrameError::TimedOut => CommunicatorError::Silent { addr: self.addr, what, waited: self.patience },
            other => CommunicatorError::Protocol { addr: self.addr, problem: format!("unreadable {what}: {other}") },
        }
    }

    /// Sends a request without waiting (pair with [`Communicator::receive`]; lets one robot
    /// process keep several requests in flight).
    pub fn send(&mut self, message: &RobotMessage) -> Result<(), CommunicatorError> {
        let addr = self.addr;
        let link = self.link.as_mut().ok_or(CommunicatorError::Disconnected(addr))?;
        if let Err(e) = write_message(link.get_mut(), message) {
            self.link = None;
            return Err(self.send_failed(e));
        }
        Ok(())
    }

    /// Waits (up to the patience) for the reply to the last request; an action is checked
    /// against the robot's action space.
    pub fn receive(&mut self) -> Result<ServerMessage, CommunicatorError> {
        let addr = self.addr;
        let link = self.link.as_mut().ok_or(CommunicatorError::Disconnected(addr))?;
        link.get_mut().expire_in(self.patience);
        let reply = match read_message::<ServerMessage>(link) {
            Ok(reply) => reply,
            Err(e) => {
                self.link = None;
                return Err(self.read_failed(e, "reply"));
            }
        };
        if let ServerMessage::Action { action } = &reply {
            check_action(action, &self.identity.action_space)
                .map_err(|problem| CommunicatorError::Protocol { addr, problem })?;
        }
        // An answered request: the connection works, so a later loss reconnects at once.
        self.unanswered = None;
        self.backoff = None;
        Ok(reply)
    }

    /// Leaves politely.
    pub fn bye(&mut self) {
        let _ = self.send(&RobotMessage::Bye);
        self.link = None;
    }
}
