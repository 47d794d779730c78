//! Pick-and-place for any arm with a cell and a vacuum gripper (the robot file's `cell` and
//! `[gripper]`): the UR5e's cell program ([`twinbots_task::cell::program`]) moves the part from
//! the pick fixture to the place fixture. The reach policy (or the classical controller) makes
//! the free moves between the stations, the controller's straight moves the last centimetres
//! onto the part and into the pocket with the tool turned down ([`Arm::straight_move`]). It is
//! the reach task with other terminations and a program for a command term: the same
//! observation and action, so a reach model runs it unchanged (`eval RUN --task pick-place`).
//!
//! Episodes start near home with the part anywhere its pocket lets it sit, at any yaw. The
//! episode ends when the program is done (success if the part then stands in the place
//! fixture's pocket), when the part was not seized, in a protective stop, or after
//! [`EPISODE_STEPS`].

use std::sync::Arc;

use bevy::prelude::*;
use twinbots_sim::{SimSettings, Supervisor, VacuumGripper};
use twinbots_task::cell::layout::Fixtures;
use twinbots_task::cell::parts::{Placement, draw_part_start, part_start_pose};
pub use twinbots_task::cell::program::EPISODE_STEPS;
use twinbots_task::cell::program::{Outcome, Program, Stage};
use twinbots_task::task::Resetting;
use twinbots_task::{Episode, StartEvent, TaskDefinition, TerminationTerm};

use crate::arm::{Arm, START_SPREAD};
use crate::reach::{self, ReachState, STOP_TERM};

/// A straight move's gain (1/s) and top tool speed (m/s): the UR5e controller's MoveL.
const LINEAR_GAIN: f64 = 8.0;
const LINEAR_SPEED: f64 = 0.25;

/// The entities of an arena's cell, on the arena entity.
#[derive(Component, Clone, Debug)]
pub struct ArmCell {
    pub part: Entity,
    pub gripper: Entity,
    /// The tool link, which carries the gripper.
    pub tool: Entity,
    pub fixtures: Fixtures,
}

/// Pick-and-place as a task of `arm` (which has a cell and a gripper): the reach's observation,
/// action and motion costs, over when the program is, at most [`EPISODE_STEPS`]. Its success is
/// judged by the evaluator ([`report`]), not by a term.
pub fn pick_place_task(arm: &Arc<Arm>) -> TaskDefinition<ReachState> {
    let mut task = reach::reach_task(arm);
    task.name = format!("{}-pick-place", arm.file.name);
    task.terms.rewards.retain(|term| term.name != "arrival");
    task.terms.terminations = vec![
        TerminationTerm::new("program_over", |s: &ReachState| s.program.is_some_and(|p| p.is_over())),
        TerminationTerm::new(STOP_TERM, |s: &ReachState| s.stopped),
    ];
    task.terms.time_limit = Some(EPISODE_STEPS);
    task.terms.start_events = vec![new_program(arm)];
    task.solved = None;
    task.goal = None;
    task
}

/// Start event: the program starts over, the arm near home and the part anywhere its pocket
/// in the pick fixture lets it sit, at any yaw.
fn new_program(arm: &Arc<Arm>) -> StartEvent<ReachState> {
    let arm = arm.clone();
    let fixtures = arm.fixtures().expect("pick-and-place is a task of arms with a cell");
    StartEvent::new("new_program", move |s: &mut ReachState, rng| {
        let program = Program::new(fixtures);
        s.target = program.target();
        s.program = Some(program);
        s.suction = false;
        s.start_pose = arm.sample_around_home(rng, START_SPREAD);
        s.last_action.clear();
        s.previous_action.clear();
        (s.part_offset, s.part_yaw) = draw_part_start(rng);
    })
}

/// Whether the controller moves the arm now rather than the policy: the program's straight
/// moves, the lift out of the pick fixture and the retract from the place fixture; the policy
/// makes the moves between the stations (approach and transfer). A reach policy that does not
/// steer the tool's axis lifted the part sideways against the pocket's rails, and the knock
/// tripped the safety system (measured on the UR10: 57 % of programs stopped there, a wrist
/// beyond its speed limit), and its retract could knock the part it had just let go.
pub fn controller_moves(program: &Program) -> bool {
    program.moves_straight() || matches!(program.stage, Stage::Lift | Stage::Retract)
}

/// Joint speeds of the controller's moves ([`controller_moves`]: a UR program's MoveL), where
/// the program moves the arm itself rather than the policy; `None` otherwise.
pub fn straight_move(arm: &Arm, state: &ReachState) -> Option<Vec<f32>> {
    let program = state.program.filter(controller_moves)?;
    Some(arm.straight_move(&state.q, program.target().as_dvec3(), LINEAR_GAIN, LINEAR_SPEED))
}

/// Runs each arena's program on the controller's reading: the next tool target and whether the
/// suction should be on (applied by [`apply_suction`] at the next actuation). A protective stop
/// halts it, as it does a UR's.
pub fn run_program(grippers: Query<&VacuumGripper>, mut arenas: Query<(&ArmCell, &mut ReachState)>) {
    for (cell, mut state) in &mut arenas {
        let (Ok(gripper), Some(mut program)) = (grippers.get(cell.gripper), state.program) else { continue };
        if state.stopped {
            continue;
        }
        state.suction = program.step(&*state, gripper.held().is_some());
        state.target = program.target();
        state.program = Some(program);
    }
}

/// The suction's digital output, as the program last asked.
pub fn apply_suction(mut grippers: Query<&mut VacuumGripper>, arenas: Query<(&ArmCell, &ReachState)>) {
    for (cell, state) in &arenas {
        if let Ok(mut gripper) = grippers.get_mut(cell.gripper) {
            gripper.on = state.suction;
        }
    }
}

/// Patterns 1 and 2: the Supervisor seats the part where the start drew it.
pub fn place_part(arm: Res<Arm>, mut supervisor: Supervisor, arenas: Query<(&ArmCell, &ReachState), With<Resetting>>) {
    for (cell, state) in &arenas {
        let seat = part_start_pose(cell.fixtures.pick, state.part_offset, state.part_yaw);
        supervisor.set_link_pose(cell.part, arm.base * seat);
    }
}

/// The figures of a program that ended: success (the part placed), its outcome, cycle time,
/// energy and stops.
pub fn report(
    arm: Res<Arm>,
    settings: Res<SimSettings>,
    supervisor: Supervisor,
    mut arenas: Query<(&ArmCell, &ReachState, &mut Episode)>,
) {
    for (cell, state, mut e) in &mut arenas {
        if !e.done() {
            continue;
        }
        let Some(program) = state.program else { continue };
        let placement = Placement::of(&supervisor, cell.part, arm.base, cell.fixtures.place);
        let outcome = Outcome::judge(&program, state.stopped, placement, &mut e.running);
        if outcome == Outcome::Placed {
            let cycle_time = (e.running.length + 1) as f32 * settings.control_dt();
            e.running.metrics.insert("cycle_time_s".into(), cycle_time);
        }
        e.running.metrics.insert("protective_stops".into(), f32::from(u8::from(state.stopped)));
        e.running.metrics.insert("energy_j".into(), state.energy);
    }
}
