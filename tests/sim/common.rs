//! Helpers: an app with one robot spawned from a URDF, and Supervisor access from a test.

use bevy::ecs::system::SystemState;
use bevy::ecs::world::CommandQueue;
use bevy::prelude::*;
use twinbots_sim::urdf::{RobotModel, parse_urdf};
use twinbots_sim::{Arena, SimPlugin, SimSettings, SpawnOptions, SpawnedRobot, Supervisor, spawn_robot};

/// Parses URDF text written by a test.
pub fn model_from(text: &str) -> RobotModel {
    parse_urdf(text, "test.urdf".as_ref(), ".".as_ref()).expect("test URDF is valid")
}

/// An app with one arena holding one robot, built (start-up done) and ready to step.
pub fn robot_app(model: &RobotModel, options: SpawnOptions, settings: SimSettings) -> (App, Entity, SpawnedRobot) {
    robot_app_with(model, options, settings, |_| {})
}

/// As [`robot_app`], with `scene` adding the cell's fixed objects to the arena first.
pub fn robot_app_with(
    model: &RobotModel,
    options: SpawnOptions,
    settings: SimSettings,
    scene: impl FnOnce(&mut Arena),
) -> (App, Entity, SpawnedRobot) {
    let mut app = App::new();
    app.add_plugins(MinimalPlugins).add_plugins(SimPlugin { settings, ..default() });
    let world = app.world_mut();
    let arena_entity = world.spawn_empty().id();
    let mut arena = Arena::new(0, 0, settings.dt, settings.gravity);
    arena.add_ground(1.0);
    scene(&mut arena);
    let mut queue = CommandQueue::default();
    let spawned = {
        let mut commands = Commands::new(&mut queue, world);
        spawn_robot(&mut commands, arena_entity, &mut arena, model, options)
    };
    queue.apply(world);
    arena.mark_initial();
    world.entity_mut(arena_entity).insert(arena);
    app.update(); // start-up only: no physics step yet
    (app, arena_entity, spawned)
}

/// Runs `f` with a Supervisor over the app's world.
pub fn with_supervisor<R>(app: &mut App, f: impl for<'w, 's> FnOnce(&mut Supervisor<'w, 's>) -> R) -> R {
    let world = app.world_mut();
    let mut state: SystemState<Supervisor> = SystemState::new(world);
    let mut supervisor = state.get_mut(world).expect("Supervisor is always valid");
    let out = f(&mut supervisor);
    state.apply(world);
    out
}

/// Spawns another robot or object into an app's arena (after start-up), as a cell adds one.
pub fn spawn_into(app: &mut App, arena_entity: Entity, model: &RobotModel, options: SpawnOptions) -> SpawnedRobot {
    let world = app.world_mut();
    let mut arena = world.entity_mut(arena_entity).take::<Arena>().expect("the arena exists");
    let mut queue = CommandQueue::default();
    let spawned = {
        let mut commands = Commands::new(&mut queue, world);
        spawn_robot(&mut commands, arena_entity, &mut arena, model, options)
    };
    queue.apply(world);
    world.entity_mut(arena_entity).insert(arena);
    spawned
}
