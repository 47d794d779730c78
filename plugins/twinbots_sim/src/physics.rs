//! Fixed-step physics: a control step is `substeps` physics steps of `dt` seconds, with motors
//! re-applied before and joint states measured after every physics step.

use bevy::ecs::schedule::{ScheduleLabel, SingleThreadedExecutor};
use bevy::math::Vec3;
use bevy::prelude::*;

use crate::SimSet;
use crate::arena::{Arena, ArenaConfig};

/// Arenas, the order of a control step ([`SimSet`]) and fixed-step physics: `substeps` runs of
/// the [`PhysicsSubstep`] schedule per control step, every arena's world stepped in each.
pub struct PhysicsPlugin {
    pub settings: SimSettings,
}

impl Plugin for PhysicsPlugin {
    fn build(&self, app: &mut App) {
        app.insert_resource(self.settings)
            .init_resource::<ArenaConfig>()
            .init_resource::<SimClock>()
            .configure_sets(
                Update,
                (
                    SimSet::Radio,
                    SimSet::ProcessActions,
                    SimSet::Actuate,
                    SimSet::Physics,
                    SimSet::Sense,
                    SimSet::Task,
                    SimSet::Reset,
                )
                    .chain()
                    .run_if(sim_started),
            )
            .add_systems(Update, run_substeps.in_set(SimSet::Physics))
            .add_systems(Last, advance_clock)
            // Run from an exclusive system many times per control step: the single-threaded
            // executor costs least, and the parallelism is inside `integrate_arenas`.
            .edit_schedule(PhysicsSubstep, |substep| {
                substep.set_executor(SingleThreadedExecutor::new());
            })
            .configure_sets(
                PhysicsSubstep,
                (SubstepSet::Actuate, SubstepSet::Integrate, SubstepSet::Measure, SubstepSet::Record).chain(),
            )
            .add_systems(PhysicsSubstep, integrate_arenas.in_set(SubstepSet::Integrate));
    }
}

/// The fixed timing of the simulation. Never tied to the wall clock.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct SimSettings {
    /// Physics step in seconds.
    pub dt: f32,
    /// Physics steps per control step.
    pub substeps: u32,
    pub gravity: Vec3,
    /// Rapier's solver iterations (substeps) per physics step: more keep long joint chains
    /// (an arm) tighter, at a cost proportional to them.
    pub solver_iterations: usize,
}

impl SimSettings {
    /// Seconds of simulated time per control step.
    pub fn control_dt(&self) -> f32 {
        self.dt * self.substeps as f32
    }
}

impl Default for SimSettings {
    fn default() -> Self {
        Self {
            dt: 0.004,
            substeps: 8,
            gravity: Vec3::new(0.0, 0.0, -9.81),
            solver_iterations: 4,
        }
    }
}

/// Counts control steps. The first `App::update` only builds the world (start-up); every later
/// update is one control step.
#[derive(Resource, Default, Debug)]
pub struct SimClock {
    pub control_steps: u64,
    started: bool,
}

impl SimClock {
    pub fn started(&self) -> bool {
        self.started
    }
}

/// Run condition: true once start-up has built the world.
pub fn sim_started(clock: Res<SimClock>) -> bool {
    clock.started
}

pub(crate) fn advance_clock(mut clock: ResMut<SimClock>) {
    if clock.started {
        clock.control_steps += 1;
    }
    clock.started = true;
}

/// The schedule run `substeps` times per control step.
#[derive(ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct PhysicsSubstep;

/// Order inside one physics step.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub enum SubstepSet {
    /// Motors write their joint motors and torques.
    Actuate,
    /// Rapier advances every arena by `dt`.
    Integrate,
    /// Joint positions and velocities are measured.
    Measure,
    /// Recorders that integrate over physics steps (energy meters) read the measured state.
    Record,
}

pub(crate) fn run_substeps(world: &mut World) {
    let substeps = world.resource::<SimSettings>().substeps;
    // The control step moves every world on, so the devices that are due sample after it.
    for mut arena in world.query::<&mut Arena>().iter_mut(world) {
        arena.unsampled.stepped = true;
    }
    for _ in 0..substeps {
        world.run_schedule(PhysicsSubstep);
    }
}

pub(crate) fn integrate_arenas(settings: Res<SimSettings>, mut arenas: Query<&mut Arena>) {
    for mut arena in &mut arenas {
        let world = &mut arena.world;
        world.integration_parameters.dt = settings.dt;
        world.integration_parameters.num_solver_iterations = settings.solver_iterations;
        world.gravity = settings.gravity;
        world.step();
    }
}
