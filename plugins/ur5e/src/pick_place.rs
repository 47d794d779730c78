//! Pick-and-place: move the part from fixture A to fixture B with the vacuum gripper. The cell
//! program is a sequence of tool targets (approach, descend, lift, transfer, align, lower,
//! retract)
//! with the suction switched on and off between them, as a UR program of MoveL waypoints and
//! digital outputs; the trained reach policy moves the arm from each waypoint to the next.
//! It is the reach task with another command term: the same observation and action, so a
//! reach model runs it unchanged.
//!
//! Episodes start near home with the part anywhere its pocket lets it sit.
//! The episode ends when the program is done (success if the part then stands in fixture B's
//! pocket), when the part was not seized, or after [`EPISODE_STEPS`].

use bevy::prelude::*;
use rand::Rng;
use twinbots_sim::rapier::math::Pose;
use twinbots_rl::Episode;
use twinbots_sim::{SimSettings, Supervisor, VacuumGripper};

use crate::arm::{ActionHistory, ArmState, reach_reward};
use crate::cell::{CellParts, FIXTURE_A, FIXTURE_B, PART_HEIGHT, POCKET_PLAY, base_pose, part_seat};
use crate::metrics::TwinMeter;
use crate::reach::{ToolTarget, sample_start};

pub const EPISODE_STEPS: u32 = 400;
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
/// A placed part's centre lies within the pocket's play of its centre (m)…
pub const PLACE_TOLERANCE: f32 = POCKET_PLAY + 0.001;
/// …and it stands upright within this angle (rad).
pub const UPRIGHT_TOLERANCE: f32 = 0.2;

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

/// Runs each arena's program and sets its tool target and suction.
pub fn run_program(
    mut grippers: Query<&mut VacuumGripper>,
    mut arenas: Query<(&CellParts, &ArmState, &mut Program, &mut ToolTarget)>,
) {
    for (parts, arm, mut program, mut target) in &mut arenas {
        let Ok(mut gripper) = grippers.get_mut(parts.gripper) else { continue };
        gripper.on = program.step(arm, gripper.held().is_some());
        target.0 = waypoint(program.stage);
    }
}

/// How far (m) the part may sit off its pocket's centre at the start. With the reach's 1 cm,
/// the part then never lands more than the pocket's play off its centre.
pub const PART_PLAY: f32 = 0.005;

/// Reset event: the program starts over, the arm near home and the part anywhere its pocket
/// in fixture A lets it sit, at any yaw (both put there by the Supervisor).
pub fn new_program(mut supervisor: Supervisor, mut arenas: Query<(Entity, &Episode, &CellParts, &mut Program, &mut ToolTarget)>) {
    for (arena, episode, parts, mut program, mut target) in &mut arenas {
        if !episode.needs_reset {
            continue;
        }
        *program = Program::default();
        target.0 = waypoint(program.stage);
        let Some(mut a) = supervisor.arena_mut(arena) else { continue };
        let start = sample_start(&mut a.rng);
        let offset = Vec3::new(a.rng.random_range(-PART_PLAY..=PART_PLAY), a.rng.random_range(-PART_PLAY..=PART_PLAY), 0.0);
        let yaw = a.rng.random_range(-std::f32::consts::PI..=std::f32::consts::PI);
        drop(a);
        for (&joint, q) in parts.joints.iter().zip(start) {
            supervisor.set_joint_position(joint, q);
        }
        let seat = Pose::from_parts(part_seat(FIXTURE_A) + offset, Quat::from_rotation_z(yaw));
        supervisor.set_link_pose(parts.part, base_pose() * seat);
    }
}

pub fn reward(mut arenas: Query<(&ArmState, &ToolTarget, &ActionHistory, &mut Episode), With<Program>>) {
    for (arm, target, actions, mut e) in &mut arenas {
        e.reward = reach_reward(arm, target.0, actions, false);
    }
}

/// Whether the part stands in fixture B's pocket: judged by the evaluator, who may look.
fn part_placed(supervisor: &Supervisor, parts: &CellParts) -> bool {
    let Some(part) = supervisor.link_state(parts.part) else { return false };
    let pose = base_pose().inverse() * part.pose;
    let seat = part_seat(FIXTURE_B);
    let off_centre = (pose.translation - seat).truncate().length();
    off_centre < PLACE_TOLERANCE
        && (pose.translation.z - seat.z).abs() < 0.005
        && (pose.rotation * Vec3::Z).angle_between(Vec3::Z) < UPRIGHT_TOLERANCE
}

pub fn terminate(
    settings: Res<SimSettings>,
    supervisor: Supervisor,
    mut arenas: Query<(&CellParts, &Program, &TwinMeter, &mut Episode)>,
) {
    for (parts, program, meter, mut e) in &mut arenas {
        e.terminated = program.is_over();
        e.truncated = !e.terminated && e.length + 1 >= EPISODE_STEPS;
        if e.terminated || e.truncated {
            let placed = program.stage == Stage::Done && part_placed(&supervisor, parts);
            e.success = Some(placed);
            let cycle_time = placed.then(|| (e.length + 1) as f32 * settings.control_dt());
            meter.report(&mut e, cycle_time);
        }
    }
}
