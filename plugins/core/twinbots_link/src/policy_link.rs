//! The far end of a robot's episode protocol, whichever it is: a RobotServer over TCP (the
//! [`Communicator`]) or a policy on board ([`crate::onboard::OnBoardLink`]).

use crate::client::{Communicator, CommunicatorError};
use crate::protocol::{RobotMessage, ServerMessage};

/// The far end of a robot's episode protocol: it hears each step's message and answers as a
/// RobotServer does (an action, an ack after an episode's last step, done, an error).
pub trait PolicyLink: Send + Sync {
    /// Sends a request without waiting for its reply (robots send all theirs first).
    fn send(&mut self, message: &RobotMessage) -> Result<(), CommunicatorError>;
    /// The reply to the last request.
    fn receive(&mut self) -> Result<ServerMessage, CommunicatorError>;
    /// Re-establishes a lost link (the episode then begins afresh from home).
    fn connect(&mut self) -> Result<(), CommunicatorError>;
}

impl PolicyLink for Communicator {
    fn send(&mut self, message: &RobotMessage) -> Result<(), CommunicatorError> {
        Communicator::send(self, message)
    }

    fn receive(&mut self) -> Result<ServerMessage, CommunicatorError> {
        Communicator::receive(self)
    }

    fn connect(&mut self) -> Result<(), CommunicatorError> {
        Communicator::connect(self)
    }
}
