//! What the arm's controller knows and does, shared by every design pattern: joint readings,
//! the TCP computed from them, and actions as joint speeds.

use bevy::prelude::*;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::{JointState, Motor, MotorCommand, PositionSensor};

use crate::cell::CellParts;
use crate::kinematics::{self, HOME, JOINT_RANGES};

/// A reach succeeds when the TCP is this close to the target (m)…
pub const REACH_TOLERANCE: f32 = 0.01;
/// …the tool points down within this angle (rad)…
pub const TILT_TOLERANCE: f32 = 0.1;
/// …and the TCP has come to rest: slower than this (m/s).
pub const SETTLED_SPEED: f32 = 0.05;
/// Joint speed (rad/s) of a full-scale action.
pub const ACTION_SPEED: f32 = std::f32::consts::FRAC_PI_2;
/// Joints the policy commands: all but wrist 3, which only turns the round suction cup about
/// its own axis (a yaw no task needs); it holds still. Left free, a policy lets it drift over a
/// long program until it meets its stop.
pub const ACTION_DIM: usize = 5;
/// A joint this close to a stop (rad) counts as at its limit.
pub const LIMIT_MARGIN: f32 = 0.01;
/// Homed: every joint this close to home (rad)…
pub const HOME_TOLERANCE: f32 = 0.01;
/// …and this slow (rad/s).
pub const HOME_SPEED: f32 = 0.02;

/// The arm as its encoders report it, and the TCP's pose and velocity computed from that by
/// the controller's kinematics: no privileged data.
#[derive(Component, Clone, Debug)]
pub struct ArmState {
    pub q: [f32; 6],
    pub qd: [f32; 6],
    /// TCP pose in the base frame.
    pub tcp: Pose,
    pub tcp_velocity: Vec3,
}

impl Default for ArmState {
    fn default() -> Self {
        Self::from_joints(HOME, [0.0; 6])
    }
}

impl ArmState {
    pub fn from_joints(q: [f32; 6], qd: [f32; 6]) -> Self {
        let tcp = kinematics::tcp(&q);
        // J(q)·q̇ by a central difference of the kinematics along q̇.
        let h = 1e-4f32;
        let shifted = |sign: f32| {
            let q: [f32; 6] = std::array::from_fn(|i| q[i] + sign * h * qd[i]);
            kinematics::tool_face(kinematics::flange(&q)).w_axis.truncate()
        };
        let tcp_velocity = ((shifted(1.0) - shifted(-1.0)) / (2.0 * h as f64)).as_vec3();
        Self { q, qd, tcp, tcp_velocity }
    }

    /// Reads the joints' position sensors and encoder speeds.
    pub fn read(parts: &CellParts, sensors: &Query<(&PositionSensor, &JointState)>) -> Self {
        let mut q = [0.0; 6];
        let mut qd = [0.0; 6];
        for (i, &joint) in parts.joints.iter().enumerate() {
            if let Ok((sensor, state)) = sensors.get(joint) {
                q[i] = sensor.value;
                qd[i] = state.velocity;
            }
        }
        Self::from_joints(q, qd)
    }

    pub fn distance_to(&self, target: Vec3) -> f32 {
        (target - self.tcp.translation).length()
    }

    /// Whether the tool has reached `target`: close, pointing down, at rest.
    pub fn has_reached(&self, target: Vec3) -> bool {
        self.has_reached_within(target, REACH_TOLERANCE)
    }

    /// [`Self::has_reached`] within `tolerance` (m) of `target`.
    pub fn has_reached_within(&self, target: Vec3, tolerance: f32) -> bool {
        self.distance_to(target) < tolerance
            && kinematics::tilt(&self.tcp) < TILT_TOLERANCE
            && self.tcp_velocity.length() < SETTLED_SPEED
    }

    /// Whether the arm is home and still.
    pub fn is_home(&self) -> bool {
        self.is_at(&HOME)
    }

    /// Whether the arm is at the joint angles `pose` (within homing's tolerance) and still.
    pub fn is_at(&self, pose: &[f32; 6]) -> bool {
        self.q.iter().zip(pose).all(|(q, p)| (q - p).abs() < HOME_TOLERANCE)
            && self.qd.iter().all(|v| v.abs() < HOME_SPEED)
    }

    /// Whether any joint is at one of its stops (±2π, the elbow ±π).
    pub fn at_joint_limit(&self) -> bool {
        self.q.iter().zip(JOINT_RANGES).any(|(q, range)| q.abs() >= range - LIMIT_MARGIN)
    }
}

/// The actions the arm was last given: the policy sees the last (Isaac Lab's last-action
/// term), and the reward charges the change from the one before (its action-rate term).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct ActionHistory {
    pub last: [f32; ACTION_DIM],
    pub previous: [f32; ACTION_DIM],
}

impl ActionHistory {
    pub fn push(&mut self, action: &[f32]) {
        self.previous = self.last;
        self.last = std::array::from_fn(|i| action.get(i).copied().unwrap_or(0.0).clamp(-1.0, 1.0));
    }
}

/// The controller's speed slider, every arm's: [`twinbots_task::cell::program::SpeedSlider`].
pub use twinbots_task::cell::program::SpeedSlider;

/// Joint speed commands for an action in [−1, 1]⁵ (wrist 3 at rest).
pub fn joint_speeds(action: &[f32]) -> [f32; 6] {
    std::array::from_fn(|i| {
        if i < ACTION_DIM { action.get(i).copied().unwrap_or(0.0).clamp(-1.0, 1.0) * ACTION_SPEED } else { 0.0 }
    })
}

/// Drives the arm's joints at these speeds.
pub fn drive(parts: &CellParts, speeds: [f32; 6], motors: &mut Query<&mut Motor>) {
    for (&joint, speed) in parts.joints.iter().zip(speeds) {
        if let Ok(mut m) = motors.get_mut(joint) {
            m.command = MotorCommand::Velocity(speed);
        }
    }
}

/// Joint speed (rad/s) of homing: the policy's top speed, half the joints' limit. Homing at
/// the full π rad/s, every joint starting at once drove the wrists and even the shoulder past
/// their limit, up to 2×, for up to 24 physics steps in a row (measured): a protective stop.
/// At π/2 the drives overshoot by 1.31× at most, for 2 steps (see [`crate::safety`]).
pub const HOMING_SPEED: f32 = ACTION_SPEED;
/// Gain (1/s) of homing's position loop: speed = gain × distance to home, within
/// [`HOMING_SPEED`]. Closed once a control step, it takes 0.4 of the distance a step.
const HOMING_GAIN: f32 = 10.0;

/// Joint speeds that take the arm from `q` home: the controller's homing move.
pub fn homing_speeds(q: &[f32; 6]) -> [f32; 6] {
    speeds_towards(q, &HOME)
}

/// Joint speeds that take the arm from `q` to the joint angles `pose` with homing's move.
pub fn speeds_towards(q: &[f32; 6], pose: &[f32; 6]) -> [f32; 6] {
    std::array::from_fn(|i| (HOMING_GAIN * (pose[i] - q[i])).clamp(-HOMING_SPEED, HOMING_SPEED))
}

/// The cell program reads the TCP; every move of the UR5e's ends with its tool pointing down
/// (its reach policy's too), so a move has reached its waypoint only level.
impl twinbots_task::cell::program::ToolReading for ArmState {
    fn tool(&self) -> Vec3 {
        self.tcp.translation
    }

    fn has_reached_within(&self, target: Vec3, tolerance: f32, _level: bool) -> bool {
        ArmState::has_reached_within(self, target, tolerance)
    }
}
