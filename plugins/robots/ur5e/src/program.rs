//! The pick-and-place cell program: its stages, the tool target of each, and how it moves on
//! (as a UR program of MoveL waypoints and digital outputs).

use bevy::prelude::*;

use crate::arm::ArmState;
use crate::cell::{FIXTURE_A, FIXTURE_B, PART_HEIGHT, part_seat};

/// Height of the approach and retract waypoints above the part's top (m).
pub const CLEARANCE: f32 = 0.10;
/// The TCP stops this far above the part's top to seize it: inside the cup's stroke.
pub const GRIP_GAP: f32 = 0.003;
/// The part is let go this far above the pocket floor (m).
pub const DROP_HEIGHT: f32 = 0.008;
/// Before lowering it, the part is aligned over the pocket this high above its seat (m): its
/// bottom clear of the rails, so the last descent is short and straight.
pub const ALIGN_HEIGHT: f32 = 0.04;
/// Control steps the suction is given to seize or release.
pub const SUCTION_STEPS: u32 = 3;
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    Approach,
    Descend,
    Grip,
    Lift,
    Transfer,
    /// Over fixture B's pocket, the part just clear of its rails.
    Align,
    Lower,
    Release,
    Retract,
    /// The program ran to its end.
    Done,
    /// The part was not seized.
    Failed,
}

/// The cell program's state in an arena.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct Program {
    pub stage: Stage,
    /// Control steps spent waiting for the suction.
    waited: u32,
}

impl Default for Program {
    fn default() -> Self {
        Self { stage: Stage::Approach, waited: 0 }
    }
}

/// The TCP target of a stage, in the base frame.
pub fn waypoint(stage: Stage) -> Vec3 {
    let top = |fixture: Vec3| part_seat(fixture) + Vec3::Z * PART_HEIGHT;
    match stage {
        Stage::Approach | Stage::Lift => top(FIXTURE_A) + Vec3::Z * CLEARANCE,
        Stage::Descend | Stage::Grip | Stage::Failed => top(FIXTURE_A) + Vec3::Z * GRIP_GAP,
        Stage::Transfer | Stage::Retract | Stage::Done => top(FIXTURE_B) + Vec3::Z * CLEARANCE,
        Stage::Align => top(FIXTURE_B) + Vec3::Z * ALIGN_HEIGHT,
        Stage::Lower | Stage::Release => top(FIXTURE_B) + Vec3::Z * DROP_HEIGHT,
    }
}

impl Program {
    /// One control step of the program: moves on when the arm has reached the waypoint or the
    /// suction has had its time; returns whether the suction should be on.
    pub fn step(&mut self, arm: &ArmState, holding: bool) -> bool {
        let reached = arm.has_reached(waypoint(self.stage));
        let next = match self.stage {
            Stage::Approach if reached => Some(Stage::Descend),
            Stage::Descend if reached => Some(Stage::Grip),
            Stage::Grip if holding => Some(Stage::Lift),
            Stage::Grip if self.waited >= SUCTION_STEPS => Some(Stage::Failed),
            Stage::Lift if reached => Some(Stage::Transfer),
            Stage::Transfer if reached => Some(Stage::Align),
            Stage::Align if reached => Some(Stage::Lower),
            Stage::Lower if reached => Some(Stage::Release),
            Stage::Release if self.waited >= SUCTION_STEPS => Some(Stage::Retract),
            Stage::Retract if reached => Some(Stage::Done),
            _ => None,
        };
        match next {
            Some(stage) => {
                self.stage = stage;
                self.waited = 0;
            }
            None if matches!(self.stage, Stage::Grip | Stage::Release) => self.waited += 1,
            None => {}
        }
        matches!(self.stage, Stage::Grip | Stage::Lift | Stage::Transfer | Stage::Align | Stage::Lower)
    }

    pub fn is_over(&self) -> bool {
        matches!(self.stage, Stage::Done | Stage::Failed)
    }
}
