//! The UR5e on its test stand: the arm alone, bolted at the cell's base pose and started at
//! home, its six servo drives under speed commands (a UR's `speedj`) every 8 ms (125 Hz). What
//! `record`, `replay` and `identify` drive; no table, so excitation cannot collide.

use std::borrow::Cow;
use std::sync::Arc;

use bevy::prelude::*;
use twinbots_sim::{Arena, Motor, MotorCommand, SpawnOptions, SpawnedRobot, spawn_robot};
use twinbots_task::robot::{JointExcitation, RigDescription};

use crate::cell::{base_pose, model};
use crate::kinematics::{HOME, JOINTS};
use crate::sim_settings;

/// The twin's nominal joint dynamics (a calibration file's format).
pub const PARAMETERS: &str = include_str!("../../../../assets/robots/ur5e/parameters.toml");

/// Where a calibration starts: published orders of magnitude of a UR5e's joint dynamics.
pub const PRIOR: &str = include_str!("../../../../assets/robots/ur5e/prior.toml");

/// Excitation: each joint within ±0.6 rad of home at up to 1 rad/s.
const EXCITATION: [JointExcitation; 6] = [
    JointExcitation { joint: Cow::Borrowed(JOINTS[0]), channel: 0, speed: 1.0, travel: 0.6 },
    JointExcitation { joint: Cow::Borrowed(JOINTS[1]), channel: 1, speed: 1.0, travel: 0.6 },
    JointExcitation { joint: Cow::Borrowed(JOINTS[2]), channel: 2, speed: 1.0, travel: 0.6 },
    JointExcitation { joint: Cow::Borrowed(JOINTS[3]), channel: 3, speed: 1.0, travel: 0.6 },
    JointExcitation { joint: Cow::Borrowed(JOINTS[4]), channel: 4, speed: 1.0, travel: 0.6 },
    JointExcitation { joint: Cow::Borrowed(JOINTS[5]), channel: 5, speed: 1.0, travel: 0.6 },
];

/// The 6 joints' damping, friction and armature, and the command delay: 19 parameters.
const FIT: [&str; 19] = [
    "shoulder_pan_joint.damping",
    "shoulder_pan_joint.friction",
    "shoulder_pan_joint.armature",
    "shoulder_lift_joint.damping",
    "shoulder_lift_joint.friction",
    "shoulder_lift_joint.armature",
    "elbow_joint.damping",
    "elbow_joint.friction",
    "elbow_joint.armature",
    "wrist_1_joint.damping",
    "wrist_1_joint.friction",
    "wrist_1_joint.armature",
    "wrist_2_joint.damping",
    "wrist_2_joint.friction",
    "wrist_2_joint.armature",
    "wrist_3_joint.damping",
    "wrist_3_joint.friction",
    "wrist_3_joint.armature",
    "command_delay",
];

pub fn rig() -> RigDescription {
    RigDescription {
        model: Arc::new(model),
        settings: sim_settings(),
        nominal: PARAMETERS.into(),
        prior: PRIOR.into(),
        fit: FIT.map(String::from).to_vec(),
        spawn: Arc::new(spawn_arm),
        excitation: EXCITATION.to_vec(),
        command_steps: 2,
    }
}

fn spawn_arm(
    commands: &mut Commands,
    arena_entity: Entity,
    arena: &mut Arena,
    start: &[(String, f32)],
) -> SpawnedRobot {
    let joint_positions = JOINTS
        .iter()
        .zip(HOME)
        .map(|(name, q)| (name.to_string(), start.iter().find(|(n, _)| n == name).map_or(q, |(_, q)| *q)))
        .collect();
    let options = SpawnOptions { base: base_pose(), fixed_base: true, joint_positions, ..default() };
    let robot = spawn_robot(commands, arena_entity, arena, &model(), options);
    for name in JOINTS {
        let joint = robot.joint(name).unwrap_or_else(|| panic!("UR5e URDF has no '{name}'"));
        commands.entity(joint).entry::<Motor>().and_modify(|mut m| {
            m.holds_position = true;
            m.command = MotorCommand::Velocity(0.0);
            m.initial_command = MotorCommand::Velocity(0.0);
        });
    }
    robot
}
