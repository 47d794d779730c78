//! Pick-and-place: move the part from fixture A to fixture B with the vacuum gripper. The cell
//! program is a sequence of tool targets (approach, descend, lift, transfer, align, lower,
//! retract)
//! with the suction switched on and off between them, as a UR program of MoveL waypoints and
//! digital outputs; the trained reach policy moves the arm between the stations, the
//! controller's straight moves do the last centimetres onto the part and into the pocket
//! ([`Program::moves_straight`]). It is the reach task with another command term: the same
//! observation and action, so a reach model runs it unchanged.
//!
//! Episodes start near home with the part anywhere its pocket lets it sit.
//! The episode ends when the program is done (success if the part then stands in fixture B's
//! pocket), when the part was not seized, in a protective stop (which halts the program), or
//! after [`EPISODE_STEPS`].

use bevy::prelude::*;
use rand_chacha::ChaCha8Rng;
use twinbots_sim::{SimSettings, Supervisor, VacuumGripper};
use twinbots_task::task::Resetting;
use twinbots_task::{Episode, Space, StartEvent, TaskDefinition, TaskTerms, TerminationTerm};

use crate::arm::{ACTION_DIM, ActionHistory};
use crate::cell::{CellParts, part_seat};
use crate::metrics::TwinMeter;
pub use crate::program::{ALIGN_HEIGHT, CLEARANCE, DROP_HEIGHT, GRIP_GAP, Program, SUCTION_STEPS, Stage, waypoint};
use crate::reach::{motion_costs, observations, sample_start};
use crate::state::CellState;
use twinbots_task::cell::parts::draw_part_start;
pub use twinbots_task::cell::parts::{PART_PLAY, part_start_pose};
pub use twinbots_task::cell::program::EPISODE_STEPS;

pub use twinbots_task::cell::parts::{PLACE_TOLERANCE, Placement, UPRIGHT_TOLERANCE};
pub use twinbots_task::cell::program::Outcome;

/// Runs each arena's program on the controller's reading: the next tool target and whether the
/// suction should be on (applied by [`apply_suction`] at the next actuation).
pub fn run_program(grippers: Query<&VacuumGripper>, mut arenas: Query<(&CellParts, &mut CellState)>) {
    for (parts, mut state) in &mut arenas {
        let Ok(gripper) = grippers.get(parts.gripper) else { continue };
        // A protective stop halts the program, as it does a UR's.
        if state.safety.stopped() {
            continue;
        }
        let state = &mut *state;
        state.suction = state.program.step(&state.arm, gripper.held().is_some());
        state.target = state.program.target();
    }
}

/// The suction's digital output, as the program last asked.
pub fn apply_suction(mut grippers: Query<&mut VacuumGripper>, arenas: Query<(&CellParts, &CellState)>) {
    for (parts, state) in &arenas {
        if let Ok(mut gripper) = grippers.get_mut(parts.gripper) {
            gripper.on = state.suction;
        }
    }
}

/// Pick-and-place as a task: the reach's observation and motion costs (the same spaces, so a
/// reach model runs it), over when the program is, at most [`EPISODE_STEPS`]. Its success is
/// judged by the evaluator ([`report`]), not by a term.
pub fn pick_place_task() -> TaskDefinition<CellState> {
    TaskDefinition {
        name: "ur5e-pick-place".into(),
        terms: TaskTerms {
            observations: observations(),
            rewards: motion_costs(),
            terminations: vec![
                TerminationTerm::new("program_over", |s: &CellState| s.program.is_over()),
                TerminationTerm::new("protective_stop", |s: &CellState| s.safety.stopped()),
            ],
            time_limit: Some(EPISODE_STEPS),
            start_events: vec![StartEvent::new("new_program", new_program)],
        },
        action_space: Space::uniform_box(ACTION_DIM, -1.0, 1.0),
        solved: None,
        goal: None,
    }
}

/// Start event: the program starts over, the arm near home and the part anywhere its pocket
/// in fixture A lets it sit, at any yaw.
fn new_program(s: &mut CellState, rng: &mut ChaCha8Rng) {
    s.program = Program::new(s.fixtures);
    s.target = s.program.target();
    s.suction = false;
    s.actions = ActionHistory::default();
    s.start_pose = sample_start(rng);
    (s.part_offset, s.part_yaw) = draw_part_start(rng);
}

/// Where the start drew the part (its bottom centre, base frame): its pick seat plus its offset.
pub fn part_start(s: &CellState) -> Vec3 {
    part_seat(s.fixtures.pick) + s.part_offset
}

/// Patterns 1 and 2: the Supervisor seats the part where the start drew it.
pub fn place_part(mut supervisor: Supervisor, arenas: Query<(&CellParts, &CellState), With<Resetting>>) {
    for (parts, state) in &arenas {
        let seat = part_start_pose(state.fixtures.pick, state.part_offset, state.part_yaw);
        supervisor.set_link_pose(parts.part, parts.base * seat);
    }
}

/// The figures of a program that ended: success (the part placed), its outcome, cycle time,
/// the meter's.
pub fn report(
    settings: Res<SimSettings>,
    supervisor: Supervisor,
    mut arenas: Query<(&CellParts, &CellState, &TwinMeter, &mut Episode)>,
) {
    for (parts, state, meter, mut e) in &mut arenas {
        if e.done() {
            let placement = Placement::of(&supervisor, parts.part, parts.base, state.fixtures.place);
            let outcome = Outcome::judge(&state.program, state.safety.stopped(), placement, &mut e.running);
            let cycle_time =
                (outcome == Outcome::Placed).then(|| (e.running.length + 1) as f32 * settings.control_dt());
            meter.report(&mut e, cycle_time);
        }
    }
}
