//! ROS 2 messages in CDR (OMG XCDR1, little endian, as rmw_fastrtps writes them): a 4-byte
//! encapsulation header `00 01 00 00`, then the fields, each aligned to its own size counted
//! from the end of the header; strings are a u32 length (with the NUL) then the bytes and a NUL;
//! sequences a u32 count then the elements (an empty sequence adds no padding).

/// The definitions of `std_msgs/Header` and the `builtin_interfaces/Time` in it, as a stamped
/// message's schema ends them.
macro_rules! header_schema {
    () => {
        "================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"
    };
}

/// `sensor_msgs/msg/JointState` as the `ros2msg` schema rosbag2 writes: the message, then
/// each type it uses after a `===` line (the schema's `data` in MCAP).
pub const JOINT_STATE_SCHEMA: &str = concat!(
    "std_msgs/Header header
string[] name
float64[] position
float64[] velocity
float64[] effort
",
    header_schema!()
);

/// `geometry_msgs/msg/PoseStamped`, as above.
pub const POSE_STAMPED_SCHEMA: &str = concat!(
    "std_msgs/Header header
geometry_msgs/Pose pose
",
    header_schema!(),
    "================================================================================
MSG: geometry_msgs/Pose
geometry_msgs/Point position
geometry_msgs/Quaternion orientation
================================================================================
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
================================================================================
MSG: geometry_msgs/Quaternion
float64 x
float64 y
float64 z
float64 w
"
);

/// `std_msgs/msg/Float64MultiArray`: what `ros2_controllers`' forward command controllers take
/// (`/forward_position_controller/commands`, …), a value per joint of the controller's own list.
pub const FLOAT64_MULTI_ARRAY_SCHEMA: &str = "std_msgs/MultiArrayLayout layout
float64[] data
================================================================================
MSG: std_msgs/MultiArrayLayout
std_msgs/MultiArrayDimension[] dim
uint32 data_offset
================================================================================
MSG: std_msgs/MultiArrayDimension
string label
uint32 size
uint32 stride
";

/// `trajectory_msgs/msg/JointTrajectory`: what joint trajectory controllers take.
pub const JOINT_TRAJECTORY_SCHEMA: &str = concat!(
    "std_msgs/Header header
string[] joint_names
JointTrajectoryPoint[] points
",
    header_schema!(),
    "================================================================================
MSG: trajectory_msgs/JointTrajectoryPoint
float64[] positions
float64[] velocities
float64[] accelerations
float64[] effort
builtin_interfaces/Duration time_from_start
================================================================================
MSG: builtin_interfaces/Duration
int32 sec
uint32 nanosec
"
);

/// A decoded Float64MultiArray (the layout's dimensions as label, size, stride).
#[derive(Clone, Debug, PartialEq)]
pub struct Float64MultiArrayMsg {
    pub dim: Vec<(String, u32, u32)>,
    pub data_offset: u32,
    pub data: Vec<f64>,
}

/// One point of a JointTrajectory (`time_from_start` in s).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrajectoryPoint {
    pub positions: Vec<f64>,
    pub velocities: Vec<f64>,
    pub accelerations: Vec<f64>,
    pub effort: Vec<f64>,
    pub time_from_start: f64,
}

/// A decoded JointTrajectory.
#[derive(Clone, Debug, PartialEq)]
pub struct JointTrajectoryMsg {
    pub stamp: f64,
    pub frame_id: String,
    pub joint_names: Vec<String>,
    pub points: Vec<TrajectoryPoint>,
}

/// A decoded JointState (times as seconds).
#[derive(Clone, Debug, PartialEq)]
pub struct JointStateMsg {
    pub stamp: f64,
    pub frame_id: String,
    pub name: Vec<String>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    pub effort: Vec<f64>,
}

/// A decoded PoseStamped.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseStampedMsg {
    pub stamp: f64,
    pub frame_id: String,
    pub position: [f64; 3],
    pub orientation: [f64; 4],
}

struct Writer {
    buf: Vec<u8>,
}

impl Writer {
    fn new() -> Self {
        Self { buf: vec![0x00, 0x01, 0x00, 0x00] }
    }
    fn align(&mut self, n: usize) {
        while !(self.buf.len() - 4).is_multiple_of(n) {
            self.buf.push(0);
        }
    }
    fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }
    fn f64s(&mut self, v: &[f64]) {
        self.u32(v.len() as u32);
        v.iter().for_each(|&x| self.f64(x));
    }
    fn time(&mut self, t: f64) {
        let sec = t.floor();
        let nanosec = ((t - sec) * 1e9).round().min(999_999_999.0);
        self.i32(sec as i32);
        self.u32(nanosec as u32);
    }
    fn header(&mut self, stamp: f64, frame_id: &str) {
        self.time(stamp);
        self.string(frame_id);
    }
}

struct Reader<'a> {
    buf: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn new(buf: &'a [u8]) -> anyhow::Result<Self> {
        anyhow::ensure!(buf.len() >= 4, "a CDR message of {} bytes has no encapsulation header", buf.len());
        anyhow::ensure!(
            buf[0] == 0 && buf[1] == 1,
            "CDR encapsulation {:02x} {:02x} is not little-endian plain CDR (00 01)",
            buf[0],
            buf[1]
        );
        Ok(Self { buf, at: 4 })
    }
    fn align(&mut self, n: usize) {
        self.at += (n - (self.at - 4) % n) % n;
    }
    fn take(&mut self, n: usize) -> anyhow::Result<&'a [u8]> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.buf.len());
        let end = end.ok_or_else(|| {
            anyhow::anyhow!("the message ends at byte {} while {n} more were expected at {}", self.buf.len(), self.at)
        })?;
        let bytes = &self.buf[self.at..end];
        self.at = end;
        Ok(bytes)
    }
    fn u32(&mut self) -> anyhow::Result<u32> {
        self.align(4);
        Ok(u32::from_le_bytes(self.take(4)?.try_into()?))
    }
    fn i32(&mut self) -> anyhow::Result<i32> {
        self.align(4);
        Ok(i32::from_le_bytes(self.take(4)?.try_into()?))
    }
    fn f64(&mut self) -> anyhow::Result<f64> {
        self.align(8);
        Ok(f64::from_le_bytes(self.take(8)?.try_into()?))
    }
    fn count(&mut self) -> anyhow::Result<usize> {
        let n = self.u32()? as usize;
        // Each element takes at least a byte: a count beyond the rest is corrupt, not a size to allocate.
        anyhow::ensure!(
            n <= self.buf.len() - self.at.min(self.buf.len()),
            "a sequence of {n} elements overruns the message"
        );
        Ok(n)
    }
    fn string(&mut self) -> anyhow::Result<String> {
        let n = self.count()?;
        let bytes = self.take(n)?;
        // Serializers differ on whether an empty string is length 0 or 1 (a lone NUL).
        let bytes = bytes.strip_suffix(&[0]).unwrap_or(bytes);
        Ok(String::from_utf8(bytes.to_vec())?)
    }
    fn f64s(&mut self) -> anyhow::Result<Vec<f64>> {
        let n = self.count()?;
        (0..n).map(|_| self.f64()).collect()
    }
    fn time(&mut self) -> anyhow::Result<f64> {
        let sec = self.i32()?;
        let nanosec = self.u32()?;
        Ok(sec as f64 + nanosec as f64 * 1e-9)
    }
    fn header(&mut self) -> anyhow::Result<(f64, String)> {
        let stamp = self.time()?;
        Ok((stamp, self.string()?))
    }
    fn strings(&mut self) -> anyhow::Result<Vec<String>> {
        let n = self.count()?;
        (0..n).map(|_| self.string()).collect()
    }
}

impl Float64MultiArrayMsg {
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new();
        w.u32(self.dim.len() as u32);
        for (label, size, stride) in &self.dim {
            w.string(label);
            w.u32(*size);
            w.u32(*stride);
        }
        w.u32(self.data_offset);
        w.f64s(&self.data);
        w.buf
    }

    pub fn decode(buf: &[u8]) -> anyhow::Result<Self> {
        let mut r = Reader::new(buf)?;
        let n = r.count()?;
        let dim = (0..n).map(|_| Ok((r.string()?, r.u32()?, r.u32()?))).collect::<anyhow::Result<_>>()?;
        Ok(Self { dim, data_offset: r.u32()?, data: r.f64s()? })
    }
}

impl JointTrajectoryMsg {
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new();
        w.header(self.stamp, &self.frame_id);
        w.u32(self.joint_names.len() as u32);
        self.joint_names.iter().for_each(|n| w.string(n));
        w.u32(self.points.len() as u32);
        for p in &self.points {
            for v in [&p.positions, &p.velocities, &p.accelerations, &p.effort] {
                w.f64s(v);
            }
            w.time(p.time_from_start);
        }
        w.buf
    }

    pub fn decode(buf: &[u8]) -> anyhow::Result<Self> {
        let mut r = Reader::new(buf)?;
        let (stamp, frame_id) = r.header()?;
        let joint_names = r.strings()?;
        let n = r.count()?;
        let points = (0..n)
            .map(|_| {
                Ok(TrajectoryPoint {
                    positions: r.f64s()?,
                    velocities: r.f64s()?,
                    accelerations: r.f64s()?,
                    effort: r.f64s()?,
                    time_from_start: r.time()?,
                })
            })
            .collect::<anyhow::Result<_>>()?;
        Ok(Self { stamp, frame_id, joint_names, points })
    }
}

impl JointStateMsg {
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new();
        w.header(self.stamp, &self.frame_id);
        w.u32(self.name.len() as u32);
        self.name.iter().for_each(|n| w.string(n));
        w.f64s(&self.position);
        w.f64s(&self.velocity);
        w.f64s(&self.effort);
        w.buf
    }

    pub fn decode(buf: &[u8]) -> anyhow::Result<Self> {
        let mut r = Reader::new(buf)?;
        let (stamp, frame_id) = r.header()?;
        let n = r.count()?;
        let name = (0..n).map(|_| r.string()).collect::<anyhow::Result<_>>()?;
        Ok(Self { stamp, frame_id, name, position: r.f64s()?, velocity: r.f64s()?, effort: r.f64s()? })
    }
}

impl PoseStampedMsg {
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new();
        w.header(self.stamp, &self.frame_id);
        self.position.iter().chain(&self.orientation).for_each(|&v| w.f64(v));
        w.buf
    }

    pub fn decode(buf: &[u8]) -> anyhow::Result<Self> {
        let mut r = Reader::new(buf)?;
        let (stamp, frame_id) = r.header()?;
        let mut v = [0.0; 7];
        for x in &mut v {
            *x = r.f64()?;
        }
        Ok(Self { stamp, frame_id, position: [v[0], v[1], v[2]], orientation: [v[3], v[4], v[5], v[6]] })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joint_state_round_trips_with_aligned_doubles() {
        let msg = JointStateMsg {
            stamp: 12.25,
            frame_id: String::new(),
            name: vec!["a".into(), "shoulder".into()],
            position: vec![0.5, -1.0],
            velocity: vec![0.0, 2.0],
            effort: vec![],
        };
        let bytes = msg.encode();
        // header 4 | sec 4 | nanosec 4 | frame_id "" (len 1 + NUL) 5 → pad 3 | count 4 | "a" 4+2 → pad 2 | "shoulder" 4+9
        assert_eq!(&bytes[..4], &[0, 1, 0, 0]);
        assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()), 250_000_000);
        assert_eq!(JointStateMsg::decode(&bytes).unwrap(), msg);
        // Each double starts at a multiple of 8 from the header's end.
        let first_position = bytes.windows(8).position(|w| w == 0.5f64.to_le_bytes()).unwrap();
        assert_eq!((first_position - 4) % 8, 0);
    }

    #[test]
    fn command_messages_round_trip() {
        let array = Float64MultiArrayMsg { dim: vec![("joints".into(), 2, 2)], data_offset: 0, data: vec![0.5, -1.5] };
        assert_eq!(Float64MultiArrayMsg::decode(&array.encode()).unwrap(), array);
        let trajectory = JointTrajectoryMsg {
            stamp: 3.5,
            frame_id: String::new(),
            joint_names: vec!["a".into(), "b".into()],
            points: vec![
                TrajectoryPoint { positions: vec![0.1, 0.2], time_from_start: 0.008, ..Default::default() },
                TrajectoryPoint { velocities: vec![1.0, 2.0], time_from_start: 1.25, ..Default::default() },
            ],
        };
        assert_eq!(JointTrajectoryMsg::decode(&trajectory.encode()).unwrap(), trajectory);
        let bytes = trajectory.encode();
        assert!(JointTrajectoryMsg::decode(&bytes[..bytes.len() - 3]).is_err());
    }

    #[test]
    fn truncated_and_oversized_messages_are_errors() {
        let bytes = JointStateMsg {
            stamp: 1.0,
            frame_id: "base".into(),
            name: vec!["j".into()],
            position: vec![1.0],
            velocity: vec![2.0],
            effort: vec![3.0],
        }
        .encode();
        for cut in [0, 3, 10, bytes.len() - 1] {
            assert!(JointStateMsg::decode(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        let mut huge = bytes.clone();
        huge[24..28].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(JointStateMsg::decode(&huge).is_err());
    }
}
