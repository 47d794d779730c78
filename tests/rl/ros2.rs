//! The twin behind `twinbots ros2`, without the network: forward commands and trajectories move
//! it, limits clip what goes beyond them, bad commands are refused and change nothing, and the
//! frames it publishes are the robot's kinematics. (The DDS side is met by Cyclone DDS in
//! python/tests/test_ros2.py.)

use std::collections::HashMap;

use bevy::math::{DMat4, DQuat, DVec3};
use twinbots_ops::ros2::Ros2Twin;
use twinbots_ros2::messages::{Duration, Time};
use twinbots_ros2::{Command, Interface, JointTrajectory, JointTrajectoryPoint, TFMessage};
use twinbots_run::registry;

fn ur5e() -> Ros2Twin {
    Ros2Twin::new(&registry::find("ur5e").unwrap(), &Default::default()).unwrap()
}

fn positions(twin: &Ros2Twin) -> Vec<f64> {
    twin.joint_state(Time::default()).position
}

fn run(twin: &mut Ros2Twin, seconds: f64) {
    let steps = (seconds / twin.dt()).round() as usize;
    for _ in 0..steps {
        twin.step();
    }
}

fn near(a: &[f64], b: &[f64], tolerance: f64) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() < tolerance)
}

#[test]
fn forward_commands_move_the_twin_and_limits_clip_them() {
    let mut twin = ur5e();
    let start = positions(&twin);
    run(&mut twin, 0.5);
    assert!(near(&positions(&twin), &start, 0.005), "the drives hold the arm where it starts");

    let target: Vec<f64> = start.iter().zip([0.3, -0.2, 0.25, 0.2, 0.3, -0.4]).map(|(a, d)| a + d).collect();
    assert_eq!(twin.apply(Command::Forward(Interface::Position, target.clone()), 0.0), Ok(0));
    run(&mut twin, 2.0);
    assert!(near(&positions(&twin), &target, 0.01), "{:?} vs {target:?}", positions(&twin));

    // The elbow's stops are at +-pi: a target of 4 rad is clipped there; speeds to the limit.
    let mut beyond = target.clone();
    beyond[2] = 4.0;
    assert_eq!(twin.apply(Command::Forward(Interface::Position, beyond), 0.0), Ok(1));
    run(&mut twin, 3.0);
    assert!(positions(&twin)[2] <= std::f64::consts::PI + 0.01, "{:?}", positions(&twin));
    assert_eq!(twin.apply(Command::Forward(Interface::Velocity, vec![0.0, 0.0, 0.0, 0.0, 0.0, 100.0]), 0.0), Ok(1));
    run(&mut twin, 0.5);
    let speed = twin.joint_state(Time::default()).velocity[5];
    assert!(speed > 1.0 && speed <= ur5e::kinematics::MAX_JOINT_SPEED as f64 + 0.05, "wrist 3 at {speed} rad/s");
}

#[test]
fn bad_commands_are_refused_and_change_nothing() {
    let mut twin = ur5e();
    let start = positions(&twin);
    let e = twin.apply(Command::Forward(Interface::Position, vec![0.0; 5]), 0.0).unwrap_err();
    assert!(e.starts_with("5 values for 6 joints (shoulder_pan_joint, shoulder_lift_joint"), "{e}");
    let mut nan = start.clone();
    nan[3] = f64::NAN;
    let e = twin.apply(Command::Forward(Interface::Effort, nan), 0.0).unwrap_err();
    assert!(e.contains("effort command NaN is not a number"), "{e}");
    let bad = JointTrajectory {
        joint_names: vec!["elbow".into()],
        points: vec![JointTrajectoryPoint::default()],
        ..Default::default()
    };
    let e = twin.apply(Command::Trajectory(bad), 0.0).unwrap_err();
    assert!(e.contains("no commandable joint 'elbow' (the robot's: shoulder_pan_joint"), "{e}");
    run(&mut twin, 0.5);
    assert!(near(&positions(&twin), &start, 0.005), "still holding");
}

#[test]
fn a_trajectory_is_followed_through_its_points() {
    let mut twin = ur5e();
    let start = positions(&twin);
    let point = |q: f64, t: f64| JointTrajectoryPoint {
        positions: vec![q],
        time_from_start: Duration::from_seconds(t),
        ..Default::default()
    };
    let message = JointTrajectory {
        joint_names: vec!["shoulder_pan_joint".into()],
        points: vec![point(0.5, 1.0), point(-0.5, 3.0)],
        ..Default::default()
    };
    assert_eq!(twin.apply(Command::Trajectory(message), 0.0), Ok(0));
    run(&mut twin, 1.0);
    assert!((positions(&twin)[0] - 0.5).abs() < 0.05, "{:?}", positions(&twin));
    run(&mut twin, 1.0);
    assert!(positions(&twin)[0].abs() < 0.05, "half way back: {:?}", positions(&twin));
    run(&mut twin, 2.0);
    let end = positions(&twin);
    assert!((end[0] + 0.5).abs() < 0.01, "{end:?}");
    assert!(near(&end[1..], &start[1..], 0.01), "the joints it does not name hold: {end:?}");
}

/// The pose of `child` in `root`'s frame, chained through the messages' transforms.
fn chain(messages: &[&TFMessage], root: &str, child: &str) -> DMat4 {
    let mut by_child: HashMap<&str, (&str, DMat4)> = HashMap::new();
    for m in messages {
        for t in &m.transforms {
            let (p, r) = (t.transform.translation, t.transform.rotation);
            let pose =
                DMat4::from_rotation_translation(DQuat::from_xyzw(r.x, r.y, r.z, r.w), DVec3::new(p.x, p.y, p.z));
            by_child.insert(&t.child_frame_id, (&t.header.frame_id, pose));
        }
    }
    let mut pose = DMat4::IDENTITY;
    let mut frame = child;
    while frame != root {
        let (parent, step) = by_child.get(frame).unwrap_or_else(|| panic!("no transform to {frame}"));
        pose = *step * pose;
        frame = parent;
    }
    pose
}

#[test]
fn the_frames_are_the_robots_kinematics() {
    let mut twin = ur5e();
    let target = vec![0.4, -1.2, 1.1, -1.4, -1.3, 0.7];
    twin.apply(Command::Forward(Interface::Position, target), 0.0).unwrap();
    run(&mut twin, 2.0);
    let q: Vec<f32> = positions(&twin).iter().map(|&v| v as f32).collect();
    let (moving, fixed) = (twin.frames(Time::default()), twin.fixed_frames(Time::default()));
    let flange = chain(&[&moving, &fixed], "base_link", "tool0");
    let dh = ur5e::kinematics::flange(&q.try_into().unwrap());
    let (a, b) = (flange.w_axis.truncate(), dh.w_axis.truncate());
    assert!((a - b).length() < 1e-3, "tool0 at {a} by /tf, {b} by UR's DH table");
    assert!((flange.z_axis.truncate() - dh.z_axis.truncate()).length() < 1e-3, "the tool axis agrees");
}

#[test]
fn the_cartpoles_wheels_take_speeds_its_pole_none_and_its_base_moves_in_the_world() {
    let mut twin = Ros2Twin::new(&registry::find("cartpole").unwrap(), &Default::default()).unwrap();
    let joints: Vec<String> = twin.commandable().map(String::from).collect();
    let names = twin.joint_state(Time::default()).name;
    assert!(joints.len() >= 2 && joints.iter().all(|j| j.contains("wheel")), "the wheels have motors: {joints:?}");
    assert_eq!(names.len(), joints.len() + 1, "the pole's hinge is published, not commanded: {names:?}");
    let base = |twin: &Ros2Twin| {
        let frames = twin.frames(Time::default());
        let t = frames
            .transforms
            .iter()
            .find(|t| t.header.frame_id == "world")
            .expect("the base in the world")
            .transform
            .translation;
        DVec3::new(t.x, t.y, t.z)
    };
    let before = base(&twin);
    twin.apply(Command::Forward(Interface::Velocity, vec![5.0; joints.len()]), 0.0).unwrap();
    run(&mut twin, 1.0);
    let moved = base(&twin) - before;
    assert!(moved.length() > 0.05, "the base moved {moved} m");
}

#[test]
fn a_payload_hangs_on_the_flange_as_ur_sims_does() {
    let rig = |name| twinbots_sysid::Rig::of(&registry::find(name).unwrap()).unwrap();
    // The UR5e's last moving link is wrist_3_link; tool0 is fixed to it (then the gripper and
    // its tcp beyond): the flange is tool0, ur-sim's FLANGE.
    assert_eq!(twinbots_ops::ros2::flange_link(&rig("ur5e")).unwrap(), twinbots_ops::ur_sim::FLANGE);
}
