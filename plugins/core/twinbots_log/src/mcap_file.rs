//! Logs as MCAP: `/joint_states` (ROS 2 `sensor_msgs/msg/JointState`, CDR), `/twinbots/joint_commands`
//! (JSON), `/tool_pose` (`geometry_msgs/msg/PoseStamped`, CDR) and a metadata record named
//! `twinbots`. Chunks are written uncompressed; compressed files (zstd, lz4) are refused with an
//! error that says how to convert them (`mcap convert` or `ros2 bag convert`): this build
//! carries no C compression libraries.

use std::collections::BTreeMap;
use std::io::Cursor;

use mcap::records::{MessageHeader, Metadata, Record};
use serde::{Deserialize, Serialize};

use crate::cdr::{
    Float64MultiArrayMsg, JOINT_STATE_SCHEMA, JointStateMsg, JointTrajectoryMsg, POSE_STAMPED_SCHEMA, PoseStampedMsg,
};
use crate::log::{CommandMode, CommandSample, JointSample, LogMeta, RobotLog, ToolSample, UNITS};

pub const JOINT_STATES_TOPIC: &str = "/joint_states";
pub const COMMANDS_TOPIC: &str = "/twinbots/joint_commands";
pub const TOOL_POSE_TOPIC: &str = "/tool_pose";
/// Name of the metadata record.
pub const METADATA_NAME: &str = "twinbots";

/// The JSON schema of a command message.
const COMMAND_SCHEMA: &str = r#"{"title":"twinbots/JointCommand","type":"object","properties":{"time":{"type":"number","description":"s, the log's clock"},"name":{"type":"array","items":{"type":"string"}},"mode":{"type":"array","items":{"enum":["velocity","position","torque"]}},"value":{"type":"array","items":{"type":"number"},"description":"rad/s, rad or N*m (m/s, m or N for prismatic joints)"}},"required":["time","name","mode","value"]}"#;

/// One message of `/twinbots/joint_commands`.
#[derive(Serialize, Deserialize)]
struct CommandMsg {
    time: f64,
    name: Vec<String>,
    mode: Vec<CommandMode>,
    value: Vec<f64>,
}

fn nanos(t: f64) -> u64 {
    (t.max(0.0) * 1e9).round() as u64
}

/// The log as MCAP bytes.
pub fn to_bytes(log: &RobotLog) -> anyhow::Result<Vec<u8>> {
    let options = mcap::WriteOptions::new().compression(None).profile("ros2");
    let mut w = options.create(Cursor::new(Vec::new()))?;
    let none = BTreeMap::new();
    let joint_schema = w.add_schema("sensor_msgs/msg/JointState", "ros2msg", JOINT_STATE_SCHEMA.as_bytes())?;
    let joints = w.add_channel(joint_schema, JOINT_STATES_TOPIC, "cdr", &none)?;
    let command_schema = w.add_schema("twinbots/JointCommand", "jsonschema", COMMAND_SCHEMA.as_bytes())?;
    let commands = w.add_channel(command_schema, COMMANDS_TOPIC, "json", &none)?;
    let pose_schema = w.add_schema("geometry_msgs/msg/PoseStamped", "ros2msg", POSE_STAMPED_SCHEMA.as_bytes())?;
    let tool = w.add_channel(pose_schema, TOOL_POSE_TOPIC, "cdr", &none)?;

    let mut metadata = log.meta.extra.clone();
    metadata.insert("robot".into(), log.meta.robot.clone());
    metadata.insert("source".into(), log.meta.source.clone());
    metadata.insert("calibration".into(), log.meta.calibration.clone());
    metadata.insert("control_period".into(), log.meta.control_period.to_string());
    metadata.insert("units".into(), UNITS.into());
    w.write_metadata(&Metadata { name: METADATA_NAME.into(), metadata })?;

    // Messages in time order across the channels, as a recorder writes them.
    let mut messages: Vec<(u64, u16, Vec<u8>)> = Vec::new();
    for s in &log.states {
        let msg = JointStateMsg {
            stamp: s.time,
            frame_id: String::new(),
            name: log.joints.clone(),
            position: s.position.clone(),
            velocity: s.velocity.clone(),
            effort: s.effort.clone(),
        };
        messages.push((nanos(s.time), joints, msg.encode()));
    }
    for c in &log.commands {
        let msg = CommandMsg { time: c.time, name: c.joints.clone(), mode: c.modes.clone(), value: c.values.clone() };
        messages.push((nanos(c.time), commands, serde_json::to_vec(&msg)?));
    }
    for t in &log.tool {
        let msg =
            PoseStampedMsg { stamp: t.time, frame_id: "base".into(), position: t.position, orientation: t.orientation };
        messages.push((nanos(t.time), tool, msg.encode()));
    }
    messages.sort_by_key(|m| m.0);
    let mut sequence = BTreeMap::<u16, u32>::new();
    for (time, channel_id, data) in messages {
        let seq = sequence.entry(channel_id).or_default();
        *seq += 1;
        w.write_to_known_channel(
            &MessageHeader { channel_id, sequence: *seq, log_time: time, publish_time: time },
            &data,
        )?;
    }
    w.finish()?;
    Ok(w.into_inner().into_inner())
}

/// Reads an MCAP log from a file.
pub fn read(path: &std::path::Path, controller_joints: &[String]) -> anyhow::Result<RobotLog> {
    let bytes = std::fs::read(path)?;
    from_bytes_mapped(&bytes, controller_joints)
}

fn mcap_error(e: mcap::McapError) -> anyhow::Error {
    match e {
        mcap::McapError::UnsupportedCompression(c) => anyhow::anyhow!(
            "its chunks are compressed with {c}; this build reads uncompressed MCAP only: convert it first (`mcap convert --compression none IN OUT`, or `ros2 bag convert` with compression off)"
        ),
        mcap::McapError::BadMagic => anyhow::anyhow!("not an MCAP file (bad magic bytes)"),
        mcap::McapError::BadChunkCrc { saved, calculated } => anyhow::anyhow!(
            "damaged MCAP: a chunk's CRC-32 is {calculated:08x}, saved as {saved:08x} (the file changed after it was written)"
        ),
        e => anyhow::anyhow!("damaged MCAP ({e}); a truncated recording can be recovered with `mcap recover`"),
    }
}

/// Parses MCAP bytes: joint states from `/joint_states`, commands and tool poses if present,
/// the `twinbots` metadata if present. Times are the header stamps (the log time where a stamp
/// is zero). Commands without joint names (a forward controller's) are refused: see
/// [`from_bytes_mapped`].
pub fn from_bytes(bytes: &[u8]) -> anyhow::Result<RobotLog> {
    from_bytes_mapped(bytes, &[])
}

/// [`from_bytes`], also reading the commands a ROS 2 driver's controllers took, as rosbag2
/// records them: `std_msgs/msg/Float64MultiArray` on a forward command controller's
/// `…/commands` topic (its interface read from the topic's name: `position`, `velocity` or
/// `effort`, as `forward_position_controller` …; a value per joint in `controller_joints`, the
/// controller's order, which the message does not carry), and
/// `trajectory_msgs/msg/JointTrajectory` on any topic (each point a position target at the
/// header's stamp plus its `time_from_start`, or a speed where it has no positions).
pub fn from_bytes_mapped(bytes: &[u8], controller_joints: &[String]) -> anyhow::Result<RobotLog> {
    let mut log = RobotLog::default();
    // A truncated file has no footer; the message stream would stop quietly at the cut.
    mcap::read::footer(bytes).map_err(|_| {
        anyhow::anyhow!("truncated MCAP: the file ends without its footer (`mcap recover` can salvage it)")
    })?;
    for record in mcap::read::LinearReader::new(bytes).map_err(mcap_error)? {
        if let Record::Metadata(m) = record.map_err(mcap_error)?
            && m.name == METADATA_NAME
        {
            log.meta = meta_from(m.metadata)?;
        }
    }
    // Each chunk's CRC-32 is checked: a flipped bit is an error, not a different number.
    let stream = mcap::MessageStream::new_with_options(bytes, mcap::read::Options::ValidateChunkCrcs.into());
    for (i, message) in stream.map_err(mcap_error)?.enumerate() {
        let message = message.map_err(mcap_error)?;
        let when = |stamp: f64| if stamp == 0.0 { message.log_time as f64 * 1e-9 } else { stamp };
        match message.channel.topic.as_str() {
            JOINT_STATES_TOPIC => {
                check_encoding(&message.channel.message_encoding, "cdr", JOINT_STATES_TOPIC)?;
                let msg = JointStateMsg::decode(&message.data)
                    .map_err(|e| anyhow::anyhow!("{JOINT_STATES_TOPIC} message {i}: {e}"))?;
                let time = when(msg.stamp);
                let sample = joint_sample(&mut log.joints, msg, time)
                    .map_err(|e| anyhow::anyhow!("{JOINT_STATES_TOPIC} message {i} (t = {time} s): {e}"))?;
                log.states.push(sample);
            }
            COMMANDS_TOPIC => {
                check_encoding(&message.channel.message_encoding, "json", COMMANDS_TOPIC)?;
                let msg: CommandMsg = serde_json::from_slice(&message.data)
                    .map_err(|e| anyhow::anyhow!("{COMMANDS_TOPIC} message {i}: {e}"))?;
                log.commands.push(CommandSample {
                    time: msg.time,
                    joints: msg.name,
                    modes: msg.mode,
                    values: msg.value,
                });
            }
            TOOL_POSE_TOPIC => {
                check_encoding(&message.channel.message_encoding, "cdr", TOOL_POSE_TOPIC)?;
                let msg = PoseStampedMsg::decode(&message.data)
                    .map_err(|e| anyhow::anyhow!("{TOOL_POSE_TOPIC} message {i}: {e}"))?;
                log.tool.push(ToolSample {
                    time: when(msg.stamp),
                    position: msg.position,
                    orientation: msg.orientation,
                });
            }
            topic => match message.channel.schema.as_ref().map(|s| s.name.as_str()) {
                Some(FLOAT64_MULTI_ARRAY) => {
                    let Some(mode) = forward_mode(topic)? else { continue };
                    check_encoding(&message.channel.message_encoding, "cdr", topic)?;
                    anyhow::ensure!(
                        !controller_joints.is_empty(),
                        "{topic}: a forward controller's commands name no joints; their order is the robot's controller order (a robot file's `joints`, or a built-in robot)"
                    );
                    let msg = Float64MultiArrayMsg::decode(&message.data)
                        .map_err(|e| anyhow::anyhow!("{topic} message {i}: {e}"))?;
                    anyhow::ensure!(
                        msg.data.len() == controller_joints.len(),
                        "{topic} message {i}: {} values for the controller's {} joints ({})",
                        msg.data.len(),
                        controller_joints.len(),
                        controller_joints.join(", ")
                    );
                    log.commands.push(CommandSample {
                        time: message.log_time as f64 * 1e-9,
                        joints: controller_joints.to_vec(),
                        modes: vec![mode; msg.data.len()],
                        values: msg.data,
                    });
                }
                Some(JOINT_TRAJECTORY) => {
                    check_encoding(&message.channel.message_encoding, "cdr", topic)?;
                    let msg = JointTrajectoryMsg::decode(&message.data)
                        .map_err(|e| anyhow::anyhow!("{topic} message {i}: {e}"))?;
                    let start = when(msg.stamp);
                    let n = msg.joint_names.len();
                    for (k, point) in msg.points.into_iter().enumerate() {
                        let (mode, values) = if !point.positions.is_empty() {
                            (CommandMode::Position, point.positions)
                        } else if !point.velocities.is_empty() {
                            (CommandMode::Velocity, point.velocities)
                        } else {
                            continue;
                        };
                        anyhow::ensure!(
                            values.len() == n,
                            "{topic} message {i}, point {k}: {} values for {n} joint names",
                            values.len()
                        );
                        log.commands.push(CommandSample {
                            time: start + point.time_from_start,
                            joints: msg.joint_names.clone(),
                            modes: vec![mode; n],
                            values,
                        });
                    }
                }
                _ => {}
            },
        }
    }
    // Trajectories may overlap: the commands in time order.
    log.commands.sort_by(|a, b| a.time.total_cmp(&b.time));
    anyhow::ensure!(!log.states.is_empty(), "no {JOINT_STATES_TOPIC} messages (sensor_msgs/msg/JointState, CDR)");
    Ok(log)
}

const FLOAT64_MULTI_ARRAY: &str = "std_msgs/msg/Float64MultiArray";
const JOINT_TRAJECTORY: &str = "trajectory_msgs/msg/JointTrajectory";

/// A forward command controller's interface, from its commands topic's name; none for a topic
/// that is not `…/commands`.
fn forward_mode(topic: &str) -> anyhow::Result<Option<CommandMode>> {
    if !topic.ends_with("/commands") {
        return Ok(None);
    }
    let lower = topic.to_ascii_lowercase();
    let mode =
        [("position", CommandMode::Position), ("velocity", CommandMode::Velocity), ("effort", CommandMode::Torque)]
            .into_iter()
            .find(|(word, _)| lower.contains(word))
            .map(|(_, mode)| mode);
    mode.map(Some).ok_or_else(|| {
        anyhow::anyhow!(
            "{topic}: a forward controller's commands, but its name does not say their interface (position, velocity or effort, as forward_position_controller/commands)"
        )
    })
}

fn check_encoding(found: &str, expected: &str, topic: &str) -> anyhow::Result<()> {
    anyhow::ensure!(found == expected, "{topic} is encoded as '{found}', expected '{expected}'");
    Ok(())
}

/// A JointState as a sample in the log's joint order; the first message fixes the order, and
/// later ones may name the same joints in another order.
fn joint_sample(joints: &mut Vec<String>, msg: JointStateMsg, time: f64) -> anyhow::Result<JointSample> {
    let n = msg.name.len();
    anyhow::ensure!(n > 0, "the message names no joints");
    anyhow::ensure!(msg.position.len() == n, "{} positions for {n} names", msg.position.len());
    anyhow::ensure!(
        msg.velocity.len() == n,
        "{} velocities for {n} names (velocities are required)",
        msg.velocity.len()
    );
    anyhow::ensure!(msg.effort.is_empty() || msg.effort.len() == n, "{} efforts for {n} names", msg.effort.len());
    if joints.is_empty() {
        *joints = msg.name.clone();
    }
    let mut order = Vec::with_capacity(n);
    for name in joints.iter() {
        let k = msg.name.iter().position(|m| m == name);
        order.push(k.ok_or_else(|| anyhow::anyhow!("names {:?}, but the first message named {:?}", msg.name, joints))?);
    }
    anyhow::ensure!(n == joints.len(), "names {:?}, but the first message named {:?}", msg.name, joints);
    let pick = |v: &[f64]| if v.is_empty() { Vec::new() } else { order.iter().map(|&k| v[k]).collect() };
    Ok(JointSample { time, position: pick(&msg.position), velocity: pick(&msg.velocity), effort: pick(&msg.effort) })
}

fn meta_from(mut m: BTreeMap<String, String>) -> anyhow::Result<LogMeta> {
    let period = m.remove("control_period").unwrap_or_default();
    let control_period = if period.is_empty() {
        0.0
    } else {
        period
            .parse()
            .map_err(|_| anyhow::anyhow!("metadata 'control_period' = '{period}' is not a number of seconds"))?
    };
    m.remove("units");
    Ok(LogMeta {
        robot: m.remove("robot").unwrap_or_default(),
        source: m.remove("source").unwrap_or_default(),
        calibration: m.remove("calibration").unwrap_or_default(),
        control_period,
        extra: m,
    })
}
