//! The safety system at work: every physics step it checks each arm's joints ([`crate::safety`]
//! says against what) and stops the arm that violates a limit.

use bevy::prelude::*;
use twinbots_sim::{JointState, Motor, MotorCommand, SimSettings};

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
        if state.safety.stopped() {
            continue;
        }
        let safety = &mut state.safety;
        let cause = parts.joints.iter().enumerate().fold(None, |cause, (i, &joint)| {
            let found = joints.get(joint).ok().and_then(|(s, m)| safety.check(i, s.velocity, s.effort, m, settings.dt));
            cause.or(found)
        });
        if let Some(cause) = cause {
            safety.stop = Some(cause);
            for &joint in &parts.joints {
                if let Ok((_, mut motor)) = joints.get_mut(joint) {
                    // Held where it is now, not where the servo was heading (its reference
                    // leads a moving joint): an arm stopped on its way into the table would
                    // otherwise keep pressing on it.
                    motor.forget_reference();
                    motor.command = MotorCommand::Velocity(0.0);
                }
            }
        }
    }
}
