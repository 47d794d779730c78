//! Devices: joints and their motors and sensors, and sensors mounted on links, as components
//! plus the systems that run them (in `SimSet::Sense`, except motors, which act every substep).

mod camera;
mod distance_sensor;
mod inertial;
mod joint;
mod motor;
mod mount;
mod position_sensor;
mod radio;
mod vacuum_gripper;

pub use camera::CameraSensor;
pub use distance_sensor::DistanceSensor;
pub use inertial::{Accelerometer, Gps, Gyro, InertialUnit, TouchSensor};
pub use joint::{Joint, JointState};
pub use motor::{Motor, MotorCommand};
pub use mount::{Mount, MountState, SamplingPeriod, gaussian};
pub use position_sensor::{PositionSensor, sample_position_sensors};
pub use radio::{BROADCAST, Emitter, Packet, Receiver};
pub use vacuum_gripper::VacuumGripper;

pub(crate) use distance_sensor::sample_distance_sensors;
pub(crate) use inertial::{sample_accelerometers, sample_gps, sample_gyros, sample_inertial_units, sample_touch_sensors};
pub(crate) use joint::measure_joints;
pub(crate) use motor::{drive_motors, measure_motor_efforts};
pub(crate) use radio::deliver_radio;
pub(crate) use vacuum_gripper::operate_vacuum_grippers;
