//! A reach task's controller side on a real robot (what `deploy` drives): the task's own
//! observation terms over the joints as the robot's controller reports them, targets from the
//! task's own sampler, actions as joint speeds, homing. Each robot crate implements it for its
//! reach (the UR5e's, a robot file's arm's), so a deployment is one loop for all of them.
//! Vectors are in the controller's joint order.

use bevy::math::Vec3;
use rand::RngCore;

pub trait ReachOnRobot {
    /// A new reach: a target from the task's sampler, no action yet.
    fn new_reach(&mut self, rng: &mut dyn RngCore);
    /// The joints as the controller reports them (positions, speeds).
    fn read(&mut self, q: &[f64], qd: &[f64]);
    /// The task's observation of the arm as last read.
    fn observation(&mut self) -> &[f32];
    /// Joint speeds for the policy's action (which the next observation shows as the last).
    fn act(&mut self, action: &[f32]) -> Vec<f64>;
    /// Joint speeds that take the arm home.
    fn homing(&self) -> Vec<f64>;
    /// Home and still.
    fn is_home(&self) -> bool;
    /// At the target by the task's own criterion.
    fn arrived(&self) -> bool;
    fn target(&self) -> Vec3;
    /// The tool's distance to the target (m).
    fn error(&self) -> f32;
}
