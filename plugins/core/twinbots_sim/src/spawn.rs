//! Building a [`RobotModel`] into an arena: one rigid body per group of links welded by fixed
//! joints, one impulse joint per movable joint, and an entity per link and joint.

use std::collections::HashMap;

use bevy::math::{Mat3, Quat, Vec3};
use bevy::prelude::*;

use crate::arena::{Arena, ENVIRONMENT_GROUP, InArena, ROBOT_GROUP};
use crate::devices::{Joint, JointDynamics, JointState, Motor, PositionSensor};
use crate::rapier::prelude::*;
use crate::robot::{Link, Robot, Visuals};
use crate::urdf::{JointKind, JointModel, RobotModel, Shape};

/// How a robot is placed and attached.
#[derive(Clone, Debug)]
pub struct SpawnOptions {
    /// Pose of the root link in the arena.
    pub base: Pose,
    /// Weld the root to the world. A root link named `world` is always welded.
    pub fixed_base: bool,
    /// Friction coefficient of the robot's colliders.
    pub friction: f32,
    /// Spawn as part of the cell (a fixture, a workpiece) rather than a robot: its colliders
    /// join the environment group, so they touch robots and each other.
    pub environment: bool,
    /// Starting positions (rad or m) of movable joints, by name; the others start at 0.
    pub joint_positions: Vec<(String, f32)>,
    /// Links whose collision meshes are split into convex parts (parry's V-HACD) instead of
    /// one convex hull: concave parts (a nest, a bin, a U-shaped gripper) that something must
    /// enter. Slower to build and to collide; primitives are unaffected.
    pub decompose: Vec<String>,
}

impl Default for SpawnOptions {
    fn default() -> Self {
        Self {
            base: Pose::IDENTITY,
            fixed_base: false,
            friction: 1.0,
            environment: false,
            joint_positions: Vec::new(),
            decompose: Vec::new(),
        }
    }
}

/// The entities a spawn created, by URDF name.
#[derive(Clone, Debug, Default)]
pub struct SpawnedRobot {
    pub robot: Option<Entity>,
    pub links: HashMap<String, Entity>,
    pub joints: HashMap<String, Entity>,
}

impl SpawnedRobot {
    pub fn robot(&self) -> Entity {
        self.robot.expect("spawned robot has an entity")
    }
    /// The entity of a link; `None` if the URDF has no such link.
    pub fn link(&self, name: &str) -> Option<Entity> {
        self.links.get(name).copied()
    }
    /// The entity of a joint; `None` if the URDF has no such joint.
    pub fn joint(&self, name: &str) -> Option<Entity> {
        self.joints.get(name).copied()
    }
}

/// Adds the robot's bodies and joints to `arena` and spawns its entities, all tagged
/// [`InArena`]`(arena_entity)`. Movable joints get a [`JointState`] and [`PositionSensor`];
/// those with a positive `<limit effort>` also get a [`Motor`].
pub fn spawn_robot(
    commands: &mut Commands,
    arena_entity: Entity,
    arena: &mut Arena,
    model: &RobotModel,
    options: SpawnOptions,
) -> SpawnedRobot {
    for (name, _) in &options.joint_positions {
        // A name that is no movable joint of the model is a bug in the calling plugin.
        assert!(
            model.joint(name).is_some_and(|j| j.kind.is_movable()),
            "SpawnOptions::joint_positions names '{name}', which is no movable joint of robot '{}'",
            model.name
        );
    }
    let robot = commands.spawn((Robot { name: model.name.clone() }, InArena(arena_entity))).id();
    let groups = if options.environment {
        InteractionGroups::new(ENVIRONMENT_GROUP, Group::ALL, InteractionTestMode::And)
    } else {
        InteractionGroups::new(ROBOT_GROUP, ENVIRONMENT_GROUP, InteractionTestMode::And)
    };
    let order = model.tree_order();

    // Which link's body each link belongs to, where its frame sits in that body, and in the world.
    let n = model.links.len();
    let mut owner = vec![usize::MAX; n];
    let mut offset = vec![Pose::IDENTITY; n];
    let world_pose = model.link_poses(options.base, |j| start_position(&options, j));
    for &l in &order {
        match model.parent_joint(l) {
            None => owner[l] = l,
            Some(j) => {
                if j.kind == JointKind::Fixed {
                    owner[l] = owner[j.parent];
                    offset[l] = offset[j.parent] * j.origin;
                } else {
                    owner[l] = l;
                }
            }
        }
    }

    let root = model.root;
    let fixed = options.fixed_base || model.links[root].name == "world";
    let mut bodies: HashMap<usize, RigidBodyHandle> = HashMap::new();
    for &l in order.iter().filter(|&&l| owner[l] == l) {
        let mass = body_mass(model, &owner, &offset, l);
        let builder = if l == root && fixed { RigidBodyBuilder::fixed() } else { RigidBodyBuilder::dynamic() };
        // A robot never sleeps (rapier would freeze an arm holding still under its motors); a
        // part of the cell may, once at rest: its contacts then leave the solver until touched.
        let mut builder = builder.pose(world_pose[l]).can_sleep(options.environment);
        if let Some(mass) = mass {
            builder = builder.additional_mass_properties(mass);
        }
        let handle = arena.world.bodies.insert(builder);
        if options.environment {
            // At rest for 0.1 s rather than rapier's 0.5 s: a part seated at a reset sleeps
            // within three of the UR5e's control steps (a falling part gains 1 m/s in that time,
            // far above the rest threshold of 5 cm/s, so only a part at rest sleeps).
            arena.world.bodies[handle].activation_mut().time_until_sleep = PART_REST_TIME;
        }
        bodies.insert(l, handle);
    }

    let mut spawned = SpawnedRobot { robot: Some(robot), ..default() };
    for &l in &order {
        let body = bodies[&owner[l]];
        let link = &model.links[l];
        for geometry in &link.collisions {
            let decompose = options.decompose.contains(&link.name);
            let collider = collider(&geometry.shape, offset[l] * geometry.origin, decompose)
                .friction(options.friction)
                .density(0.0)
                .collision_groups(groups);
            let w = &mut arena.world;
            w.colliders.insert_with_parent(collider, body, &mut w.bodies);
        }
        let entity = commands
            .spawn((
                Link { name: link.name.clone(), robot, body, offset: offset[l] },
                Visuals(link.visuals.clone()),
                InArena(arena_entity),
            ))
            .id();
        spawned.links.insert(link.name.clone(), entity);
    }

    for j in model.joints.iter().filter(|j| j.kind.is_movable()) {
        let parent_body = bodies[&owner[j.parent]];
        let child_body = bodies[&j.child];
        // Rapier's free axis is local X: turn X onto the URDF axis in both frames.
        let align = Pose::from_rotation(Quat::from_rotation_arc(Vec3::X, j.axis));
        let locked = if j.kind.is_rotational() {
            JointAxesMask::LOCKED_REVOLUTE_AXES
        } else {
            JointAxesMask::LOCKED_PRISMATIC_AXES
        };
        let mut data = GenericJointBuilder::new(locked)
            .local_frame1(offset[j.parent] * j.origin * align)
            .local_frame2(align)
            .contacts_enabled(false)
            .build();
        let axis = if j.kind.is_rotational() { JointAxis::AngX } else { JointAxis::LinX };
        if let Some(stops) = crate::devices::stop_window(j.kind, j.limits.position, start_position(&options, j)) {
            data.set_limits(axis, stops);
        }
        let handle = arena.world.impulse_joints.insert(parent_body, child_body, data, true);
        let joint = Joint {
            name: j.name.clone(),
            kind: j.kind,
            robot,
            handle,
            parent_body,
            child_body,
            limits: j.limits.position,
        };
        let mut state = JointState::measured(&joint, &arena.world);
        if j.kind.is_rotational() {
            // Keep the turns of a starting position beyond ±π (the measurement is wrapped).
            let start = start_position(&options, j);
            state.position += std::f32::consts::TAU * ((start - state.position) / std::f32::consts::TAU).round();
        }
        let dynamics = JointDynamics::new(j.damping, j.friction);
        let mut entity = commands.spawn((joint, state, dynamics, PositionSensor::default(), InArena(arena_entity)));
        if j.limits.effort > 0.0 {
            entity.insert(Motor::new(j.limits.velocity, j.limits.effort));
        }
        spawned.joints.insert(j.name.clone(), entity.id());
    }
    spawned
}

/// Seconds a body of the cell must stay at rest before it sleeps.
const PART_REST_TIME: f32 = 0.1;

/// The starting position `options` give the joint (0 if none).
fn start_position(options: &SpawnOptions, joint: &JointModel) -> f32 {
    options.joint_positions.iter().find(|(name, _)| *name == joint.name).map_or(0.0, |&(_, q)| q)
}

/// The summed mass properties of the links welded into `body`, in that body's frame.
fn body_mass(model: &RobotModel, owner: &[usize], offset: &[Pose], body: usize) -> Option<MassProperties> {
    let mut total: Option<MassProperties> = None;
    for l in (0..model.links.len()).filter(|&l| owner[l] == body) {
        let Some(inertial) = model.links[l].inertial else { continue };
        let frame = offset[l] * inertial.origin;
        let r = Mat3::from_quat(frame.rotation);
        let inertia = r * inertial.inertia * r.transpose();
        let mp = MassProperties::with_inertia_matrix(frame.translation, inertial.mass, inertia);
        total = Some(total.map_or(mp, |t| t + mp));
    }
    total
}

/// The most triangles a collision mesh split into convex parts may have: the split's time
/// grows with them (docs/urdf.md has the measurement), so a larger mesh is refused
/// with its link named rather than left to run for minutes.
pub const MAX_DECOMPOSED_TRIANGLES: usize = 200_000;

/// How a collision mesh is split into convex parts (V-HACD): parry's voxel resolution (64, so
/// at most 64³ voxels whatever the mesh), at most 32 parts (V-HACD 4's default is 64 and
/// parry's 1,024; every part is a shape the narrow phase tests each step).
fn decomposition_parameters() -> crate::rapier::parry::transformation::vhacd::VHACDParameters {
    crate::rapier::parry::transformation::vhacd::VHACDParameters { max_convex_hulls: 32, ..Default::default() }
}

/// A rapier collider for a URDF shape placed at `pose` in its body; a mesh as its convex
/// hull, or split into convex parts (`decompose`; the caller has kept the mesh within
/// [`MAX_DECOMPOSED_TRIANGLES`]).
fn collider(shape: &Shape, pose: Pose, decompose: bool) -> ColliderBuilder {
    if let (true, Shape::Mesh(mesh)) = (decompose, shape) {
        let parameters = decomposition_parameters();
        return ColliderBuilder::convex_decomposition_with_params(&mesh.vertices, &mesh.triangles, &parameters)
            .position(pose);
    }
    let (shape, local) = shape.parry().expect("the URDF loader rejects meshes without a convex hull");
    ColliderBuilder::new(shape).position(pose * local)
}
