//! `twinbots monitor`: the twin follows a robot live. Every controller report (RTDE, 500 Hz; or a
//! ROS 2 driver's joint states, [`ros2`])
//! gives the robot's measured joints and the joint speeds its controller is commanding; the twin
//! takes the same command for the same 2 ms and is compared with the robot, joint by joint:
//! the divergence over the last second (RMSE and largest error), an alarm when it passes a
//! threshold, and an alarm when the commanded motion would, within the shadow's look-ahead,
//! take a joint into its stop or the arm into the table — before it happens. The twin is
//! re-anchored to the robot whenever both stand still, so slow drift never adds up; a twin
//! that misses a load diverges as soon as the arm moves. Robot and twin are logged side by
//! side (robot logs: MCAP), with a running account of the motions (their duration and energy).

use std::collections::VecDeque;

use serde::Serialize;
use twinbots_live::{JsonSchema, Place};
use twinbots_log::{CommandMode, CommandSample, JointSample, LogMeta, RobotLog};
use twinbots_sim::{MotorCommand, Parameters};
use twinbots_sysid::Stand;
use twinbots_task::shadow::Shadow;

use crate::live::{ALARM, RobotJoints, RobotView};
use crate::ur_sim::{CYCLE, ServedArm, controller_stand};

pub mod recording;
#[cfg(feature = "ros2")]
pub mod ros2;
pub mod source;

/// The errors of the last window, per joint: position (rad) and effort (N·m), one pair a report.
#[derive(Default)]
struct Window(VecDeque<[[f64; 6]; 2]>);

/// Which error of a [`Window`]'s pair.
const POSITION: usize = 0;
const EFFORT: usize = 1;

impl Window {
    /// Adds a report's errors, keeping the last `keep`.
    fn push(&mut self, errors: [[f64; 6]; 2], keep: usize) {
        self.0.push_back(errors);
        while self.0.len() > keep {
            self.0.pop_front();
        }
    }

    /// Per joint, the RMSE of error `which` over the window.
    fn rmse(&self, which: usize) -> [f64; 6] {
        let n = self.0.len().max(1) as f64;
        std::array::from_fn(|j| (self.0.iter().map(|e| e[which][j] * e[which][j]).sum::<f64>() / n).sqrt())
    }
}

/// How the monitor judges.
#[derive(Clone, Debug)]
pub struct MonitorOptions {
    /// The twin's calibration (over its nominal parameters).
    pub calibration: Parameters,
    /// Position divergence (rad, RMSE over the window) beyond which a joint raises the alarm.
    pub position_threshold: f64,
    /// Effort divergence (N·m, RMSE over the window of the measured effort less the twin's):
    /// what a load the twin does not know shows first, as the servos hold position against it.
    pub effort_threshold: f64,
    /// The rolling window (s).
    pub window: f64,
    /// Where the robot's reports come from, as its log names it ("robot (RTDE)").
    pub source: String,
    /// What the predicted alarm checks each command against (the cell's obstacles with `--cell`).
    pub shadow: Shadow,
    /// The arm the robot is, as the twin models it (the UR5e, or a robot file's six-joint arm).
    pub arm: ServedArm,
}

impl Default for MonitorOptions {
    fn default() -> Self {
        Self {
            calibration: Parameters::default(),
            position_threshold: 0.005,
            effort_threshold: 1.5,
            window: 1.0,
            source: "robot (RTDE)".into(),
            shadow: ur5e::deploy::shadow(),
            arm: ServedArm::ur5e(),
        }
    }
}

/// One controller report.
#[derive(Clone, Debug)]
pub struct Report {
    pub time: f64,
    pub q: [f64; 6],
    pub qd: [f64; 6],
    /// The joint speeds the controller commands (`target_qd`).
    pub command: [f64; 6],
    pub effort: [f64; 6],
}

/// `/residuals` of the live view (see [`Monitor::publish_live`]).
pub const RESIDUALS: JsonSchema = JsonSchema {
    name: "twinbots/Residuals",
    schema: r#"{"title":"twinbots/Residuals","type":"object","properties":{"time":{"type":"number"},"name":{"type":"array","items":{"type":"string"}},"position_error_mrad":{"type":"array","items":{"type":"number"}},"effort_error":{"type":"array","items":{"type":"number"}},"position_rmse_mrad":{"type":"array","items":{"type":"number"}},"effort_rmse":{"type":"array","items":{"type":"number"}},"alarms_standing":{"type":"array","items":{"type":"boolean"}}}}"#,
};

/// Something the monitor raises.
#[derive(Clone, Debug, Serialize)]
pub struct Alarm {
    pub time: f64,
    /// `divergence` or `predicted`.
    pub kind: String,
    pub message: String,
}

/// A motion of the robot, from leaving rest to coming back to it.
#[derive(Clone, Debug, Serialize)]
pub struct Motion {
    pub start: f64,
    pub duration_s: f64,
    pub energy_j: f64,
}

/// The monitor's account so far.
#[derive(Clone, Debug, Serialize)]
pub struct MonitorReport {
    pub seconds: f64,
    pub reports: usize,
    /// Reports the controller's clock says were skipped (the twin stepped over them).
    pub skipped: u64,
    /// Per joint: the largest windowed position RMSE seen (rad), the largest position error
    /// (rad), the largest windowed effort RMSE (N·m).
    pub worst_rmse: [f64; 6],
    pub worst_error: [f64; 6],
    pub worst_effort_rmse: [f64; 6],
    pub alarms: Vec<Alarm>,
    pub motions: Vec<Motion>,
    pub anchors: usize,
}

/// Still: every joint slower than this (rad/s), and no command.
const REST_SPEED: f64 = 0.005;
/// The shortest motion counted (s).
const MIN_MOTION: f64 = 0.1;
/// Cycles at rest before the twin may be re-anchored…
const REST_CYCLES: usize = 25;
/// …if it stands this far from the robot (rad).
const ANCHOR_ERROR: f64 = 0.0005;
/// Cycles the twin stands before it is put where the robot is (1 s).
const SETTLE_CYCLES: usize = 500;
/// Cycles after the twin is put somewhere before it is compared (0.5 s): moving it shakes it.
const WARM_UP_CYCLES: usize = 250;

pub struct Monitor {
    options: MonitorOptions,
    stand: Stand,
    bias: Vec<f64>,
    shadow: Shadow,
    /// The controller's time of the last report (the twin stands there).
    last_time: f64,
    last_command: [f64; 6],
    errors: Window,
    report: MonitorReport,
    /// Per joint: its divergence alarm stands (raised, not yet back under half its threshold).
    /// Joints alarm independently: one that stays diverged hides no other.
    divergence_alarm: [bool; 6],
    predicted_alarm: bool,
    rest_cycles: usize,
    /// Cycles left before comparisons count (after the twin was put in place).
    warm_up: usize,
    motion: Option<Motion>,
    pub robot_log: RobotLog,
    pub twin_log: RobotLog,
}

impl Monitor {
    /// The arm's twin (the controller's 2 ms step) standing where the robot's first report says.
    pub fn new(options: MonitorOptions, first: &Report) -> anyhow::Result<Self> {
        anyhow::ensure!(
            options.position_threshold > 0.0 && options.effort_threshold > 0.0 && options.window > 0.0,
            "the thresholds and the window must be positive"
        );
        let (mut stand, bias) = controller_stand(&options.arm, &options.calibration, &first.q)?;
        // Settled under its own weight first (its drives take up the load), then put exactly
        // where the robot stands: it holds there as the robot does.
        for _ in 0..SETTLE_CYCLES {
            stand.step();
        }
        let at: Vec<f32> = (0..6).map(|j| (first.q[j] - bias[j]) as f32).collect();
        stand.place(0, &at);
        let meta = |source: &str| LogMeta {
            robot: options.arm.robot.name.into(),
            source: source.into(),
            control_period: CYCLE,
            ..Default::default()
        };
        let joints = options.arm.joints.clone();
        let log = |source: &str| RobotLog {
            meta: meta(source),
            joints: joints.clone(),
            states: Vec::new(),
            commands: Vec::new(),
            tool: Vec::new(),
        };
        let robot_log = log(&options.source);
        let shadow = options.shadow.clone();
        Ok(Self {
            options,
            stand,
            bias,
            shadow,
            // The twin stands at the first report: it steps from the next on.
            last_time: first.time,
            last_command: first.command,
            errors: Window::default(),
            report: MonitorReport {
                seconds: 0.0,
                reports: 0,
                skipped: 0,
                worst_rmse: [0.0; 6],
                worst_error: [0.0; 6],
                worst_effort_rmse: [0.0; 6],
                alarms: Vec::new(),
                motions: Vec::new(),
                anchors: 0,
            },
            divergence_alarm: [false; 6],
            predicted_alarm: false,
            rest_cycles: 0,
            warm_up: WARM_UP_CYCLES,
            motion: None,
            robot_log,
            twin_log: log("twinbots monitor: the twin on the robot's commands"),
        })
    }

    /// Takes one report: steps the twin over the cycles since the last, compares, and returns
    /// the alarms it raised.
    pub fn observe(&mut self, r: &Report) -> Vec<Alarm> {
        let mut raised = Vec::new();
        let cycles = ((r.time - self.last_time) / CYCLE).round().max(0.0) as u64;
        self.report.skipped += cycles.saturating_sub(1);
        self.last_time = r.time;
        // Skipped reports' commands are unknown: the program's speeds ramp linearly, so the
        // twin takes the line from the last command to this one.
        for k in 1..=cycles {
            let f = k as f64 / cycles as f64;
            for j in 0..6 {
                let v = self.last_command[j] + f * (r.command[j] - self.last_command[j]);
                self.stand.command(0, j, MotorCommand::Velocity(v as f32));
            }
            self.stand.step();
        }
        self.last_command = r.command;
        let twin = self.stand.reading(0);
        let twin_q: [f64; 6] = std::array::from_fn(|j| twin.position[j] as f64 + self.bias[j]);
        let error: [f64; 6] = std::array::from_fn(|j| r.q[j] - twin_q[j]);
        self.report.reports += 1;
        self.report.seconds = r.time;
        self.log(r, &twin, &twin_q);

        // The divergence over the window (once the twin has settled where it was put).
        let effort_error: [f64; 6] = std::array::from_fn(|j| r.effort[j] - twin.effort[j] as f64);
        if self.warm_up > 0 {
            self.warm_up -= 1;
        } else {
            self.errors.push([error, effort_error], (self.options.window / CYCLE).round() as usize);
        }
        let rmse = self.rmse();
        let effort_rmse = self.effort_rmse();
        for j in 0..6 {
            self.report.worst_rmse[j] = self.report.worst_rmse[j].max(rmse[j]);
            self.report.worst_effort_rmse[j] = self.report.worst_effort_rmse[j].max(effort_rmse[j]);
            if self.warm_up == 0 {
                self.report.worst_error[j] = self.report.worst_error[j].max(error[j].abs());
            }
        }
        // Each joint against its thresholds, in units of them.
        for j in 0..6 {
            let ratio = (rmse[j] / self.options.position_threshold).max(effort_rmse[j] / self.options.effort_threshold);
            if !self.divergence_alarm[j] && ratio > 1.0 {
                self.divergence_alarm[j] = true;
                raised.push(Alarm {
                    time: r.time,
                    kind: "divergence".into(),
                    message: format!(
                        "{} diverged over the last {:.1} s: position RMSE {:.2} mrad (threshold {:.2}), effort RMSE {:.2} N*m (threshold {:.2})",
                        self.options.arm.joints[j],
                        self.options.window,
                        rmse[j] * 1e3,
                        self.options.position_threshold * 1e3,
                        effort_rmse[j],
                        self.options.effort_threshold
                    ),
                });
            } else if self.divergence_alarm[j] && ratio < 0.5 {
                self.divergence_alarm[j] = false;
            }
        }

        // What the command would do next, by the twin's kinematics.
        let verdict = self.shadow.check(&r.q, &r.command, &r.command, CYCLE);
        if verdict.refused && !self.predicted_alarm {
            raised.push(Alarm {
                time: r.time,
                kind: "predicted".into(),
                message: format!("predicted: {}", verdict.notes.join("; ")),
            });
        }
        self.predicted_alarm = verdict.refused;

        self.follow_motion(r, &error);
        self.report.alarms.extend(raised.iter().cloned());
        raised
    }

    /// Motions (rest to rest) with their energy; the twin re-anchored at rest.
    fn follow_motion(&mut self, r: &Report, error: &[f64; 6]) {
        let still = r.qd.iter().all(|v| v.abs() < REST_SPEED) && r.command.iter().all(|v| *v == 0.0);
        let power: f64 = r.effort.iter().zip(&r.qd).map(|(e, v)| (e * v).abs()).sum();
        if still {
            self.rest_cycles += 1;
            // A motion is one that lasts (a command that flickers at rest is none).
            if let Some(m) = self.motion.take().filter(|m| r.time - m.start >= MIN_MOTION) {
                self.report.motions.push(Motion { duration_s: r.time - m.start, ..m });
            }
            if self.rest_cycles == REST_CYCLES && error.iter().any(|e| e.abs() > ANCHOR_ERROR) {
                let at: Vec<f32> = (0..6).map(|j| (r.q[j] - self.bias[j]) as f32).collect();
                self.stand.place(0, &at);
                self.report.anchors += 1;
                self.warm_up = WARM_UP_CYCLES;
                self.errors = Window::default();
            }
        } else {
            self.rest_cycles = 0;
            let m = self.motion.get_or_insert(Motion { start: r.time, duration_s: 0.0, energy_j: 0.0 });
            m.energy_j += power * CYCLE;
        }
    }

    fn log(&mut self, r: &Report, twin: &twinbots_sysid::rig::Reading, twin_q: &[f64; 6]) {
        self.robot_log.states.push(JointSample {
            time: r.time,
            position: r.q.to_vec(),
            velocity: r.qd.to_vec(),
            effort: r.effort.to_vec(),
        });
        self.robot_log.commands.push(CommandSample {
            time: r.time,
            joints: self.options.arm.joints.clone(),
            modes: vec![CommandMode::Velocity; 6],
            values: r.command.to_vec(),
        });
        self.twin_log.states.push(JointSample {
            time: r.time,
            position: twin_q.to_vec(),
            velocity: twin.velocity.iter().map(|&v| v as f64).collect(),
            effort: twin.effort.iter().map(|&v| v as f64).collect(),
        });
    }

    /// The twin's world and its arena (to render it).
    pub fn twin_scene(&mut self) -> (&mut bevy::prelude::World, bevy::prelude::Entity) {
        self.stand.scene(0)
    }

    /// Advertises the live view's channels of [`Monitor::publish_live`] before anything is
    /// published on them, so that a viewer can be listening when the first alarm is raised.
    pub fn advertise_live(view: &RobotView) -> anyhow::Result<()> {
        let server = view.server();
        server.advertise("/alarms", ALARM)?;
        server.advertise("/residuals", RESIDUALS)?;
        server.advertise("/twin/joint_states", twinbots_live::JOINT_STATE)
    }

    /// The live view's frame for report `r`, when one is due: the robot's ghost and joint
    /// states, the twin (`twin/…`, `/twin/joint_states`) and the residuals (`/residuals`: the
    /// robot less the twin now, and their RMSE over the window, per joint); `alarms` as raised.
    pub fn publish_live(&mut self, view: &mut RobotView, r: &Report, alarms: &[Alarm]) {
        for alarm in alarms {
            if let Ok(value) = serde_json::to_value(alarm) {
                view.server().publish_json("/alarms", ALARM, &value);
            }
        }
        let (rmse, effort_rmse) = (self.rmse(), self.effort_rmse());
        let twin = self.twin_log.states.last().cloned();
        let robot = RobotJoints { time: r.time, q: &r.q, qd: &r.qd, effort: &r.effort };
        view.publish(robot, |frame| {
            let (world, _) = self.stand.scene(0);
            frame.world(world, Place::Named { name: "twin" });
            let Some(twin) = twin else { return };
            let residuals = serde_json::json!({
                "time": r.time,
                "name": &self.options.arm.joints,
                "position_error_mrad": (0..6).map(|j| 1e3 * (r.q[j] - twin.position[j])).collect::<Vec<_>>(),
                "effort_error": (0..6).map(|j| r.effort[j] - twin.effort[j]).collect::<Vec<_>>(),
                "position_rmse_mrad": rmse.map(|e| 1e3 * e),
                "effort_rmse": effort_rmse,
                "alarms_standing": self.divergence_alarm,
            });
            frame.json("/residuals", RESIDUALS, &residuals);
        });
    }

    /// The arm's joints, the controller's order.
    pub fn joints(&self) -> &[String] {
        &self.options.arm.joints
    }

    /// The account so far.
    pub fn report(&self) -> &MonitorReport {
        &self.report
    }

    /// Per joint, the RMSE over the current window (rad).
    pub fn rmse(&self) -> [f64; 6] {
        self.errors.rmse(POSITION)
    }

    /// Per joint, the effort residual's RMSE over the current window (N·m).
    pub fn effort_rmse(&self) -> [f64; 6] {
        self.errors.rmse(EFFORT)
    }
}
