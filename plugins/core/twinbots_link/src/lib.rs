//! twinbots_link: the robot's end of design pattern 3 (no learner, no candle).
//!
//! [`client::Communicator`] is the robot's device that talks to a RobotServer, and
//! [`robot::Conversation`] its side of the episode protocol; [`onboard`] answers that protocol
//! from a policy the robot runs itself (no server). The wire: [`protocol`] (messages, version
//! 2), [`frame`] (length-prefixed JSON), [`checks`] (what is refused at the boundary), and
//! [`deadline`] (reads and writes that give up in time), and [`tls`] (the stream, plain or
//! encrypted).

pub mod audit;
pub mod checks;
pub mod client;
pub mod deadline;
pub mod frame;
pub mod onboard;
pub mod policy_link;
pub mod protocol;
pub mod robot;
pub mod tls;
pub mod token;
