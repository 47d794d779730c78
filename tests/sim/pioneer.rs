//! The Pioneer 3-AT drives straight and turns in place as skid steering predicts, and its
//! sonars read the distance to a wall.

use bevy::math::{EulerRot, Vec3};
use bevy::prelude::*;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::{Arena, DistanceSensor, InArena, Link, Motor, MotorCommand, Mount, SpawnOptions, SpawnedRobot};

use crate::common::{robot_app, robot_app_with};

const WHEELS: [&str; 4] = ["front_left", "front_right", "back_left", "back_right"];

fn on_ground() -> SpawnOptions {
    SpawnOptions { base: Pose::from_translation(Vec3::new(0.0, 0.0, pioneer3at::AXLE_HEIGHT)), ..Default::default() }
}

fn drive(app: &mut App, robot: &SpawnedRobot, speeds: [f32; 4]) {
    for (w, s) in WHEELS.iter().zip(speeds) {
        let joint = robot.joint(&format!("{w}_wheel_joint")).unwrap();
        app.world_mut().get_mut::<Motor>(joint).unwrap().command = MotorCommand::Velocity(s);
    }
}

/// (x, y, yaw) of the base.
fn base(app: &App, arena: Entity, robot: &SpawnedRobot) -> (f32, f32, f32) {
    let link = app.world().get::<Link>(robot.link("base_link").unwrap()).unwrap();
    let pose = *twinbots_sim::physics_in(app.world(), arena).unwrap().bodies[link.body].position();
    let (yaw, _, _) = pose.rotation.to_euler(EulerRot::ZYX);
    (pose.translation.x, pose.translation.y, yaw)
}

#[test]
fn drives_straight_when_all_wheels_turn_alike() {
    let (mut app, arena, robot) = robot_app(&pioneer3at::model(), on_ground(), pioneer3at::sim_settings());
    drive(&mut app, &robot, [3.0; 4]);
    let steps = 40; // 2.56 s
    for _ in 0..steps {
        app.update();
    }
    let (x, y, yaw) = base(&app, arena, &robot);
    let t = steps as f32 * pioneer3at::sim_settings().control_dt();
    let ideal = 3.0 * pioneer3at::WHEEL_RADIUS * t;
    assert!(x > 0.85 * ideal && x < 1.02 * ideal, "x {x:.3} m vs rolling without slip {ideal:.3} m");
    assert!(y.abs() < 0.02 * x && yaw.abs() < 0.02, "straight: y {y:.4}, yaw {yaw:.4}");
}

#[test]
fn turns_in_place_when_the_sides_turn_opposite() {
    let (mut app, arena, robot) = robot_app(&pioneer3at::model(), on_ground(), pioneer3at::sim_settings());
    let w = 2.0;
    drive(&mut app, &robot, [-w, w, -w, w]); // left back, right forward: turn left (+yaw)
    let (mut yaw_total, mut last) = (0.0f32, 0.0f32);
    let steps = 30;
    for _ in 0..steps {
        app.update();
        let (_, _, yaw) = base(&app, arena, &robot);
        let mut d = yaw - last;
        d -= std::f32::consts::TAU * (d / std::f32::consts::TAU).round();
        yaw_total += d;
        last = yaw;
    }
    let (x, y, _) = base(&app, arena, &robot);
    let t = steps as f32 * pioneer3at::sim_settings().control_dt();
    // Differential-drive kinematics give r·2w/B; skid steering turns slower by a slip factor χ
    // (1 ≤ χ ≤ 3 for four-wheel skid steer), since the wheels must scrub sideways.
    let track = 2.0 * 0.197;
    let ideal = pioneer3at::WHEEL_RADIUS * 2.0 * w / track;
    let rate = yaw_total / t;
    assert!(rate > ideal / 3.0 && rate <= ideal * 1.02, "yaw rate {rate:.3} rad/s vs ideal {ideal:.3}");
    assert!((x * x + y * y).sqrt() < 0.05, "in place: moved ({x:.3}, {y:.3})");
}

#[test]
fn sonars_read_the_distance_to_a_wall() {
    let wall = |a: &mut Arena| {
        a.add_static_box(Vec3::new(0.05, 2.0, 0.5), Vec3::new(2.0, 0.0, 0.5), 1.0);
    };
    let (mut app, arena, robot) = robot_app_with(&pioneer3at::model(), on_ground(), pioneer3at::sim_settings(), wall);
    let link = robot.link("base_link").unwrap();
    let sonars: Vec<Entity> = (0..16)
        .map(|i| {
            let mount = Mount { link, offset: pioneer3at::sonar_offset(i) };
            app.world_mut().spawn((DistanceSensor::linear(pioneer3at::SONAR_RANGE), mount, InArena(arena))).id()
        })
        .collect();
    app.update();
    let base_pose = {
        let l = app.world().get::<Link>(link).unwrap();
        *twinbots_sim::physics_in(app.world(), arena).unwrap().bodies[l.body].position() * l.offset
    };
    for (i, &s) in sonars.iter().enumerate() {
        let reading = app.world().get::<DistanceSensor>(s).unwrap().distance;
        let pose = base_pose * pioneer3at::sonar_offset(i);
        let dir = pose.rotation * Vec3::X;
        // The wall's face is the plane x = 1.95; sonars facing away see nothing within range.
        let expected = if dir.x > 1e-3 {
            ((1.95 - pose.translation.x) / dir.x).min(pioneer3at::SONAR_RANGE)
        } else {
            pioneer3at::SONAR_RANGE
        };
        let hits_wall = (pose.translation + dir * expected).y.abs() < 2.0;
        let expected = if hits_wall { expected } else { pioneer3at::SONAR_RANGE };
        assert!(
            (reading - expected).abs() < 0.01,
            "sonar {i} ({}°): {reading:.3} m, expected {expected:.3} m",
            pioneer3at::SONAR_BEARINGS[i]
        );
    }
}
