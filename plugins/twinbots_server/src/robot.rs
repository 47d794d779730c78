//! A design-pattern-3 robot's side of the episode protocol, shared by every robot plugin: it
//! homes (with its own motors, nothing said to the server), starts an episode once home,
//! reports each step's outcome and applies the action it gets back, and after an episode's
//! last step goes home again. A lost server is reconnected with backoff and the episode
//! begins afresh from home.

use std::net::SocketAddr;
use std::time::Duration;

use bevy::prelude::*;

use crate::client::{Communicator, CommunicatorError, Identity};
use crate::protocol::{RobotMessage, ServerMessage};

/// Where the RobotServer is, and how long a robot keeps trying to reach it.
#[derive(Resource, Clone, Copy, Debug)]
pub struct ServerAddress {
    pub addr: SocketAddr,
    pub patience: Duration,
}

/// Set when the robots should stop: `Ok(reason)` when the server finished training.
#[derive(Resource, Clone, Debug, Default)]
pub struct RobotRunState {
    pub stop: Option<Result<String, String>>,
    /// Episodes the robots finished, and reconnections they made.
    pub episodes: u64,
    pub reconnects: u32,
}

/// Where a robot is in its episode cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Returning to its start state with its own motors; the server hears nothing.
    Homing,
    /// Home: this step announces a new episode.
    Starting,
    Running,
}

/// One robot's conversation with the RobotServer.
pub struct Conversation {
    communicator: Communicator,
    pub phase: Phase,
    awaiting_reply: bool,
}

impl Conversation {
    /// Connects (retrying until the address's patience runs out) and begins by homing.
    pub fn connect(address: &ServerAddress, identity: Identity) -> Result<Self, CommunicatorError> {
        let mut communicator = Communicator::new(address.addr, identity, address.patience);
        communicator.connect()?;
        Ok(Self { communicator, phase: Phase::Homing, awaiting_reply: false })
    }

    /// Connects the robot of arena `index`; if it cannot, the robots stop, naming it.
    pub fn connect_robot(address: &ServerAddress, identity: Identity, index: usize, state: &mut RobotRunState) -> Option<Self> {
        Self::connect(address, identity)
            .map_err(|e| state.stop = Some(Err(format!("robot {index}: {e}"))))
            .ok()
    }

    /// Sends this step's message: `start` when starting, the step's outcome when running.
    /// Send every robot's message before receiving any reply, so the server works on all.
    pub fn send(&mut self, message: &RobotMessage, state: &mut RobotRunState) {
        self.awaiting_reply = self.communicator.send(message).is_ok();
        if !self.awaiting_reply {
            self.lost(state);
        }
    }

    /// The reply to this step's message: the action to apply, if the server sent one.
    pub fn receive(&mut self, state: &mut RobotRunState) -> Option<Vec<f32>> {
        if !std::mem::take(&mut self.awaiting_reply) {
            return None;
        }
        match self.communicator.receive() {
            Ok(ServerMessage::Action { action }) => {
                if self.phase == Phase::Starting {
                    self.phase = Phase::Running;
                }
                return Some(action);
            }
            Ok(ServerMessage::Ack) => {
                state.episodes += 1;
                self.phase = Phase::Homing;
            }
            Ok(ServerMessage::Done { reason }) => state.stop = Some(Ok(reason)),
            Ok(ServerMessage::Error { message, fatal: true }) => state.stop = Some(Err(message)),
            Ok(ServerMessage::Error { message, .. }) => warn!("server: {message}"),
            Ok(ServerMessage::Welcome { .. }) => {}
            Err(_) => self.lost(state),
        }
        None
    }

    /// The server went away: reconnect (with backoff) and begin a fresh episode from home.
    fn lost(&mut self, state: &mut RobotRunState) {
        self.phase = Phase::Homing;
        match self.communicator.connect() {
            Ok(()) => state.reconnects += 1,
            Err(e) => state.stop = Some(Err(e.to_string())),
        }
    }
}
