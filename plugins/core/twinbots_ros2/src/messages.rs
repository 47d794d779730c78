//! The ROS 2 messages the link speaks, field for field as their `.msg` files define them (ROS 2
//! Jazzy; the same in Humble): serde structs that ros2-client writes as CDR, the encoding every
//! ROS 2 middleware puts on the wire. A DDS peer finds them by [`Ros2Type::dds_name`].

use ros2_client::Message;
use serde::{Deserialize, Serialize};

/// A ROS 2 message type: its package and name (`sensor_msgs`, `JointState`).
pub trait Ros2Type {
    const PACKAGE: &'static str;
    const NAME: &'static str;

    /// The type name on the DDS wire (`sensor_msgs::msg::dds_::JointState_`), as rmw writes it.
    fn dds_name() -> String {
        format!("{}::msg::dds_::{}_", Self::PACKAGE, Self::NAME)
    }
}

macro_rules! ros2_type {
    ($t:ty, $package:literal, $name:literal) => {
        impl Message for $t {}
        impl Ros2Type for $t {
            const PACKAGE: &'static str = $package;
            const NAME: &'static str = $name;
        }
    };
}

/// `builtin_interfaces/msg/Time`: since the Unix epoch.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// The time `seconds` after the epoch (to the nanosecond; negative times are before it).
    pub fn from_seconds(seconds: f64) -> Self {
        let sec = seconds.floor();
        let nanosec = (((seconds - sec) * 1e9).round() as u32).min(999_999_999);
        Self { sec: sec as i32, nanosec }
    }

    pub fn seconds(self) -> f64 {
        self.sec as f64 + self.nanosec as f64 * 1e-9
    }

    /// The wall clock now, as `std_msgs/Header` stamps it.
    pub fn now() -> Self {
        let since = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
        Self { sec: since.as_secs() as i32, nanosec: since.subsec_nanos() }
    }
}

/// `builtin_interfaces/msg/Duration`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Duration {
    pub sec: i32,
    pub nanosec: u32,
}

impl Duration {
    pub fn seconds(self) -> f64 {
        self.sec as f64 + self.nanosec as f64 * 1e-9
    }

    pub fn from_seconds(seconds: f64) -> Self {
        let t = Time::from_seconds(seconds);
        Self { sec: t.sec, nanosec: t.nanosec }
    }
}

/// `std_msgs/msg/Header`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

/// `sensor_msgs/msg/JointState`: positions (rad or m), velocities (rad/s or m/s), efforts
/// (N·m or N), one entry per name.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    pub header: Header,
    pub name: Vec<String>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    pub effort: Vec<f64>,
}
ros2_type!(JointState, "sensor_msgs", "JointState");

/// `geometry_msgs/msg/Vector3`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion` (x, y, z, w).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

/// `geometry_msgs/msg/Transform`: the child frame in the parent's (m; a unit quaternion).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    pub translation: Vector3,
    pub rotation: Quaternion,
}

/// `geometry_msgs/msg/TransformStamped`: `header.frame_id` is the parent frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub transform: Transform,
}

/// `tf2_msgs/msg/TFMessage`: what `/tf` and `/tf_static` carry.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TFMessage {
    pub transforms: Vec<TransformStamped>,
}
ros2_type!(TFMessage, "tf2_msgs", "TFMessage");

/// `std_msgs/msg/MultiArrayDimension`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MultiArrayDimension {
    pub label: String,
    pub size: u32,
    pub stride: u32,
}

/// `std_msgs/msg/MultiArrayLayout`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MultiArrayLayout {
    pub dim: Vec<MultiArrayDimension>,
    pub data_offset: u32,
}

/// `std_msgs/msg/Float64MultiArray`: what ros2_control's forward command controllers take,
/// one value per joint in the controller's joint order.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Float64MultiArray {
    pub layout: MultiArrayLayout,
    pub data: Vec<f64>,
}
ros2_type!(Float64MultiArray, "std_msgs", "Float64MultiArray");

impl Float64MultiArray {
    /// A flat array, as `ros2 topic pub` writes one (an empty layout).
    pub fn of(data: Vec<f64>) -> Self {
        Self { layout: MultiArrayLayout::default(), data }
    }
}

/// `trajectory_msgs/msg/JointTrajectoryPoint`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointTrajectoryPoint {
    pub positions: Vec<f64>,
    pub velocities: Vec<f64>,
    pub accelerations: Vec<f64>,
    pub effort: Vec<f64>,
    pub time_from_start: Duration,
}

/// `trajectory_msgs/msg/JointTrajectory`: what ros2_control's joint trajectory controller takes.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointTrajectory {
    pub header: Header,
    pub joint_names: Vec<String>,
    pub points: Vec<JointTrajectoryPoint>,
}
ros2_type!(JointTrajectory, "trajectory_msgs", "JointTrajectory");

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dds_type_names_are_rmws() {
        assert_eq!(JointState::dds_name(), "sensor_msgs::msg::dds_::JointState_");
        assert_eq!(TFMessage::dds_name(), "tf2_msgs::msg::dds_::TFMessage_");
        assert_eq!(Float64MultiArray::dds_name(), "std_msgs::msg::dds_::Float64MultiArray_");
        assert_eq!(JointTrajectory::dds_name(), "trajectory_msgs::msg::dds_::JointTrajectory_");
    }

    #[test]
    fn times_round_trip_to_the_nanosecond() {
        for s in [0.0, 1.5, 1_764_000_000.123_456_7, -0.25] {
            let t = Time::from_seconds(s);
            assert!(t.nanosec < 1_000_000_000);
            assert!((t.seconds() - s).abs() < 1e-6, "{s} -> {t:?}");
        }
        assert_eq!(Time::from_seconds(-0.25), Time { sec: -1, nanosec: 750_000_000 });
    }
}
