//! twinbots_server: design pattern 3. The [`server::RobotServer`] hosts the policy and the
//! learner and is reached over TCP; [`client::Communicator`] is the robot's end, and
//! [`robot::Conversation`] its side of the episode protocol; [`onboard`] answers that protocol
//! from a policy the robot runs itself (no server).

pub mod client;
pub mod onboard;
pub mod protocol;
pub mod robot;
pub mod server;
