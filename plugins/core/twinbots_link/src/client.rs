//! The robot's end of the RobotServer protocol: the Communicator device's connection. It
//! introduces itself, exchanges one request and reply per control step, and when the server
//! goes away it reconnects with exponential backoff.

use std::io::{BufReader, BufWriter};
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

use twinbots_api::Space;

use crate::frame::{FrameError, read_message, write_message};
use crate::protocol::{ErrorCode, RobotMessage, ServerMessage, TaskInterface, VERSION};

#[derive(Debug, thiserror::Error)]
pub enum CommunicatorError {
    #[error("lost the server at {0}")]
    Disconnected(SocketAddr),
    #[error("no server at {addr} after trying for {waited:?}")]
    Unreachable { addr: SocketAddr, waited: Duration },
    #[error("the server refused: {0}")]
    Refused(String),
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
    /// How long to keep trying to (re)connect before giving up.
    pub patience: Duration,
    link: Option<(BufReader<TcpStream>, BufWriter<TcpStream>)>,
    pub robot_id: Option<u64>,
    /// What the server expects of this robot (its `welcome`).
    pub task: Option<TaskInterface>,
    /// Reconnections after the first connection.
    pub reconnects: u32,
}

impl Communicator {
    pub fn new(addr: SocketAddr, identity: Identity, patience: Duration) -> Self {
        Self { addr, identity, patience, link: None, robot_id: None, task: None, reconnects: 0 }
    }

    pub fn is_connected(&self) -> bool {
        self.link.is_some()
    }

    /// Connects (or reconnects) and says hello, retrying with backoff from 20 ms doubling to
    /// 1 s until `patience` runs out.
    pub fn connect(&mut self) -> Result<(), CommunicatorError> {
        let started = Instant::now();
        let mut delay = Duration::from_millis(20);
        loop {
            match self.try_connect() {
                Ok(()) => {
                    if self.robot_id.is_some() {
                        self.reconnects += 1;
                    }
                    return Ok(());
                }
                Err(CommunicatorError::Refused(r)) => return Err(CommunicatorError::Refused(r)),
                Err(_) if started.elapsed() + delay < self.patience => {
                    std::thread::sleep(delay);
                    delay = (delay * 2).min(Duration::from_secs(1));
                }
                Err(_) => return Err(CommunicatorError::Unreachable { addr: self.addr, waited: started.elapsed() }),
            }
        }
    }

    fn try_connect(&mut self) -> Result<(), CommunicatorError> {
        let gone = |_| CommunicatorError::Disconnected(self.addr);
        let stream = TcpStream::connect_timeout(&self.addr, Duration::from_secs(1)).map_err(gone)?;
        let _ = stream.set_nodelay(true);
        let mut reader = BufReader::new(stream.try_clone().map_err(gone)?);
        let mut writer = BufWriter::new(stream);
        let hello = RobotMessage::Hello {
            version: VERSION,
            robot: self.identity.robot.clone(),
            observation_space: self.identity.observation_space.clone(),
            action_space: self.identity.action_space.clone(),
            token: self.identity.token.clone(),
        };
        write_message(&mut writer, &hello).map_err(gone)?;
        match read_message::<ServerMessage>(&mut reader) {
            Ok(ServerMessage::Welcome { robot_id, task, .. }) => {
                self.robot_id = Some(robot_id);
                self.task = Some(task);
                self.link = Some((reader, writer));
                Ok(())
            }
            // A full or busy server may have room later: keep trying within the patience.
            Ok(ServerMessage::Error { code: ErrorCode::ServerFull | ErrorCode::Unavailable, .. }) => Err(CommunicatorError::Disconnected(self.addr)),
            Ok(ServerMessage::Error { message, .. }) => Err(CommunicatorError::Refused(message)),
            Ok(other) => Err(CommunicatorError::Refused(format!("unexpected reply to hello: {other:?}"))),
            Err(_) => Err(CommunicatorError::Disconnected(self.addr)),
        }
    }

    /// Sends a request without waiting (pair with [`Communicator::receive`]; lets one robot
    /// process keep several requests in flight).
    pub fn send(&mut self, message: &RobotMessage) -> Result<(), CommunicatorError> {
        let addr = self.addr;
        let (_, writer) = self.link.as_mut().ok_or(CommunicatorError::Disconnected(addr))?;
        if write_message(writer, message).is_err() {
            self.link = None;
            return Err(CommunicatorError::Disconnected(addr));
        }
        Ok(())
    }

    /// Waits for the reply to the last request.
    pub fn receive(&mut self) -> Result<ServerMessage, CommunicatorError> {
        let addr = self.addr;
        let (reader, _) = self.link.as_mut().ok_or(CommunicatorError::Disconnected(addr))?;
        match read_message::<ServerMessage>(reader) {
            Ok(m) => Ok(m),
            Err(FrameError::Io(_)) => {
                self.link = None;
                Err(CommunicatorError::Disconnected(addr))
            }
            Err(e) => Err(CommunicatorError::Refused(format!("unreadable reply: {e}"))),
        }
    }

    /// Leaves politely.
    pub fn bye(&mut self) {
        let _ = self.send(&RobotMessage::Bye);
        self.link = None;
    }
}
