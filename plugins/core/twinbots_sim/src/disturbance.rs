//! Disturbances a test engineer applies to a twin: a push on a link for a while ([`Push`]) and
//! a payload added to a link ([`add_link_mass`]). Studies and policy test suites use them to
//! ask how a controller copes with what the task's episodes never contain.

use bevy::prelude::*;

use crate::arena::{Arena, InArena};
use crate::rapier::prelude::*;
use crate::robot::Link;

/// A force on a link, applied in every physics step until `physics_steps` have passed, then
/// removed (with the component). Put it on the link's entity.
///
/// The force acts at `point` (in the link frame), in arena coordinates, recomputed each physics
/// step as the link moves; it replaces any other user force on the link's body while it lasts
/// (nothing else in twinbots applies user forces).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct Push {
    /// Newtons, arena frame.
    pub force: Vec3,
    /// Where it acts, in the link frame (m).
    pub point: Vec3,
    /// Physics steps left to push.
    pub physics_steps: u32,
}

impl Push {
    /// A push lasting `seconds`, rounded to whole physics steps of `dt` (at least one).
    pub fn lasting(force: Vec3, point: Vec3, seconds: f32, dt: f32) -> Self {
        Self { force, point, physics_steps: ((seconds / dt).round() as u32).max(1) }
    }
}

/// In each physics step (`SubstepSet::Actuate`): pushed links get their force, finished pushes
/// let go.
pub(crate) fn apply_pushes(
    mut commands: Commands,
    mut pushes: Query<(Entity, &Link, &InArena, &mut Push)>,
    mut arenas: Query<&mut Arena>,
) {
    for (entity, link, in_arena, mut push) in &mut pushes {
        let Ok(mut arena) = arenas.get_mut(in_arena.0) else { continue };
        let Some(body) = arena.world.bodies.get_mut(link.body) else { continue };
        body.reset_forces(true);
        if push.physics_steps == 0 {
            commands.entity(entity).remove::<Push>();
            continue;
        }
        let point = (*body.position() * link.offset).transform_point(push.point);
        body.add_force_at_point(push.force, point, true);
        push.physics_steps -= 1;
    }
}

/// Adds `mass` (kg; negative takes it away) as a point mass at the link frame's origin: a
/// payload at a pendulum's tip, a part in a gripper. Changes the link body's mass, centre of
/// mass and inertia as a real added mass would. Until the arena is next restored to its initial
/// state (an episode reset undoes it). Errors when the link has no body or the body would end
/// with no positive mass.
pub fn add_link_mass(world: &mut PhysicsWorld, link: &Link, mass: f32) -> Result<(), String> {
    let body =
        world.bodies.get_mut(link.body).ok_or_else(|| format!("link '{}' has no body in its arena", link.name))?;
    let current = body.mass_properties().additional_local_mprops.as_deref().cloned();
    let base = match current {
        Some(RigidBodyAdditionalMassProps::MassProps(props)) => props,
        _ => MassProperties::default(),
    };
    let point = MassProperties::new(link.offset.translation, mass.abs(), Vec3::ZERO);
    let changed = if mass >= 0.0 { base + point } else { base - point };
    if !(changed.mass() > 0.0) {
        return Err(format!("link '{}': taking {} kg away leaves its body without mass", link.name, -mass));
    }
    body.set_additional_mass_properties(changed, true);
    Ok(())
}
