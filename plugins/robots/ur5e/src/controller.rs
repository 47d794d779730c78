//! A classical resolved-rate controller for the reach, the baseline a learned policy is
//! measured against: the TCP twist that closes the position error and turns the tool down,
//! mapped to joint speeds through the Jacobian by damped least squares, and returned as an
//! action of the reach task.

use bevy::math::Vec3;
use twinbots_sim::rapier::na::{Matrix5, Vector5};

use crate::arm::{ACTION_DIM, ACTION_SPEED, ArmState};
use crate::kinematics;

/// Position gain (1/s) and top TCP speed (m/s).
const POSITION_GAIN: f32 = 2.5;
const MAX_SPEED: f32 = 0.5;
/// Gain (1/s) that turns the tool axis down.
const TILT_GAIN: f32 = 3.0;
/// Damping (m) of the least-squares solve, which keeps speeds bounded near singularities.
const DAMPING: f64 = 0.02;

/// The action (speeds of the first five joints in [−1, 1] of [`ACTION_SPEED`]) that moves the
/// tool towards `target`, pointing down. The task is five-dimensional (position, and the two
/// tilts of the tool axis; its yaw is free), as are the joints it commands.
pub fn resolved_rate(arm: &ArmState, target: Vec3) -> Vec<f32> {
    let error = target - arm.tcp.translation;
    let v = (error * POSITION_GAIN).clamp_length_max(MAX_SPEED);
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

/// The controller as a policy over the reach observation (q, q̇, TCP, target − TCP, …):
/// a drop-in stand-in for a trained model on every UR5e task.
pub fn act(observation: &[f32]) -> Vec<f32> {
    let q: [f32; 6] = std::array::from_fn(|i| observation[i]);
    let qd: [f32; 6] = std::array::from_fn(|i| observation[6 + i]);
    let arm = ArmState::from_joints(q, qd);
    let target = arm.tcp.translation + Vec3::from_slice(&observation[15..18]);
    resolved_rate(&arm, target)
}
