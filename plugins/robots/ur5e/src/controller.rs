//! A classical resolved-rate controller for the reach, the baseline a learned policy is
//! measured against: the TCP twist that closes the position error and turns the tool down,
//! mapped to joint speeds through the Jacobian by damped least squares, and returned as an
//! action of the reach task.

use bevy::math::Vec3;
use twinbots_sim::rapier::na::{Matrix5, Vector5};

use crate::arm::{ACTION_DIM, ACTION_SPEED, ArmState};
use crate::kinematics;

/// Position gain (1/s) and top TCP speed (m/s) of the reach.
const POSITION_GAIN: f32 = 2.5;
const MAX_SPEED: f32 = 0.5;
/// The same of a straight move: UR's MoveL default speed, and a gain that brings the tool
/// within millimetres without a long creep (0.3 of the error closed per 40 ms control step).
const LINEAR_GAIN: f32 = 8.0;
const LINEAR_SPEED: f32 = 0.25;
/// Gain (1/s) that turns the tool axis down.
const TILT_GAIN: f32 = 3.0;
/// Damping (m) of the least-squares solve, which keeps speeds bounded near singularities.
const DAMPING: f64 = 0.02;

/// The action (speeds of the first five joints in [−1, 1] of [`ACTION_SPEED`]) that moves the
/// tool towards `target`, pointing down. The task is five-dimensional (position, and the two
/// tilts of the tool axis; its yaw is free), as are the joints it commands.
pub fn resolved_rate(arm: &ArmState, target: Vec3) -> Vec<f32> {
    twist_towards(arm, target, POSITION_GAIN, MAX_SPEED)
}

/// The action of a straight move to `target` (a UR's MoveL): the resolved-rate law, stiffer and
/// slower, for the last centimetres of the pick-and-place program.
pub fn move_linear(arm: &ArmState, target: Vec3) -> Vec<f32> {
    twist_towards(arm, target, LINEAR_GAIN, LINEAR_SPEED)
}

fn twist_towards(arm: &ArmState, target: Vec3, gain: f32, max_speed: f32) -> Vec<f32> {
    let error = target - arm.tcp.translation;
    tool_velocity(arm, (error * gain).clamp_length_max(max_speed))
}

/// The action (speeds of the first five joints, as [`resolved_rate`]'s) that moves the tool at
/// the velocity `v` (m/s, base frame) while turning it down: the learned pick-and-place's
/// tool moves.
pub fn tool_velocity(arm: &ArmState, v: Vec3) -> Vec<f32> {
    let axis = arm.tcp.rotation * Vec3::Z;
    let w = axis.cross(-Vec3::Z) * TILT_GAIN;
    let twist = Vector5::new(v.x as f64, v.y as f64, v.z as f64, w.x as f64, w.y as f64);
    let columns = kinematics::jacobian(&arm.q);
    let j = Matrix5::from_fn(|r, c| columns[c][r]);
    // q̇ = Jᵀ (J Jᵀ + λ² I)⁻¹ x
    let jjt = j * j.transpose() + Matrix5::identity() * DAMPING * DAMPING;
    let qd = match jjt.cholesky() {
        Some(c) => j.transpose() * c.solve(&twist),
        None => Vector5::zeros(),
    };
    // Scaled as a whole when a joint would exceed its speed, so the motion keeps its direction.
    let action: Vec<f32> = qd.iter().take(ACTION_DIM).map(|&s| s as f32 / ACTION_SPEED).collect();
    let top = action.iter().fold(1.0f32, |m, a| m.max(a.abs()));
    action.into_iter().map(|a| a / top).collect()
}

/// Whether the arm can bring its tool to `target` (base frame), pointing down, within the
/// reach tolerance: the resolved-rate law run on the kinematics alone (no physics, no time
/// limit that matters: 12 s of control steps from home), joints inside their ranges all the
/// way. Cell studies map reachability over the table with it and call a program sent to a
/// waypoint it cannot reach a reach failure.
pub fn reachable(target: Vec3) -> bool {
    const DT: f32 = 0.04;
    let mut q = crate::kinematics::HOME;
    for _ in 0..300 {
        let arm = ArmState::from_joints(q, [0.0; 6]);
        if arm.at_joint_limit() {
            return false;
        }
        if arm.distance_to(target) < crate::arm::REACH_TOLERANCE
            && crate::kinematics::tilt(&arm.tcp) < crate::arm::TILT_TOLERANCE
        {
            return true;
        }
        let speeds = crate::arm::joint_speeds(&resolved_rate(&arm, target));
        for (q, s) in q.iter_mut().zip(speeds) {
            *q += s * DT;
        }
    }
    false
}

/// The controller as a policy over the reach observation (q, q̇, TCP, target − TCP, …):
/// a drop-in stand-in for a trained model on every UR5e task.
pub fn act(observation: &[f32]) -> Vec<f32> {
    let q: [f32; 6] = std::array::from_fn(|i| observation[i]);
    let qd: [f32; 6] = std::array::from_fn(|i| observation[6 + i]);
    let arm = ArmState::from_joints(q, qd);
    let target = arm.tcp.translation + Vec3::from_slice(&observation[15..18]);
    resolved_rate(&arm, target)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::Fixtures;
    use crate::program::{Stage, waypoint};

    #[test]
    fn the_default_cells_waypoints_are_reachable_and_the_far_corner_of_the_table_is_not() {
        let fixtures = Fixtures::default();
        for stage in [Stage::Approach, Stage::Grip, Stage::Transfer, Stage::Lower] {
            assert!(reachable(waypoint(stage, &fixtures)), "{stage:?}");
        }
        // 1.1 m out: beyond the UR5e's 0.85 m.
        assert!(!reachable(Vec3::new(-0.95, -0.55, 0.2)));
        // Close in front of the base, low over the table.
        assert!(reachable(Vec3::new(-0.3, 0.0, 0.1)));
    }
}
