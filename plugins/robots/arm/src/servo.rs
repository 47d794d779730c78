//! The arm's twin under a position servo, as a UR's controller follows `servoj` targets: every
//! control period the twin's drives take the speed that brings each joint from where the twin
//! stands to the next target within the period (the target's own speed fed forward, and what
//! the twin trails by made up), limited by the joints' speeds and efforts; the physics (the
//! URDF's links under gravity, the drives' limited torque) decides where the joints get to.
//! `replay ROBOT.toml LOG` runs a recording's `target_q` through it and compares the joints
//! with the recording's `actual_q`.

use bevy::prelude::*;
use twinbots_log::{CommandMode, CommandSample, RobotLog};
use twinbots_sim::urdf::dynamics::{Dynamics, GRAVITY};
use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_sim::{Arena, JointState, Motor, MotorCommand, PhysicsSubstep, SimPlugin, SpawnOptions, spawn_robot};

use crate::arm::Arm;

/// The servo's integral gain (1/s): what the joints trail their targets by is made up over
/// about 1/gain seconds. Chosen on the real UR5's recordings (docs/logs.md): 2–5 hold the
/// shoulder's sag under gravity to under 2 mrad; from 10 the shoulder starts to swing, at 20 it
/// trails by 20 mrad, at 50 it is unstable.
pub const SERVO_INTEGRAL_GAIN: f64 = 3.0;

/// How the twin's drives follow the targets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Servo {
    /// A UR's `servoj` as the drives' own position loops can have it: speeds that reach each
    /// target within the period, an integral action for what gravity leaves; the positions
    /// follow the arm's closely, the drives' efforts are the constraint solver's and do not.
    Position,
    /// The description's inverse dynamics plus a feedback, as torques
    /// ([`COMPUTED_TORQUE_NATURAL_FREQUENCY`]): efforts near the arm's, positions a little
    /// less close.
    ComputedTorque,
}

impl Servo {
    /// `position` or `computed-torque`.
    pub fn parse(s: &str) -> anyhow::Result<Self> {
        match s {
            "position" => Ok(Self::Position),
            "computed-torque" => Ok(Self::ComputedTorque),
            _ => anyhow::bail!("unknown servo '{s}' (known: position, computed-torque)"),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Position => "position",
            Self::ComputedTorque => "computed-torque",
        }
    }
}

/// Where the twin's joints (the file's controlled joints, in its order) were at each target's
/// time, and the efforts its drives applied over the period before it (their mean over its
/// physics steps, as a current measurement averages; 0 at the start).
pub struct Followed {
    pub positions: Vec<Vec<f64>>,
    pub efforts: Vec<Vec<f64>>,
}

/// The twin from `start` at `times[0]`, driven by `servo` towards `targets[k + 1]` over
/// `times[k]..times[k + 1]`. `targets` and `times` are as long as each other; a gap between
/// times is stepped in whole physics steps (at least one).
pub fn follow_targets(
    file: &RobotFile,
    servo: Servo,
    start: &[f64],
    times: &[f64],
    targets: &[Vec<f64>],
) -> anyhow::Result<Followed> {
    let arm = Arm::of(file.clone())?;
    let dof = arm.dof();
    anyhow::ensure!(
        start.len() == dof && targets.iter().all(|t| t.len() == dof) && targets.len() == times.len(),
        "{} joints, {} start values, {} targets at {} times: they do not match",
        dof,
        start.len(),
        targets.len(),
        times.len()
    );
    let settings = crate::sim_settings(file);
    let mut app = App::new();
    app.add_plugins(MinimalPlugins).add_plugins(SimPlugin { settings, supervisor: true });
    let world = app.world_mut();
    let entity = world.spawn_empty().id();
    let mut arena = Arena::new(0, 0, settings.dt, settings.gravity);
    let joint_positions: Vec<(String, f32)> =
        file.joints.iter().cloned().zip(start.iter().map(|&q| q as f32)).collect();
    let robot = {
        let mut commands = world.commands();
        spawn_robot(
            &mut commands,
            entity,
            &mut arena,
            &arm.model,
            SpawnOptions { fixed_base: true, joint_positions, ..default() },
        )
    };
    world.flush();
    world.entity_mut(entity).insert(arena);
    let joints: Vec<Entity> = file
        .joints
        .iter()
        .map(|name| robot.joint(name).ok_or_else(|| anyhow::anyhow!("the twin has no joint '{name}'")))
        .collect::<anyhow::Result<_>>()?;
    // Drives that hold a position reference (the robot's own joint position loops), which
    // the servo's trajectory generator below moves along the targets. Either servo lets a drive
    // go as fast as it is rated for or as the targets were commanded, whichever is more: a
    // recording is what the robot did (the real UR5's elbow followed 3.2 rad/s where its URDF
    // rates it for 3.15).
    let commanded = peak_speeds(times, targets, dof);
    for (&joint, &peak) in joints.iter().zip(&commanded) {
        if let Some(mut motor) = world.get_mut::<Motor>(joint) {
            motor.holds_position = true;
            motor.command = MotorCommand::Velocity(0.0);
            motor.max_velocity = motor.max_velocity.max(peak as f32);
        }
    }
    // Start-up: the world as built.
    app.update();
    if servo == Servo::ComputedTorque {
        return computed_torque(file, &mut app, &joints, settings.dt as f64, times, targets);
    }
    let dt = settings.dt as f64;
    let mut out = Followed::from(joint_values(app.world(), &joints, |s| s.position));
    // The drives' reference: where the trajectory generator has put it (it moves the reference
    // a speed × the physics steps each period, as the motors integrate it).
    let mut reference = out.positions[0].clone();
    // What the drives' position loops leave under load (gravity holds a shoulder a little
    // below its reference), integrated and added to the reference: the servo's integral action.
    let mut integral = vec![0.0; dof];
    for k in 0..times.len().saturating_sub(1) {
        let steps = period_steps(times[k + 1] - times[k], dt);
        let span = steps as f64 * dt;
        let world = app.world_mut();
        for (j, &joint) in joints.iter().enumerate() {
            let Some(mut motor) = world.get_mut::<Motor>(joint) else { continue };
            // Within the drive's speed above (not the tasks' safety factor).
            let limit = motor.max_velocity as f64;
            let speed = ((targets[k + 1][j] + integral[j] - reference[j]) / span).clamp(-limit, limit);
            reference[j] += speed * span;
            motor.command = MotorCommand::Velocity(speed as f32);
        }
        let effort = run_period(&mut app, &joints, steps, |_, _| {});
        let q = joint_values(app.world(), &joints, |s| s.position);
        for j in 0..dof {
            integral[j] += SERVO_INTEGRAL_GAIN * (targets[k + 1][j] - q[j]) * span;
        }
        out.positions.push(q);
        out.efforts.push(effort);
    }
    Ok(out)
}

/// Each joint's fastest commanded speed: the largest change of its target between two
/// consecutive targets over the time between them (0 with fewer than two targets).
fn peak_speeds(times: &[f64], targets: &[Vec<f64>], dof: usize) -> Vec<f64> {
    let mut peak = vec![0.0f64; dof];
    for k in 1..targets.len() {
        let span = times[k] - times[k - 1];
        if span <= 0.0 {
            continue;
        }
        for (p, (a, b)) in peak.iter_mut().zip(targets[k - 1].iter().zip(&targets[k])) {
            *p = p.max((b - a).abs() / span);
        }
    }
    peak
}

impl Followed {
    /// The twin standing at `start`, no period behind it (its efforts 0).
    fn from(start: Vec<f64>) -> Self {
        let efforts = vec![vec![0.0; start.len()]];
        Self { positions: vec![start], efforts }
    }
}

/// Each of `joints`' `what` (position, speed or effort) as its joint state reads now.
fn joint_values(world: &World, joints: &[Entity], what: fn(&JointState) -> f32) -> Vec<f64> {
    joints.iter().map(|&j| world.get::<JointState>(j).map_or(f64::NAN, |s| what(s) as f64)).collect()
}

/// The whole physics steps of `dt` a control period of `span` seconds takes (at least one).
fn period_steps(span: f64, dt: f64) -> usize {
    ((span / dt).round() as usize).max(1)
}

/// One control period of `steps` physics steps, `before_step` (given the app and the step's
/// index) setting the drives before each; the drives' mean effort over the period.
fn run_period(
    app: &mut App,
    joints: &[Entity],
    steps: usize,
    mut before_step: impl FnMut(&mut App, usize),
) -> Vec<f64> {
    let mut effort = vec![0.0; joints.len()];
    for step in 0..steps {
        before_step(app, step);
        app.world_mut().run_schedule(PhysicsSubstep);
        for (sum, e) in effort.iter_mut().zip(joint_values(app.world(), joints, |s| s.effort)) {
            *sum += e / steps as f64;
        }
    }
    effort
}

/// A log's measured joints, efforts (where it holds them) and the twin under the servo along
/// its position targets, per sample, in the robot file's joint order.
pub struct FollowedLog {
    pub measured: Vec<Vec<f64>>,
    pub measured_efforts: Option<Vec<Vec<f64>>>,
    pub twin: Followed,
}

/// The twin under the servo along `log`'s position targets (one per measured sample, at its
/// time: a UR recording's `target_q`), from its first measured pose. A log whose commands are
/// not positions, one per sample, is an error naming it (`name`).
pub fn follow_log(file: &RobotFile, servo: Servo, log: &RobotLog, name: &str) -> anyhow::Result<FollowedLog> {
    let positions = |c: &CommandSample| c.modes.iter().all(|m| *m == CommandMode::Position);
    anyhow::ensure!(
        !log.commands.is_empty() && log.commands.iter().all(positions),
        "{name}: the servo follows position targets, and the log's commands are not all positions"
    );
    anyhow::ensure!(
        log.commands.len() == log.states.len()
            && log.commands.iter().zip(&log.states).all(|(c, s)| (c.time - s.time).abs() < 1e-9),
        "{name}: the position targets are not one per measured sample, at its time"
    );
    let column = |joints: &[String], joint: &str| {
        joints.iter().position(|j| j == joint).ok_or_else(|| anyhow::anyhow!("{name}: no joint '{joint}'"))
    };
    let state_columns: Vec<usize> =
        file.joints.iter().map(|j| column(&log.joints, j)).collect::<anyhow::Result<_>>()?;
    let pick = |values: &[f64], columns: &[usize]| columns.iter().map(|&c| values[c]).collect::<Vec<f64>>();
    let targets: Vec<Vec<f64>> = log
        .commands
        .iter()
        .map(|c| {
            let columns: Vec<usize> =
                file.joints.iter().map(|j| column(&c.joints, j)).collect::<anyhow::Result<_>>()?;
            Ok(pick(&c.values, &columns))
        })
        .collect::<anyhow::Result<_>>()?;
    let measured: Vec<Vec<f64>> = log.states.iter().map(|s| pick(&s.position, &state_columns)).collect();
    let measured_efforts = log
        .states
        .iter()
        .all(|s| !s.effort.is_empty())
        .then(|| log.states.iter().map(|s| pick(&s.effort, &state_columns)).collect());
    let times: Vec<f64> = log.states.iter().map(|s| s.time).collect();
    let twin = follow_targets(file, servo, &measured[0], &times, &targets)?;
    Ok(FollowedLog { measured, measured_efforts, twin })
}

/// The computed-torque servo's natural frequency (rad/s): the error closes as a critically
/// damped second-order system at this rate (gains ω² and 2ω on the error and its rate). Chosen on
/// the real UR5's fitting runs (No5, No6; docs/logs.md): the highest, in steps of 5, at which
/// the twin stays stable on both; at 25 it oscillates away on No6, whose pose lines the pan and
/// wrist-2 axes up, where the physics' coupled joints answer a torque less stiffly than the
/// description's mass matrix says.
pub const COMPUTED_TORQUE_NATURAL_FREQUENCY: f64 = 20.0;

/// Computed torque: each physics step the drives take the torque the description's inverse
/// dynamics gives at the joints' state for the targets' acceleration plus a feedback on the
/// error (the targets linearly interpolated within the period, their speed and acceleration by
/// differences), so the drives' efforts are what such a controller would command.
fn computed_torque(
    file: &RobotFile,
    app: &mut App,
    joints: &[Entity],
    dt: f64,
    times: &[f64],
    targets: &[Vec<f64>],
) -> anyhow::Result<Followed> {
    let dynamics = Dynamics::of(&file.chain);
    let dof = joints.len();
    anyhow::ensure!(
        dynamics.dof() == dof,
        "the computed-torque servo drives every movable joint: the description has {}, the file controls {dof}",
        dynamics.dof()
    );
    let wn = COMPUTED_TORQUE_NATURAL_FREQUENCY;
    let (kp, kd) = (wn * wn, 2.0 * wn);
    for &joint in joints {
        if let Some(mut motor) = app.world_mut().get_mut::<Motor>(joint) {
            motor.holds_position = false;
            motor.command = MotorCommand::Torque(0.0);
        }
    }
    let mut out = Followed::from(joint_values(app.world(), joints, |s| s.position));
    let n = times.len();
    let speed = |a: usize, b: usize, j: usize| (targets[b][j] - targets[a][j]) / (times[b] - times[a]).max(1e-9);
    for k in 0..n.saturating_sub(1) {
        let steps = period_steps(times[k + 1] - times[k], dt);
        let span = steps as f64 * dt;
        let qd_d: Vec<f64> = (0..dof).map(|j| speed(k, k + 1, j)).collect();
        let qdd_d: Vec<f64> =
            (0..dof).map(|j| if k + 2 < n { (speed(k + 1, k + 2, j) - qd_d[j]) / span } else { 0.0 }).collect();
        let effort = run_period(app, joints, steps, |app, step| {
            let q = joint_values(app.world(), joints, |s| s.position);
            let qd = joint_values(app.world(), joints, |s| s.velocity);
            let s = step as f64 * dt;
            let acc: Vec<f64> = (0..dof)
                .map(|j| qdd_d[j] + kp * (targets[k][j] + qd_d[j] * s - q[j]) + kd * (qd_d[j] - qd[j]))
                .collect();
            let tau = dynamics.inverse(&q, &qd, &acc, GRAVITY);
            for (&joint, t) in joints.iter().zip(&tau) {
                if let Some(mut motor) = app.world_mut().get_mut::<Motor>(joint) {
                    motor.command = MotorCommand::Torque(*t as f32);
                }
            }
        });
        out.positions.push(joint_values(app.world(), joints, |s| s.position));
        out.efforts.push(effort);
    }
    Ok(out)
}
