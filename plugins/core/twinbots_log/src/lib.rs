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

pub use log::{CommandMode, CommandSample, JointSample, LogMeta, RobotLog, ToolSample};

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
/// forward controller's, [`mcap_file::from_bytes_mapped`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mapping {
    pub efforts: rtde_csv::Efforts,
    pub controller_joints: Vec<String>,
}

/// [`read`] with a [`Mapping`].
pub fn read_mapped(path: &Path, mapping: &Mapping) -> anyhow::Result<RobotLog> {
    let efforts = &mapping.efforts;
    let log = match Format::of(path)? {
        Format::Mcap => mcap_file::read(path, &mapping.controller_joints),
        Format::Csv => csv_text(path).and_then(|text| {
            let first = text.lines().find(|l| !l.trim().is_empty()).unwrap_or("");
            if rtde_csv::is_rtde_header(first) { rtde_csv::from_str(&text, efforts) } else { csv_file::from_str(&text) }
        }),
    };
    let log = log.map_err(|e| anyhow::anyhow!("{}: {e:#}", path.display()))?;
    log.validate().map_err(|e| anyhow::anyhow!("{}: {e:#}", path.display()))?;
    Ok(log)
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
