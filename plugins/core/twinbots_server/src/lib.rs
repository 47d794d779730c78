//! twinbots_server: design pattern 3's RobotServer. It hosts the policy and the learner and is
//! reached over TCP by robots' Communicators (`twinbots_link`, which also holds the protocol).
//!
//! [`server`] (accepting, limits, failing loudly), `connection` (one robot's thread), `learner`
//! (the protocol's side of the model: PPO, SAC or TD3 on what robots send), `closing` (a last
//! reply before the socket closes).

mod closing;
mod connection;
mod learner;
pub mod server;
mod shared;
