//! Replaying a log on the twin: the twin starts in the logged state, takes the logged commands at
//! the logged times, and is compared with the log joint by joint.

use serde::Serialize;
use twinbots_log::{CommandMode, JointSample, LogMeta, RobotLog};
use twinbots_sim::{MotorCommand, Parameters};

use crate::rig::{Program, Reading, Rig, Trajectory};

/// A log made ready to replay on a rig: its commands by physics step and its measurements
/// interpolated onto the twin's physics steps.
#[derive(Clone, Debug)]
pub struct PreparedLog {
    /// Where it came from (for reports).
    pub name: String,
    /// The logged start positions, by joint (encoder readings: bias included).
    pub start: Vec<f64>,
    pub program: Program,
    /// The log after each physics step, in the rig's joint order.
    pub reference: Vec<Reading>,
    /// Whether the log holds efforts.
    pub has_effort: bool,
    /// Each joint's measurement noise (std) of position, speed and effort, estimated from the
    /// log: the scales errors are measured in (0: not compared).
    pub scale: Vec<[f64; 3]>,
}

/// The longest log a replay or a calibration takes (s): an hour, as `record --seconds`.
pub const MAX_REPLAY_SECONDS: f64 = 3600.0;

/// Checks a log against the rig and makes it ready to replay; errors say what does not fit.
pub fn prepare(rig: &Rig, log: &RobotLog, name: &str) -> anyhow::Result<PreparedLog> {
    log.validate()?;
    log.check_robot(rig.robot, &rig.joints)?;
    let index: Vec<usize> =
        rig.joints.iter().map(|j| log.joint_index(j).expect("checked: every joint is logged")).collect();
    let dt = rig.dt();
    let t0 = log.states[0].time;
    // The replay steps the physics over the whole span and keeps every step's reference.
    anyhow::ensure!(
        log.duration() <= MAX_REPLAY_SECONDS,
        "the log lasts {:.0} s: a replay takes at most {MAX_REPLAY_SECONDS} s (cut it into parts)",
        log.duration()
    );
    let steps = ((log.duration() / dt) + 1e-6).floor() as usize;
    anyhow::ensure!(steps >= 10, "the log lasts {:.3} s, under 10 physics steps of {dt} s", log.duration());
    let mut changes = vec![Vec::new(); steps];
    for (i, c) in log.commands.iter().enumerate() {
        // A command acts from the first physics step that starts at or after it.
        let k = ((c.time - t0) / dt - 1e-3).ceil().max(0.0) as usize;
        if k >= steps {
            continue;
        }
        for ((joint, mode), value) in c.joints.iter().zip(&c.modes).zip(&c.values) {
            let j = rig.joints.iter().position(|n| n == joint).ok_or_else(|| {
                anyhow::anyhow!(
                    "command {i} (t = {} s) drives '{joint}', which robot '{}' does not have",
                    c.time,
                    rig.robot
                )
            })?;
            anyhow::ensure!(rig.actuated[j], "command {i} (t = {} s) drives '{joint}', which has no motor", c.time);
            let v = *value as f32;
            let command = match mode {
                CommandMode::Velocity => MotorCommand::Velocity(v),
                CommandMode::Position => MotorCommand::Position(v),
                CommandMode::Torque => MotorCommand::Torque(v),
            };
            changes[k].retain(|(other, _)| *other != j);
            changes[k].push((j, command));
        }
    }
    let has_effort = log.states.iter().all(|s| !s.effort.is_empty());
    let mut cursor = 0;
    let reference: Vec<Reading> = (1..=steps)
        .map(|k| {
            let t = t0 + k as f64 * dt;
            while cursor + 2 < log.states.len() && log.states[cursor + 1].time < t {
                cursor += 1;
            }
            interpolate(&log.states[cursor], &log.states[(cursor + 1).min(log.states.len() - 1)], t, &index, has_effort)
        })
        .collect();
    let scale = (0..rig.joints.len())
        .map(|j| {
            let effort = has_effort && rig.actuated[j];
            [
                noise_scale(&reference, |r| r.position[j], 1e-7),
                noise_scale(&reference, |r| r.velocity[j], 1e-6),
                if effort { noise_scale(&reference, |r| r.effort[j], 1e-5) } else { 0.0 },
            ]
        })
        .collect();
    let start = index.iter().map(|&i| log.states[0].position[i]).collect();
    Ok(PreparedLog { name: name.to_string(), start, program: Program { changes }, reference, has_effort, scale })
}

/// A signal's measurement noise, estimated from how far each sample lies off the midpoint of its
/// neighbours (for white noise σ, that has variance 1.5 σ²; a smooth signal adds only its
/// curvature over one step). At least `floor` and a ten-thousandth of the signal's spread, so
/// a noise-free log does not weigh rounding errors.
fn noise_scale(reference: &[Reading], f: impl Fn(&Reading) -> f32, floor: f64) -> f64 {
    let x: Vec<f64> = reference.iter().map(|r| f(r) as f64).collect();
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    let spread = (x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    let off: Vec<f64> = x.windows(3).map(|w| w[1] - (w[0] + w[2]) / 2.0).collect();
    let noise = (off.iter().map(|d| d * d).sum::<f64>() / off.len().max(1) as f64 / 1.5).sqrt();
    noise.max(spread * 1e-4).max(floor)
}

fn interpolate(a: &JointSample, b: &JointSample, t: f64, index: &[usize], effort: bool) -> Reading {
    let w = if b.time > a.time { ((t - a.time) / (b.time - a.time)).clamp(0.0, 1.0) } else { 0.0 };
    let lerp = |x: &[f64], y: &[f64]| index.iter().map(|&i| (x[i] + (y[i] - x[i]) * w) as f32).collect();
    Reading {
        position: lerp(&a.position, &b.position),
        velocity: lerp(&a.velocity, &b.velocity),
        effort: if effort { lerp(&a.effort, &b.effort) } else { Vec::new() },
    }
}

impl PreparedLog {
    /// Where the twin's joints start for parameters `params`: the logged readings less their bias.
    pub fn start_positions(&self, rig: &Rig, params: &Parameters) -> Vec<(String, f32)> {
        let bias = rig.biases(params);
        rig.joints.iter().zip(&self.start).zip(bias).map(|((j, q), b)| (j.clone(), (q - b) as f32)).collect()
    }
}

/// Joint `j`'s errors in one signal (0 position, 1 speed, 2 effort), twin less log, step by
/// step: what both the tracking error and its residuals are made of.
fn errors<'a>(
    log: &'a PreparedLog,
    twin: &'a Trajectory,
    bias: &'a [f64],
    j: usize,
    signal: usize,
) -> impl Iterator<Item = f64> + 'a {
    log.reference.iter().zip(&twin.steps).map(move |(r, t)| match signal {
        0 => t.position[j] as f64 + bias[j] - r.position[j] as f64,
        1 => t.velocity[j] as f64 - r.velocity[j] as f64,
        _ => t.effort[j] as f64 - r.effort[j] as f64,
    })
}

/// The weighted tracking error of a twin trajectory against the log (what `identify`
/// minimises): per joint, the mean squared position, speed and effort errors, each in units of
/// that signal's noise (χ² per step), summed over joints and signals. Effort counts only for
/// driven joints. A twin that matches up to the noise scores about the number of signals.
/// Per joint, in the rig's order.
pub fn tracking_cost(log: &PreparedLog, twin: &Trajectory, bias: &[f64]) -> Vec<f64> {
    let n = log.reference.len().min(twin.steps.len()).max(1) as f64;
    (0..log.scale.len())
        .map(|j| {
            let compared = log.scale[j].iter().enumerate().filter(|(_, s)| **s > 0.0);
            compared
                .map(|(signal, s)| errors(log, twin, bias, j, signal).map(|e| e * e).sum::<f64>() / n / (s * s))
                .sum()
        })
        .collect()
}

/// The tracking error as residuals: every sample's position, speed and effort error in units of
/// its noise, over √n, so that their squares sum to [`tracking_cost`]'s total. Appended to `out`
/// in a fixed order (joint, signal, step): what a sensitivity of the error is measured on.
pub fn residuals(log: &PreparedLog, twin: &Trajectory, bias: &[f64], out: &mut Vec<f64>) {
    let n = log.reference.len().min(twin.steps.len()).max(1) as f64;
    for (j, scale) in log.scale.iter().enumerate() {
        for (signal, s) in scale.iter().enumerate().filter(|(_, s)| **s > 0.0) {
            let w = 1.0 / (s * n.sqrt());
            out.extend(errors(log, twin, bias, j, signal).map(|e| w * e));
        }
    }
}

/// How far the twin strayed from the log, per joint.
#[derive(Clone, Debug, Serialize)]
pub struct JointError {
    pub joint: String,
    pub position_rmse: f64,
    pub position_max: f64,
    pub velocity_rmse: f64,
    pub velocity_max: f64,
    /// `None` when the log holds no efforts or the joint has no motor.
    pub effort_rmse: Option<f64>,
    /// When the position error first exceeded the threshold (s from the log's start).
    pub diverged_at: Option<f64>,
}

/// The comparison of one replay.
#[derive(Clone, Debug, Serialize)]
pub struct ReplayReport {
    pub log: String,
    pub seconds: f64,
    pub threshold: f64,
    pub joints: Vec<JointError>,
    /// RMS over joints of the position RMSEs.
    pub position_rmse: f64,
}

/// Compares a twin trajectory with the log.
pub fn compare(rig: &Rig, log: &PreparedLog, twin: &Trajectory, bias: &[f64], threshold: f64) -> ReplayReport {
    let dt = rig.dt();
    let joints: Vec<JointError> = rig
        .joints
        .iter()
        .enumerate()
        .map(|(j, name)| {
            let (mut sq, mut sv, mut se, mut mq, mut mv) = (0.0, 0.0, 0.0, 0.0f64, 0.0f64);
            let mut diverged_at = None;
            for (k, (r, t)) in log.reference.iter().zip(&twin.steps).enumerate() {
                let eq = (t.position[j] as f64 + bias[j] - r.position[j] as f64).abs();
                let ev = (t.velocity[j] - r.velocity[j]).abs() as f64;
                sq += eq * eq;
                sv += ev * ev;
                mq = mq.max(eq);
                mv = mv.max(ev);
                if log.has_effort {
                    se += ((t.effort[j] - r.effort[j]) as f64).powi(2);
                }
                if eq > threshold && diverged_at.is_none() {
                    diverged_at = Some((k + 1) as f64 * dt);
                }
            }
            let n = log.reference.len().max(1) as f64;
            JointError {
                joint: name.clone(),
                position_rmse: (sq / n).sqrt(),
                position_max: mq,
                velocity_rmse: (sv / n).sqrt(),
                velocity_max: mv,
                effort_rmse: (log.has_effort && rig.actuated[j]).then(|| (se / n).sqrt()),
                diverged_at,
            }
        })
        .collect();
    let position_rmse = (joints.iter().map(|j| j.position_rmse.powi(2)).sum::<f64>() / joints.len() as f64).sqrt();
    ReplayReport { log: log.name.clone(), seconds: log.reference.len() as f64 * dt, threshold, joints, position_rmse }
}

impl ReplayReport {
    /// A table for people.
    pub fn table(&self) -> String {
        let mut out = format!(
            "{}: {:.2} s replayed; position RMSE over joints {:.5}\n{:<22} {:>12} {:>12} {:>12} {:>12} {:>11} {:>12}\n",
            self.log,
            self.seconds,
            self.position_rmse,
            "joint",
            "pos RMSE",
            "pos max",
            "vel RMSE",
            "vel max",
            "effort RMSE",
            "diverged at"
        );
        for j in &self.joints {
            let effort = j.effort_rmse.map_or("-".to_string(), |e| format!("{e:.4}"));
            let diverged = j.diverged_at.map_or("never".to_string(), |t| format!("{t:.3} s"));
            out += &format!(
                "{:<22} {:>12.6} {:>12.6} {:>12.5} {:>12.5} {:>11} {:>12}\n",
                j.joint, j.position_rmse, j.position_max, j.velocity_rmse, j.velocity_max, effort, diverged
            );
        }
        out + &format!(
            "(SI units: rad or m, rad/s or m/s, N*m or N; diverged: position error over {} first)\n",
            self.threshold
        )
    }
}

/// The twin's replay as a log (what its encoders would have read, bias included), beside the
/// robot's for tools that overlay them.
pub fn twin_log(rig: &Rig, log: &PreparedLog, twin: &Trajectory, bias: &[f64], calibration: &str) -> RobotLog {
    let dt = rig.dt();
    let states = twin.samples(dt, bias);
    let meta = LogMeta {
        robot: rig.robot.to_string(),
        source: format!("twinbots {} replay of {}", env!("CARGO_PKG_VERSION"), log.name),
        calibration: calibration.to_string(),
        control_period: dt * rig.description.command_steps.max(1) as f64,
        extra: Default::default(),
    };
    RobotLog { meta, joints: rig.joints.clone(), states, commands: Vec::new(), tool: Vec::new() }
}
