//! The second line behind design pattern 3's structure. The first is the types: an arena's
//! physics world is private to the simulator and reached only with the Supervisor's privilege
//! (`twinbots_sim::Arena::physics`, `SupervisorAccess`), which a pattern-3 app never grants, and
//! the lab [`Operator`](twinbots_sim::Operator) reaches only the objects its cell marks
//! `Handled`, in the arena named. This audit asks every system of every schedule of a built app
//! for its data access (`System::initialize` returns it) and names each one that could get
//! around that: one that asks for the Supervisor's privilege (the app must not grant it either),
//! one that changes an `Arena` (its random stream, its fixed geometry) without being the
//! framework's plumbing or the operator, and an exclusive system (it holds the whole world)
//! that is not plumbing. Plumbing is what an app of `MinimalPlugins`, the simulation without
//! the Supervisor (devices, physics, radio) and [`ServerRobotPlugin`] (the robot cycle, whose
//! boot seeds each controller's random stream from its arena's) already has, recognised by
//! system type, and whatever the caller's own framework adds beside the robot (the twin's
//! calibration and robot log, [`Plumbing::beside`]). `twinbots robot` runs it on every app it
//! builds, so it covers any robot plugin, registered or not.

use std::any::TypeId;
use std::collections::HashSet;

use bevy::prelude::*;
use twinbots_sim::{Arena, OperatorAccess, SimPlugin, SupervisorAccess};

use crate::robot::ServerRobotPlugin;

/// A robot state for building the framework's own systems.
#[derive(Component)]
struct ProbeState;

/// The system types of the framework's plumbing (see the module's doc): found once, then used
/// to audit any number of apps.
pub struct Plumbing(HashSet<TypeId>);

impl Plumbing {
    /// The plumbing, with what `framework` adds to an app (the caller's own tools beside the
    /// robot, such as a controller's log) counted in.
    pub fn beside(framework: impl FnOnce(&mut App)) -> Self {
        let mut app = App::new();
        app.add_plugins(MinimalPlugins)
            .add_plugins(SimPlugin { supervisor: false, ..default() })
            .add_plugins(ServerRobotPlugin::<ProbeState>::new("probe"));
        framework(&mut app);
        let mut types = HashSet::new();
        app.world_mut().resource_scope(|_, schedules: Mut<Schedules>| {
            for (_, schedule) in schedules.iter() {
                types.extend(schedule.graph().systems.iter().map(|(_, system, _)| system.system_type()));
            }
        });
        Self(types)
    }

    /// Every way `app` (finished, before or after its start-up) lets robot-side code reach what
    /// a pattern-3 robot must not, as "schedule: system #i name: what" (system names need
    /// bevy's `debug` feature). Empty: none.
    pub fn violations(&self, app: &mut App) -> Vec<String> {
        let world = app.world_mut();
        let mut found = Vec::new();
        if world.contains_resource::<SupervisorAccess>() {
            found.push("the app grants the Supervisor (SupervisorAccess)".to_string());
        }
        let arena = world.register_component::<Arena>();
        let supervisor = world.register_component::<SupervisorAccess>();
        let operator = world.register_component::<OperatorAccess>();
        world.resource_scope(|world, mut schedules: Mut<Schedules>| {
            for (label, schedule) in schedules.iter_mut() {
                let keys: Vec<_> = schedule.graph().systems.iter().map(|(key, _, _)| key).collect();
                for (i, key) in keys.into_iter().enumerate() {
                    let system = schedule.graph_mut().systems.get_mut(key).expect("a listed system");
                    let name = format!("system #{i} {}", system.name());
                    let framework = self.0.contains(&system.system_type());
                    let exclusive = system.is_exclusive();
                    let access = system.initialize(world);
                    let access = access.combined_access();
                    let everything = exclusive || access.has_read_all() || access.has_write_all();
                    if access.has_read(supervisor) || access.has_write(supervisor) {
                        found.push(format!("{label:?}: {name} asks for the Supervisor's privilege"));
                    } else if everything && !framework {
                        found.push(format!("{label:?}: {name} holds the whole world"));
                    } else if access.has_write(arena) && !(framework || access.has_read(operator)) {
                        found.push(format!("{label:?}: {name} changes an Arena"));
                    }
                }
            }
        });
        found
    }
}

/// [`Plumbing::violations`] of `app` against the framework's own plumbing alone.
pub fn pattern_3_violations(app: &mut App) -> Vec<String> {
    Plumbing::beside(|_| {}).violations(app)
}
