//! Logs as MCAP: `/joint_states` (ROS 2 `sensor_msgs/msg/JointState`, CDR), `/twinbots/joint_commands`
//! (JSON), `/tool_pose` (`geometry_msgs/msg/PoseStamped`, CDR) and a metadata record named
//! `twinbots`. Chunks are written uncompressed; compressed files (zstd, lz4) are refused with an
//! error that says how to convert them (`mcap convert` or `ros2 bag convert`): this build
//! carries no C compression libraries.

use std::collections::{BTreeMap, VecDeque};
use std::fs::File;
use std::io::{BufWriter, Cursor, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use mcap::records::{MessageHeader, Metadata, Record};
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use serde::{Deserialize, Serialize};

use crate::cdr::{
    Float64MultiArrayMsg, JOINT_STATE_SCHEMA, JointStateMsg, JointTrajectoryMsg, POSE_STAMPED_SCHEMA, PoseStampedMsg,
};
use crate::log::{CommandMode, CommandSample, Entry, JointSample, LogMeta, RobotLog, ToolSample, UNITS};

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

/// Writes a log as MCAP, a record at a time: memory stays that of one chunk however long the
/// log. Records go in the order given (a recorder's: time order across the channels).
pub struct Writer<W: Write + Seek> {
    mcap: mcap::Writer<W>,
    joints: Vec<String>,
    /// The channels of joint states, commands and tool poses, and each one's last sequence number.
    channels: [(u16, u32); 3],
}

impl<W: Write + Seek> Writer<W> {
    /// Starts a log of `joints` (the states' order) described by `meta`.
    pub fn new(sink: W, meta: &LogMeta, joints: &[String]) -> anyhow::Result<Self> {
        let options = mcap::WriteOptions::new().compression(None).profile("ros2");
        let mut w = options.create(sink)?;
        let none = BTreeMap::new();
        let joint_schema = w.add_schema("sensor_msgs/msg/JointState", "ros2msg", JOINT_STATE_SCHEMA.as_bytes())?;
        let states = w.add_channel(joint_schema, JOINT_STATES_TOPIC, "cdr", &none)?;
        let command_schema = w.add_schema("twinbots/JointCommand", "jsonschema", COMMAND_SCHEMA.as_bytes())?;
        let commands = w.add_channel(command_schema, COMMANDS_TOPIC, "json", &none)?;
        let pose_schema = w.add_schema("geometry_msgs/msg/PoseStamped", "ros2msg", POSE_STAMPED_SCHEMA.as_bytes())?;
        let tool = w.add_channel(pose_schema, TOOL_POSE_TOPIC, "cdr", &none)?;
        let mut metadata = meta.extra.clone();
        metadata.insert("robot".into(), meta.robot.clone());
        metadata.insert("source".into(), meta.source.clone());
        metadata.insert("calibration".into(), meta.calibration.clone());
        metadata.insert("control_period".into(), meta.control_period.to_string());
        metadata.insert("units".into(), UNITS.into());
        w.write_metadata(&Metadata { name: METADATA_NAME.into(), metadata })?;
        Ok(Self { mcap: w, joints: joints.to_vec(), channels: [(states, 0), (commands, 0), (tool, 0)] })
    }

    /// Appends one record.
    pub fn write(&mut self, entry: &Entry) -> anyhow::Result<()> {
        let (kind, data) = match entry {
            Entry::State(s) => {
                let msg = JointStateMsg {
                    stamp: s.time,
                    frame_id: String::new(),
                    name: self.joints.clone(),
                    position: s.position.clone(),
                    velocity: s.velocity.clone(),
                    effort: s.effort.clone(),
                };
                (0, msg.encode())
            }
            Entry::Command(c) => {
                let msg =
                    CommandMsg { time: c.time, name: c.joints.clone(), mode: c.modes.clone(), value: c.values.clone() };
                (1, serde_json::to_vec(&msg)?)
            }
            Entry::Tool(t) => {
                let msg = PoseStampedMsg {
                    stamp: t.time,
                    frame_id: "base".into(),
                    position: t.position,
                    orientation: t.orientation,
                };
                (2, msg.encode())
            }
        };
        let (channel_id, sequence) = &mut self.channels[kind];
        *sequence += 1;
        let time = nanos(entry.time());
        self.mcap.write_to_known_channel(
            &MessageHeader { channel_id: *channel_id, sequence: *sequence, log_time: time, publish_time: time },
            &data,
        )?;
        Ok(())
    }

    /// Writes the summary and footer; the sink back.
    pub fn finish(mut self) -> anyhow::Result<W> {
        self.mcap.finish()?;
        Ok(self.mcap.into_inner())
    }
}

/// The log as MCAP bytes.
pub fn to_bytes(log: &RobotLog) -> anyhow::Result<Vec<u8>> {
    let mut w = Writer::new(Cursor::new(Vec::new()), &log.meta, &log.joints)?;
    for entry in log.entries() {
        w.write(&entry)?;
    }
    Ok(w.finish()?.into_inner())
}

/// A log written to a file as it is made ([`Writer`]), under a temporary name until
/// [`FileWriter::finish`] renames it into place: an unfinished log never stands at `path`.
pub struct FileWriter {
    path: PathBuf,
    tmp: PathBuf,
    writer: Option<Writer<BufWriter<File>>>,
}

impl FileWriter {
    /// Starts the log at `path` (through its temporary name); errors name the file.
    pub fn create(path: &Path, meta: &LogMeta, joints: &[String]) -> anyhow::Result<Self> {
        let tmp = twinbots_api::files::temporary(path);
        let file = File::create(&tmp).map_err(|e| anyhow::anyhow!("{}: {e}", tmp.display()))?;
        let writer = Writer::new(BufWriter::new(file), meta, joints)?;
        Ok(Self { path: path.to_path_buf(), tmp, writer: Some(writer) })
    }

    /// Appends one record.
    pub fn write(&mut self, entry: &Entry) -> anyhow::Result<()> {
        let writer = self.writer.as_mut().expect("a FileWriter writes until finished");
        writer.write(entry).map_err(|e| anyhow::anyhow!("{}: {e:#}", self.tmp.display()))
    }

    /// Finishes the file, syncs it and moves it into place.
    pub fn finish(mut self) -> anyhow::Result<()> {
        let writer = self.writer.take().expect("a FileWriter finishes once");
        let at = |e: &dyn std::fmt::Display| anyhow::anyhow!("{}: {e}", self.tmp.display());
        let file = writer.finish().map_err(|e| at(&e))?.into_inner().map_err(|e| at(&e))?;
        file.sync_all().map_err(|e| at(&e))?;
        std::fs::rename(&self.tmp, &self.path).map_err(|e| anyhow::anyhow!("{}: {e}", self.path.display()))
    }
}

impl Drop for FileWriter {
    fn drop(&mut self) {
        if self.writer.take().is_some() {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// The longest record a log may hold (bytes): past it the file is damaged or not a log (a
/// length field read from garbage would otherwise size a buffer).
pub const MAX_RECORD_BYTES: usize = 256 << 20;

fn read_options() -> LinearReaderOptions {
    // Each chunk's CRC-32 is checked: a flipped bit is an error, not a different number.
    LinearReaderOptions::default().with_validate_chunk_crcs(true).with_record_length_limit(MAX_RECORD_BYTES)
}

/// Opens an MCAP log for reading as a stream ([`Reader`]): checks that the file is whole (its
/// end magic present: a cut recording would otherwise end quietly at the cut) and reads its
/// `twinbots` metadata record, wherever it stands, in a first pass over the records.
pub fn open<R: Read + Seek>(mut source: R, controller_joints: &[String]) -> anyhow::Result<(LogMeta, Reader<R>)> {
    let mut magic = [0u8; 8];
    let start = source.read_exact(&mut magic);
    anyhow::ensure!(start.is_ok() && magic == mcap::MAGIC, "not an MCAP file (bad magic bytes)");
    let end = source.seek(SeekFrom::End(-8)).and_then(|_| source.read_exact(&mut magic));
    anyhow::ensure!(
        end.is_ok() && magic == mcap::MAGIC,
        "truncated MCAP: the file ends without its footer (`mcap recover` can salvage it)"
    );
    source.seek(SeekFrom::Start(0))?;
    let mut meta = LogMeta::default();
    let mut records = LinearReader::new_with_options(read_options());
    while let Some(event) = records.next_event() {
        match event.map_err(mcap_error)? {
            LinearReadEvent::ReadRequest(need) => {
                let read = source.read(records.insert(need))?;
                records.notify_read(read);
            }
            LinearReadEvent::Record { opcode, data } if opcode == mcap::records::op::METADATA => {
                if let Record::Metadata(m) = mcap::parse_record(opcode, data).map_err(mcap_error)?
                    && m.name == METADATA_NAME
                {
                    meta = meta_from(m.metadata)?;
                }
            }
            LinearReadEvent::Record { .. } => {}
        }
    }
    source.seek(SeekFrom::Start(0))?;
    let messages = mcap::io::MessageReader::new_with_options(source, read_options());
    let reader = Reader {
        messages,
        joints: Vec::new(),
        controller_joints: controller_joints.to_vec(),
        pending: VecDeque::new(),
        index: 0,
    };
    Ok((meta, reader))
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

/// [`from_bytes`], also reading the commands a ROS 2 driver's controllers took (see [`Reader`]).
pub fn from_bytes_mapped(bytes: &[u8], controller_joints: &[String]) -> anyhow::Result<RobotLog> {
    // A stream owns its source: the bytes copied once.
    let (meta, reader) = open(Cursor::new(bytes.to_vec()), controller_joints)?;
    crate::LogStream::new(String::new(), meta, reader)?.into_log()
}

/// An MCAP log's records in file order, read from the source as they are needed (memory: a
/// chunk's worth). `/joint_states` gives joint states (in the first message's joint order; later
/// ones may name the same joints in another order), `/twinbots/joint_commands` and `/tool_pose`
/// commands and tool poses; beside them, the commands a ROS 2 driver's controllers took, as
/// rosbag2 records them: `std_msgs/msg/Float64MultiArray` on a forward command controller's
/// `…/commands` topic (its interface read from the topic's name: `position`, `velocity` or
/// `effort`, as `forward_position_controller` …; a value per joint in the controller's order,
/// which the message does not carry), and `trajectory_msgs/msg/JointTrajectory` on any topic
/// (each point a position target at the header's stamp plus its `time_from_start`, or a speed
/// where it has no positions: so commands may come ahead of their time). Other topics are
/// skipped.
pub struct Reader<R: Read> {
    messages: mcap::io::MessageReader<R>,
    /// The joints' order, fixed by the first joint state (empty before it).
    pub joints: Vec<String>,
    controller_joints: Vec<String>,
    /// Records decoded from one message and not yet handed out (a trajectory's points).
    pending: VecDeque<Entry>,
    index: usize,
}

impl<R: Read> Iterator for Reader<R> {
    type Item = anyhow::Result<Entry>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(entry) = self.pending.pop_front() {
                return Some(Ok(entry));
            }
            let message = match self.messages.next()? {
                Ok(message) => message,
                Err(e) => return Some(Err(mcap_error(e))),
            };
            let i = self.index;
            self.index += 1;
            if let Err(e) = self.decode(i, &message) {
                return Some(Err(e));
            }
        }
    }
}

impl<R: Read> Reader<R> {
    /// Decodes message `i` into [`Self::pending`].
    fn decode(&mut self, i: usize, message: &mcap::Message) -> anyhow::Result<()> {
        let when = |stamp: f64| if stamp == 0.0 { message.log_time as f64 * 1e-9 } else { stamp };
        match message.channel.topic.as_str() {
            JOINT_STATES_TOPIC => {
                check_encoding(&message.channel.message_encoding, "cdr", JOINT_STATES_TOPIC)?;
                let msg = JointStateMsg::decode(&message.data)
                    .map_err(|e| anyhow::anyhow!("{JOINT_STATES_TOPIC} message {i}: {e}"))?;
                let time = when(msg.stamp);
                let sample = joint_sample(&mut self.joints, msg, time)
                    .map_err(|e| anyhow::anyhow!("{JOINT_STATES_TOPIC} message {i} (t = {time} s): {e}"))?;
                self.pending.push_back(Entry::State(sample));
            }
            COMMANDS_TOPIC => {
                check_encoding(&message.channel.message_encoding, "json", COMMANDS_TOPIC)?;
                let msg: CommandMsg = serde_json::from_slice(&message.data)
                    .map_err(|e| anyhow::anyhow!("{COMMANDS_TOPIC} message {i}: {e}"))?;
                self.pending.push_back(Entry::Command(CommandSample {
                    time: msg.time,
                    joints: msg.name,
                    modes: msg.mode,
                    values: msg.value,
                }));
            }
            TOOL_POSE_TOPIC => {
                check_encoding(&message.channel.message_encoding, "cdr", TOOL_POSE_TOPIC)?;
                let msg = PoseStampedMsg::decode(&message.data)
                    .map_err(|e| anyhow::anyhow!("{TOOL_POSE_TOPIC} message {i}: {e}"))?;
                self.pending.push_back(Entry::Tool(ToolSample {
                    time: when(msg.stamp),
                    position: msg.position,
                    orientation: msg.orientation,
                }));
            }
            topic => match message.channel.schema.as_ref().map(|s| s.name.as_str()) {
                Some(FLOAT64_MULTI_ARRAY) => {
                    let Some(mode) = forward_mode(topic)? else { return Ok(()) };
                    check_encoding(&message.channel.message_encoding, "cdr", topic)?;
                    let controller = &self.controller_joints;
                    anyhow::ensure!(
                        !controller.is_empty(),
                        "{topic}: a forward controller's commands name no joints; their order is the robot's controller order (a robot file's `joints`, or a built-in robot)"
                    );
                    let msg = Float64MultiArrayMsg::decode(&message.data)
                        .map_err(|e| anyhow::anyhow!("{topic} message {i}: {e}"))?;
                    anyhow::ensure!(
                        msg.data.len() == controller.len(),
                        "{topic} message {i}: {} values for the controller's {} joints ({})",
                        msg.data.len(),
                        controller.len(),
                        controller.join(", ")
                    );
                    self.pending.push_back(Entry::Command(CommandSample {
                        time: message.log_time as f64 * 1e-9,
                        joints: controller.clone(),
                        modes: vec![mode; msg.data.len()],
                        values: msg.data,
                    }));
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
                        self.pending.push_back(Entry::Command(CommandSample {
                            time: start + point.time_from_start,
                            joints: msg.joint_names.clone(),
                            modes: vec![mode; n],
                            values,
                        }));
                    }
                }
                _ => {}
            },
        }
        Ok(())
    }
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
