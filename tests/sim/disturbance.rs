//! Disturbances: a push is a force for its physics steps and then none; a payload adds its
//! mass where it sits.

use bevy::prelude::*;
use twinbots_sim::{Arena, Link, Push, SimSettings, SpawnOptions, add_link_mass};

use crate::common::{model_from, robot_app, with_supervisor};

/// A 2 kg box floating free, without gravity, and a 0.5 kg tip welded 1 m along x.
const FLOATING: &str = r#"<robot name="floating">
  <link name="body"><inertial><mass value="2.0"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
    <collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision></link>
  <link name="tip"><inertial><mass value="0.5"/><inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial></link>
  <joint name="weld" type="fixed"><parent link="body"/><child link="tip"/><origin xyz="1 0 0"/></joint>
</robot>"#;

fn floating() -> (App, Entity, twinbots_sim::SpawnedRobot, SimSettings) {
    let settings = SimSettings { dt: 0.01, substeps: 4, gravity: Vec3::ZERO, ..default() };
    let options = SpawnOptions {
        base: twinbots_sim::rapier::math::Pose::from_translation(Vec3::new(0.0, 0.0, 2.0)),
        ..default()
    };
    let (app, arena, robot) = robot_app(&model_from(FLOATING), options, settings);
    (app, arena, robot, settings)
}

/// The mass and centre of mass of `link`'s body, brought up to date as a physics step would.
fn body_mass(app: &mut App, arena: Entity, link: Entity) -> (f32, Vec3) {
    let link = app.world().get::<Link>(link).unwrap().clone();
    let mut world = twinbots_sim::physics_in_mut(app.world_mut(), arena).unwrap();
    recompute(&mut world, &link);
    let body = &world.bodies[link.body];
    (body.mass(), body.center_of_mass())
}

/// What the next physics step would do first: the body's mass from its parts.
fn recompute(world: &mut twinbots_sim::rapier::prelude::PhysicsWorld, link: &Link) {
    world.bodies[link.body].recompute_mass_properties_from_colliders(&world.colliders);
}

#[test]
fn a_push_gives_its_impulse_and_then_lets_go() {
    let (mut app, arena, robot, settings) = floating();
    let body = robot.link("body").unwrap();
    // 5 N through the centre of mass (0.2 m along x from the body's origin) for 6 physics steps.
    let (mass, com) = body_mass(&mut app, arena, body);
    assert!((mass - 2.5).abs() < 1e-5, "{mass}");
    let com_local = Vec3::new(0.2, 0.0, 0.0);
    assert!((com - Vec3::new(0.2, 0.0, 2.0)).length() < 1e-5, "{com}");
    app.world_mut().entity_mut(body).insert(Push::lasting(Vec3::new(0.0, 5.0, 0.0), com_local, 0.06, settings.dt));
    for _ in 0..4 {
        app.update();
    }
    let velocity = with_supervisor(&mut app, |s| s.link_state(body).unwrap());
    // Impulse 5 N × 0.06 s on 2.5 kg: 0.12 m/s, no spin (it acts through the centre of mass).
    assert!((velocity.linvel.y - 0.12).abs() < 1e-4, "{:?}", velocity.linvel);
    assert!(velocity.angvel.length() < 1e-4, "{:?}", velocity.angvel);
    assert!(app.world().get::<Push>(body).is_none(), "the finished push is gone");
}

#[test]
fn a_push_off_the_centre_of_mass_spins_the_body() {
    let (mut app, arena, robot, settings) = floating();
    let body = robot.link("body").unwrap();
    app.world_mut().entity_mut(body).insert(Push::lasting(
        Vec3::new(0.0, 5.0, 0.0),
        Vec3::new(1.0, 0.0, 0.0),
        0.01,
        settings.dt,
    ));
    app.update();
    let state = with_supervisor(&mut app, |s| s.link_state(body).unwrap());
    assert!(state.angvel.z > 0.01, "pushed +y at +x spins it about +z: {:?}", state.angvel);
    let _ = arena;
}

#[test]
fn a_payload_adds_its_mass_at_the_link_and_a_reset_takes_it_away() {
    let (mut app, arena, robot, _) = floating();
    let tip = robot.link("tip").unwrap();
    let link = app.world().get::<Link>(tip).unwrap().clone();
    {
        let mut world = twinbots_sim::physics_in_mut(app.world_mut(), arena).unwrap();
        add_link_mass(&mut world, &link, 0.5).unwrap();
    }
    let (mass, com) = body_mass(&mut app, arena, tip);
    // 2 kg at 0 and 1 kg at 1 m: 3 kg, centre of mass at 1/3 m.
    assert!((mass - 3.0).abs() < 1e-5, "{mass}");
    assert!((com.x - 1.0 / 3.0).abs() < 1e-5, "{com}");
    {
        let mut world = twinbots_sim::physics_in_mut(app.world_mut(), arena).unwrap();
        add_link_mass(&mut world, &link, -1.0).unwrap();
        let err = add_link_mass(&mut world, &link, -5.0).unwrap_err();
        assert!(err.contains("'tip'") && err.contains("without mass"), "{err}");
    }
    {
        let world = app.world_mut();
        world.resource_scope(|world, privilege: Mut<twinbots_sim::SupervisorAccess>| {
            assert!(world.get_mut::<Arena>(arena).unwrap().restore_initial(&privilege));
        });
    }
    let (mass, _) = body_mass(&mut app, arena, tip);
    assert!((mass - 2.5).abs() < 1e-5, "restored: {mass}");
}
