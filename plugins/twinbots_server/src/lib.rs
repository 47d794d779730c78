//! twinbots_server: design pattern 3. The [`server::RobotServer`] hosts the policy and the
//! learner and is reached over TCP; [`client::Communicator`] is the robot's end, and
//! [`robot::Conversation`] its side of the episode protocol; [`onboard`] answers that protocol
//! from a policy the robot runs itself (no server).
//!
//! The wire: [`protocol`] (messages, version 2), [`frame`] (length-prefixed JSON), [`checks`]
//! (what is refused at the boundary). The server's parts: [`server`] (accepting, limits,
//! failing loudly), `connection` (one robot's thread), `learner` (PPO on what robots send).

pub mod checks;
pub mod client;
mod closing;
mod connection;
mod deadline;
pub mod frame;
mod learner;
pub mod onboard;
pub mod protocol;
pub mod robot;
pub mod server;
