//! Devices against known geometry and motion.

use bevy::math::{EulerRot, Quat, Vec3};
use bevy::prelude::*;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::{
    Accelerometer, ContactSensor, DistanceSensor, Gps, Gyro, InArena, InertialUnit, Motor, MotorCommand, Mount,
    SamplingPeriod, SimSettings, SpawnOptions, TouchSensor, Touched,
};

use crate::common::{model_from, robot_app, robot_app_with, spawn_into};

/// A 1 kg, 0.2 m cube with a 1 kg·m² flywheel on a Y axle.
const PROBE: &str = r#"<robot name="probe">
  <link name="base">
    <inertial><mass value="1"/><inertia ixx="0.00667" ixy="0" ixz="0" iyy="0.00667" iyz="0" izz="0.00667"/></inertial>
    <collision><geometry><box size="0.2 0.2 0.2"/></geometry></collision>
  </link>
  <link name="wheel">
    <inertial><mass value="10"/><inertia ixx="0.6" ixy="0" ixz="0" iyy="1.0" iyz="0" izz="0.6"/></inertial>
  </link>
  <joint name="axle" type="continuous">
    <parent link="base"/><child link="wheel"/><axis xyz="0 1 0"/>
    <limit effort="50" velocity="3"/>
  </joint>
</robot>"#;

fn mount<T: Component>(app: &mut App, arena: Entity, link: Entity, device: T) -> Entity {
    app.world_mut().spawn((device, Mount { link, offset: Pose::IDENTITY }, InArena(arena))).id()
}

fn fixed_at(pose: Pose) -> SpawnOptions {
    SpawnOptions { base: pose, fixed_base: true, ..Default::default() }
}

#[test]
fn distance_sensor_reads_the_wall_and_applies_its_lookup_table() {
    let wall = |a: &mut twinbots_sim::Arena| {
        a.add_static_box(Vec3::new(0.05, 1.0, 1.0), Vec3::new(2.0, 0.0, 0.5), 1.0);
    };
    let base = Pose::from_translation(Vec3::new(0.0, 0.0, 0.5));
    let (mut app, arena, robot) = robot_app_with(&model_from(PROBE), fixed_at(base), SimSettings::default(), wall);
    let link = robot.link("base").unwrap();
    let plain = mount(&mut app, arena, link, DistanceSensor::linear(5.0));
    let table = mount(&mut app, arena, link, DistanceSensor::with_lookup(vec![[0.0, 1000.0, 0.0], [4.0, 0.0, 0.0]]));
    let short = mount(&mut app, arena, link, DistanceSensor::linear(1.5));
    app.update();
    let read = |e| app.world().get::<DistanceSensor>(e).unwrap().clone();
    // The wall's near face is at x = 1.95; the ray starts inside the robot's own box, unseen.
    assert!((read(plain).value - 1.95).abs() < 1e-3, "{:?}", read(plain));
    assert!((read(table).value - 1000.0 * (1.0 - 1.95 / 4.0)).abs() < 0.5, "{:?}", read(table));
    assert_eq!(read(short).distance, 1.5, "out of range reads the maximum");
}

#[test]
fn distance_sensor_sees_nothing_where_nothing_is() {
    let base = Pose::from_translation(Vec3::new(0.0, 0.0, 0.5));
    let (mut app, arena, robot) = robot_app(&model_from(PROBE), fixed_at(base), SimSettings::default());
    let sensor = mount(&mut app, arena, robot.link("base").unwrap(), DistanceSensor::linear(5.0));
    app.update();
    assert_eq!(app.world().get::<DistanceSensor>(sensor).unwrap().distance, 5.0);
}

#[test]
fn inertial_unit_reads_roll_pitch_yaw() {
    let rotation = Quat::from_euler(EulerRot::ZYX, 0.5, 0.2, -0.1);
    let base = Pose::from_parts(Vec3::new(0.0, 0.0, 1.0), rotation);
    let (mut app, arena, robot) = robot_app(&model_from(PROBE), fixed_at(base), SimSettings::default());
    let imu = mount(&mut app, arena, robot.link("base").unwrap(), InertialUnit::default());
    app.update();
    let [roll, pitch, yaw] = app.world().get::<InertialUnit>(imu).unwrap().roll_pitch_yaw;
    assert!(
        (roll + 0.1).abs() < 1e-4 && (pitch - 0.2).abs() < 1e-4 && (yaw - 0.5).abs() < 1e-4,
        "{roll} {pitch} {yaw}"
    );
}

#[test]
fn gyro_reads_the_spin_of_its_link() {
    let base = Pose::from_translation(Vec3::new(0.0, 0.0, 1.0));
    let (mut app, arena, robot) = robot_app(&model_from(PROBE), fixed_at(base), SimSettings::default());
    let gyro = mount(&mut app, arena, robot.link("wheel").unwrap(), Gyro::default());
    app.world_mut().get_mut::<Motor>(robot.joint("axle").unwrap()).unwrap().command = MotorCommand::Velocity(3.0);
    for _ in 0..100 {
        app.update();
    }
    let w = app.world().get::<Gyro>(gyro).unwrap().value;
    assert!((w.y - 3.0).abs() < 0.01 && w.x.abs() < 0.01 && w.z.abs() < 0.01, "{w}");
}

#[test]
fn accelerometer_reads_g_at_rest_and_nothing_in_free_fall() {
    let at = |z: f32| SpawnOptions { base: Pose::from_translation(Vec3::new(1.0, 2.0, z)), ..Default::default() };
    // Resting on the ground (cube half-height 0.1).
    let (mut app, arena, robot) = robot_app(&model_from(PROBE), at(0.1), SimSettings::default());
    let base = robot.link("base").unwrap();
    let acc = mount(&mut app, arena, base, Accelerometer::default());
    let gps = mount(&mut app, arena, base, Gps::default());
    let touch = mount(&mut app, arena, base, TouchSensor::default());
    for _ in 0..60 {
        app.update();
    }
    let a = app.world().get::<Accelerometer>(acc).unwrap().value;
    assert!((a - Vec3::new(0.0, 0.0, 9.81)).length() < 0.1, "at rest (contact jitter): {a}");
    let p = app.world().get::<Gps>(gps).unwrap().position;
    assert!((p - Vec3::new(1.0, 2.0, 0.1)).length() < 0.01, "gps {p}");
    let t = *app.world().get::<TouchSensor>(touch).unwrap();
    assert!(t.touching && t.force > 11.0 * 9.81 * 0.9, "touch {t:?}");

    let (mut app, arena, robot) = robot_app(&model_from(PROBE), at(20.0), SimSettings::default());
    let acc = mount(&mut app, arena, robot.link("base").unwrap(), Accelerometer::default());
    let touch = mount(&mut app, arena, robot.link("base").unwrap(), TouchSensor::default());
    for _ in 0..5 {
        app.update();
    }
    let a = app.world().get::<Accelerometer>(acc).unwrap().value;
    assert!(a.length() < 0.05, "free fall: {a}");
    let t = *app.world().get::<TouchSensor>(touch).unwrap();
    assert!(!t.touching && t.force == 0.0, "{t:?}");
}

/// A 2 kg, 0.2 m cube.
const CUBE: &str = r#"<robot name="cube"><link name="base">
  <inertial><mass value="2"/><inertia ixx="0.0133" ixy="0" ixz="0" iyy="0.0133" iyz="0" izz="0.0133"/></inertial>
  <collision><geometry><box size="0.2 0.2 0.2"/></geometry></collision></link></robot>"#;

#[test]
fn touch_sensor_reads_the_weight_of_a_resting_body() {
    let options = SpawnOptions { base: Pose::from_translation(Vec3::new(0.0, 0.0, 0.1)), ..Default::default() };
    let (mut app, arena, robot) = robot_app(&model_from(CUBE), options, SimSettings::default());
    let touch = mount(&mut app, arena, robot.link("base").unwrap(), TouchSensor::default());
    for _ in 0..50 {
        app.update();
    }
    let t = *app.world().get::<TouchSensor>(touch).unwrap();
    assert!(t.touching && (t.force - 2.0 * 9.81).abs() < 0.02 * 2.0 * 9.81, "{t:?}");
}

#[test]
fn sampling_period_holds_readings_between_samples() {
    let (mut app, arena, robot) = robot_app(
        &model_from(PROBE),
        SpawnOptions { base: Pose::from_translation(Vec3::new(0.0, 0.0, 50.0)), ..Default::default() },
        SimSettings::default(),
    );
    let gps = app
        .world_mut()
        .spawn((
            Gps::default(),
            Mount { link: robot.link("base").unwrap(), offset: Pose::IDENTITY },
            InArena(arena),
            SamplingPeriod(4),
        ))
        .id();
    let mut heights = Vec::new();
    for _ in 0..8 {
        app.update();
        heights.push(app.world().get::<Gps>(gps).unwrap().position.z);
    }
    // Falling all along, but the reading changes only every 4th step.
    let changes = heights.windows(2).filter(|w| w[0] != w[1]).count();
    assert_eq!(changes, 1, "{heights:?}");
}

/// A reset schedule as a task's (`EnvReset`) would have it: devices sample after the restore.
#[derive(bevy::ecs::schedule::ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
struct ResetSense;

#[test]
fn a_reset_samples_every_device_of_the_arena_whatever_its_period() {
    let (mut app, arena, robot) = robot_app(
        &model_from(PROBE),
        SpawnOptions { base: Pose::from_translation(Vec3::new(0.0, 0.0, 50.0)), ..Default::default() },
        SimSettings::default(),
    );
    app.add_systems(ResetSense, twinbots_sim::devices::sample_devices());
    let base = robot.link("base").unwrap();
    let gps = app
        .world_mut()
        .spawn((Gps::default(), Mount { link: base, offset: Pose::IDENTITY }, InArena(arena), SamplingPeriod(4)))
        .id();
    let acc = mount(&mut app, arena, base, Accelerometer::default());
    for _ in 0..6 {
        app.update();
    }
    let fallen = app.world().get::<Gps>(gps).unwrap().position.z;
    assert!(fallen < 49.9, "falling: {fallen}");
    assert!(crate::common::with_supervisor(&mut app, |s| s.reset_arena(arena)));
    app.world_mut().run_schedule(ResetSense);
    // Step 6 is not a step of the GPS's period, but the reset reads the start state at once.
    assert_eq!(app.world().get::<Gps>(gps).unwrap().position.z, 50.0);
    // At rest again: +g, with no acceleration read across the jump from free fall.
    let a = app.world().get::<Accelerometer>(acc).unwrap().value;
    assert!((a - Vec3::new(0.0, 0.0, 9.81)).length() < 1e-4, "after the reset: {a}");
    // Nothing changed since: sampling again reads nothing new.
    app.world_mut().get_mut::<Gps>(gps).unwrap().position.z = -1.0;
    app.world_mut().run_schedule(ResetSense);
    assert_eq!(app.world().get::<Gps>(gps).unwrap().position.z, -1.0, "an arena not reset does not sample again");
}

/// A stack of two cubes on the ground and a third falling from high up: each cube's contact
/// sensor names what its body touches — the ground (no link), the other cube's link — and the
/// falling one touches nothing.
#[test]
fn contact_sensor_tells_what_its_body_touches() {
    let cube = model_from(CUBE);
    // Objects of the cell (the environment group) touch each other; robots' links would not.
    let at = |z: f32| SpawnOptions {
        base: Pose::from_translation(Vec3::new(0.0, 0.0, z)),
        environment: true,
        ..Default::default()
    };
    let (mut app, arena, bottom) = robot_app(&cube, at(0.1), SimSettings::default());
    let top = spawn_into(&mut app, arena, &cube, at(0.3));
    let falling = spawn_into(
        &mut app,
        arena,
        &cube,
        SpawnOptions { base: Pose::from_translation(Vec3::new(3.0, 0.0, 50.0)), ..at(0.0) },
    );
    let link = |r: &twinbots_sim::SpawnedRobot| r.link("base").unwrap();
    let sensors = [&bottom, &top, &falling].map(|r| mount(&mut app, arena, link(r), ContactSensor::default()));
    for _ in 0..30 {
        app.update();
    }
    let read = |e| app.world().get::<ContactSensor>(e).unwrap().clone();
    let below = read(sensors[0]);
    assert_eq!(below.contacts.len(), 2, "{below:?}");
    assert!(
        below.contacts.contains(&Touched::Fixed) && below.contacts.contains(&Touched::Link(link(&top))),
        "{below:?}"
    );
    assert_eq!(read(sensors[1]).contacts, vec![Touched::Link(link(&bottom))]);
    assert!(
        read(sensors[1]).touches_other_than(Touched::Fixed)
            && !read(sensors[1]).touches_other_than(Touched::Link(link(&bottom)))
    );
    assert!(!read(sensors[2]).touching(), "{:?}", read(sensors[2]));
}
