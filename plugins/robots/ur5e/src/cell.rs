//! The assembly cell: a table on the floor, the UR5e bolted to it, two nest fixtures and a part
//! that starts in the pick fixture, where its [`CellLayout`] puts them. The program and the tasks
//! work in the robot's base frame (on the table top, z up, the arm's zero pose pointing along −x).

use std::path::Path;

use bevy::prelude::*;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::{RobotModel, parse_urdf};
use twinbots_sim::{
    Arena, ContactSensor, Handled, InArena, Motor, MotorCommand, Mount, SpawnOptions, VacuumGripper, spawn_robot,
};

use crate::kinematics::JOINTS;
use crate::layout::CellLayout;

pub const URDF: &str = include_str!("../../../../assets/robots/ur5e/ur5e.urdf");
pub const URDF_PATH: &str = "assets/robots/ur5e/ur5e.urdf";
const FIXTURE_URDF: &str = include_str!("../../../../assets/robots/ur5e/fixture.urdf");
const PART_URDF: &str = include_str!("../../../../assets/robots/ur5e/part.urdf");
const ASSETS: &str = "assets/robots/ur5e";

/// Thickness of a fixture's plate: the pocket floor's height.
pub const POCKET_FLOOR: f32 = 0.02;
/// How far the part can sit off its pocket's centre (m): an 8 cm pocket for a 5 cm part.
pub const POCKET_PLAY: f32 = 0.015;
pub const PART_HEIGHT: f32 = 0.05;
pub const PART_RADIUS: f32 = 0.025;
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

/// Where the part rests in a fixture: its bottom on the pocket floor, in the base frame.
pub fn part_seat(fixture: Vec3) -> Vec3 {
    fixture + Vec3::new(0.0, 0.0, POCKET_FLOOR)
}

/// The cell's models, parsed once.
#[derive(Resource, Clone)]
pub struct CellModels {
    pub robot: RobotModel,
    pub fixture: RobotModel,
    pub part: RobotModel,
}

fn parse(text: &str, file: &str) -> RobotModel {
    let path = Path::new(ASSETS).join(file);
    parse_urdf(text, &path, Path::new(ASSETS)).unwrap_or_else(|e| panic!("built-in URDF {}: {e}", path.display()))
}

impl Default for CellModels {
    fn default() -> Self {
        Self { robot: model(), fixture: parse(FIXTURE_URDF, "fixture.urdf"), part: parse(PART_URDF, "part.urdf") }
    }
}

/// The UR5e's model (checked by the tests).
pub fn model() -> RobotModel {
    parse(URDF, "ur5e.urdf")
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
    arena.add_ground(layout.floor.friction);
    let table = &layout.table;
    let half = Vec3::new(table.size[0] / 2.0, table.size[1] / 2.0, table.height / 2.0);
    arena.add_static_box(half, Vec3::new(table.centre[0], table.centre[1], table.height / 2.0), table.friction);
    for obstacle in &layout.obstacles {
        arena.add_static_box(Vec3::from(obstacle.size) / 2.0, Vec3::from(obstacle.centre), 0.8);
    }
    for fixture in [&layout.pick, &layout.place] {
        let pose = layout.fixture_pose(fixture);
        spawn_robot(
            commands,
            arena_entity,
            arena,
            &models.fixture,
            SpawnOptions { base: pose, fixed_base: true, environment: true, ..default() },
        );
    }
    let part_pose = base * Pose::from_translation(part_seat(layout.fixtures().pick));
    let part = spawn_robot(
        commands,
        arena_entity,
        arena,
        &models.part,
        SpawnOptions { base: part_pose, environment: true, friction: 0.8, ..default() },
    );

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
    // The workpiece: the one thing of the cell a person puts back by hand.
    let part = get(part.link("part"), "part");
    commands.entity(part).insert(Handled);
    CellParts { robot: robot.robot(), joints, tcp, gripper, contact_sensors, part, base }
}
