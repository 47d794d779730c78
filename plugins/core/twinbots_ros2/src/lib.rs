//! The twin on ROS 2, without a ROS install: the messages ([`messages`]) and a DDS node
//! ([`node`]) that publishes a robot's joint states and frames and takes its commands on the
//! topics and types a ROS 2 robot driver uses (docs/ros2.md). What the twin does with them is
//! the application's (`twinbots ros2`).

pub mod messages;
pub mod node;

pub use messages::{Float64MultiArray, JointState, JointTrajectory, JointTrajectoryPoint, TFMessage};
pub use node::{Command, Interface, Ros2Listener, Ros2Node};

/// What can go wrong on the link.
#[derive(Debug, thiserror::Error)]
pub enum Ros2Error {
    #[error("{0}")]
    Domain(String),
    #[error("could not create {0}")]
    Create(String),
    #[error("could not publish on {0}")]
    Publish(String),
    #[error("a message on {0} did not decode")]
    Take(String),
}
