//! The UR5e twin against its published model: forward kinematics at known joint angles match
//! the DH model within a millimetre (also after holding against gravity), the ±2π joint
//! limits, the elbow's ±π and the torque limits hold, homing returns the arm home, and the vacuum gripper
//! seizes only what is within its stroke.

use bevy::ecs::world::CommandQueue;
use bevy::prelude::*;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::{Arena, ContactSensor, JointState, Link, Motor, MotorCommand, SimPlugin, Touched, VacuumGripper};
use ur5e::arm::{self, ArmState};
use ur5e::cell::{CellModels, CellParts, spawn_cell};
use ur5e::kinematics::{self, HOME, JOINT_RANGE, MAX_TORQUE};

/// An app with one UR5e cell, the arm spawned at `start`, built and ready to step.
fn cell_app(start: [f32; 6]) -> (App, Entity, CellParts) {
    let settings = ur5e::sim_settings();
    let mut app = App::new();
    app.add_plugins(MinimalPlugins).add_plugins(SimPlugin { settings, ..default() });
    let world = app.world_mut();
    let arena_entity = world.spawn_empty().id();
    let mut arena = Arena::new(0, 0, settings.dt, settings.gravity);
    let mut queue = CommandQueue::default();
    let parts = {
        let mut commands = Commands::new(&mut queue, world);
        spawn_cell(
            &mut commands,
            arena_entity,
            &mut arena,
            &CellModels::default(),
            &ur5e::layout::CellLayout::default(),
            start,
        )
    };
    queue.apply(world);
    arena.mark_initial();
    world.entity_mut(arena_entity).insert(arena);
    app.update(); // start-up only
    (app, arena_entity, parts)
}

fn joint_states(app: &App, parts: &CellParts) -> [JointState; 6] {
    parts.joints.map(|j| *app.world().get::<JointState>(j).unwrap())
}

fn arm_state(app: &App, parts: &CellParts) -> ArmState {
    let s = joint_states(app, parts);
    ArmState::from_joints(s.map(|s| s.position), s.map(|s| s.velocity))
}

/// Where the physics world has the TCP link, in the base frame.
fn simulated_tcp(app: &App, arena: Entity, parts: &CellParts) -> Pose {
    let link = app.world().get::<Link>(parts.tcp).unwrap();
    let body = &twinbots_sim::physics_in(app.world(), arena).unwrap().bodies[link.body];
    parts.base.inverse() * *body.position() * link.offset
}

fn command(app: &mut App, joint: Entity, command: MotorCommand) {
    app.world_mut().get_mut::<Motor>(joint).unwrap().command = command;
}

fn run(app: &mut App, steps: usize) {
    for _ in 0..steps {
        app.update();
    }
}

const POSES: [[f32; 6]; 5] = [
    HOME,
    [0.5, -1.0, 1.2, -1.7, -1.57, 0.3],
    [-0.8, -2.0, 1.6, -0.9, 1.0, -2.0],
    [2.5, -1.3, -1.0, 2.0, 0.7, 4.0],
    [-3.5, -1.8, 0.9, -2.5, 2.2, -5.0],
];

#[test]
fn forward_kinematics_matches_the_dh_model_within_a_millimetre() {
    for q in POSES {
        let (mut app, arena, parts) = cell_app(q);
        let at_spawn = simulated_tcp(&app, arena, &parts);
        let dh = kinematics::tcp(&q);
        let error = (at_spawn.translation - dh.translation).length();
        assert!(error < 1e-4, "{q:?}: the URDF's TCP is {error} m from the DH model's");
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            let off = (at_spawn.rotation * axis - dh.rotation * axis).length();
            assert!(off < 1e-4, "{q:?}: the tool's {axis} axis is off by {off}");
        }
        let measured = joint_states(&app, &parts).map(|s| s.position);
        for (m, want) in measured.iter().zip(q) {
            assert!((m - want).abs() < 1e-4, "{q:?}: encoder reads {m}, joint is at {want}");
        }

        // Two seconds holding position against gravity: the joints barely sag, and the TCP
        // the physics computes stays where the DH model puts it for the measured angles.
        run(&mut app, 50);
        let measured = joint_states(&app, &parts).map(|s| s.position);
        for (m, want) in measured.iter().zip(q) {
            assert!((m - want).abs() < 0.01, "{q:?}: sagged to {measured:?}");
        }
        let held = simulated_tcp(&app, arena, &parts);
        let error = (held.translation - kinematics::tcp(&measured).translation).length();
        assert!(error < 1e-3, "{q:?}: after 2 s the TCP is {:.2} mm from the DH model's", error * 1000.0);
    }
}

#[test]
fn joints_stop_at_their_plus_minus_two_pi_limits() {
    let (mut app, _, parts) = cell_app(HOME);
    // Base and wrist 3 turn freely in the cell: drive them past their stops at full speed.
    let (pan, wrist3) = (parts.joints[0], parts.joints[5]);
    command(&mut app, pan, MotorCommand::Velocity(-kinematics::MAX_JOINT_SPEED));
    command(&mut app, wrist3, MotorCommand::Velocity(kinematics::MAX_JOINT_SPEED));
    let mut extreme = [0.0f32; 2];
    for _ in 0..100 {
        app.update();
        let s = joint_states(&app, &parts);
        extreme[0] = extreme[0].min(s[0].position);
        extreme[1] = extreme[1].max(s[5].position);
    }
    assert!(extreme[0] >= -JOINT_RANGE - 0.005, "base turned to {}", extreme[0]);
    assert!(extreme[1] <= JOINT_RANGE + 0.005, "wrist 3 turned to {}", extreme[1]);
    let s = joint_states(&app, &parts);
    assert!((s[0].position + JOINT_RANGE).abs() < 0.01, "base rests at its stop: {}", s[0].position);
    assert!((s[5].position - JOINT_RANGE).abs() < 0.01, "wrist 3 rests at its stop: {}", s[5].position);
    assert!(s[0].velocity.abs() < 0.01 && s[5].velocity.abs() < 0.01);
    // Turning back is allowed.
    command(&mut app, wrist3, MotorCommand::Velocity(-1.0));
    run(&mut app, 10);
    assert!(joint_states(&app, &parts)[5].position < JOINT_RANGE - 0.3);
}

/// The elbow's hardware range is ±π (ur_description), narrower than the other joints' ±2π.
#[test]
fn the_elbow_stops_at_plus_minus_pi_under_commands_and_under_a_push() {
    use std::f32::consts::PI;
    let elbow_at = |app: &App, parts: &CellParts| joint_states(app, parts)[2];
    // Commands: a position target beyond the stop is held at the stop; full speed stops there.
    let (mut app, _, parts) = cell_app(HOME);
    command(&mut app, parts.joints[2], MotorCommand::Position(4.0));
    let mut highest = f32::MIN;
    for _ in 0..100 {
        app.update();
        highest = highest.max(elbow_at(&app, &parts).position);
    }
    assert!(highest <= PI + 0.005, "the elbow turned to {highest}");
    assert!((elbow_at(&app, &parts).position - PI).abs() < 0.01, "rests at π: {}", elbow_at(&app, &parts).position);

    // A push stronger than any motor (the elbow's motor off, 300 N·m on the forearm, as a
    // collision would): rapier's stop holds the joint at π.
    let (mut app, arena, parts) = cell_app([0.0, -PI / 2.0, 2.5, -PI / 2.0, -PI / 2.0, 0.0]);
    command(&mut app, parts.joints[2], MotorCommand::Off);
    let forearm = {
        let mut links = app.world_mut().query::<&Link>();
        links.iter(app.world()).find(|l| l.robot == parts.robot && l.name == "forearm_link").unwrap().body
    };
    let joint = app.world().get::<twinbots_sim::Joint>(parts.joints[2]).unwrap().clone();
    let mut highest = f32::MIN;
    for _ in 0..50 {
        {
            let dt = ur5e::sim_settings().control_dt();
            let mut world = twinbots_sim::physics_in_mut(app.world_mut(), arena).unwrap();
            let (axis, _, _) = joint.measure(&world).unwrap();
            world.bodies[forearm].apply_torque_impulse(axis * 300.0 * dt, true);
        }
        app.update();
        highest = highest.max(elbow_at(&app, &parts).position);
    }
    assert!(highest > PI - 0.05, "the push did not reach the stop: {highest}");
    assert!(highest <= PI + 0.02, "the push drove the elbow through its stop to {highest}");
}

/// Gravity's torque about the shoulder-lift axis, from the simulated bodies beyond it.
fn shoulder_gravity_torque(app: &App, arena: Entity, parts: &CellParts) -> f32 {
    let world = &twinbots_sim::physics_in(app.world(), arena).unwrap();
    let beyond = ["upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link"];
    let mut links = app.world().try_query::<&Link>().unwrap();
    let bodies: std::collections::HashSet<_> = links
        .iter(app.world())
        .filter(|l| l.robot == parts.robot && beyond.contains(&l.name.as_str()))
        .map(|l| l.body)
        .collect();
    let axis_x = parts.base.translation.x; // the arm stretched out: the axis is horizontal, through x = 0
    bodies.iter().map(|&b| world.bodies[b].mass() * 9.81 * (world.bodies[b].center_of_mass().x - axis_x).abs()).sum()
}

#[test]
fn torque_limits_hold_and_effort_reads_the_gravity_torque() {
    // Stretched out horizontally, the shoulder carries the whole arm: about 60 N·m. Turned
    // round (q1 = π) the arm reaches out past the table's back edge, free to sink.
    let reaching_out = [std::f32::consts::PI, 0.0, 0.0, 0.0, 0.0, 0.0];
    let (mut app, arena, parts) = cell_app(reaching_out);
    run(&mut app, 25);
    let gravity = shoulder_gravity_torque(&app, arena, &parts);
    assert!((55.0..65.0).contains(&gravity), "gravity torque {gravity}");
    let s = joint_states(&app, &parts);
    assert!(s[1].position.abs() < 0.01, "a full-strength shoulder holds: {}", s[1].position);
    assert!((s[1].effort.abs() - gravity).abs() < 0.04 * gravity, "effort {} vs gravity {gravity}", s[1].effort);

    // A motor at 30 % (45 N·m) cannot: the arm sinks, and the torque never exceeds 45 N·m.
    let (mut app, _, parts) = cell_app(reaching_out);
    let weak = 0.3;
    app.world_mut().get_mut::<Motor>(parts.joints[1]).unwrap().strength = weak;
    let mut peak = [0.0f32; 6];
    for _ in 0..20 {
        app.update();
        for (p, s) in peak.iter_mut().zip(joint_states(&app, &parts)) {
            *p = p.max(s.effort.abs());
        }
    }
    let limits: [f32; 6] = std::array::from_fn(|i| MAX_TORQUE[i] * if i == 1 { weak } else { 1.0 });
    for i in 0..6 {
        assert!(peak[i] <= limits[i] * 1.001, "joint {i}: {} N·m > {}", peak[i], limits[i]);
    }
    assert!((peak[1] - limits[1]).abs() < 0.01 * limits[1], "the weak shoulder works at its limit: {}", peak[1]);
    let sag = joint_states(&app, &parts)[1].position;
    assert!(sag.abs() > 0.1, "the weak shoulder sank only {sag} rad");
}

/// Runs `f` on the motors, as a system would.
fn with_motors(app: &mut App, f: impl FnOnce(&mut Query<&mut Motor>)) {
    let world = app.world_mut();
    let mut state = bevy::ecs::system::SystemState::<Query<&mut Motor>>::new(world);
    f(&mut state.get_mut(world).expect("motors are always queryable"));
}

#[test]
fn homing_returns_the_arm_to_its_home_pose() {
    let (mut app, arena, parts) = cell_app([1.0, -1.2, 1.0, -1.0, -0.8, 1.5]);
    let mut steps = 0;
    while !arm_state(&app, &parts).is_home() {
        let speeds = arm::homing_speeds(&arm_state(&app, &parts).q);
        with_motors(&mut app, |motors| arm::drive(&parts, speeds, motors));
        app.update();
        steps += 1;
        assert!(steps < 125, "not home after 5 s: {:?}", arm_state(&app, &parts).q);
    }
    // Within 0.01 rad a joint, the servos' static error under load: a few millimetres at the TCP.
    let home = kinematics::tcp(&HOME).translation;
    let error = (simulated_tcp(&app, arena, &parts).translation - home).length();
    assert!(error < 5e-3, "the TCP is {:.1} mm from home", error * 1000.0);
}

#[test]
fn the_vacuum_gripper_seizes_only_what_is_within_its_stroke() {
    let (mut app, _, parts) = cell_app(HOME);
    let top = ur5e::cell::part_seat(ur5e::layout::Fixtures::default().pick) + Vec3::Z * ur5e::cell::PART_HEIGHT;
    let part_z = |app: &App| {
        let link = app.world().get::<Link>(parts.part).unwrap();
        let world = twinbots_sim::physics_in(app.world(), link_arena(app, &parts)).unwrap();
        (parts.base.inverse() * *world.bodies[link.body].position()).translation.z
    };
    let rest = part_z(&app);
    let gripper = |app: &mut App, on: bool| app.world_mut().get_mut::<VacuumGripper>(parts.gripper).unwrap().on = on;
    let holding = |app: &App| app.world().get::<VacuumGripper>(parts.gripper).unwrap().held().is_some();

    // 3 cm above the part, suction on: out of the cup's 1.5 cm stroke, nothing is seized.
    move_tool(&mut app, &parts, top + Vec3::Z * 0.03);
    gripper(&mut app, true);
    run(&mut app, 5);
    assert!(!holding(&app), "seized a part 3 cm away");
    // Coming down to 3 mm above, it seizes the part (once within the stroke) and draws it in
    // against the cup face; lifted 10 cm, the part comes along, hanging from the face.
    move_tool(&mut app, &parts, top + Vec3::Z * 0.003);
    assert!(holding(&app), "did not seize the part 3 mm away");
    move_tool(&mut app, &parts, top + Vec3::Z * 0.103);
    let gap = arm_state(&app, &parts).tcp.translation.z - (part_z(&app) + ur5e::cell::PART_HEIGHT);
    assert!(part_z(&app) - rest > 0.07, "the part did not come along: {}", part_z(&app) - rest);
    assert!((-0.001..=0.001).contains(&gap), "the part hangs {gap} m below the cup face");
    // Suction off: it drops back into the fixture.
    gripper(&mut app, false);
    run(&mut app, 25);
    assert!(!holding(&app));
    assert!((part_z(&app) - rest).abs() < 0.003, "the part fell to {}", part_z(&app));
}

/// Whether the arm is in collision, as the twin's collision figure judges it from the arm's
/// contact sensors.
fn in_collision(app: &mut App, parts: &CellParts) -> bool {
    let world = app.world_mut();
    let mut state = bevy::ecs::system::SystemState::<Query<&ContactSensor>>::new(world);
    ur5e::metrics::arm_in_collision(parts, &state.get(world).expect("sensors are always queryable"))
}

/// The collision figure comes from the arm's contact sensors: the cup set down on the part it
/// is to pick is no collision, the arm pressed onto the table is.
#[test]
fn collisions_are_what_the_arms_contact_sensors_report() {
    let (mut app, _, parts) = cell_app(HOME);
    let cup = |app: &App| app.world().get::<ContactSensor>(parts.contact_sensors[6]).unwrap().clone();
    assert!(!in_collision(&mut app, &parts), "the arm at home touches nothing");
    let top = ur5e::cell::part_seat(ur5e::layout::Fixtures::default().pick) + Vec3::Z * ur5e::cell::PART_HEIGHT;
    move_tool(&mut app, &parts, top);
    run(&mut app, 5);
    assert_eq!(cup(&app).contacts, vec![Touched::Link(parts.part)], "the cup rests on the part");
    assert!(!in_collision(&mut app, &parts), "the cup on the part it picks is no collision");

    // Turned to the side, away from the fixtures, the shoulder lifting forward and the elbow
    // folding: the arm comes down on the bare table.
    let side = [HOME[0] + std::f32::consts::FRAC_PI_2, HOME[1], HOME[2], HOME[3], HOME[4], HOME[5]];
    let (mut app, _, parts) = cell_app(side);
    let mut steps = 0;
    while !in_collision(&mut app, &parts) {
        with_motors(&mut app, |motors| arm::drive(&parts, [0.0, 1.0, 0.5, 0.0, 0.0, 0.0], motors));
        app.update();
        steps += 1;
        assert!(steps < 100, "no collision after 4 s");
    }
    let touched: Vec<Touched> = parts
        .contact_sensors
        .iter()
        .flat_map(|&s| app.world().get::<ContactSensor>(s).unwrap().contacts.clone())
        .collect();
    assert_eq!(touched, vec![Touched::Fixed], "the arm touches the table (no link), and only it");
}

fn link_arena(app: &App, parts: &CellParts) -> Entity {
    app.world().get::<twinbots_sim::InArena>(parts.part).unwrap().0
}

/// Drives the tool to `target` with the resolved-rate controller until it has arrived.
fn move_tool(app: &mut App, parts: &CellParts, target: Vec3) {
    for _ in 0..150 {
        let arm = arm_state(app, parts);
        if arm.has_reached(target) {
            return;
        }
        let speeds = arm::joint_speeds(&ur5e::controller::resolved_rate(&arm, target));
        with_motors(app, |motors| arm::drive(parts, speeds, motors));
        app.update();
    }
    panic!("the tool did not reach {target}: at {}", arm_state(app, parts).tcp.translation);
}
