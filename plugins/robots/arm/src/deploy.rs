//! A robot file's reach policy on the robot (or its stand-in), as the UR5e's: the task's own
//! observation terms over the arm as its controller reports it, targets from the task's own
//! sampler, actions as joint speeds; and the arm's geometry for the shadow, from its URDF chain.

use std::sync::Arc;

use bevy::math::{DVec3, Vec3};
use rand::RngCore;
use twinbots_task::TaskTerms;
use twinbots_task::on_robot::ReachOnRobot;
use twinbots_task::shadow::{ArmGeometry, Shadow};

use crate::arm::Arm;
use crate::reach::{self, ReachState};

/// Homing speed's gain (1/s): speed = gain × distance to home, within each joint's task speed
/// (the pattern-3 arm's homing).
const HOMING_GAIN: f64 = 10.0;
/// Home: every joint this close to it (rad or m)…
const HOME_TOLERANCE: f64 = 0.01;
/// …and this slow (rad/s or m/s).
const HOME_SPEED: f64 = 0.02;

/// The reach task on a robot: its state as the controller knows it, the task's observation.
pub struct ReachController {
    arm: Arc<Arm>,
    terms: TaskTerms<ReachState>,
    pub state: ReachState,
    observation: Vec<f32>,
}

impl ReachController {
    pub fn new(arm: Arc<Arm>) -> Self {
        let terms = reach::reach_task(&arm).terms;
        Self { arm, terms, state: ReachState::default(), observation: Vec::new() }
    }
}

impl ReachOnRobot for ReachController {
    fn new_reach(&mut self, mut rng: &mut dyn RngCore) {
        self.state.target = self.arm.sample_target(&mut rng);
        self.state.last_action.clear();
        self.state.previous_action.clear();
    }

    /// The joints, and the tool through the controller's own kinematics, as the twin's
    /// controller reads them.
    fn read(&mut self, q: &[f64], qd: &[f64]) {
        let q: Vec<f32> = q.iter().map(|&v| v as f32).collect();
        let qd: Vec<f32> = qd.iter().map(|&v| v as f32).collect();
        self.state.at_limit = self.state.read(&self.arm, q, qd);
    }

    fn observation(&mut self) -> &[f32] {
        self.terms.observe(&self.state, &mut self.observation);
        &self.observation
    }

    /// Each value within [-1, 1] times its joint's task speed, as in the twin.
    fn act(&mut self, action: &[f32]) -> Vec<f64> {
        self.state.push_action(action);
        self.state.last_action.iter().zip(&self.arm.file.speed_limits).map(|(&a, &s)| a as f64 * s).collect()
    }

    /// Towards the file's home at up to each joint's task speed.
    fn homing(&self) -> Vec<f64> {
        let home = &self.arm.file.home;
        (self.state.q.iter().zip(home).zip(&self.arm.file.speed_limits))
            .map(|((&q, &h), &limit)| (HOMING_GAIN * (h - q as f64)).clamp(-limit, limit))
            .collect()
    }

    fn is_home(&self) -> bool {
        let near = self.state.q.iter().zip(&self.arm.file.home).all(|(&q, &h)| (q as f64 - h).abs() < HOME_TOLERANCE);
        near && self.state.qd.iter().all(|v| (v.abs() as f64) < HOME_SPEED)
    }

    fn arrived(&self) -> bool {
        self.state.arrived()
    }

    fn target(&self) -> Vec3 {
        self.state.target
    }

    fn error(&self) -> f32 {
        self.state.distance()
    }
}

/// A six-joint robot file arm's geometry for the shadow: its URDF chain in the controller's
/// order, its ranges, the floor as the table (the arm stands on it in its cell).
#[derive(Debug)]
pub struct ChainGeometry {
    arm: Arc<Arm>,
}

impl ChainGeometry {
    /// An error unless the arm has six controlled joints (the shadow's, a UR controller's).
    pub fn new(arm: Arc<Arm>) -> anyhow::Result<Self> {
        anyhow::ensure!(
            arm.dof() == 6 && arm.file.chain.dof() == 6,
            "{}: a UR controller's link (RTDE) and its shadow take six-joint arms; the file controls {} ({} in its chain)",
            arm.file.path.display(),
            arm.dof(),
            arm.file.chain.dof()
        );
        Ok(Self { arm })
    }

    /// The joints' origins (chain order; the base frame) and the tool's, at controller-order `q`.
    fn points(&self, q: &[f64; 6]) -> (Vec<DVec3>, DVec3) {
        let (origins, tool) = self.arm.file.chain.joint_origins_and_tool(&self.arm.file.chain_order(q));
        (origins, tool.translation)
    }

    /// The movable joints' names, chain order.
    fn names(&self) -> impl Iterator<Item = &str> {
        self.arm.file.chain.movable().map(|j| j.name.as_str())
    }

    /// Height above the floor of a base-frame point.
    /// Above the floor, or the table of the arm's cell.
    fn height(&self, p: DVec3) -> f64 {
        let base = &self.arm.base;
        (base.rotation.as_dquat() * p).z + (base.translation.z - self.arm.surface) as f64
    }
}

impl ArmGeometry for ChainGeometry {
    fn range(&self, joint: usize) -> (f64, f64) {
        self.arm.file.ranges[joint]
    }

    /// The origins of the second joint on (the first's never moves) and the tool.
    fn skeleton(&self, q: &[f64; 6]) -> Vec<(&str, DVec3)> {
        let (origins, tool) = self.points(q);
        let names = self.names().chain([self.arm.file.chain.tool.as_str()]);
        names.zip(origins.into_iter().chain([tool])).skip(1).collect()
    }

    /// The lowest of the third joint's origin on (a UR's elbow) and the tool, above the floor.
    fn lowest_point(&self, q: &[f64; 6]) -> (&str, f64) {
        let (origins, tool) = self.points(q);
        let names = self.names().chain([self.arm.file.chain.tool.as_str()]);
        names
            .zip(origins.into_iter().chain([tool]))
            .skip(2)
            .map(|(name, p)| (name, self.height(p)))
            .fold(("", f64::INFINITY), |low, p| if p.1 < low.1 { p } else { low })
    }
}

/// The arm's shadow: its geometry, each joint's task speed and, where the file gives them, its
/// acceleration limits (else a UR's 40 rad/s², [`Shadow::new`]'s).
pub fn shadow(arm: &Arc<Arm>) -> anyhow::Result<Shadow> {
    let geometry = ChainGeometry::new(arm.clone())?;
    let speeds = &arm.file.speed_limits;
    let mut shadow = Shadow::new(Arc::new(geometry), std::array::from_fn(|k| speeds[k]));
    if let Some(limits) = &arm.file.acceleration_limits {
        shadow.max_acceleration = std::array::from_fn(|k| limits[k]);
    }
    Ok(shadow)
}
