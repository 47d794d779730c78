//! twinbots_log: robot logs, the data a twin is validated and calibrated against.
//!
//! A [`RobotLog`] is what a robot controller can know: its joints' measured positions,
//! speeds and efforts over time, the commands it sent, the tool pose its kinematics
//! computed, and metadata (robot, control period, units). Never privileged simulator state.
//! It is stored as MCAP ([`mcap_file`]) with joint states as ROS 2 `sensor_msgs/msg/JointState`
//! messages, so a rosbag2 recording of a real driver is a valid input, or as CSV ([`csv_file`]).
//! The layout is documented in `docs/logs.md`.

pub mod cdr;
pub mod csv_file;
pub mod log;
pub mod mcap_file;
pub mod rtde_csv;

pub use log::{Checker, CommandMode, CommandSample, Entry, JointSample, LogMeta, RobotLog, ToolSample};

use std::path::Path;

/// A log file's format, told by its extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Mcap,
    Csv,
}

impl Format {
    /// The format of `path` (`.mcap`, `.csv` or `.csv.gz`, any case), or an error naming the file.
    pub fn of(path: &Path) -> anyhow::Result<Self> {
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("").to_ascii_lowercase();
        if name.ends_with(".csv.gz") {
            return Ok(Self::Csv);
        }
        match path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase().as_str() {
            "mcap" => Ok(Self::Mcap),
            "csv" => Ok(Self::Csv),
            other => anyhow::bail!(
                "{}: unknown log format '.{other}': a robot log is an .mcap or a .csv file (docs/logs.md)",
                path.display()
            ),
        }
    }
}

/// Reads a log, MCAP or CSV by its extension (`.mcap`, `.csv`, `.csv.gz`); a CSV whose header
/// is RTDE output names is a UR recording ([`rtde_csv`], without efforts: see [`read_with`]).
/// Errors name the file.
pub fn read(path: &Path) -> anyhow::Result<RobotLog> {
    read_with(path, &rtde_csv::Efforts::None)
}

/// The most bytes a CSV log may hold once decompressed.
pub const MAX_CSV_BYTES: u64 = 1 << 30;

/// [`read`], a UR recording's efforts taken as `efforts` says.
pub fn read_with(path: &Path, efforts: &rtde_csv::Efforts) -> anyhow::Result<RobotLog> {
    read_mapped(path, &Mapping { efforts: efforts.clone(), controller_joints: Vec::new() })
}

/// How a recording maps onto the robot: where a UR recording's efforts come from, and the
/// robot's controller order of its joints, which commands that name no joints follow (a ROS 2
/// forward controller's, [`mcap_file::Reader`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mapping {
    pub efforts: rtde_csv::Efforts,
    pub controller_joints: Vec<String>,
}

/// [`read`] with a [`Mapping`]: the whole log in memory, which spans at most
/// [`MAX_READ_SECONDS`] (a longer one is refused as it is read; [`open`] streams any length).
pub fn read_mapped(path: &Path, mapping: &Mapping) -> anyhow::Result<RobotLog> {
    let read = || -> anyhow::Result<RobotLog> {
        match Format::of(path)? {
            Format::Mcap => open(path, mapping)?.into_log(),
            Format::Csv => {
                let log = csv_log(path, mapping)?;
                log.validate()?;
                Ok(log)
            }
        }
    };
    read().map_err(|e| named(e, &path.display().to_string()))
}

/// A CSV log as its text says, not yet checked: a UR recording by its header ([`rtde_csv`]),
/// else the project's layout ([`csv_file`]).
fn csv_log(path: &Path, mapping: &Mapping) -> anyhow::Result<RobotLog> {
    let text = csv_text(path)?;
    let first = text.lines().find(|l| !l.trim().is_empty()).unwrap_or("");
    if rtde_csv::is_rtde_header(first) {
        rtde_csv::from_str(&text, &mapping.efforts)
    } else {
        csv_file::from_str(&text)
    }
}

/// `e` prefixed with the file's name, unless it starts with it already.
fn named(e: anyhow::Error, name: &str) -> anyhow::Error {
    if e.to_string().starts_with(name) { e } else { anyhow::anyhow!("{name}: {e:#}") }
}

/// The longest span a log read whole ([`read_mapped`]) may hold (s): an hour.
pub const MAX_READ_SECONDS: f64 = 3600.0;

/// The most records a log may hold before its first joint state (which tells its joints).
pub const MAX_RECORDS_BEFORE_STATES: usize = 100_000;

/// A log read as a stream: its metadata, joints and first time up front, then its records as
/// they are read ([`Entry`]), each checked as it comes ([`Checker`]: joint states in time order;
/// commands' values, not their order, since a trajectory's points come ahead of their times).
/// An MCAP file is read a chunk at a time, so memory does not grow with the log; a CSV file is
/// read whole first ([`MAX_CSV_BYTES`]). Errors name the file.
pub struct LogStream {
    /// The file, as errors name it.
    pub name: String,
    pub meta: LogMeta,
    /// The joints the states name, in their order.
    pub joints: Vec<String>,
    /// The first joint state's time (s).
    pub start: f64,
    ahead: std::collections::VecDeque<Entry>,
    rest: Box<dyn Iterator<Item = anyhow::Result<Entry>>>,
    /// Checks each record as it comes; none for a log checked whole already.
    check: Option<Checker>,
    failed: bool,
}

/// Opens a log as a [`LogStream`], MCAP or CSV by its extension, a UR recording's efforts and
/// a controller's joint order taken from `mapping`.
pub fn open(path: &Path, mapping: &Mapping) -> anyhow::Result<LogStream> {
    let name = path.display().to_string();
    let opened = || -> anyhow::Result<LogStream> {
        match Format::of(path)? {
            Format::Mcap => {
                let file = std::io::BufReader::new(std::fs::File::open(path)?);
                let (meta, reader) = mcap_file::open(file, &mapping.controller_joints)?;
                LogStream::new(name.clone(), meta, reader)
            }
            Format::Csv => LogStream::of_log(name.clone(), csv_log(path, mapping)?),
        }
    };
    opened().map_err(|e| named(e, &name))
}

impl LogStream {
    /// A stream of `reader`'s records: reads ahead to the first joint state, which tells the
    /// joints (an MCAP reader's order).
    pub(crate) fn new<R: std::io::Read + 'static>(
        name: String,
        meta: LogMeta,
        mut reader: mcap_file::Reader<R>,
    ) -> anyhow::Result<Self> {
        let mut ahead = std::collections::VecDeque::new();
        let start = loop {
            match reader.next().transpose()? {
                Some(entry) => {
                    let time = matches!(entry, Entry::State(_)).then(|| entry.time());
                    ahead.push_back(entry);
                    if let Some(time) = time {
                        break time;
                    }
                    anyhow::ensure!(
                        ahead.len() < MAX_RECORDS_BEFORE_STATES,
                        "no {} message in its first {MAX_RECORDS_BEFORE_STATES} records",
                        mcap_file::JOINT_STATES_TOPIC
                    );
                }
                None => {
                    anyhow::bail!("no {} messages (sensor_msgs/msg/JointState, CDR)", mcap_file::JOINT_STATES_TOPIC)
                }
            }
        };
        let joints = reader.joints.clone();
        let check = Some(Checker::new(&joints)?);
        Ok(Self { name, meta, joints, start, ahead, rest: Box::new(reader), check, failed: false })
    }

    /// A stream of a log in memory, in time order ([`RobotLog::entries`]): checked whole here
    /// ([`RobotLog::validate`]), so not again record by record.
    pub fn of_log(name: String, log: RobotLog) -> anyhow::Result<Self> {
        log.validate()?;
        let start = log.states[0].time;
        let (meta, joints) = (log.meta.clone(), log.joints.clone());
        let rest = Box::new(log.into_entries().map(Ok));
        Ok(Self { name, meta, joints, start, ahead: Default::default(), rest, check: None, failed: false })
    }

    /// The whole log in memory, refused as it is read once it spans more than
    /// [`MAX_READ_SECONDS`]; commands in time order (trajectories may overlap). Every record was
    /// checked as it came, and sorted the commands keep their order: it passes
    /// [`RobotLog::validate`] without a second pass.
    pub fn into_log(mut self) -> anyhow::Result<RobotLog> {
        let mut log = RobotLog { meta: self.meta.clone(), joints: self.joints.clone(), ..Default::default() };
        let t0 = self.start;
        for entry in self.by_ref() {
            match entry? {
                Entry::State(s) => {
                    anyhow::ensure!(
                        s.time - t0 <= MAX_READ_SECONDS,
                        "the log lasts over {MAX_READ_SECONDS} s (a joint state at {} s): a log read whole spans at most that; `replay` of a built-in robot streams any length (docs/logs.md)",
                        s.time
                    );
                    log.states.push(s)
                }
                Entry::Command(c) => log.commands.push(c),
                Entry::Tool(t) => log.tool.push(t),
            }
        }
        log.commands.sort_by(|a, b| a.time.total_cmp(&b.time));
        Ok(log)
    }

    /// Checks that the log is of `robot` with the joints `expected` ([`log::check_robot`]).
    pub fn check_robot(&self, robot: &str, expected: &[String]) -> anyhow::Result<()> {
        log::check_robot(&self.meta, &self.joints, robot, expected).map_err(|e| named(e, &self.name))
    }

    fn checked(&mut self, entry: Entry) -> anyhow::Result<Entry> {
        let Some(check) = self.check.as_mut() else { return Ok(entry) };
        match &entry {
            Entry::State(s) => check.state(s)?,
            Entry::Command(c) => check.command_values(c)?,
            Entry::Tool(t) => check.tool(t)?,
        }
        Ok(entry)
    }
}

impl Iterator for LogStream {
    type Item = anyhow::Result<Entry>;

    /// The next record; after an error, none.
    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        let entry = match self.ahead.pop_front() {
            Some(entry) => Ok(entry),
            None => self.rest.next()?,
        };
        let checked = entry.and_then(|e| self.checked(e));
        self.failed = checked.is_err();
        Some(checked.map_err(|e| named(e, &self.name)))
    }
}

/// Whether `path` names a gzip file (`.gz`, any case).
fn gzipped(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("gz"))
}

/// A CSV file's text, gunzipped when its name ends in `.gz`, refused past [`MAX_CSV_BYTES`].
fn csv_text(path: &Path) -> anyhow::Result<String> {
    use std::io::Read;
    let file = std::fs::File::open(path)?;
    let gz = gzipped(path);
    let reader: Box<dyn Read> = if gz { Box::new(flate2::read::GzDecoder::new(file)) } else { Box::new(file) };
    let mut bytes = Vec::new();
    reader
        .take(MAX_CSV_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| anyhow::anyhow!("{}: {e}", if gz { "not a whole gzip stream" } else { "unreadable" }))?;
    anyhow::ensure!(bytes.len() as u64 <= MAX_CSV_BYTES, "more than {} MB of text", MAX_CSV_BYTES >> 20);
    String::from_utf8(bytes).map_err(|e| anyhow::anyhow!("not UTF-8 text: {e}"))
}

/// Writes a log, MCAP or CSV by its extension, atomically (a temporary file renamed).
pub fn write(log: &RobotLog, path: &Path) -> anyhow::Result<()> {
    log.validate().map_err(|e| anyhow::anyhow!("refusing to write {}: {e:#}", path.display()))?;
    anyhow::ensure!(
        !gzipped(path),
        "{}: logs are written as .mcap or plain .csv (gzip is read, not written)",
        path.display()
    );
    let format = Format::of(path)?;
    let bytes = match format {
        Format::Mcap => mcap_file::to_bytes(log)?,
        Format::Csv => csv_file::to_string(log).into_bytes(),
    };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?;
    }
    twinbots_api::files::write_atomic(path, &bytes).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_log() -> RobotLog {
        let joints = vec!["a".to_string(), "b".to_string()];
        RobotLog {
            meta: LogMeta { robot: "arm".into(), source: "test".into(), control_period: 0.008, ..Default::default() },
            states: (0..5)
                .map(|i| {
                    let t = i as f64 * 0.004;
                    JointSample { time: t, position: vec![t, -t], velocity: vec![1.0, -1.0], effort: vec![0.5, 0.25] }
                })
                .collect(),
            commands: (0..3)
                .map(|i| CommandSample {
                    time: i as f64 * 0.008,
                    joints: joints.clone(),
                    modes: vec![CommandMode::Velocity; 2],
                    values: vec![1.0, -1.0],
                })
                .collect(),
            tool: vec![ToolSample { time: 0.0, position: [0.1, 0.2, 0.3], orientation: [0.0, 0.0, 0.0, 1.0] }],
            joints,
        }
    }

    #[test]
    fn mcap_and_csv_round_trip() {
        let log = sample_log();
        let back = mcap_file::from_bytes(&mcap_file::to_bytes(&log).unwrap()).unwrap();
        assert_eq!(back, log);
        let back = csv_file::from_str(&csv_file::to_string(&log)).unwrap();
        assert_eq!(back.states, log.states);
        assert_eq!(back.commands, log.commands);
        assert_eq!(back.tool, log.tool);
        assert_eq!(back.meta.robot, "arm");
    }

    /// A rosbag2 recording of a UR's ROS 2 driver: `/joint_states` in the driver's (alphabetical)
    /// order, the forward velocity controller's `Float64MultiArray` and a trajectory controller's
    /// `JointTrajectory`, written with the mcap crate as rosbag2 writes them.
    fn ros2_bag(array_topic: &str, array_len: usize) -> Vec<u8> {
        use crate::cdr::{
            FLOAT64_MULTI_ARRAY_SCHEMA, Float64MultiArrayMsg, JOINT_STATE_SCHEMA, JOINT_TRAJECTORY_SCHEMA,
            JointStateMsg, JointTrajectoryMsg, TrajectoryPoint,
        };
        use mcap::records::MessageHeader;
        let mut w = mcap::WriteOptions::new()
            .compression(None)
            .profile("ros2")
            .create(std::io::Cursor::new(Vec::new()))
            .unwrap();
        let none = std::collections::BTreeMap::new();
        let schema =
            |w: &mut mcap::Writer<_>, name: &str, text: &str| w.add_schema(name, "ros2msg", text.as_bytes()).unwrap();
        let s = schema(&mut w, "sensor_msgs/msg/JointState", JOINT_STATE_SCHEMA);
        let states = w.add_channel(s, "/joint_states", "cdr", &none).unwrap();
        let s = schema(&mut w, "std_msgs/msg/Float64MultiArray", FLOAT64_MULTI_ARRAY_SCHEMA);
        let array = w.add_channel(s, array_topic, "cdr", &none).unwrap();
        let s = schema(&mut w, "trajectory_msgs/msg/JointTrajectory", JOINT_TRAJECTORY_SCHEMA);
        let trajectory =
            w.add_channel(s, "/scaled_joint_trajectory_controller/joint_trajectory", "cdr", &none).unwrap();
        let write = |w: &mut mcap::Writer<_>, channel_id: u16, seq: u32, t: f64, data: Vec<u8>| {
            let time = (t * 1e9) as u64;
            w.write_to_known_channel(
                &MessageHeader { channel_id, sequence: seq, log_time: time, publish_time: time },
                &data,
            )
            .unwrap();
        };
        for k in 0..20u32 {
            let t = 100.0 + k as f64 * 0.002;
            let state = JointStateMsg {
                stamp: t,
                frame_id: String::new(),
                name: vec!["elbow_joint".into(), "shoulder_pan_joint".into()],
                position: vec![k as f64 * 0.01, 0.5],
                velocity: vec![0.0, 0.0],
                effort: vec![],
            };
            write(&mut w, states, k + 1, t, state.encode());
            let command = Float64MultiArrayMsg { dim: vec![], data_offset: 0, data: vec![0.25; array_len] };
            write(&mut w, array, k + 1, t + 0.001, command.encode());
        }
        let points = vec![
            TrajectoryPoint { positions: vec![0.5, 0.1], time_from_start: 0.01, ..Default::default() },
            TrajectoryPoint { positions: vec![0.6, 0.2], time_from_start: 0.02, ..Default::default() },
        ];
        let goal = JointTrajectoryMsg {
            stamp: 100.005,
            frame_id: String::new(),
            joint_names: vec!["shoulder_pan_joint".into(), "elbow_joint".into()],
            points,
        };
        write(&mut w, trajectory, 1, 100.005, goal.encode());
        w.finish().unwrap();
        w.into_inner().into_inner()
    }

    #[test]
    fn a_ros2_bag_gives_its_controllers_commands_in_the_robots_order() {
        let order: Vec<String> = vec!["shoulder_pan_joint".into(), "elbow_joint".into()];
        let log = mcap_file::from_bytes_mapped(&ros2_bag("/forward_velocity_controller/commands", 2), &order).unwrap();
        assert_eq!(log.joints, vec!["elbow_joint".to_string(), "shoulder_pan_joint".into()]);
        let speeds: Vec<_> = log.commands.iter().filter(|c| c.modes[0] == CommandMode::Velocity).collect();
        assert_eq!(speeds.len(), 20);
        assert_eq!((speeds[0].joints.clone(), speeds[0].values.clone()), (order.clone(), vec![0.25, 0.25]));
        assert!((speeds[0].time - 100.001).abs() < 1e-9, "{}", speeds[0].time);
        let targets: Vec<_> = log.commands.iter().filter(|c| c.modes[0] == CommandMode::Position).collect();
        assert_eq!(targets.len(), 2);
        assert!((targets[1].time - 100.025).abs() < 1e-9 && targets[1].values == vec![0.6, 0.2], "{:?}", targets[1]);
        assert!(log.commands.windows(2).all(|w| w[0].time <= w[1].time));
        log.validate().unwrap();

        let err = mcap_file::from_bytes(&ros2_bag("/forward_velocity_controller/commands", 2)).unwrap_err().to_string();
        assert!(err.contains("/forward_velocity_controller/commands") && err.contains("name no joints"), "{err}");
        let err = mcap_file::from_bytes_mapped(&ros2_bag("/forward_velocity_controller/commands", 3), &order)
            .unwrap_err()
            .to_string();
        assert!(err.contains("message 1: 3 values for the controller's 2 joints"), "{err}");
        let err =
            mcap_file::from_bytes_mapped(&ros2_bag("/my_controller/commands", 2), &order).unwrap_err().to_string();
        assert!(err.contains("/my_controller/commands") && err.contains("does not say their interface"), "{err}");
    }

    /// A log spanning more than an hour streams to its end, and is refused as it is read whole.
    #[test]
    fn a_log_over_an_hour_streams_and_is_not_read_whole() {
        let mut log = sample_log();
        log.states = (0..70)
            .map(|i| JointSample {
                time: i as f64 * 55.0,
                position: vec![0.0, 0.0],
                velocity: vec![0.0, 0.0],
                effort: vec![],
            })
            .collect();
        let path = std::env::temp_dir().join(format!("twinbots-log-hours-{}.mcap", std::process::id()));
        write(&log, &path).unwrap();
        let mapping = Mapping::default();
        let stream = open(&path, &mapping).unwrap();
        assert_eq!((stream.joints.clone(), stream.meta.robot.clone()), (log.joints.clone(), "arm".to_string()));
        let entries: Vec<Entry> = stream.collect::<anyhow::Result<_>>().unwrap();
        assert_eq!(entries, log.entries().collect::<Vec<_>>());
        let err = read(&path).unwrap_err().to_string();
        assert!(
            err.starts_with(&path.display().to_string()) && err.contains("lasts over 3600 s (a joint state at 3630 s)"),
            "{err}"
        );
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn damaged_logs_are_clear_errors() {
        let bytes = mcap_file::to_bytes(&sample_log()).unwrap();
        let err = mcap_file::from_bytes(&bytes[..bytes.len() / 2]).unwrap_err().to_string();
        assert!(err.contains("truncated"), "{err}");
        assert!(mcap_file::from_bytes(b"not an mcap at all, just text").is_err());
        // One bit flipped in a joint position (inside a chunk): the chunk's CRC names it.
        let mut flipped = bytes.clone();
        let at = flipped.windows(8).position(|w| w == 0.5f64.to_le_bytes()).expect("a position of 0.5");
        flipped[at] ^= 1;
        let err = mcap_file::from_bytes(&flipped).unwrap_err().to_string();
        assert!(err.contains("CRC-32"), "{err}");

        let mut log = sample_log();
        log.states[3].time = log.states[1].time;
        assert!(log.validate().unwrap_err().to_string().contains("not increasing"));
        let mut log = sample_log();
        log.states[2].position[1] = f64::NAN;
        assert!(log.validate().unwrap_err().to_string().contains("position of 'b' is NaN"));
        let err = sample_log().check_robot("ur5e", &[]).unwrap_err().to_string();
        assert!(err.contains("robot 'arm', not 'ur5e'"), "{err}");
        let err = sample_log().check_robot("arm", &["a".into(), "c".into()]).unwrap_err().to_string();
        assert!(err.contains("lacks joint(s) c"), "{err}");
        let err = csv_file::from_str("time,a.position,a.velocity\n0,1,x\n").unwrap_err().to_string();
        assert!(err.contains("line 2") && err.contains("'x' is not a number"), "{err}");
    }
}
