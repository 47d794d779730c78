//! Devices: joints and their motors and sensors, and sensors mounted on links, as components
//! plus the systems that run them (in `SimSet::Sense`, except motors, which act every substep).

use bevy::prelude::*;

use crate::SimSet;
use crate::physics::{PhysicsSubstep, SubstepSet};

mod camera;
mod contact_sensor;
mod distance_sensor;
mod due;
mod dynamics;
mod inertial;
mod joint;
mod motor;
mod mount;
mod position_sensor;
mod radio;
mod sampling;
mod vacuum_gripper;

pub use camera::{CameraSensor, KeepObservedImages, ObservedImage};
pub use contact_sensor::{ContactSensor, Touched};
pub use distance_sensor::DistanceSensor;
pub use dynamics::{FRICTION_SMOOTHING, JointDynamics, set_armature};
pub use inertial::{Accelerometer, Gps, Gyro, InertialUnit, TouchSensor};
pub(crate) use joint::stop_window;
pub use joint::{Joint, JointState};
pub use motor::{Motor, MotorCommand};
pub use mount::{Mount, MountState, SamplingPeriod, gaussian};
pub use position_sensor::PositionSensor;
pub use radio::{BROADCAST, Emitter, Packet, RadioPlugin, Receiver};
pub use sampling::{DeviceSampling, sample_devices};
pub use vacuum_gripper::VacuumGripper;

/// Motors, grippers, joint stops and joint measurement in every physics step; sensors in `SimSet::Sense`.
pub struct DevicesPlugin;

impl Plugin for DevicesPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(Update, sample_devices().in_set(SimSet::Sense)).add_systems(
            PhysicsSubstep,
            (
                (
                    vacuum_gripper::operate_vacuum_grippers,
                    motor::drive_motors,
                    dynamics::apply_joint_dynamics,
                    joint::place_stops,
                )
                    .in_set(SubstepSet::Actuate),
                // The motor's effort reading needs the joint's new position (a torque is cut at a stop).
                (joint::measure_joints, motor::measure_motor_efforts).chain().in_set(SubstepSet::Measure),
            ),
        );
    }
}
