//! The log in memory: samples in SI units, times in seconds from the log's start.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// The longest a log's joint states may be apart (s): a clock that jumps (by 10⁶ s, say) is a
/// damaged log, not a pause to replay.
pub const MAX_GAP: f64 = 60.0;
/// The largest joint position a log may hold (rad or m): a thousand and more turns is a damaged value.
pub const MAX_POSITION: f64 = 1e4;
/// The largest joint speed (rad/s or m/s).
pub const MAX_VELOCITY: f64 = 1e4;
/// The largest effort or command (N·m or N).
pub const MAX_EFFORT: f64 = 1e7;

/// What the log says about itself (MCAP metadata record `twinbots`; CSV `#` header lines).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LogMeta {
    /// The robot's registry name (`ur5e`); empty when a converter did not say.
    pub robot: String,
    /// The twin's version that wrote it (`twinbots 0.1.0`), or the source (`ur_robot_driver`).
    pub source: String,
    /// The calibration file the twin ran with, if any.
    pub calibration: String,
    /// The controller's command period (s); 0 when unknown.
    pub control_period: f64,
    /// Any other key of the metadata record.
    pub extra: BTreeMap<String, String>,
}

/// The units every number is in (written into every log's metadata).
pub const UNITS: &str = "SI: s, rad, rad/s, N*m for revolute joints; m, m/s, N for prismatic joints";

/// The joints' measured state at one time: one value per joint, in `RobotLog::joints`' order.
#[derive(Clone, Debug, PartialEq)]
pub struct JointSample {
    pub time: f64,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    /// Empty when the robot does not measure efforts.
    pub effort: Vec<f64>,
}

/// How a command drives its joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CommandMode {
    Velocity,
    Position,
    Torque,
}

impl CommandMode {
    pub fn name(self) -> &'static str {
        match self {
            Self::Velocity => "velocity",
            Self::Position => "position",
            Self::Torque => "torque",
        }
    }

    pub fn parse(s: &str) -> anyhow::Result<Self> {
        match s {
            "velocity" => Ok(Self::Velocity),
            "position" => Ok(Self::Position),
            "torque" => Ok(Self::Torque),
            _ => anyhow::bail!("unknown command mode '{s}' (known: velocity, position, torque)"),
        }
    }
}

/// The commands sent at one time: to the named joints (a subset of the log's), one mode and
/// value each. A command holds until the next one for the same joint.
#[derive(Clone, Debug, PartialEq)]
pub struct CommandSample {
    pub time: f64,
    pub joints: Vec<String>,
    pub modes: Vec<CommandMode>,
    pub values: Vec<f64>,
}

/// The tool (TCP) pose the controller computed: position (m) and orientation as a unit
/// quaternion (x, y, z, w), in the robot's base frame.
#[derive(Clone, Debug, PartialEq)]
pub struct ToolSample {
    pub time: f64,
    pub position: [f64; 3],
    pub orientation: [f64; 4],
}

/// A robot's log.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RobotLog {
    pub meta: LogMeta,
    /// The joints the states name, in their order.
    pub joints: Vec<String>,
    pub states: Vec<JointSample>,
    pub commands: Vec<CommandSample>,
    pub tool: Vec<ToolSample>,
}

impl RobotLog {
    /// Index of a joint in the states, by name.
    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j == name)
    }

    /// Seconds from the first state to the last.
    pub fn duration(&self) -> f64 {
        match (self.states.first(), self.states.last()) {
            (Some(a), Some(b)) => b.time - a.time,
            _ => 0.0,
        }
    }

    /// The records in time order across the kinds (at one time: states, then commands, then
    /// tool poses), as a recorder writes them.
    pub fn entries(&self) -> impl Iterator<Item = Entry> + '_ {
        let mut cursor = [0; 3];
        std::iter::from_fn(move || self.next_entry(&mut cursor))
    }

    /// [`Self::entries`], owning the log.
    pub fn into_entries(self) -> impl Iterator<Item = Entry> {
        let mut cursor = [0; 3];
        std::iter::from_fn(move || self.next_entry(&mut cursor))
    }

    /// The earliest record at or after `cursor` (per kind: states, commands, tool poses).
    fn next_entry(&self, cursor: &mut [usize; 3]) -> Option<Entry> {
        let times = [
            self.states.get(cursor[0]).map(|s| s.time),
            self.commands.get(cursor[1]).map(|c| c.time),
            self.tool.get(cursor[2]).map(|t| t.time),
        ];
        // The first of equal times: a state before a command before a tool pose.
        let kind = (0..3).filter_map(|k| Some((k, times[k]?))).min_by(|a, b| a.1.total_cmp(&b.1))?.0;
        let i = cursor[kind];
        cursor[kind] += 1;
        Some(match kind {
            0 => Entry::State(self.states[i].clone()),
            1 => Entry::Command(self.commands[i].clone()),
            _ => Entry::Tool(self.tool[i].clone()),
        })
    }

    /// Checks what every reader relies on; the error names the problem and where it is.
    pub fn validate(&self) -> anyhow::Result<()> {
        let mut check = Checker::new(&self.joints)?;
        anyhow::ensure!(!self.states.is_empty(), "the log has no joint states");
        for s in &self.states {
            check.state(s)?;
        }
        for c in &self.commands {
            check.command(c)?;
        }
        for t in &self.tool {
            check.tool(t)?;
        }
        Ok(())
    }

    /// Checks that the log is of `robot` with the joints `expected` ([`check_robot`]).
    pub fn check_robot(&self, robot: &str, expected: &[String]) -> anyhow::Result<()> {
        check_robot(&self.meta, &self.joints, robot, expected)
    }
}

/// Checks that a log (its metadata and joints) is of `robot` with the joints `expected`: the
/// metadata's robot (when it names one) and every expected joint present. Extra joints are
/// allowed (a driver may publish more); the error lists what is missing.
pub fn check_robot(meta: &LogMeta, joints: &[String], robot: &str, expected: &[String]) -> anyhow::Result<()> {
    if !meta.robot.is_empty() && meta.robot != robot {
        anyhow::bail!("the log is of robot '{}', not '{robot}'", meta.robot);
    }
    let missing: Vec<&str> = expected.iter().filter(|j| !joints.contains(j)).map(|s| s.as_str()).collect();
    anyhow::ensure!(
        missing.is_empty(),
        "the log lacks joint(s) {} of robot '{robot}' (it has: {})",
        missing.join(", "),
        joints.join(", ")
    );
    Ok(())
}

/// One record of a log as a reader meets it: what a stream of a log ([`crate::LogStream`])
/// yields.
#[derive(Clone, Debug, PartialEq)]
pub enum Entry {
    State(JointSample),
    Command(CommandSample),
    Tool(ToolSample),
}

impl Entry {
    pub fn time(&self) -> f64 {
        match self {
            Self::State(s) => s.time,
            Self::Command(c) => c.time,
            Self::Tool(t) => t.time,
        }
    }
}

/// [`RobotLog::validate`] a record at a time, for a log read as a stream: each kind's records
/// in time order (joint states increasing, at most [`MAX_GAP`] apart; commands not going
/// backwards), every value finite and within its bound, every command to a logged joint.
pub struct Checker {
    joints: Vec<String>,
    states: usize,
    commands: usize,
    tools: usize,
    last_state: f64,
    last_command: f64,
}

impl Checker {
    /// A checker of a log whose states name `joints`; an error if the names themselves are bad.
    pub fn new(joints: &[String]) -> anyhow::Result<Self> {
        anyhow::ensure!(!joints.is_empty(), "the log names no joints");
        for (i, name) in joints.iter().enumerate() {
            anyhow::ensure!(!name.is_empty(), "joint {i} has an empty name");
            anyhow::ensure!(!joints[..i].contains(name), "joint '{name}' is named twice");
        }
        Ok(Self {
            joints: joints.to_vec(),
            states: 0,
            commands: 0,
            tools: 0,
            last_state: f64::NEG_INFINITY,
            last_command: f64::NEG_INFINITY,
        })
    }

    /// Checks the next joint state.
    pub fn state(&mut self, s: &JointSample) -> anyhow::Result<()> {
        let (i, last, n) = (self.states, self.last_state, self.joints.len());
        let at = || format!("joint state {i} (t = {} s)", s.time);
        anyhow::ensure!(s.time.is_finite(), "{}: time is not a finite number", at());
        anyhow::ensure!(s.time > last, "{}: times are not increasing (previous {last} s)", at());
        anyhow::ensure!(
            i == 0 || s.time - last <= MAX_GAP,
            "{}: {:.3} s after the sample before (previous {last} s): a log's samples are at most {MAX_GAP} s apart",
            at(),
            s.time - last
        );
        anyhow::ensure!(s.position.len() == n, "{}: {} positions for {n} joints", at(), s.position.len());
        anyhow::ensure!(s.velocity.len() == n, "{}: {} velocities for {n} joints", at(), s.velocity.len());
        anyhow::ensure!(
            s.effort.is_empty() || s.effort.len() == n,
            "{}: {} efforts for {n} joints",
            at(),
            s.effort.len()
        );
        for (what, values, bound) in [
            ("position", &s.position, MAX_POSITION),
            ("velocity", &s.velocity, MAX_VELOCITY),
            ("effort", &s.effort, MAX_EFFORT),
        ] {
            if let Some(j) = values.iter().position(|v| !v.is_finite()) {
                anyhow::bail!("{}: {what} of '{}' is {}", at(), self.joints[j], values[j]);
            }
            if let Some(j) = values.iter().position(|v| v.abs() > bound) {
                anyhow::bail!(
                    "{}: {what} of '{}' is {:e}, beyond ±{bound:e} (rad or m and their rates, N·m or N)",
                    at(),
                    self.joints[j],
                    values[j]
                );
            }
        }
        self.states += 1;
        self.last_state = s.time;
        Ok(())
    }

    /// Checks the next command (in time order).
    pub fn command(&mut self, c: &CommandSample) -> anyhow::Result<()> {
        let (i, last) = (self.commands, self.last_command);
        anyhow::ensure!(!(c.time < last), "command {i} (t = {} s): times go backwards (previous {last} s)", c.time);
        self.command_values(c)?;
        self.last_command = c.time;
        Ok(())
    }

    /// Checks a command's time and values, not its order: for a stream, where a trajectory's
    /// points come ahead of their times.
    pub fn command_values(&mut self, c: &CommandSample) -> anyhow::Result<()> {
        let i = self.commands;
        let at = || format!("command {i} (t = {} s)", c.time);
        anyhow::ensure!(c.time.is_finite(), "{}: time is not a finite number", at());
        anyhow::ensure!(
            c.joints.len() == c.modes.len() && c.joints.len() == c.values.len(),
            "{}: {} joints, {} modes, {} values",
            at(),
            c.joints.len(),
            c.modes.len(),
            c.values.len()
        );
        for (j, v) in c.joints.iter().zip(&c.values) {
            anyhow::ensure!(
                self.joints.contains(j),
                "{}: joint '{j}' is not among the logged joints ({})",
                at(),
                self.joints.join(", ")
            );
            anyhow::ensure!(v.is_finite(), "{}: the command to '{j}' is {v}", at());
            anyhow::ensure!(v.abs() <= MAX_EFFORT, "{}: the command to '{j}' is {v:e}, beyond ±{MAX_EFFORT:e}", at());
        }
        self.commands += 1;
        Ok(())
    }

    /// Checks the next tool pose.
    pub fn tool(&mut self, t: &ToolSample) -> anyhow::Result<()> {
        anyhow::ensure!(
            t.time.is_finite() && t.position.iter().chain(&t.orientation).all(|v| v.is_finite()),
            "tool pose {} (t = {} s) holds a value that is not a finite number",
            self.tools,
            t.time
        );
        self.tools += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn log(samples: &[(f64, f64)]) -> RobotLog {
        RobotLog {
            meta: LogMeta::default(),
            joints: vec!["j".into()],
            states: samples
                .iter()
                .map(|&(time, q)| JointSample { time, position: vec![q], velocity: vec![0.0], effort: Vec::new() })
                .collect(),
            commands: Vec::new(),
            tool: Vec::new(),
        }
    }

    /// A clock that jumps and values no joint reaches are refused, naming the sample, before
    /// anything is sized from them (a replay allocated 18 GB for a 10⁶ s jump, and spun on 1e300 rad).
    #[test]
    fn a_jumping_clock_and_wild_values_are_named() {
        log(&[(0.0, 0.0), (0.008, 0.1), (60.008, 0.2)]).validate().unwrap();
        let cases = [
            (log(&[(0.0, 0.0), (0.008, 0.1), (1e6, 0.2)]), "joint state 2 (t = 1000000 s): 999999.992 s after"),
            (log(&[(0.0, 0.0), (0.008, 1e300)]), "joint state 1 (t = 0.008 s): position of 'j' is 1e300, beyond"),
            (log(&[(0.0, 1e15), (0.008, 0.0)]), "joint state 0 (t = 0 s): position of 'j' is 1e15, beyond"),
        ];
        for (log, expected) in cases {
            let err = log.validate().unwrap_err().to_string();
            assert!(err.starts_with(expected), "{err:?} does not start with {expected:?}");
        }
    }
}
