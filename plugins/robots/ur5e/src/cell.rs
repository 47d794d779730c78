//! The assembly cell: a table on the floor, the UR5e bolted to it, two nest fixtures and a part
//! that starts in the pick fixture, where its [`CellLayout`] puts them. The program and the tasks
//! work in the robot's base frame (on the table top, z up, the arm's zero pose pointing along −x).

use std::path::Path;

use bevy::prelude::*;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::{RobotModel, parse_urdf};
use twinbots_sim::{
    Arena, ContactSensor, InArena, Motor, MotorCommand, Mount, SpawnOptions, VacuumGripper, spawn_robot,
};
use twinbots_task::cell::parts::CellFurniture;
pub use twinbots_task::cell::parts::{PART_HEIGHT, PART_RADIUS, POCKET_FLOOR, POCKET_PLAY, part_seat};

use crate::kinematics::JOINTS;
use crate::layout::CellLayout;

pub const URDF: &str = include_str!("../../../../assets/robots/ur5e/ur5e.urdf");
pub const URDF_PATH: &str = "assets/robots/ur5e/ur5e.urdf";
const ASSETS: &str = "assets/robots/ur5e";

/// The suction cup: radius and bellows stroke (m).
pub const CUP_RADIUS: f32 = 0.02;
pub const CUP_STROKE: f32 = 0.015;

/// The links that own the arm's rigid bodies, base to wrist: the flange, the gripper and the
/// tcp are welded to wrist 3's, so its contact sensor also covers the suction cup.
pub const ARM_BODIES: [&str; 7] =
    ["base_link", "shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link"];

/// The robot's base in the arena (world) frame, in the default cell.
pub fn base_pose() -> Pose {
    CellLayout::default().base_pose()
}

/// The cell's models, parsed once.
#[derive(Resource, Clone)]
pub struct CellModels {
    pub robot: RobotModel,
    /// The fixtures and the part.
    pub furniture: CellFurniture,
}

impl Default for CellModels {
    fn default() -> Self {
        Self { robot: model(), furniture: CellFurniture::default() }
    }
}

/// The UR5e's model (checked by the tests).
pub fn model() -> RobotModel {
    let path = Path::new(ASSETS).join("ur5e.urdf");
    parse_urdf(URDF, &path, Path::new(ASSETS)).unwrap_or_else(|e| panic!("built-in URDF {}: {e}", path.display()))
}

/// The entities of an arena's cell, on the arena entity.
#[derive(Component, Clone, Debug)]
pub struct CellParts {
    pub robot: Entity,
    /// The arm's joints, base to wrist.
    pub joints: [Entity; 6],
    /// The suction cup's face: the tool centre point.
    pub tcp: Entity,
    pub gripper: Entity,
    /// A contact sensor on each of the arm's bodies ([`ARM_BODIES`]); the last carries the cup.
    pub contact_sensors: [Entity; 7],
    /// The part's link.
    pub part: Entity,
    /// The robot's base in the arena frame.
    pub base: Pose,
}

/// Builds the cell of `layout` into `arena`, the arm at `start` (joint angles), and returns its
/// parts.
pub fn spawn_cell(
    commands: &mut Commands,
    arena_entity: Entity,
    arena: &mut Arena,
    models: &CellModels,
    layout: &CellLayout,
    start: [f32; 6],
) -> CellParts {
    let base = layout.base_pose();
    let part = models.furniture.spawn(commands, arena_entity, arena, layout);
    let joint_positions = JOINTS.iter().zip(start).map(|(name, q)| (name.to_string(), q)).collect();
    let robot = spawn_robot(
        commands,
        arena_entity,
        arena,
        &models.robot,
        SpawnOptions { base, fixed_base: true, joint_positions, ..default() },
    );
    let get = |found: Option<Entity>, name: &str| found.unwrap_or_else(|| panic!("UR5e URDF has no '{name}'"));
    let joints = JOINTS.map(|name| get(robot.joint(name), name));
    for &joint in &joints {
        // Servo drives: speed commands track a held position reference, and the arm holds its
        // pose (zero speed) until told otherwise, as a powered UR does.
        commands.entity(joint).entry::<Motor>().and_modify(|mut m| {
            m.holds_position = true;
            m.command = MotorCommand::Velocity(0.0);
            m.initial_command = MotorCommand::Velocity(0.0);
        });
    }
    let tcp = get(robot.link("tcp"), "tcp");
    // The cup sucks along the tcp's z; a mounted device's forward axis is its +X.
    let cup = Mount { link: tcp, offset: Pose::from_rotation(Quat::from_rotation_arc(Vec3::X, Vec3::Z)) };
    let gripper = commands.spawn((VacuumGripper::new(CUP_RADIUS, CUP_STROKE), cup, InArena(arena_entity))).id();
    // The arm's skin: what each of its bodies touches, for the collision figure.
    let contact_sensors = ARM_BODIES.map(|name| {
        let mount = Mount { link: get(robot.link(name), name), offset: Pose::IDENTITY };
        commands.spawn((ContactSensor::default(), mount, InArena(arena_entity))).id()
    });
    CellParts { robot: robot.robot(), joints, tcp, gripper, contact_sensors, part, base }
}
