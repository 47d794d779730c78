//! Design pattern 3 made structural (issue 15.4): in a pattern-3 robot app no system of the
//! robot or its task can reach privileged world state. Every system of every schedule is asked
//! for its data access (`System::initialize` returns it). Only the framework's plumbing — the
//! systems an app of `MinimalPlugins`, `SimPlugin { supervisor: false }` (devices, physics,
//! radio) and `ServerRobotPlugin` (the robot cycle, whose boot seeds each controller's random
//! stream from its arena's) already has, recognised by system type — and the lab's operator
//! events (systems holding the narrow `Operator` parameter, which can only place a hinge or an
//! object) may touch an `Arena`, which holds the physics world. No system may use the
//! Supervisor, and the app must not grant it (`SupervisorAccess`). There are no exceptions:
//! what a robot measures of its cell (the UR5e's collisions) comes from devices (its contact
//! sensors), which the framework's systems fill.

use std::any::TypeId;
use std::collections::HashSet;

use bevy::ecs::component::ComponentId;
use bevy::prelude::*;
use twinbots_link::robot::ServerRobotPlugin;
use twinbots::registry;
use twinbots_api::DesignPattern;
use twinbots_sim::{Arena, OperatorAccess, SimPlugin, SupervisorAccess, SupervisorPlugin};

/// A robot state for building the framework's own systems.
#[derive(Component)]
struct ProbeState;

/// The system types of the framework's plumbing (see the module's doc).
fn plumbing() -> HashSet<TypeId> {
    let mut app = App::new();
    app.add_plugins(MinimalPlugins)
        .add_plugins(SimPlugin { supervisor: false, ..default() })
        .add_plugins(ServerRobotPlugin::<ProbeState>::new("probe"));
    let mut types = HashSet::new();
    app.world_mut().resource_scope(|_, schedules: Mut<Schedules>| {
        for (_, schedule) in schedules.iter() {
            types.extend(schedule.graph().systems.iter().map(|(_, system, _)| system.system_type()));
        }
    });
    types
}

/// What a system may touch that a pattern-3 robot must not.
struct Privileged {
    arena: ComponentId,
    supervisor: ComponentId,
    operator: ComponentId,
}

/// Every system of every schedule of `app` that reaches privileged state without being
/// allowed to, as "schedule: system #i: what" (system names need bevy's `debug` feature).
fn violations(app: &mut App) -> Vec<String> {
    let plumbing = plumbing();
    let world = app.world_mut();
    let privileged = Privileged {
        arena: world.register_component::<Arena>(),
        supervisor: world.register_component::<SupervisorAccess>(),
        operator: world.register_component::<OperatorAccess>(),
    };
    let mut found = Vec::new();
    world.resource_scope(|world, mut schedules: Mut<Schedules>| {
        for (label, schedule) in schedules.iter_mut() {
            let keys: Vec<_> = schedule.graph().systems.iter().map(|(key, _, _)| key).collect();
            for (i, key) in keys.into_iter().enumerate() {
                let system = schedule.graph_mut().systems.get_mut(key).expect("a listed system");
                let name = format!("system #{i} {}", system.name());
                let framework = plumbing.contains(&system.system_type());
                let exclusive = system.is_exclusive();
                let access = system.initialize(world);
                let access = access.combined_access();
                let everything = exclusive || access.has_read_all() || access.has_write_all();
                let reads_arena = everything || access.has_read(privileged.arena) || access.has_write(privileged.arena);
                let uses = |id| access.has_read(id);
                let supervisor = uses(privileged.supervisor);
                let lab_operator = uses(privileged.operator) && !everything;
                if supervisor {
                    found.push(format!("{label:?}: {name} uses the Supervisor"));
                    continue;
                }
                if reads_arena && !(framework || lab_operator) {
                    let what = if everything { "the whole world" } else { "an Arena" };
                    found.push(format!("{label:?}: {name} reaches {what}"));
                }
            }
        }
    });
    found
}

/// Every built-in robot task that runs under pattern 3, as a built app (start-up done).
fn pattern_3_apps() -> Vec<(String, App)> {
    let mut apps = Vec::new();
    for robot in registry::robots() {
        for task in robot.task_names() {
            if robot.supports(Some(task), DesignPattern::Server).unwrap() {
                let app = robot.app(Some(task), 2, 0, DesignPattern::Server).expect("a pattern-3 app");
                apps.push((format!("{} ({task})", robot.name), app));
            }
        }
    }
    apps
}

#[test]
fn no_pattern_3_robot_system_reaches_the_physics_world_or_the_supervisor() {
    let apps = pattern_3_apps();
    assert!(apps.len() >= 2, "the cart-pole and the UR5e run under pattern 3");
    for (name, mut app) in apps {
        assert!(!app.world().contains_resource::<SupervisorAccess>(), "{name}: the pattern-3 app grants the Supervisor");
        let found = violations(&mut app);
        assert!(found.is_empty(), "{name}:\n{}", found.join("\n"));
    }
}

/// The check can fail: a pattern-3 app given the Supervisor, or a robot-side system that
/// reads an arena's physics world, is caught.
#[test]
fn the_check_catches_a_supervisor_or_a_robot_system_reading_the_world() {
    fn peeks_at_the_world(arenas: Query<&Arena>) {
        for arena in &arenas {
            let _ = arena.world.bodies.len();
        }
    }
    fn asks_the_supervisor(_supervisor: twinbots_sim::Supervisor) {}

    let cartpole = registry::find("cartpole").unwrap();
    let mut app = cartpole.app(None, 1, 0, DesignPattern::Server).unwrap();
    app.add_systems(Update, peeks_at_the_world);
    let found = violations(&mut app);
    assert_eq!(found.len(), 1, "only the added system: {found:?}");
    assert!(found[0].contains("reaches an Arena"), "{found:?}");

    let mut app = cartpole.app(None, 1, 0, DesignPattern::Server).unwrap();
    app.add_plugins(SupervisorPlugin).add_systems(Update, asks_the_supervisor);
    assert!(app.world().contains_resource::<SupervisorAccess>());
    let found = violations(&mut app);
    assert_eq!(found.len(), 1, "only the added system: {found:?}");
    assert!(found[0].contains("uses the Supervisor"), "{found:?}");
}
