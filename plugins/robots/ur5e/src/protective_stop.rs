//! The safety system at work: every physics step it checks each arm's joints ([`crate::safety`]
//! says against what) and stops the arm that violates a limit.

use bevy::prelude::*;
use twinbots_sim::{JointState, Motor, SimSettings};

use crate::cell::CellParts;
use crate::state::CellState;

/// Every physics step, after the joints are measured: checks each arm's joints and, on a
/// violation, stops the arm: every joint holds where it is (zero speed, the servo brakes
/// within its torque limit).
pub fn monitor(
    settings: Res<SimSettings>,
    mut joints: Query<(&JointState, &mut Motor)>,
    mut arenas: Query<(&CellParts, &mut CellState)>,
) {
    for (parts, mut state) in &mut arenas {
        if !state.safety.stopped() {
            twinbots_task::safety::watch(&mut state.safety, &parts.joints, &mut joints, settings.dt);
        }
    }
}
