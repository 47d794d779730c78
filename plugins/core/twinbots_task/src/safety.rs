//! The controller's protective stop, as a UR's safety system makes one (the UR5e's and every
//! robot-file arm's): from what the controller knows of its joints every physics step (encoder speed, the motor's torque
//! feedback) it detects a joint beyond its URDF velocity or effort limit, then stops the arm:
//! every joint is braked to a standstill and held, and the arm takes no more motion commands
//! until the stop is unlocked. The episode ends the control step the stop trips; braking to
//! rest and unlocking belong to the reset (a pattern-3 robot brakes, then homes; pattern 1's
//! Supervisor puts the arm back). (A UR stops with category 0 on a limit violation: drives
//! off, the joints' holding brakes on. The twin brakes with its servos at zero speed instead,
//! within their torque limits: its joints have no brakes, and rapier's plain velocity motor,
//! which would stand in for one, lets the arm sag under gravity at up to 1 rad/s.)
//!
//! Why a joint gets there although the drives never ask for more than their limits: a 28 N·m
//! wrist is overpowered when the shoulder and elbow reverse at full torque (random actions do,
//! every 40 ms) and is whipped round, for a few physics steps, at up to 3× its speed limit
//! (5× measured); an arm pressed on the table is back-driven at up to 1.9× for as long as it
//! is pressed. A real arm stops there; so does the twin.
//!
//! The drives themselves overshoot too, which is no fault: the twin's servos take a new speed
//! command at once (a UR's ramps it), and when every joint starts or reverses at once a wrist
//! overshoots for a few physics steps. Measured per 4 ms physics step, without contact: the
//! resolved-rate controller up to 1.23× its limit, a trained reach policy 1.37×, homing at π/2
//! rad/s 1.31×, each for at most 3 steps in a row. Hence two thresholds, as safety functions
//! have a tolerance and a filter time: a joint stops the arm at once above 1.5× its limit, or
//! above 1.1× for 20 ms (5 steps).

use bevy::prelude::*;
use twinbots_sim::{JointState, Motor, MotorCommand};

/// How far over its velocity limit (a fraction of it) a joint may run for a moment: the
/// drives' own overshoot stays within it (see the module's doc). UR's safety system has a
/// tolerance too, 1.15°/s, for a controller that ramps its speeds, as the twin's drives do not.
pub const SPEED_MARGIN: f32 = 0.10;
/// How long (s) a joint may run over [`SPEED_MARGIN`] without a break: a safety function's
/// filter time, which lets the drives' transients pass (3 physics steps at most, measured) and
/// stops a joint that is being driven round (an arm pressed on the cell: 5 to over 10).
pub const OVERSPEED_TIME: f32 = 0.02;
/// Above this fraction over its velocity limit a joint stops the arm at once: a wrist being
/// whipped round, which lasts only a few physics steps. The drives' own overshoot peaks at
/// 0.37 (measured, see the module's doc).
pub const PEAK_SPEED_MARGIN: f32 = 0.50;
/// How far over its effort limit a motor's torque feedback may read. The drives deliver at
/// most their rating times their strength, so this trips only for a motor randomised
/// stronger than 1.1× its rating: torque beyond the rating, which a real controller would not
/// allow either.
pub const EFFORT_MARGIN: f32 = 0.10;
/// A stopped arm is at rest when every joint is slower than this (rad/s): as still as homing
/// leaves it.
pub const REST_SPEED: f32 = 0.02;
/// Control steps (2 s) after which a pattern-3 robot unlocks its stop and homes even if the arm
/// is still moving (something keeps pushing it). Measured under random actions: the arm comes
/// to rest within 11 steps typically, 28 at most in 4,503 stops; the servos holding a fast arm
/// ring a while (a UR, whose brakes stop it, takes under 0.5 s).
pub const MAX_BRAKING_STEPS: u32 = 50;

/// What tripped a protective stop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StopCause {
    /// Joint `joint` (base to tool, the controller's order) ran at `ratio` × its velocity limit: over
    /// [`PEAK_SPEED_MARGIN`], or over [`SPEED_MARGIN`] for [`OVERSPEED_TIME`].
    Speed { joint: usize, ratio: f32 },
    /// Joint `joint`'s motor exerted `ratio` × its effort limit.
    Effort { joint: usize, ratio: f32 },
    /// A stop known from a stored step's record (its episode ended by the stop's termination
    /// term), as hindsight relabelling rebuilds the state: which joint tripped is not kept.
    Recorded,
}

/// The safety system's state: how long each joint has overspeeded, and the stop, once made.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Safety {
    /// Per joint (the controller's order), how long it has run over [`SPEED_MARGIN`].
    overspeed_for: Vec<f32>,
    /// The stop, until it is unlocked (a reset, or a pattern-3 robot before it homes).
    pub stop: Option<StopCause>,
    /// Control steps since the stop.
    pub braking_steps: u32,
}

impl Safety {
    pub fn stopped(&self) -> bool {
        self.stop.is_some()
    }

    /// Checks joint `joint`'s readings of the last physics step of `dt` (its encoder speed and
    /// its motor's torque feedback) against its motor's limits; returns what trips a stop now,
    /// if anything does.
    pub fn check(&mut self, joint: usize, velocity: f32, effort: f32, motor: &Motor, dt: f32) -> Option<StopCause> {
        let speed = velocity.abs() / motor.max_velocity;
        let effort = effort.abs() / motor.max_effort;
        if self.overspeed_for.len() <= joint {
            self.overspeed_for.resize(joint + 1, 0.0);
        }
        let over = &mut self.overspeed_for[joint];
        *over = if speed > 1.0 + SPEED_MARGIN { *over + dt } else { 0.0 };
        // Half a step's slack: the sum of n steps' dt is n·dt only within rounding.
        if speed > 1.0 + PEAK_SPEED_MARGIN || *over > OVERSPEED_TIME - dt / 2.0 {
            Some(StopCause::Speed { joint, ratio: speed })
        } else if effort > 1.0 + EFFORT_MARGIN {
            Some(StopCause::Effort { joint, ratio: effort })
        } else {
            None
        }
    }

    /// Whether the stop has run its course: the arm braked to rest, or braking took too long.
    pub fn stop_ended(&self, qd: &[f32]) -> bool {
        self.stopped() && (qd.iter().all(|v| v.abs() < REST_SPEED) || self.braking_steps >= MAX_BRAKING_STEPS)
    }

    /// Clears the stop (and the filters), as a UR's "unlock protective stop" does.
    pub fn unlock(&mut self) {
        *self = Self::default();
    }
}

/// The safety system at work on one arm after a physics step of `dt`: checks its joints (the
/// controller's order) and, on a violation, stops the arm (`safety.stop`) and every joint holds
/// where it is (zero speed; the servo brakes within its torque limit). Returns the cause.
pub fn watch(
    safety: &mut Safety,
    joints: &[Entity],
    readings: &mut Query<(&JointState, &mut Motor)>,
    dt: f32,
) -> Option<StopCause> {
    let cause = joints.iter().enumerate().fold(None, |cause, (i, &joint)| {
        let found = readings.get(joint).ok().and_then(|(s, m)| safety.check(i, s.velocity, s.effort, m, dt));
        cause.or(found)
    })?;
    safety.stop = Some(cause);
    for &joint in joints {
        if let Ok((_, mut motor)) = readings.get_mut(joint) {
            // Held where it is now, not where the servo was heading (its reference leads a
            // moving joint): an arm stopped on its way into the table would otherwise keep
            // pressing on it.
            motor.forget_reference();
            motor.command = MotorCommand::Velocity(0.0);
        }
    }
    Some(cause)
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f32 = 0.004;

    /// A wrist's motor: π rad/s, 28 N·m.
    fn wrist() -> Motor {
        Motor::new(std::f32::consts::PI, 28.0)
    }

    #[test]
    fn overspeeding_stops_only_when_it_lasts_the_filter_time() {
        let (mut safety, motor) = (Safety::default(), wrist());
        let fast = 1.2 * motor.max_velocity;
        let steps = (OVERSPEED_TIME / DT).round() as usize;
        for _ in 0..steps - 1 {
            assert_eq!(safety.check(3, -fast, 0.0, &motor, DT), None, "a transient passes");
        }
        // A step back within the margin restarts the filter.
        assert_eq!(safety.check(3, 1.05 * motor.max_velocity, 0.0, &motor, DT), None);
        for _ in 0..steps - 1 {
            assert_eq!(safety.check(3, fast, 0.0, &motor, DT), None);
        }
        match safety.check(3, fast, 0.0, &motor, DT) {
            Some(StopCause::Speed { joint: 3, ratio }) => assert!((ratio - 1.2).abs() < 1e-5, "{ratio}"),
            other => panic!("the {steps}th step over the margin stops the arm: {other:?}"),
        }
        // Within the margin, however long: no stop.
        let mut safety = Safety::default();
        for _ in 0..1000 {
            assert_eq!(safety.check(4, 1.09 * motor.max_velocity, 0.0, &motor, DT), None);
        }
    }

    #[test]
    fn a_joint_whipped_past_the_peak_margin_stops_at_once() {
        let (mut safety, motor) = (Safety::default(), wrist());
        assert_eq!(safety.check(3, 1.49 * motor.max_velocity, 0.0, &motor, DT), None);
        let mut safety = Safety::default();
        assert!(matches!(
            safety.check(3, -1.51 * motor.max_velocity, 0.0, &motor, DT),
            Some(StopCause::Speed { joint: 3, .. })
        ));
    }

    #[test]
    fn torque_beyond_the_rating_stops_at_once() {
        let (mut safety, motor) = (Safety::default(), wrist());
        assert_eq!(safety.check(5, 0.0, -28.0 * 1.1, &motor, DT), None, "within the margin");
        match safety.check(5, 0.0, -28.0 * 1.15, &motor, DT) {
            Some(StopCause::Effort { joint: 5, ratio }) => assert!((ratio - 1.15).abs() < 1e-5, "{ratio}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_stop_ends_when_the_arm_is_at_rest_or_braking_takes_too_long() {
        let mut safety = Safety::default();
        let still = [0.01, -0.01, 0.0, 0.0, 0.0, 0.0];
        let moving = [0.0, 0.0, 0.0, 0.5, 0.0, 0.0];
        assert!(!safety.stop_ended(&still), "no stop, nothing ends");
        safety.stop = Some(StopCause::Speed { joint: 3, ratio: 2.0 });
        assert!(!safety.stop_ended(&moving) && safety.stop_ended(&still));
        safety.braking_steps = MAX_BRAKING_STEPS;
        assert!(safety.stop_ended(&moving), "after a second of braking the episode ends anyway");
        safety.unlock();
        assert_eq!(safety, Safety::default());
    }
}
