//! The camera sensor sees an object in front of it, and stops seeing it once it is removed.

use bevy::ecs::world::CommandQueue;
use bevy::prelude::*;
use twinbots_render::CameraRig;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::parse_urdf;
use twinbots_sim::{Arena, CameraSensor, InArena, Mount, SimPlugin, SimSettings, SpawnOptions, spawn_robot};

use crate::red;

const POST: &str = r#"<robot name="post"><link name="world"/></robot>"#;
const TARGET: &str = r#"<robot name="target"><link name="world">
  <visual><geometry><box size="0.3 0.3 0.3"/></geometry><material name="red"><color rgba="0.9 0.05 0.05 1"/></material></visual>
</link></robot>"#;

/// An app (plugins given by `setup`) with a camera post at the origin looking along +X and a
/// red box 1 m in front; returns the app, the camera and the box robot's link.
fn camera_scene(setup: impl FnOnce(&mut App), size: (u32, u32)) -> (App, Entity, Entity) {
    let mut app = App::new();
    setup(&mut app);
    let world = app.world_mut();
    let arena_entity = world.spawn_empty().id();
    let mut arena = Arena::new(0, 0, SimSettings::default().dt, SimSettings::default().gravity);
    let model = |text: &str| parse_urdf(text, "t.urdf".as_ref(), ".".as_ref()).unwrap();
    let at =
        |x: f32| SpawnOptions { base: Pose::from_translation(Vec3::new(x, 0.0, 0.5)), fixed_base: true, ..default() };
    let mut queue = CommandQueue::default();
    let (post, target) = {
        let mut commands = Commands::new(&mut queue, world);
        let post = spawn_robot(&mut commands, arena_entity, &mut arena, &model(POST), at(0.0));
        let target = spawn_robot(&mut commands, arena_entity, &mut arena, &model(TARGET), at(1.0));
        (post, target)
    };
    queue.apply(world);
    arena.mark_initial();
    world.entity_mut(arena_entity).insert(arena);
    let camera = world
        .spawn((
            CameraSensor::new(40f32.to_radians(), size.0, size.1),
            Mount { link: post.link("world").unwrap(), offset: Pose::IDENTITY },
            InArena(arena_entity),
        ))
        .id();
    app.update(); // start-up
    (app, camera, target.link("world").unwrap())
}

#[test]
fn the_camera_sees_an_object_placed_in_front_of_it_and_not_once_it_is_removed() {
    if crate::renderer("the_camera_sees_an_object_placed_in_front_of_it_and_not_once_it_is_removed", 8, 8).is_none() {
        return;
    }
    let (mut app, camera, target) = camera_scene(
        |app| {
            app.add_plugins(MinimalPlugins).add_plugins(SimPlugin::default());
        },
        (64, 48),
    );
    let mut rig = CameraRig::default();
    assert_eq!(rig.sample(app.world_mut()).unwrap(), 1);
    let centre = |app: &App| app.world().get::<CameraSensor>(camera).unwrap().pixel(32, 24).unwrap();
    assert!(red(centre(&app)), "the red box fills the centre: {:?}", centre(&app));
    assert_eq!(app.world().get::<CameraSensor>(camera).unwrap().image.len(), 64 * 48 * 3);

    app.world_mut().entity_mut(target).despawn();
    app.update();
    rig.sample(app.world_mut()).unwrap();
    assert!(!red(centre(&app)), "removed: {:?}", centre(&app));
}

#[test]
fn with_the_camera_plugin_images_are_fresh_in_every_control_step() {
    if crate::renderer("with_the_camera_plugin_images_are_fresh_in_every_control_step", 8, 8).is_none() {
        return;
    }
    let (mut app, camera, _) = camera_scene(
        |app| {
            app.add_plugins(MinimalPlugins)
                .add_plugins(SimPlugin::default())
                .add_plugins(twinbots_render::CameraPlugin);
        },
        (32, 24),
    );
    for step in 0..3u64 {
        app.update();
        let c = app.world().get::<CameraSensor>(camera).unwrap();
        assert_eq!(c.captured_at, Some(step), "rendered during control step {step}");
        assert!(red(c.pixel(16, 12).unwrap()));
    }
}
