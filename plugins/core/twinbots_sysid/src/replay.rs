//! Replaying a log on the twin: the twin starts in the logged state, takes the logged commands at
//! the logged times, and is compared with the log joint by joint.

use serde::Serialize;
use twinbots_log::{CommandMode, CommandSample, Entry, JointSample, LogMeta, LogStream, RobotLog};
use twinbots_sim::{MotorCommand, Parameters};

use std::collections::{BinaryHeap, VecDeque};

use crate::rig::{Program, Reading, Rig, Stand, Trajectory};
use crate::trace::ReplayPlot;

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
    let steps = physics_steps(log.duration(), dt);
    anyhow::ensure!(
        steps >= MIN_STEPS,
        "the log lasts {:.3} s, under {MIN_STEPS} physics steps of {dt} s",
        log.duration()
    );
    let mut changes = vec![Vec::new(); steps];
    for (i, c) in log.commands.iter().enumerate() {
        let k = command_step(c.time, t0, dt);
        if k >= steps {
            continue;
        }
        for (j, command) in motor_commands(rig, i, c)? {
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

/// The fewest physics steps a replay takes.
const MIN_STEPS: usize = 10;

/// The whole physics steps of `dt` a log spanning `span` seconds replays over.
fn physics_steps(span: f64, dt: f64) -> usize {
    (span / dt + 1e-6).floor() as usize
}

/// The physics step (from the log's start `t0`) a command at `time` acts from: the first that
/// starts at or after it.
fn command_step(time: f64, t0: f64, dt: f64) -> usize {
    ((time - t0) / dt - 1e-3).ceil().max(0.0) as usize
}

/// Command `i` as motor commands to the rig's joints (index into [`Rig::joints`]).
fn motor_commands(rig: &Rig, i: usize, c: &CommandSample) -> anyhow::Result<Vec<(usize, MotorCommand)>> {
    let mut out = Vec::with_capacity(c.joints.len());
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
        out.push((j, command));
    }
    Ok(out)
}

/// Where the twin's joints start for parameters `params`: the logged readings `start` (by
/// [`Rig::joints`]) less their bias.
fn start_positions(rig: &Rig, start: &[f64], params: &Parameters) -> Vec<(String, f32)> {
    let bias = rig.biases(params);
    rig.joints.iter().zip(start).zip(bias).map(|((j, q), b)| (j.clone(), (q - b) as f32)).collect()
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
        effort: if effort && !a.effort.is_empty() && !b.effort.is_empty() {
            lerp(&a.effort, &b.effort)
        } else {
            Vec::new()
        },
    }
}

impl PreparedLog {
    /// Where the twin's joints start for parameters `params`: the logged readings less their bias.
    pub fn start_positions(&self, rig: &Rig, params: &Parameters) -> Vec<(String, f32)> {
        start_positions(rig, &self.start, params)
    }

    /// The figure of the log and whole twin trajectories (with their biases) replayed on it.
    pub fn plot(&self, rig: &Rig, twins: &[(&str, &Trajectory, Vec<f64>)]) -> ReplayPlot {
        let labels: Vec<&str> = twins.iter().map(|t| t.0).collect();
        let mut plot = ReplayPlot::new(&self.name, &labels, rig.joints.len());
        for (k, reference) in self.reference.iter().enumerate() {
            let readings: Vec<(&Reading, &[f64])> = twins.iter().map(|(_, t, b)| (&t.steps[k], b.as_slice())).collect();
            plot.push((k + 1) as f64 * rig.dt(), &reference.position, &readings);
        }
        plot
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

/// A replay's errors, tallied a physics step at a time: what [`compare`] folds over a whole
/// trajectory and [`replay_stream`] over a log as it is read.
struct Comparison {
    threshold: f64,
    dt: f64,
    steps: usize,
    /// Per joint: sums of squared position, speed and effort errors, the largest position and
    /// speed errors, when the position error first passed the threshold.
    tallies: Vec<([f64; 3], [f64; 2], Option<f64>)>,
}

impl Comparison {
    fn new(rig: &Rig, threshold: f64) -> Self {
        Self { threshold, dt: rig.dt(), steps: 0, tallies: vec![([0.0; 3], [0.0; 2], None); rig.joints.len()] }
    }

    /// The twin's reading `twin` after the next step against the log's `reference` there.
    fn add(&mut self, reference: &Reading, twin: &Reading, bias: &[f64]) {
        self.steps += 1;
        for (j, (sums, max, diverged_at)) in self.tallies.iter_mut().enumerate() {
            let eq = (twin.position[j] as f64 + bias[j] - reference.position[j] as f64).abs();
            let ev = (twin.velocity[j] - reference.velocity[j]).abs() as f64;
            sums[0] += eq * eq;
            sums[1] += ev * ev;
            max[0] = max[0].max(eq);
            max[1] = max[1].max(ev);
            if !reference.effort.is_empty() {
                sums[2] += ((twin.effort[j] - reference.effort[j]) as f64).powi(2);
            }
            if eq > self.threshold && diverged_at.is_none() {
                *diverged_at = Some(self.steps as f64 * self.dt);
            }
        }
    }

    fn report(self, rig: &Rig, log: &str, has_effort: bool) -> ReplayReport {
        let n = self.steps.max(1) as f64;
        let joints: Vec<JointError> = rig
            .joints
            .iter()
            .zip(self.tallies)
            .enumerate()
            .map(|(j, (name, (sums, max, diverged_at)))| JointError {
                joint: name.clone(),
                position_rmse: (sums[0] / n).sqrt(),
                position_max: max[0],
                velocity_rmse: (sums[1] / n).sqrt(),
                velocity_max: max[1],
                effort_rmse: (has_effort && rig.actuated[j]).then(|| (sums[2] / n).sqrt()),
                diverged_at,
            })
            .collect();
        let position_rmse = (joints.iter().map(|j| j.position_rmse.powi(2)).sum::<f64>() / joints.len() as f64).sqrt();
        let seconds = self.steps as f64 * self.dt;
        ReplayReport { log: log.to_string(), seconds, threshold: self.threshold, joints, position_rmse }
    }
}

/// Compares a twin trajectory with the log.
pub fn compare(rig: &Rig, log: &PreparedLog, twin: &Trajectory, bias: &[f64], threshold: f64) -> ReplayReport {
    let mut comparison = Comparison::new(rig, threshold);
    for (r, t) in log.reference.iter().zip(&twin.steps) {
        comparison.add(r, t, bias);
    }
    comparison.report(rig, &log.name, log.has_effort)
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

/// The metadata of the twin's replay of log `name` as a log (what its encoders would have read,
/// bias included, beside the robot's for tools that overlay them).
pub fn twin_meta(rig: &Rig, name: &str, calibration: &str) -> LogMeta {
    LogMeta {
        robot: rig.robot.to_string(),
        source: format!("twinbots {} replay of {name}", env!("CARGO_PKG_VERSION")),
        calibration: calibration.to_string(),
        control_period: rig.dt() * rig.description.command_steps.max(1) as f64,
        extra: Default::default(),
    }
}

/// How far behind its time a command may come in a log's file and still act at its step (s):
/// a trajectory's header stamp and the time a bag logged it may differ by this much.
pub const COMMAND_LOOKAHEAD: f64 = 1.0;

/// A command read from a stream and waiting for its step: the earliest first, then the first read.
struct Pending {
    time: f64,
    index: usize,
    command: CommandSample,
}

impl Ord for Pending {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        // Reversed: the heap's top is the earliest.
        other.time.total_cmp(&self.time).then(other.index.cmp(&self.index))
    }
}

impl PartialOrd for Pending {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl PartialEq for Pending {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other).is_eq()
    }
}

impl Eq for Pending {}

/// A log's stream read [`COMMAND_LOOKAHEAD`] ahead of the replay: the joint states from the
/// pair around the replay's time on, and the commands not yet due.
struct Feed<'a> {
    stream: &'a mut LogStream,
    ended: bool,
    states: VecDeque<JointSample>,
    pending: BinaryHeap<Pending>,
    commands: usize,
    /// Whether every joint state read holds efforts.
    efforts: bool,
}

impl Feed<'_> {
    /// Reads until a joint state at or after `until`, or the log's end.
    fn fill(&mut self, until: f64) -> anyhow::Result<()> {
        while !self.ended && self.states.back().is_none_or(|s| s.time < until) {
            match self.stream.next().transpose()? {
                None => self.ended = true,
                Some(Entry::State(s)) => {
                    self.efforts &= !s.effort.is_empty();
                    self.states.push_back(s);
                }
                Some(Entry::Command(command)) => {
                    self.pending.push(Pending { time: command.time, index: self.commands, command });
                    self.commands += 1;
                }
                Some(Entry::Tool(_)) => {}
            }
        }
        Ok(())
    }
}

/// [`prepare`], [`run`](crate::rig::run) and [`compare`] as the log is read: the twin (on
/// `params`) steps along the stream, each step's reading handed to `on_twin` as the twin's log
/// sample and tallied against the log, so memory does not grow with the log's length. The same
/// report as the three on the whole log, and the plot of it (`label` the twin's line).
pub fn replay_stream(
    rig: &Rig,
    params: &Parameters,
    log: &mut LogStream,
    threshold: f64,
    label: &str,
    mut on_twin: impl FnMut(JointSample) -> anyhow::Result<()>,
) -> anyhow::Result<(ReplayReport, ReplayPlot)> {
    log.check_robot(rig.robot, &rig.joints)?;
    let name = log.name.clone();
    let index: Vec<usize> = rig
        .joints
        .iter()
        .map(|j| log.joints.iter().position(|n| n == j).expect("checked: every joint is logged"))
        .collect();
    let (dt, t0) = (rig.dt(), log.start);
    let mut feed = Feed {
        stream: log,
        ended: false,
        states: VecDeque::new(),
        pending: BinaryHeap::new(),
        commands: 0,
        efforts: true,
    };
    feed.fill(t0 + COMMAND_LOOKAHEAD)?;
    let first = feed.states.front().expect("a log stream starts at a joint state");
    let start: Vec<f64> = index.iter().map(|&i| first.position[i]).collect();
    let mut stand = Stand::new(rig, &start_positions(rig, &start, params), std::slice::from_ref(params));
    let bias = rig.biases(params);
    on_twin(stand.reading(0).sample(0.0, &bias))?;
    let mut comparison = Comparison::new(rig, threshold);
    let mut plot = ReplayPlot::new(&name, &[label], rig.joints.len());
    for k in 0.. {
        let t = t0 + (k + 1) as f64 * dt;
        feed.fill(t + COMMAND_LOOKAHEAD)?;
        let last = feed.states.back().expect("states from the first on").time;
        // As `prepare`: the whole physics steps the log spans.
        if feed.ended && k + 1 > physics_steps(last - t0, dt) {
            break;
        }
        while feed.states.len() > 2 && feed.states[1].time < t {
            feed.states.pop_front();
        }
        while feed.pending.peek().is_some_and(|p| command_step(p.time, t0, dt) <= k) {
            let p = feed.pending.pop().expect("peeked");
            anyhow::ensure!(
                command_step(p.time, t0, dt) == k || k == 0,
                "{name}: command {} of the file (t = {} s) comes after joint states over {COMMAND_LOOKAHEAD} s later than it: a command may stand at most {COMMAND_LOOKAHEAD} s behind its time",
                p.index,
                p.time
            );
            for (j, command) in
                motor_commands(rig, p.index, &p.command).map_err(|e| anyhow::anyhow!("{name}: {e:#}"))?
            {
                stand.command(0, j, command);
            }
        }
        stand.step();
        let twin = stand.reading(0);
        let (a, b) = (&feed.states[0], &feed.states[feed.states.len().min(2) - 1]);
        let reference = interpolate(a, b, t, &index, true);
        comparison.add(&reference, &twin, &bias);
        let time = (k + 1) as f64 * dt;
        plot.push(time, &reference.position, &[(&twin, &bias)]);
        on_twin(twin.sample(time, &bias))?;
    }
    anyhow::ensure!(
        comparison.steps >= MIN_STEPS,
        "{name}: the log lasts {:.3} s, under {MIN_STEPS} physics steps of {dt} s",
        comparison.steps as f64 * dt
    );
    Ok((comparison.report(rig, &name, feed.efforts), plot))
}
