//! twinbots_sim: the simulated world of a robot cell.
//!
//! Arenas (independent environment instances, each its own rapier world), fixed-step physics,
//! the URDF loader, motors and sensors, and the privileged [`Supervisor`]. One `App::update` is
//! one control step; see [`SimSet`] for the order of a step.

pub mod arena;
pub mod devices;
pub mod physics;
pub mod spawn;
pub mod supervisor;
pub mod urdf;

pub use bevy_rapier3d::rapier;

use bevy::prelude::*;

pub use arena::{Arena, ArenaConfig, InArena};
pub use devices::{
    Accelerometer, BROADCAST, CameraSensor, DistanceSensor, Emitter, Gps, Gyro, InertialUnit, Joint, JointState, Motor,
    MotorCommand, Mount, Packet, PositionSensor, Receiver, SamplingPeriod, TouchSensor, VacuumGripper,
};
pub use physics::{PhysicsSubstep, SimClock, SimSettings, SubstepSet};
pub use spawn::{Link, Robot, SpawnOptions, SpawnedRobot, Visuals, spawn_robot};
pub use supervisor::{LinkState, Operator, OperatorAccess, Supervisor, SupervisorAccess};

/// The order of one control step, in `Update`. Nothing in these sets runs on the first update,
/// which only builds the world.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub enum SimSet {
    /// Radio packets sent during the previous control step are delivered.
    Radio,
    /// Actions become motor commands.
    Actuate,
    /// `substeps` physics steps.
    Physics,
    /// Sensors sample the new state.
    Sense,
    /// Tasks compute observations, rewards and episode ends.
    Task,
    /// Finished episodes are reset.
    Reset,
}

/// Physics stepping, arenas and devices.
pub struct SimPlugin {
    pub settings: SimSettings,
    /// Whether systems may use the [`Supervisor`] (false under design pattern 3).
    pub supervisor: bool,
}

impl Default for SimPlugin {
    fn default() -> Self {
        Self { settings: SimSettings::default(), supervisor: true }
    }
}

impl Plugin for SimPlugin {
    fn build(&self, app: &mut App) {
        if self.supervisor {
            app.init_resource::<SupervisorAccess>();
        }
        app.insert_resource(self.settings)
            .init_resource::<ArenaConfig>()
            .init_resource::<SimClock>()
            .configure_sets(
                Update,
                (
                    SimSet::Radio,
                    SimSet::Actuate,
                    SimSet::Physics,
                    SimSet::Sense,
                    SimSet::Task,
                    SimSet::Reset,
                )
                    .chain()
                    .run_if(physics::sim_started),
            )
            .add_systems(Update, devices::deliver_radio.in_set(SimSet::Radio))
            .add_systems(Update, physics::run_substeps.in_set(SimSet::Physics))
            .add_systems(
                Update,
                (
                    devices::sample_position_sensors,
                    devices::sample_distance_sensors,
                    devices::sample_inertial_units,
                    devices::sample_gyros,
                    devices::sample_accelerometers,
                    devices::sample_gps,
                    devices::sample_touch_sensors,
                )
                    .in_set(SimSet::Sense),
            )
            .add_systems(Last, physics::advance_clock);

        let mut substep = Schedule::new(PhysicsSubstep);
        substep.set_executor(bevy::ecs::schedule::SingleThreadedExecutor::new());
        app.add_schedule(substep)
            .configure_sets(
                PhysicsSubstep,
                (SubstepSet::Actuate, SubstepSet::Integrate, SubstepSet::Measure, SubstepSet::Record).chain(),
            )
            .add_systems(
                PhysicsSubstep,
                (
                    (devices::operate_vacuum_grippers, devices::drive_motors).in_set(SubstepSet::Actuate),
                    physics::integrate_arenas.in_set(SubstepSet::Integrate),
                    // The motor's effort reading needs the joint's new position (a torque is cut at a stop).
                    (devices::measure_joints, devices::measure_motor_efforts).chain().in_set(SubstepSet::Measure),
                ),
            );
    }
}
