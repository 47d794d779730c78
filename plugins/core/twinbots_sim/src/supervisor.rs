//! The Supervisor: privileged access to the simulated world, as in Webots.
//!
//! It reads and moves any body and resets arenas. Real robots have nothing like it, so it is a
//! separate `SystemParam` that a task must ask for by name; design pattern 3 never does.

use std::collections::{HashMap, VecDeque};

use bevy::ecs::system::SystemParam;
use bevy::math::Vec3;
use bevy::prelude::*;

use crate::arena::{Arena, InArena};
use crate::devices::{Joint, JointState, Motor, VacuumGripper};
pub use crate::privilege::SupervisorAccess;
use crate::rapier::prelude::*;
use crate::robot::Link;

/// Pose and velocity of a link frame, in arena coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkState {
    pub pose: Pose,
    /// Linear velocity of the link frame's origin.
    pub linvel: Vec3,
    pub angvel: Vec3,
}

/// Grants the [`Supervisor`] (design patterns 1 and 2). Pattern-3 apps leave it out, and any
/// system that asks for the Supervisor there fails on its first run.
pub struct SupervisorPlugin;

impl Plugin for SupervisorPlugin {
    fn build(&self, app: &mut App) {
        app.insert_resource(SupervisorAccess::granted());
    }
}

/// Present in apps with a lab operator (see [`Operator`]).
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct OperatorAccess;

type JointQuery<'w, 's> =
    Query<'w, 's, (&'static Joint, &'static InArena, &'static mut JointState, Option<&'static mut Motor>)>;

#[derive(SystemParam)]
pub struct Supervisor<'w, 's> {
    /// Named for the error a pattern-3 app raises: "Parameter `…::design_pattern_3_forbids_the_supervisor`
    /// failed validation: Resource does not exist".
    design_pattern_3_forbids_the_supervisor: Res<'w, SupervisorAccess>,
    arenas: Query<'w, 's, &'static mut Arena>,
    links: Query<'w, 's, (&'static Link, &'static InArena)>,
    joints: JointQuery<'w, 's>,
    grippers: Query<'w, 's, (&'static mut VacuumGripper, &'static InArena)>,
}

/// An object the lab operator handles: a workpiece it puts back in its fixture (the link of a
/// free body), or a hinge it holds and lets go (the pendulum's joint). The cell marks them when
/// it is built; the [`Operator`] touches and sees nothing else.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct Handled;

/// A person in the lab: outside the robot, at one arena's cell, able to put an object on a
/// hinge (the pendulum) at a given angle and hold it there, or a workpiece back in its
/// fixture, and to see where that workpiece lies. Design pattern 3 resets episodes through
/// explicitly named operator events like this one, never through the robot. It reaches only
/// objects marked [`Handled`], and only in the arena named in the call: what a real operator
/// standing at that cell can see and hold (calls beyond it return `false` / `None`).
#[derive(SystemParam)]
pub struct Operator<'w, 's> {
    #[allow(dead_code)]
    this_app_has_no_lab_operator: Res<'w, OperatorAccess>,
    arenas: Query<'w, 's, &'static mut Arena>,
    handled: Query<'w, 's, &'static InArena, With<Handled>>,
    links: Query<'w, 's, (&'static Link, &'static InArena)>,
    joints: JointQuery<'w, 's>,
}

impl Operator<'_, '_> {
    /// Whether `object` is one the operator handles, at `arena`'s cell.
    fn reaches(&self, arena: Entity, object: Entity) -> bool {
        self.handled.get(object).is_ok_and(|at| at.0 == arena)
    }

    /// At `arena`'s cell, puts the handled `joint` at `position` with the parts beyond it at
    /// rest relative to its parent.
    pub fn place_joint(&mut self, arena: Entity, joint: Entity, position: f32) -> bool {
        self.reaches(arena, joint) && place_joint(&mut self.arenas, &mut self.joints, joint, position)
    }

    /// At `arena`'s cell, puts a handled loose object (a workpiece: the link of a free body) at
    /// `pose`, at rest, as an operator puts a part back in its fixture.
    pub fn place_object(&mut self, arena: Entity, link: Entity, pose: Pose) -> bool {
        self.reaches(arena, link)
            && move_body(&mut self.arenas, &self.links, link, |body, offset| {
                body.set_position(pose * offset.inverse(), true);
                body.set_linvel(Vec3::ZERO, true);
                body.set_angvel(Vec3::ZERO, true);
            })
    }

    /// Where a handled object's link frame is now, at `arena`'s cell (the operator sees it).
    pub fn object_pose(&self, arena: Entity, link: Entity) -> Option<Pose> {
        if !self.reaches(arena, link) {
            return None;
        }
        let (link, in_arena) = self.links.get(link).ok()?;
        let body = self.arenas.get(in_arena.0).ok()?.world.bodies.get(link.body)?;
        Some(*body.position() * link.offset)
    }
}

/// Applies `change` to the body of `link` (given the link's offset in it).
fn move_body(
    arenas: &mut Query<&mut Arena>,
    links: &Query<(&Link, &InArena)>,
    link: Entity,
    change: impl FnOnce(&mut RigidBody, Pose),
) -> bool {
    let Ok((link, in_arena)) = links.get(link) else { return false };
    let Ok(mut arena) = arenas.get_mut(in_arena.0) else { return false };
    let Some(body) = arena.world.bodies.get_mut(link.body) else { return false };
    change(body, link.offset);
    true
}

impl Supervisor<'_, '_> {
    /// The arena component of an arena entity.
    pub fn arena(&self, arena: Entity) -> Option<&Arena> {
        self.arenas.get(arena).ok()
    }

    /// The arena component, mutably (its random stream, its world).
    pub fn arena_mut(&mut self, arena: Entity) -> Option<Mut<'_, Arena>> {
        self.arenas.get_mut(arena).ok()
    }

    /// Pose and velocity of any link.
    pub fn link_state(&self, link: Entity) -> Option<LinkState> {
        let (link, in_arena) = self.links.get(link).ok()?;
        let body = self.arenas.get(in_arena.0).ok()?.world.bodies.get(link.body)?;
        let pose = *body.position() * link.offset;
        Some(LinkState { pose, linvel: body.velocity_at_point(pose.translation), angvel: body.angvel() })
    }

    /// The true position of any joint (privileged: no sensor noise, no sampling period).
    pub fn joint_position(&self, joint: Entity) -> Option<f32> {
        self.joints.get(joint).ok().map(|(_, _, state, _)| state.position)
    }

    /// Teleports a link's body so that the link frame lands on `pose`, keeping its velocity.
    /// Only that body moves: joints pull the rest along on the next step.
    pub fn set_link_pose(&mut self, link: Entity, pose: Pose) -> bool {
        move_body(&mut self.arenas, &self.links, link, |body, offset| body.set_position(pose * offset.inverse(), true))
    }

    /// Sets a link body's linear and angular velocity.
    pub fn set_link_velocity(&mut self, link: Entity, linvel: Vec3, angvel: Vec3) -> bool {
        move_body(&mut self.arenas, &self.links, link, |body, _| {
            body.set_linvel(linvel, true);
            body.set_angvel(angvel, true);
        })
    }

    /// Puts a joint at `position` by moving its child body and everything beyond it rigidly,
    /// with zero relative velocity: a teleport only the Supervisor can do.
    pub fn set_joint_position(&mut self, joint: Entity, position: f32) -> bool {
        place_joint(&mut self.arenas, &mut self.joints, joint, position)
    }

    /// Puts an arena back to exactly its initial state: every body's pose and velocity, joint
    /// positions, motor commands, and grippers off and empty. Returns false for an unknown arena or one never marked.
    pub fn reset_arena(&mut self, arena: Entity) -> bool {
        let Ok(mut a) = self.arenas.get_mut(arena) else { return false };
        if !a.restore_initial(&self.design_pattern_3_forbids_the_supervisor) {
            return false;
        }
        for (_, in_arena, _, motor) in &mut self.joints {
            if in_arena.0 == arena
                && let Some(mut motor) = motor
            {
                motor.command = motor.initial_command;
                motor.clear_history();
                motor.forget_reference();
            }
        }
        for (mut gripper, in_arena) in &mut self.grippers {
            if in_arena.0 == arena {
                gripper.forget();
            }
        }
        self.remeasure(arena);
        true
    }

    fn remeasure(&mut self, arena: Entity) {
        remeasure(&self.arenas, &mut self.joints, arena);
    }
}

/// Moves a joint's child body and everything beyond it rigidly so the joint reads `position`.
fn place_joint(arenas: &mut Query<&mut Arena>, joints: &mut JointQuery, joint: Entity, position: f32) -> bool {
    let Ok((j, in_arena, _, _)) = joints.get(joint) else { return false };
    let (j, arena_entity) = (j.clone(), in_arena.0);
    // Bodies beyond the joint, through the robot's other joints.
    let mut children: HashMap<RigidBodyHandle, Vec<RigidBodyHandle>> = HashMap::new();
    for (other, a, _, _) in joints.iter() {
        if a.0 == arena_entity && other.robot == j.robot {
            children.entry(other.parent_body).or_default().push(other.child_body);
        }
    }
    let Ok(mut arena) = arenas.get_mut(arena_entity) else { return false };
    let world = &mut arena.world;
    let Some((axis, current, _)) = j.measure(world) else { return false };
    let Some(data) = world.impulse_joints.get(j.handle).map(|ij| ij.data) else { return false };
    let Some(child) = world.bodies.get(j.child_body) else { return false };
    let anchor = (*child.position() * data.local_frame2).translation;
    let delta = position - current;
    let motion = if j.kind.is_rotational() {
        Pose::from_translation(anchor)
            * Pose::from_rotation(Quat::from_axis_angle(axis, delta))
            * Pose::from_translation(-anchor)
    } else {
        Pose::from_translation(axis * delta)
    };
    let parent_vel = world.bodies.get(j.parent_body).map(|b| (b.linvel(), b.angvel()));
    let mut queue = VecDeque::from([j.child_body]);
    while let Some(handle) = queue.pop_front() {
        if let Some(body) = world.bodies.get_mut(handle) {
            body.set_position(motion * *body.position(), true);
            if let Some((v, w)) = parent_vel {
                body.set_linvel(v, true);
                body.set_angvel(w, true);
            }
        }
        queue.extend(children.get(&handle).into_iter().flatten().copied());
    }
    remeasure(arenas, joints, arena_entity);
    true
}

/// Re-reads joint states from the world after a teleport; holding motors restart from there.
fn remeasure(arenas: &Query<&mut Arena>, joints: &mut JointQuery, arena: Entity) {
    let Ok(a) = arenas.get(arena) else { return };
    for (joint, in_arena, mut state, motor) in joints.iter_mut() {
        if in_arena.0 == arena {
            *state = JointState::measured(joint, &a.world);
            if let Some(mut motor) = motor {
                motor.forget_reference();
            }
        }
    }
}
