//! Design pattern 3 made structural (issue 15.4, issue 32.4). The first line is the types: an
//! arena's physics world is private to the simulator and reached only with the Supervisor's
//! privilege, which a pattern-3 app never grants, so a robot system that asks for it fails on
//! its first run; the lab operator reaches only what its cell marks `Handled`, in the arena
//! named. The second line is `twinbots_link::audit` (also run by `twinbots robot` on every app
//! it builds): every system of every schedule asked for its data access.

use bevy::prelude::*;
use twinbots_api::DesignPattern;
use twinbots_link::audit::pattern_3_violations as violations;
use twinbots_run::registry;
use twinbots_sim::{
    Arena, Handled, JointState, Link, Motor, MotorCommand, Operator, SupervisorAccess, SupervisorPlugin,
};

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
        assert!(
            !app.world().contains_resource::<SupervisorAccess>(),
            "{name}: the pattern-3 app grants the Supervisor"
        );
        let found = violations(&mut app);
        assert!(found.is_empty(), "{name}:\n{}", found.join("\n"));
    }
}

/// The first line: a robot system that reads the true world needs the Supervisor's privilege,
/// and a pattern-3 app has none, so the system cannot run (it stops the app, naming it).
#[test]
fn a_robot_system_that_reads_the_world_cannot_run_under_pattern_3() {
    fn peeks_at_the_world(privilege: Res<SupervisorAccess>, arenas: Query<&Arena>) {
        for arena in &arenas {
            let _ = arena.physics(&privilege).bodies.len();
        }
    }
    let cartpole = registry::find("cartpole").unwrap();
    let mut app = cartpole.app(None, 1, 0, DesignPattern::Server).unwrap();
    app.add_systems(Update, peeks_at_the_world);
    let failed = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| app.update())).expect_err("the system ran");
    let text = failed.downcast_ref::<String>().cloned().unwrap_or_default();
    // (Bevy names the parameter only with its `debug` feature.)
    assert!(text.contains("failed validation: Resource does not exist"), "{text}");
    // The same system in a pattern-1 app runs.
    let mut app = cartpole.app(None, 1, 0, DesignPattern::Supervised).unwrap();
    app.add_systems(Update, peeks_at_the_world);
    app.update();
}

/// The second line catches what the types let through: a pattern-3 app given the Supervisor, a
/// system asking for its privilege, one that changes an arena, one that holds the whole world
/// — in a registered robot's app and in one that is registered nowhere.
#[test]
fn the_audit_catches_the_supervisor_a_changed_arena_or_the_whole_world() {
    fn asks_the_supervisor(_supervisor: twinbots_sim::Supervisor) {}
    fn reseeds_an_arena(mut arenas: Query<&mut Arena>) {
        for mut arena in &mut arenas {
            arena.reseed(7);
        }
    }
    fn holds_the_world(_world: &mut World) {}

    let cartpole = registry::find("cartpole").unwrap();
    let mut app = cartpole.app(None, 1, 0, DesignPattern::Server).unwrap();
    app.add_plugins(SupervisorPlugin).add_systems(Update, asks_the_supervisor);
    let found = violations(&mut app);
    assert_eq!(found.len(), 2, "the grant and the added system: {found:?}");
    assert!(found[0].contains("grants the Supervisor") && found[1].contains("Supervisor's privilege"), "{found:?}");

    /// A robot no registry knows: the simulation without the Supervisor, one system of its own.
    fn unregistered_robot_with<M>(
        system: impl IntoScheduleConfigs<bevy::ecs::system::ScheduleSystem, M>,
    ) -> Vec<String> {
        let mut app = App::new();
        app.add_plugins(MinimalPlugins).add_plugins(twinbots_sim::SimPlugin { supervisor: false, ..default() });
        app.add_systems(Update, system);
        violations(&mut app)
    }
    for (found, what) in [
        (unregistered_robot_with(reseeds_an_arena), "changes an Arena"),
        (unregistered_robot_with(holds_the_world), "whole world"),
    ] {
        assert_eq!(found.len(), 1, "only the added system: {found:?}");
        assert!(found[0].contains(what), "{found:?}");
    }
}

/// The lab operator at one cell: places and sees only what the cell marks `Handled`, and only
/// in the arena named in the call.
#[test]
fn the_operator_reaches_only_handled_objects_in_the_arena_named() {
    #[derive(Resource, Default, Debug)]
    struct Seen(Vec<(&'static str, bool)>);
    fn operate(mut operator: Operator, arenas: Query<(Entity, &ur5e::cell::CellParts)>, mut seen: ResMut<Seen>) {
        let mut cells: Vec<(Entity, &ur5e::cell::CellParts)> = arenas.iter().collect();
        cells.sort_by_key(|(e, _)| *e);
        let [(a, parts_a), (b, parts_b)] = cells[..] else { panic!("two arenas") };
        let seat = operator.object_pose(a, parts_a.part).expect("the part, in its own arena");
        seen.0.push(("own part seen", true));
        seen.0.push(("own part placed", operator.place_object(a, parts_a.part, seat)));
        seen.0.push(("other arena's part seen", operator.object_pose(a, parts_b.part).is_some()));
        seen.0.push(("other arena's part placed", operator.place_object(a, parts_b.part, seat)));
        seen.0.push(("the arm's tool seen", operator.object_pose(a, parts_a.tcp).is_some()));
        seen.0.push(("an arm joint placed", operator.place_joint(b, parts_b.joints[2], 0.5)));
    }
    let ur5e = registry::find("ur5e").unwrap();
    let mut app = ur5e.app(None, 2, 0, DesignPattern::Server).unwrap();
    app.init_resource::<Seen>().add_systems(Update, operate);
    app.update();
    let seen = &app.world().resource::<Seen>().0;
    let expected = [
        ("own part seen", true),
        ("own part placed", true),
        ("other arena's part seen", false),
        ("other arena's part placed", false),
        ("the arm's tool seen", false),
        ("an arm joint placed", false),
    ];
    assert_eq!(&seen[..6], &expected, "{seen:?}");
    let world = app.world_mut();
    assert_eq!(world.query_filtered::<(), With<Handled>>().iter(world).count(), 2, "one part per cell is handled");
}

/// What the pattern-3 cart-pole knows of itself comes from devices that measure the cart and
/// the pole (a GPS and an inertial unit on the cart, a gyro on the pole), not from its wheels:
/// they reach a new speed within a step and slip under the cart, so at a reversal they read
/// the speed commanded while the cart still rolls the other way. Driven back and forth, its
/// readings follow the true world (read here through the Supervisor the test adds) while the
/// pole is within the task's range.
#[test]
fn the_pattern_3_cart_pole_measures_its_cart_and_pole_not_its_wheels() {
    let cartpole = registry::find("cartpole").unwrap();
    let mut app = cartpole.app(None, 1, 0, DesignPattern::Server).unwrap();
    app.add_plugins(SupervisorPlugin);
    // Start-up mounts the devices; the step after, the cart at rest, they read it first.
    app.update();
    app.update();
    let (arena, parts) = app.world_mut().query::<(Entity, &cartpole::CartPoleParts)>().single(app.world()).unwrap();
    let parts = *parts;
    let truth = |world: &World| {
        let physics = twinbots_sim::physics_in(world, arena).unwrap();
        let (cart, pole) = (world.get::<Link>(parts.cart).unwrap(), world.get::<Link>(parts.pole_link).unwrap());
        let (cart, pole) = (&physics.bodies[cart.body], &physics.bodies[pole.body]);
        (cart.translation().x, cart.linvel().x, pole.angvel().y)
    };
    let (start_x, _, _) = truth(app.world());
    let mut wheels_off = 0.0f32;
    for step in 0..60 {
        let speed = if (step / 4) % 2 == 0 { cartpole::WHEEL_SPEED } else { -cartpole::WHEEL_SPEED };
        for wheel in parts.wheels {
            app.world_mut().get_mut::<Motor>(wheel).unwrap().command = MotorCommand::Velocity(speed);
        }
        app.update();
        let state = *app.world().get::<cartpole::CartPoleState>(arena).unwrap();
        if state.angle.abs() > cartpole::MAX_POLE_ANGLE {
            // An episode would have ended; the pole falls to its stops.
            assert!(step > 8, "the pole fell before the cart reversed twice, at step {step}");
            break;
        }
        let (x, v, rate) = truth(app.world());
        assert!((state.x - (x - start_x)).abs() < 2e-3, "step {step}: x {} vs the cart's {}", state.x, x - start_x);
        assert!((state.v - v).abs() < 1e-3, "step {step}: speed {} vs the cart's {v}", state.v);
        assert!((state.rate - rate).abs() < 1e-3, "step {step}: rate {} vs the pole's {rate}", state.rate);
        let wheel = app.world().get::<JointState>(parts.wheels[0]).unwrap().velocity * cartpole::WHEEL_RADIUS;
        wheels_off = wheels_off.max((wheel - v).abs());
    }
    assert!(wheels_off > 0.1, "the wheels read the cart's speed within {wheels_off} m/s: they did not slip");
}
