//! A suction gripper, in the manner of Webots' Connector as used for vacuum grippers: switched
//! on, it seizes the nearest loose object whose surface lies within the cup's stroke in front
//! of the cup face (the mount's +X axis) and holds it by a rigid joint; switched off, it lets
//! go. It holds objects only, never robot links or the fixed cell. Unlike Webots' Connector,
//! which holds an object at the pose it had, the cup draws it in against its face, as a bellows
//! cup contracts under vacuum: where in the stroke it was seized does not change how it hangs.

use bevy::math::Vec3;
use bevy::prelude::*;

use super::mount::Mount;
use crate::arena::{Arena, ENVIRONMENT_GROUP, InArena};
use crate::rapier::parry::shape::Cylinder as CylinderShape;
use crate::rapier::prelude::*;
use crate::robot::Link;

#[derive(Component, Clone, Debug, PartialEq)]
pub struct VacuumGripper {
    /// Suction on: seize an object in reach, and keep holding it.
    pub on: bool,
    /// How far in front of the cup face (m) an object's surface may be to be seized: the
    /// stroke of the cup's bellows.
    pub stroke: f32,
    /// Radius of the cup (m): the object's surface must lie within it, sideways.
    pub radius: f32,
    /// A leaking cup (a torn seal, a blocked line: a failed grasp, as studies stage it):
    /// switched on, it seizes nothing.
    pub leaking: bool,
    /// The object held and the joint holding it.
    held: Option<(RigidBodyHandle, ImpulseJointHandle)>,
}

impl VacuumGripper {
    pub fn new(radius: f32, stroke: f32) -> Self {
        Self { on: false, stroke, radius, leaking: false, held: None }
    }

    /// The body held, if any.
    pub fn held(&self) -> Option<RigidBodyHandle> {
        self.held.map(|(body, _)| body)
    }

    /// Forgets what it held without touching the world: for when the world was restored to a
    /// state without the holding joint (an arena reset).
    pub fn forget(&mut self) {
        self.held = None;
        self.on = false;
    }
}

/// Runs before every physics step, so an object is seized the moment it comes within reach.
pub(crate) fn operate_vacuum_grippers(
    links: Query<&Link>,
    mut arenas: Query<&mut Arena>,
    mut grippers: Query<(&mut VacuumGripper, &Mount, &InArena)>,
) {
    for (mut gripper, mount, in_arena) in &mut grippers {
        let Ok(mut arena) = arenas.get_mut(in_arena.0) else { continue };
        let world = &mut arena.world;
        match (gripper.on, gripper.held) {
            (false, Some((_, joint))) => {
                world.impulse_joints.remove(joint, true);
                gripper.held = None;
            }
            (true, None) if !gripper.leaking => {
                let Some(state) = mount.state(&links, world) else { continue };
                if let Some((object, surface)) = object_in_reach(world, state.pose, state.body, &gripper) {
                    gripper.held = Some((object, hold(world, state.body, object, drawn_in(state.pose, surface))));
                }
            }
            _ => {}
        }
    }
}

/// The nearest loose object (a dynamic body in the environment group) whose surface lies in
/// the cylinder of the cup's radius and stroke in front of the cup face, and the point of its
/// surface nearest the face's centre.
fn object_in_reach(
    world: &PhysicsWorld,
    cup: Pose,
    own_body: RigidBodyHandle,
    gripper: &VacuumGripper,
) -> Option<(RigidBodyHandle, Vec3)> {
    let axis = cup.rotation * Vec3::X;
    // The reach cylinder; rapier's cylinders run along their local Y.
    let centre = cup.translation + axis * (gripper.stroke / 2.0);
    let region = Pose::from_parts(centre, Quat::from_rotation_arc(Vec3::Y, axis));
    let shape = CylinderShape::new(gripper.stroke / 2.0, gripper.radius);
    let loose = |_: ColliderHandle, c: &Collider| {
        c.collision_groups().memberships.contains(ENVIRONMENT_GROUP)
            && c.parent().is_some_and(|b| b != own_body && world.bodies.get(b).is_some_and(|b| b.is_dynamic()))
    };
    let filter = QueryFilter::new().predicate(&loose);
    world
        .intersect_shape(region, &shape, filter)
        .filter_map(|(_, c)| {
            let surface = c.shape().project_point(c.position(), cup.translation, false).point;
            Some((c.parent()?, surface))
        })
        .min_by(|a, b| a.1.distance(cup.translation).total_cmp(&b.1.distance(cup.translation)))
}

/// How the cup moves an object it seizes (a world-frame motion): drawn in along the cup's
/// axis until the surface nearest the face's centre touches it, as the bellows contract.
fn drawn_in(cup: Pose, surface: Vec3) -> Pose {
    let axis = cup.rotation * Vec3::X;
    Pose::from_translation(-axis * (surface - cup.translation).dot(axis))
}

/// A rigid joint between the cup's body and the object, at their relative pose once the
/// object is moved by `draw_in` (world frame): against the cup face.
fn hold(
    world: &mut PhysicsWorld,
    cup_body: RigidBodyHandle,
    object: RigidBodyHandle,
    draw_in: Pose,
) -> ImpulseJointHandle {
    let relative = match (world.bodies.get(cup_body), world.bodies.get(object)) {
        (Some(a), Some(b)) => a.position().inv_mul(&(draw_in * *b.position())),
        _ => Pose::IDENTITY,
    };
    let joint = GenericJointBuilder::new(JointAxesMask::LOCKED_FIXED_AXES)
        .local_frame1(relative)
        .local_frame2(Pose::IDENTITY)
        .contacts_enabled(false)
        .build();
    world.impulse_joints.insert(cup_body, object, joint, true)
}
