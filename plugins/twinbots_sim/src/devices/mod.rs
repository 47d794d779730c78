//! Devices: joints and their motors and sensors, as components plus the systems that run them.

mod joint;
mod motor;
mod position_sensor;

pub use joint::{Joint, JointState};
pub use motor::{Motor, MotorCommand};
pub use position_sensor::PositionSensor;

pub(crate) use joint::measure_joints;
pub(crate) use motor::drive_motors;
pub use position_sensor::sample_position_sensors;
