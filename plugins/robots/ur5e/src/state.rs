//! What the cell's controller knows and is doing at a step, under every design pattern: the arm
//! as its encoders report it, its safety system's state, the tool target it is sent to, the
//! actions it was given, the cell program's progress, and the start the next episode drew.

use bevy::prelude::*;

use crate::arm::{ActionHistory, ArmState};
use crate::layout::Fixtures;
use crate::program::Program;
use crate::safety::Safety;

/// The state the UR5e tasks' terms read (one per arena).
#[derive(Component, Clone, Debug, Default)]
pub struct CellState {
    /// Whether the controller has read its encoders yet: a robot homes only from a reading.
    pub read: bool,
    pub arm: ArmState,
    /// The safety system: whether the arm is in a protective stop.
    pub safety: Safety,
    /// Where the task sends the tool: a point in the base frame, the tool pointing down
    /// (Isaac Lab's command term).
    pub target: Vec3,
    pub actions: ActionHistory,
    /// Pick-and-place: the cell program's progress, and whether it wants the suction on.
    pub program: Program,
    pub suction: bool,
    /// Drawn when an episode starts, for the pattern to put in place: the arm's joint angles
    /// (the Supervisor sets them; a pattern-3 arm homes instead), and the part's offset in its
    /// pocket and its yaw (pick-and-place).
    pub start_pose: [f32; 6],
    pub part_offset: Vec3,
    pub part_yaw: f32,
    /// Where the arena's cell has its fixtures (its layout's; the default cell's by default).
    pub fixtures: Fixtures,
    /// Learned pick-and-place: the part as the cell measures it, and where the task wants it.
    pub part: PartReading,
    pub part_goal: Vec3,
}

/// The part as the cell measures it (learned pick-and-place), every arm's.
pub use twinbots_task::cell::learned::PartReading;

impl CellState {
    /// Whether the tool has reached the target: an arm the safety system has stopped has not.
    pub fn arrived(&self) -> bool {
        !self.safety.stopped() && self.arm.has_reached(self.target)
    }
}
