//! Motors in the manner of Webots' RotationalMotor / LinearMotor: velocity, position or torque
//! control, always within the motor's max velocity and max torque (force).

use std::collections::VecDeque;

use bevy::prelude::*;

use super::joint::{Joint, JointState, wrap_angle};
use crate::arena::{Arena, InArena};
use crate::physics::SimSettings;
use crate::rapier::prelude::*;

/// Gain of rapier's velocity motor: high, so the motor tracks its target as fast as its torque
/// limit allows (the torque limit, not this gain, is what bounds it).
const VELOCITY_MOTOR_GAIN: f32 = 1.0e4;
/// Stiffness (1/s², per unit of the joint's effective inertia) of a position-holding motor's
/// position loop; with [`VELOCITY_MOTOR_GAIN`] as its damping, a load that makes a plain velocity
/// motor creep at v leaves a static error of about v / 500 s (the UR5e's shoulder: 2 mrad).
const POSITION_HOLD_STIFFNESS: f32 = 1.0e7;
/// How far (rad or m) a holding motor's reference may run ahead of the joint (a drive's
/// following-error limit): a blocked or torque-limited joint does not wind its reference up.
const MAX_FOLLOWING_ERROR: f32 = 0.05;
/// The share of a step's travel by which a holding motor's spring target leads the joint.
const SPRING_LEAD: f32 = 0.7;

/// What the motor is asked to do. Values outside the motor's limits are clamped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MotorCommand {
    /// No torque: the joint turns freely.
    Off,
    /// Target velocity (rad/s or m/s).
    Velocity(f32),
    /// Target position (rad or m), reached with a P controller whose speed is bounded.
    Position(f32),
    /// Torque (N·m) or force (N).
    Torque(f32),
}

/// A motor on a joint.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct Motor {
    /// Max speed (rad/s or m/s): URDF `<limit velocity>`.
    pub max_velocity: f32,
    /// Max torque or force: URDF `<limit effort>`.
    pub max_effort: f32,
    /// Proportional gain of position control (1/s), Webots' default P = 10.
    pub position_gain: f32,
    /// Fraction of `max_effort` the motor actually delivers (1: as rated; domain
    /// randomization lowers it to model weak or worn motors).
    pub strength: f32,
    pub command: MotorCommand,
    /// The command restored when the arena is reset.
    pub initial_command: MotorCommand,
    /// Velocity and position commands drive a position reference that the motor holds, as an
    /// industrial servo's position loop does under speed commands (a UR's `speedj`). Without
    /// it, rapier's velocity motor lets a joint under a static load (an arm against gravity)
    /// creep slowly, whatever its gain. Off by default (Webots' plain velocity motors: wheels).
    pub holds_position: bool,
    /// Dead time (s) between a command and the drive acting on it (a controller's command
    /// latency): the motor applies the command given `delay` ago, interpolated between physics
    /// steps. 0 by default; set by a calibration (`command_delay`).
    pub delay: f32,
    /// Torque constant relative to the rating (1: as rated): the drive delivers `gain` × the
    /// torque it is asked for, and its limit scales with it. Set by a calibration (`<joint>.gain`).
    pub gain: f32,
    /// The fastest the drive changes the speed it moves at (rad/s² or m/s²), as a servo's
    /// trajectory generator ramps a speed command (a UR's `speedj` acceleration, a Franka's
    /// rate limiter); a stop's braking ahead of the joint's range is not ramped. `None`: the
    /// speed changes as fast as the effort limit allows (the URDF's only bound).
    pub max_acceleration: Option<f32>,
    /// The speed the drive moved at last physics step, while `max_acceleration` ramps it.
    speed: f32,
    /// The held position reference (rad or m), once the motor holds.
    reference: Option<f32>,
    /// The commands of the last physics steps, newest first, while `delay` > 0.
    history: VecDeque<MotorCommand>,
    /// The command the drive acts on this physics step (`command`, `delay` ago).
    applied: MotorCommand,
}

impl Motor {
    pub fn new(max_velocity: f32, max_effort: f32) -> Self {
        Self {
            max_velocity,
            max_effort,
            position_gain: 10.0,
            strength: 1.0,
            command: MotorCommand::Off,
            initial_command: MotorCommand::Off,
            holds_position: false,
            delay: 0.0,
            gain: 1.0,
            max_acceleration: None,
            speed: 0.0,
            reference: None,
            history: VecDeque::new(),
            applied: MotorCommand::Off,
        }
    }

    /// The command the drive acts on this physics step.
    pub fn applied(&self) -> MotorCommand {
        self.applied
    }

    /// Forgets the commands in flight (an arena reset: the controller restarts).
    pub fn clear_history(&mut self) {
        self.history.clear();
        self.applied = self.command;
    }

    /// Takes this physics step's command into the delay line and picks the one the drive acts
    /// on: the command of `delay / dt` steps ago, blended between the two steps around it when
    /// both are of the same kind (so a fitted delay is not stuck to whole steps).
    fn advance_delay_line(&mut self, dt: f32) {
        if self.delay <= 0.0 {
            self.history.clear();
            self.applied = self.command;
            return;
        }
        let steps = self.delay / dt;
        let whole = steps.floor() as usize;
        let frac = steps - whole as f32;
        self.history.push_front(self.command);
        self.history.truncate(whole + 2);
        // Before the line's first command (a reset, a start) the drive acts on its initial one.
        let at = |k: usize| self.history.get(k).copied().unwrap_or(self.initial_command);
        let (newer, older) = (at(whole), at(whole + 1));
        self.applied = match (newer, older) {
            (MotorCommand::Velocity(a), MotorCommand::Velocity(b)) => MotorCommand::Velocity(a + (b - a) * frac),
            (MotorCommand::Position(a), MotorCommand::Position(b)) => MotorCommand::Position(a + (b - a) * frac),
            (MotorCommand::Torque(a), MotorCommand::Torque(b)) => MotorCommand::Torque(a + (b - a) * frac),
            _ if frac >= 0.5 => older,
            _ => newer,
        };
    }

    /// The most the drive delivers (N·m or N).
    pub fn effort_limit(&self) -> f32 {
        self.max_effort * self.strength * self.gain
    }

    /// Drops the held reference, so it restarts from the joint's position, and the ramped
    /// speed: after the joint was moved from outside (a reset, a teleport) or stopped.
    pub fn forget_reference(&mut self) {
        self.reference = None;
        self.speed = 0.0;
    }

    /// Moves the held reference by `delta` with the joint: after the joint was moved from
    /// outside by `delta`, the drive holds it where it now is, with the same following error
    /// (the load it held, it holds still).
    pub fn shift_reference(&mut self, delta: f32) {
        if let Some(r) = &mut self.reference {
            *r += delta;
        }
    }

    /// Advances the held reference by `v` over `dt`, kept within the following-error limit of
    /// the joint's position and within its stops; returns it.
    fn advance_reference(&mut self, position: f32, v: f32, dt: f32, limits: Option<[f32; 2]>) -> f32 {
        let r = self.reference.unwrap_or(position) + v * dt;
        let r = r.clamp(position - MAX_FOLLOWING_ERROR, position + MAX_FOLLOWING_ERROR);
        let r = limits.map_or(r, |[lo, hi]| r.clamp(lo, hi));
        self.reference = Some(r);
        r
    }

    /// The effort the motor applied over the last physics step: the solved constraint effort
    /// of velocity and position control, the clamped command of torque control.
    pub fn applied_effort(&self, joint: &Joint, state: &JointState, world: &PhysicsWorld, dt: f32) -> f32 {
        match self.applied {
            MotorCommand::Off => 0.0,
            MotorCommand::Torque(t) => self.torque_within_limits(t, state, joint.limits),
            MotorCommand::Velocity(_) | MotorCommand::Position(_) => solved_effort(joint, world, dt),
        }
    }

    /// A torque command clamped to what the motor can deliver.
    fn torque_limit(&self, torque: f32) -> f32 {
        let limit = self.effort_limit();
        (torque * self.gain).clamp(-limit, limit)
    }

    /// The velocity the motor's controller asks for now, bounded by `max_velocity` and by the
    /// joint's position stops: it never drives past a stop, and brakes ahead of one as position
    /// control approaches its target (speed at most `position_gain` × distance), so a heavy
    /// load has time to stop (Webots' minPosition/maxPosition; a UR controller's software
    /// limits). Rapier enforces stops only within one turn, so for wider ranges (the UR5e's
    /// ±2π) this is what holds them. With `max_acceleration` the speed moves from the last
    /// step's by at most that much per second.
    pub fn target_velocity(&mut self, state: &JointState, limits: Option<[f32; 2]>, dt: f32) -> Option<f32> {
        // A holding motor eases its reference to the target (a servo's trajectory generator),
        // and its position loop makes the joint follow the reference.
        let from = if self.holds_position { self.reference.unwrap_or(state.position) } else { state.position };
        let v = match self.applied {
            MotorCommand::Velocity(v) => v,
            // The target itself is kept within the stops (a controller's software limits).
            MotorCommand::Position(p) => {
                let p = limits.map_or(p, |[lo, hi]| p.clamp(lo, hi));
                self.position_gain * (p - from)
            }
            MotorCommand::Off | MotorCommand::Torque(_) => {
                // A speed command after these ramps from how the joint moves.
                self.speed = state.velocity;
                return None;
            }
        };
        let v = v.clamp(-self.max_velocity, self.max_velocity);
        let v = match self.max_acceleration {
            Some(a) => self.speed + (v - self.speed).clamp(-a * dt, a * dt),
            None => v,
        };
        let brake = self.position_gain.min(1.0 / dt);
        let v = match limits {
            Some([lo, hi]) => {
                v.clamp(((lo - state.position) * brake).min(0.0), ((hi - state.position) * brake).max(0.0))
            }
            None => v,
        };
        self.speed = v;
        Some(v)
    }

    /// A torque command, clamped to what the motor delivers and cut where it would push the
    /// joint further past a stop.
    fn torque_within_limits(&self, torque: f32, state: &JointState, limits: Option<[f32; 2]>) -> f32 {
        let t = self.torque_limit(torque);
        match limits {
            Some([_, hi]) if state.position >= hi => t.min(0.0),
            Some([lo, _]) if state.position <= lo => t.max(0.0),
            _ => t,
        }
    }
}

pub(crate) fn drive_motors(
    settings: Res<SimSettings>,
    mut arenas: Query<&mut Arena>,
    mut motors: Query<(&Joint, &JointState, &mut Motor, &InArena)>,
) {
    for (joint, state, mut motor, in_arena) in &mut motors {
        let Ok(mut arena) = arenas.get_mut(in_arena.0) else { continue };
        let world = &mut arena.world;
        let axis = joint.axis();
        motor.advance_delay_line(settings.dt);
        let target = motor.target_velocity(state, joint.limits, settings.dt);
        // The reference a holding motor keeps.
        let reference = match target {
            Some(v) if motor.holds_position => {
                Some(motor.advance_reference(state.position, v, settings.dt, joint.limits))
            }
            _ => {
                motor.reference = None;
                None
            }
        };
        let rotational = joint.kind.is_rotational();
        let rate = spring_rate(world, settings.dt);
        if let Some(j) = world.impulse_joints.get_mut(joint.handle, false) {
            match (target, reference) {
                (Some(v), Some(r)) => {
                    // Rapier's position motor turns the following error into a speed of
                    // `spring_rate` × error on top of `v`, with its target fixed over the
                    // physics step. The target leads the joint by the share of the step's travel
                    // that makes a free joint cover `v·dt` ([`SPRING_LEAD`]); a lag beyond it (a
                    // joint held back by a contact or a load) is passed on only as far as keeps
                    // the speed it asks for within the velocity limit, so a freed joint is not
                    // flung at its reference (33 rad/s for the 0.05 rad following-error limit).
                    let max_v = motor.max_velocity;
                    let lead = SPRING_LEAD * v * settings.dt;
                    let lag = (r - state.position - lead).clamp((-max_v - v) / rate, (max_v - v) / rate);
                    let r = state.position + lead + lag;
                    // Rapier's motor targets the wrapped joint angle.
                    let r = if rotational { wrap_angle(r) } else { r };
                    j.data.set_motor(axis, r, v, POSITION_HOLD_STIFFNESS, VELOCITY_MOTOR_GAIN);
                    j.data.set_motor_max_force(axis, motor.effort_limit());
                }
                (Some(v), None) => {
                    j.data.set_motor_velocity(axis, v, VELOCITY_MOTOR_GAIN);
                    j.data.set_motor_max_force(axis, motor.effort_limit());
                }
                (None, _) => {
                    j.data.set_motor_velocity(axis, 0.0, 0.0);
                    j.data.set_motor_max_force(axis, 0.0);
                }
            }
        }
        if let MotorCommand::Torque(t) = motor.applied {
            apply_effort(world, joint, motor.torque_within_limits(t, state, joint.limits), settings.dt);
        }
    }
}

/// The speed (1/s) per unit of following error at which rapier's position motor (stiffness
/// [`POSITION_HOLD_STIFFNESS`], damping [`VELOCITY_MOTOR_GAIN`], acceleration-based) drives a
/// joint towards its reference: its `erp_inv_dt` over a solver substep of `dt` ÷ iterations.
fn spring_rate(world: &PhysicsWorld, dt: f32) -> f32 {
    let substep = dt / world.integration_parameters.num_solver_iterations.max(1) as f32;
    POSITION_HOLD_STIFFNESS / (substep * POSITION_HOLD_STIFFNESS + VELOCITY_MOTOR_GAIN)
}

/// The effort rapier's motor constraint applied over the last step of `dt` seconds. Rapier
/// solves a step as `num_solver_iterations` substeps and keeps the impulse of the last, so the
/// effort is that impulse over the substep's length (checked against a link held against
/// gravity: it reads m·g·l).
fn solved_effort(joint: &Joint, world: &PhysicsWorld, dt: f32) -> f32 {
    let substeps = world.integration_parameters.num_solver_iterations.max(1) as f32;
    // Rapier's motor impulse acts on the parent along the axis; the effort is what the drive
    // exerts on the child (as a torque command's, and as Pinocchio's and a UR's joint torques).
    world
        .impulse_joints
        .get(joint.handle)
        .map_or(0.0, |j| -j.data.motors[joint.axis() as usize].impulse * substeps / dt)
}

/// Writes what each motor applied over the physics step into its joint's state, after the
/// joint's position was measured (a torque command is cut at a stop the joint now touches).
pub(crate) fn measure_motor_efforts(
    settings: Res<SimSettings>,
    arenas: Query<&Arena>,
    mut motors: Query<(&Joint, &InArena, &mut JointState, &Motor)>,
) {
    for (joint, in_arena, mut state, motor) in &mut motors {
        if let Ok(arena) = arenas.get(in_arena.0) {
            state.effort = motor.applied_effort(joint, &state, &arena.world, settings.dt);
        }
    }
}

/// Applies an effort between the joint's two bodies for one step, as equal and opposite impulses.
pub(crate) fn apply_effort(world: &mut PhysicsWorld, joint: &Joint, effort: f32, dt: f32) {
    act_between(
        world,
        joint,
        effort * dt,
        |body, torque| body.apply_torque_impulse(torque, true),
        |body, force, at| body.apply_impulse_at_point(force, at, true),
    );
}

/// Acts along the joint's axis on its child (+`amount`) and its parent (−`amount`): `turn`
/// with a torque vector for a rotational joint, `push` with a force vector at the joint's
/// anchor for a linear one.
pub(crate) fn act_between(
    world: &mut PhysicsWorld,
    joint: &Joint,
    amount: f32,
    turn: impl Fn(&mut RigidBody, Vec3),
    push: impl Fn(&mut RigidBody, Vec3, Vec3),
) {
    let Some((axis, _, _)) = joint.measure(world) else { return };
    let rotational = joint.kind.is_rotational();
    let anchor = world
        .impulse_joints
        .get(joint.handle)
        .zip(world.bodies.get(joint.child_body))
        .map(|(j, b)| (*b.position() * j.data.local_frame2).translation);
    for (handle, sign) in [(joint.child_body, 1.0), (joint.parent_body, -1.0)] {
        let Some(body) = world.bodies.get_mut(handle) else { continue };
        if rotational {
            turn(body, axis * amount * sign);
        } else if let Some(anchor) = anchor {
            push(body, axis * amount * sign, anchor);
        }
    }
}
