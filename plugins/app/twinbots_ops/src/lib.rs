//! The twin beside a robot: deploy bundles ([`bundle`]), a policy deployed through RTDE with the
//! twin as its shadow ([`deploy`]), a robot followed by its twin ([`monitor`]), the UR
//! controller stand-in ([`ur_sim`]), the twin on ROS 2 ([`ros2`]), the simulated robots of
//! design pattern 3 ([`fleet`]), a robot in the live view ([`live`]), and the clocks they keep
//! ([`pacer`], [`realtime`]).

pub mod bundle;
pub mod deploy;
pub mod fleet;
pub mod linked_arm;
pub mod live;
pub mod monitor;
pub mod pacer;
pub mod realtime;
#[cfg(feature = "ros2")]
pub mod ros2;
pub mod stop_signal;
pub mod ur_sim;
