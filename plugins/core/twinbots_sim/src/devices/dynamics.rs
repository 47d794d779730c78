//! A joint's own dynamics beyond its links' rigid bodies: viscous damping and Coulomb friction
//! (URDF `<dynamics damping friction>`), and armature, the reflected inertia of the motor's
//! rotor and gearbox (MuJoCo's `armature`). These are what system identification fits.

use bevy::prelude::*;

use super::joint::{Joint, JointState};
use super::motor::act_between;
use crate::arena::{Arena, InArena};
use crate::rapier::prelude::*;

/// Speed (rad/s or m/s) over which Coulomb friction rises to its full value: friction is
/// `friction · tanh(v / FRICTION_SMOOTHING)`, a smooth sign that an explicit step can integrate.
pub const FRICTION_SMOOTHING: f32 = 0.05;

/// A joint's damping, friction and armature. Every movable joint has one (zeros where the URDF
/// says nothing); change `armature` through [`set_armature`], which adds it to the child body.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct JointDynamics {
    /// Viscous damping (N·m·s/rad or N·s/m).
    pub damping: f32,
    /// Coulomb friction (N·m or N).
    pub friction: f32,
    /// Reflected rotor inertia (kg·m² or kg) added about the joint's axis.
    armature: f32,
}

impl JointDynamics {
    pub fn new(damping: f32, friction: f32) -> Self {
        Self { damping, friction, armature: 0.0 }
    }

    pub fn armature(&self) -> f32 {
        self.armature
    }

    /// Records that the child body holds `armature` again, after the arena's world was restored
    /// to a snapshot taken with it (so [`set_armature`] adds the next one relative to it).
    pub fn armature_restored(&mut self, armature: f32) {
        self.armature = armature;
    }

    /// The torque (force) damping and friction exert on the joint at speed `v`.
    pub fn torque(&self, v: f32) -> f32 {
        -(self.damping * v + self.friction * (v / FRICTION_SMOOTHING).tanh())
    }
}

/// Sets a joint's armature: the difference to its current one is added to the child body as
/// inertia about the joint's axis (no mass), so the joint's effective inertia grows by exactly
/// that amount. Applied to the world directly; an arena's initial state keeps what it held
/// when it was marked.
pub fn set_armature(world: &mut PhysicsWorld, joint: &Joint, dynamics: &mut JointDynamics, armature: f32) {
    let delta = armature - dynamics.armature;
    if delta == 0.0 {
        return;
    }
    let Some(frame) = world.impulse_joints.get(joint.handle).map(|j| j.data.local_frame2) else { return };
    let Some(body) = world.bodies.get_mut(joint.child_body) else { return };
    let props = match body.mass_properties().additional_local_mprops.as_deref() {
        Some(RigidBodyAdditionalMassProps::MassProps(p)) => *p,
        _ => body.mass_properties().local_mprops,
    };
    if joint.kind.is_rotational() {
        // The rotor's inertia about the axis, added to the body's matrix (a sum of mass
        // properties would drop a negative change, and a smaller armature must come off too).
        let axis = frame.rotation * Vec3::X;
        let rotor = Mat3::from_cols(axis * axis.x, axis * axis.y, axis * axis.z) * delta;
        let inertia = props.reconstruct_inertia_matrix() + rotor;
        body.set_additional_mass_properties(
            MassProperties::with_inertia_matrix(props.local_com, props.mass(), inertia),
            true,
        );
    } else {
        // A linear axis's armature is reflected mass.
        let mut p = props;
        p.set_mass(props.mass() + delta, false);
        body.set_additional_mass_properties(p, true);
    }
    dynamics.armature = armature;
}

/// Applies damping and friction as equal and opposite torques (forces) on the joint's bodies,
/// from the joint's speed over the last physics step, before the motors' constraints are
/// solved: a motor that holds its joint then works against them, and its effort shows them.
/// As forces, not impulses: rapier spreads a force over its solver substeps as it spreads the
/// motor's work, so the motor's solved effort (read from its last substep) includes them; an
/// impulse would land in the first substep only, and the effort would all but miss it.
pub(crate) fn apply_joint_dynamics(
    settings: Res<crate::SimSettings>,
    mut arenas: Query<&mut Arena>,
    joints: Query<(&Joint, &JointState, &JointDynamics, &InArena)>,
) {
    // Forces persist in rapier until reset: clear last step's on every body a joint acts on.
    for (joint, _, _, in_arena) in &joints {
        if let Ok(mut arena) = arenas.get_mut(in_arena.0) {
            for handle in [joint.child_body, joint.parent_body] {
                if let Some(body) = arena.world.bodies.get_mut(handle)
                    && (body.user_force() != Vec3::ZERO || body.user_torque() != Vec3::ZERO)
                {
                    body.reset_forces(false);
                    body.reset_torques(false);
                }
            }
        }
    }
    for (joint, state, dynamics, in_arena) in &joints {
        if dynamics.damping == 0.0 && dynamics.friction == 0.0 {
            continue;
        }
        if let Ok(mut arena) = arenas.get_mut(in_arena.0) {
            let torque = dynamics.torque(state.velocity);
            let limit = stopping_effort(&arena.world, joint, state.velocity, settings.dt);
            add_joint_force(&mut arena.world, joint, torque.clamp(-limit, limit));
        }
    }
}

/// The most damping and friction may exert in one explicit step: what stops the joint's child
/// body alone (its inertia about the joint's axis, or its mass along a sliding one) from speed
/// `v` within `dt`. A light link under a vendor's damping (the xArm7's last link: 1.3e-4 kg·m²
/// under 2 N·m·s/rad, 60 times what a 4 ms step stops) would otherwise swing the sign of its
/// speed every step and grow: the clamp keeps the explicit step from overshooting, and binds
/// only where it would have. The child alone is the least inertia the joint moves, so the
/// clamp never allows an overshoot.
fn stopping_effort(world: &PhysicsWorld, joint: &Joint, v: f32, dt: f32) -> f32 {
    let Some(body) = world.bodies.get(joint.child_body) else { return f32::INFINITY };
    let props = body.mass_properties().local_mprops;
    let inertia = if joint.kind.is_rotational() {
        let Some((axis, _, _)) = joint.measure(world) else { return f32::INFINITY };
        let Some(anchor) =
            world.impulse_joints.get(joint.handle).map(|j| (*body.position() * j.data.local_frame2).translation)
        else {
            return f32::INFINITY;
        };
        let rotation = body.position().rotation;
        let local_axis = rotation.inverse() * axis;
        let about_com = local_axis.dot(props.reconstruct_inertia_matrix() * local_axis);
        let arm = body.center_of_mass() - anchor;
        about_com + props.mass() * (arm - axis * arm.dot(axis)).length_squared()
    } else {
        props.mass()
    };
    inertia * v.abs() / dt
}

/// Adds a torque (force) between the joint's two bodies along its axis, for this physics step.
fn add_joint_force(world: &mut PhysicsWorld, joint: &Joint, effort: f32) {
    act_between(
        world,
        joint,
        effort,
        |body, torque| body.add_torque(torque, true),
        |body, force, at| body.add_force_at_point(force, at, true),
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn friction_opposes_motion_and_saturates() {
        let d = JointDynamics::new(0.5, 2.0);
        assert_eq!(d.torque(0.0), 0.0);
        assert!((d.torque(1.0) - (-0.5 - 2.0)).abs() < 1e-3);
        assert!(d.torque(-1.0) > 0.0);
        assert!(d.torque(0.01).abs() < 1.0, "smooth near rest");
    }
}
