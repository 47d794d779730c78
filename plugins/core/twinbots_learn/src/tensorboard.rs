//! TensorBoard event files, written without TensorFlow: a file of TFRecords (a little-endian
//! u64 length, the masked CRC-32C of those 8 bytes, the data, the masked CRC-32C of the data),
//! each record one `Event` protobuf (tensorflow/core/util/event.proto; only the fields a scalar
//! log needs are declared here). TensorBoard reads any file whose name contains `tfevents` in
//! the directory it is pointed at; the first event names the format (`brain.Event:2`).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{SystemTime, UNIX_EPOCH};

use prost::Message;

/// `tensorflow.Event`.
#[derive(Clone, PartialEq, prost::Message)]
struct Event {
    /// Seconds since the Unix epoch.
    #[prost(double, tag = "1")]
    wall_time: f64,
    #[prost(int64, tag = "2")]
    step: i64,
    #[prost(oneof = "EventKind", tags = "3, 5, 7")]
    kind: Option<EventKind>,
}

#[derive(Clone, PartialEq, prost::Oneof)]
enum EventKind {
    #[prost(string, tag = "3")]
    FileVersion(String),
    #[prost(message, tag = "5")]
    Summary(Summary),
    #[prost(message, tag = "7")]
    SessionLog(SessionLog),
}

/// `tensorflow.Summary`: named values at one step.
#[derive(Clone, PartialEq, prost::Message)]
struct Summary {
    #[prost(message, repeated, tag = "1")]
    value: Vec<SummaryValue>,
}

#[derive(Clone, PartialEq, prost::Message)]
struct SummaryValue {
    #[prost(string, tag = "1")]
    tag: String,
    /// A oneof in event.proto: declared as one here too, so that 0.0 is written (a plain proto3
    /// float field equal to 0 is left out, and the point would be lost).
    #[prost(oneof = "SummaryData", tags = "2")]
    data: Option<SummaryData>,
}

#[derive(Clone, PartialEq, prost::Oneof)]
enum SummaryData {
    #[prost(float, tag = "2")]
    SimpleValue(f32),
}

/// `tensorflow.SessionLog`. A `START` at step s tells TensorBoard that the run (re)starts there
/// (a resumed run): it drops the points it holds from steps ≥ s, which the resumed run logs again.
#[derive(Clone, PartialEq, prost::Message)]
struct SessionLog {
    #[prost(int32, tag = "1")]
    status: i32,
}

const SESSION_START: i32 = 1;
const FILE_VERSION: &str = "brain.Event:2";

const CRC32C: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);

/// TFRecord's checksum: CRC-32C, rotated and offset (a CRC of data that holds CRCs is weak).
pub fn masked_crc32c(data: &[u8]) -> u32 {
    let crc = CRC32C.checksum(data);
    crc.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// `data` framed as one TFRecord.
pub fn tfrecord(data: &[u8]) -> Vec<u8> {
    let length = (data.len() as u64).to_le_bytes();
    let mut out = Vec::with_capacity(data.len() + 16);
    out.extend_from_slice(&length);
    out.extend_from_slice(&masked_crc32c(&length).to_le_bytes());
    out.extend_from_slice(data);
    out.extend_from_slice(&masked_crc32c(data).to_le_bytes());
    out
}

/// The records of a TFRecord file's bytes; an error names the first damaged one.
pub fn read_tfrecords(bytes: &[u8]) -> Result<Vec<&[u8]>, String> {
    let mut records = Vec::new();
    let mut rest = bytes;
    while !rest.is_empty() {
        let n = records.len();
        let header = rest.get(..12).ok_or(format!("record {n}: truncated header"))?;
        let (length, length_crc) = header.split_at(8);
        if masked_crc32c(length).to_le_bytes() != length_crc {
            return Err(format!("record {n}: bad length checksum"));
        }
        let len = u64::from_le_bytes(length.try_into().expect("8 bytes")) as usize;
        let body = rest.get(12..12 + len + 4).ok_or(format!("record {n}: truncated data"))?;
        let (data, data_crc) = body.split_at(len);
        if masked_crc32c(data).to_le_bytes() != data_crc {
            return Err(format!("record {n}: bad data checksum"));
        }
        records.push(data);
        rest = &rest[12 + len + 4..];
    }
    Ok(records)
}

/// An event file being written. Clones are handles to the same file, so several callbacks
/// (training statistics, evaluations) can log into one run.
#[derive(Clone, Debug)]
pub struct EventWriter {
    path: PathBuf,
    file: Arc<Mutex<std::io::BufWriter<std::fs::File>>>,
}

impl EventWriter {
    /// A new event file in `dir` (created if needed), named as TensorBoard's writers name them:
    /// `events.out.tfevents.<unix seconds>.<host>.<pid>.<n>`.
    pub fn create(dir: &Path) -> anyhow::Result<Self> {
        static FILES: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        std::fs::create_dir_all(dir).map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?;
        let n = FILES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let name = format!("events.out.tfevents.{}.twinbots.{}.{n}", wall_time() as u64, std::process::id());
        let path = dir.join(name);
        let file = std::fs::File::create(&path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let writer = Self { path, file: Arc::new(Mutex::new(std::io::BufWriter::new(file))) };
        writer.write(0, EventKind::FileVersion(FILE_VERSION.into()))?;
        Ok(writer)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Marks a (re)start of training: points at `step` and after, in files written before this
    /// one, are stale.
    pub fn session_start(&self, step: u64) -> anyhow::Result<()> {
        self.write(step, EventKind::SessionLog(SessionLog { status: SESSION_START }))
    }

    /// One point of each named scalar at `step`, written out at once (a TensorBoard watching
    /// the run sees it). Non-finite values are left out: TensorBoard cannot draw them.
    pub fn scalars(&self, step: u64, values: &[(String, f32)]) -> anyhow::Result<()> {
        let value = values
            .iter()
            .filter(|(_, v)| v.is_finite())
            .map(|(tag, v)| SummaryValue { tag: tag.clone(), data: Some(SummaryData::SimpleValue(*v)) })
            .collect();
        self.write(step, EventKind::Summary(Summary { value }))
    }

    fn write(&self, step: u64, kind: EventKind) -> anyhow::Result<()> {
        let event = Event { wall_time: wall_time(), step: step as i64, kind: Some(kind) };
        let mut file = self.file.lock().map_err(|_| anyhow::anyhow!("{}: a writer panicked", self.path.display()))?;
        let io = |e: std::io::Error| anyhow::anyhow!("{}: {e}", self.path.display());
        file.write_all(&tfrecord(&event.encode_to_vec())).map_err(io)?;
        file.flush().map_err(io)
    }
}

fn wall_time() -> f64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}

/// The scalars of an event file's bytes, as `(step, tag, value)` in the order written (for
/// tests and tools; TensorBoard has its own reader).
pub fn read_scalars(bytes: &[u8]) -> Result<Vec<(u64, String, f32)>, String> {
    let mut out = Vec::new();
    for (i, record) in read_tfrecords(bytes)?.into_iter().enumerate() {
        let event = Event::decode(record).map_err(|e| format!("record {i}: not an event: {e}"))?;
        if let Some(EventKind::Summary(summary)) = event.kind {
            for value in summary.value {
                if let Some(SummaryData::SimpleValue(v)) = value.data {
                    out.push((event.step as u64, value.tag, v));
                }
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32c_is_castagnolis_and_masked_as_tfrecord_masks_it() {
        // The CRC-32C check value (RFC 3720) and its mask, worked by hand:
        // 0xE3069283 rotated right by 15 is 0x2507C60D; + 0xA282EAD8 = 0xC78AB0E5.
        assert_eq!(CRC32C.checksum(b"123456789"), 0xE306_9283);
        assert_eq!(masked_crc32c(b"123456789"), 0xC78A_B0E5);
    }

    #[test]
    fn records_read_back_and_damage_is_found() {
        let mut bytes = tfrecord(b"first");
        bytes.extend(tfrecord(b""));
        bytes.extend(tfrecord(&[7u8; 300]));
        let records = read_tfrecords(&bytes).unwrap();
        assert_eq!(records, vec![&b"first"[..], &b""[..], &[7u8; 300][..]]);
        let mut damaged = bytes.clone();
        damaged[14] ^= 1; // a byte of the first record's data
        assert_eq!(read_tfrecords(&damaged).unwrap_err(), "record 0: bad data checksum");
        assert!(read_tfrecords(&bytes[..bytes.len() - 1]).unwrap_err().contains("record 2: truncated"));
    }

    #[test]
    fn scalars_are_written_with_their_steps_zeros_included_and_non_finite_values_left_out() {
        let dir = std::env::temp_dir().join(format!("twinbots-tb-{}", std::process::id()));
        let writer = EventWriter::create(&dir).unwrap();
        writer.session_start(0).unwrap();
        writer.scalars(100, &[("a/x".into(), 0.0), ("a/y".into(), f32::NAN), ("b".into(), -2.5)]).unwrap();
        writer.clone().scalars(200, &[("a/x".into(), 1.5)]).unwrap();
        let bytes = std::fs::read(writer.path()).unwrap();
        assert!(writer.path().file_name().unwrap().to_str().unwrap().starts_with("events.out.tfevents."));
        let records = read_tfrecords(&bytes).unwrap();
        let first = Event::decode(records[0]).unwrap();
        assert_eq!(first.kind, Some(EventKind::FileVersion("brain.Event:2".into())));
        // event.proto's field numbers: session_log is 7 (6 is the deprecated log_message), its
        // status 1, START = 1: bytes 0x3a (field 7, length-delimited), 2, 0x08 (field 1), 1.
        assert!(records[1].ends_with(&[0x3a, 0x02, 0x08, 0x01]), "{:x?}", records[1]);
        let scalars = read_scalars(&bytes).unwrap();
        assert_eq!(scalars, vec![(100, "a/x".into(), 0.0), (100, "b".into(), -2.5), (200, "a/x".into(), 1.5)]);
        std::fs::remove_dir_all(&dir).ok();
    }
}
