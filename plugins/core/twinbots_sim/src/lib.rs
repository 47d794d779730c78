//! twinbots_sim: the simulated world of a robot cell.
//!
//! Arenas (independent environment instances, each its own rapier world), fixed-step physics,
//! the URDF loader, motors and sensors, and the privileged [`Supervisor`]. One `App::update` is
//! one control step; see [`SimSet`] for the order of a step.

pub mod arena;
pub mod devices;
pub mod disturbance;
pub mod framing;
pub mod look;
pub mod marker;
pub mod parameters;
pub mod physics;
pub mod privilege;
pub mod robot;
pub mod spawn;
pub mod supervisor;
pub mod urdf;

pub use bevy_rapier3d::rapier;

pub use arena::{Arena, ArenaConfig, InArena, physics_in, physics_in_mut};
pub use devices::{
    Accelerometer, BROADCAST, CameraSensor, ContactSensor, DevicesPlugin, DistanceSensor, Emitter, Gps, Gyro,
    InertialUnit, Joint, JointDynamics, JointState, KeepObservedImages, Motor, MotorCommand, Mount, ObservedImage,
    Packet, PositionSensor, RadioPlugin, Receiver, SamplingPeriod, TouchSensor, Touched, VacuumGripper,
};
pub use disturbance::{Push, add_link_mass};
pub use framing::Framing;
pub use look::Look;
pub use marker::Marker;
pub use parameters::{ParameterKind, ParameterSpec, Parameters, ParametersPlugin};
pub use physics::{PhysicsPlugin, PhysicsSubstep, SimClock, SimSettings, SubstepSet};
pub use robot::{Link, Robot, Visuals};
pub use spawn::{SpawnOptions, SpawnedRobot, spawn_robot};
pub use supervisor::{Handled, LinkState, Operator, OperatorAccess, Supervisor, SupervisorAccess, SupervisorPlugin};

use bevy::app::PluginGroupBuilder;
use bevy::prelude::*;

/// The order of one control step, in `Update`. Nothing in these sets runs on the first update,
/// which only builds the world.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub enum SimSet {
    /// Radio packets sent during the previous control step are delivered.
    Radio,
    /// The step's actions are processed before anything applies them (Isaac Lab's
    /// `process_action`): domain randomisation replaces or delays them here. After `Radio`, so
    /// the actions a supervisor robot radios (design pattern 2) are the processed ones.
    ProcessActions,
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

/// The simulation as Bevy plugins: [`PhysicsPlugin`] (arenas, the control step, fixed-step
/// physics), [`DevicesPlugin`] (motors and sensors), [`ParametersPlugin`] (a calibration's
/// joint dynamics), [`RadioPlugin`] (emitters and receivers)
/// and [`SupervisorPlugin`] (privileged access). Design pattern 3 apps go without the
/// Supervisor: `SimPlugins { supervisor: false, .. }`, or
/// `SimPlugins::default().build().disable::<SupervisorPlugin>()`.
#[derive(Clone, Copy, Debug)]
pub struct SimPlugins {
    pub settings: SimSettings,
    /// Whether systems may use the [`Supervisor`] (false under design pattern 3).
    pub supervisor: bool,
}

/// The name robot plugins build the simulation with: `SimPlugin { settings, supervisor }` is
/// the [`SimPlugins`] group.
pub type SimPlugin = SimPlugins;

impl Default for SimPlugins {
    fn default() -> Self {
        Self { settings: SimSettings::default(), supervisor: true }
    }
}

impl PluginGroup for SimPlugins {
    fn build(self) -> PluginGroupBuilder {
        let group = PluginGroupBuilder::start::<Self>()
            .add(PhysicsPlugin { settings: self.settings })
            .add(DevicesPlugin)
            .add(ParametersPlugin)
            .add(RadioPlugin)
            .add(SupervisorPlugin);
        if self.supervisor { group } else { group.disable::<SupervisorPlugin>() }
    }
}
