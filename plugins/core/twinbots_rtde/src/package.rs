//! RTDE's packages (RTDE guide, "Protocol"): a 3-byte header (uint16 size of the whole package,
//! uint8 type), then the payload, big-endian. The payloads of protocol version 2.

use std::io::{ErrorKind, Read};

use crate::RtdeError;

/// Package types: the ASCII letter the guide gives each.
pub mod kind {
    pub const REQUEST_PROTOCOL_VERSION: u8 = b'V';
    pub const GET_URCONTROL_VERSION: u8 = b'v';
    pub const TEXT_MESSAGE: u8 = b'M';
    pub const DATA_PACKAGE: u8 = b'U';
    pub const SETUP_OUTPUTS: u8 = b'O';
    pub const SETUP_INPUTS: u8 = b'I';
    pub const START: u8 = b'S';
    pub const PAUSE: u8 = b'P';

    /// The type's name in the guide, for errors.
    pub fn name(kind: u8) -> String {
        match kind {
            REQUEST_PROTOCOL_VERSION => "RTDE_REQUEST_PROTOCOL_VERSION".into(),
            GET_URCONTROL_VERSION => "RTDE_GET_URCONTROL_VERSION".into(),
            TEXT_MESSAGE => "RTDE_TEXT_MESSAGE".into(),
            DATA_PACKAGE => "RTDE_DATA_PACKAGE".into(),
            SETUP_OUTPUTS => "RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS".into(),
            SETUP_INPUTS => "RTDE_CONTROL_PACKAGE_SETUP_INPUTS".into(),
            START => "RTDE_CONTROL_PACKAGE_START".into(),
            PAUSE => "RTDE_CONTROL_PACKAGE_PAUSE".into(),
            other => format!("unknown package type {other}"),
        }
    }
}

/// Bytes in a header.
pub const HEADER: usize = 3;

/// One package: its type and payload.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Package {
    pub kind: u8,
    pub payload: Vec<u8>,
}

impl Package {
    pub fn new(kind: u8, payload: Vec<u8>) -> Self {
        Self { kind, payload }
    }

    /// The package on the wire; an error if it exceeds the 65,535 bytes the size field holds.
    pub fn encode(&self) -> Result<Vec<u8>, RtdeError> {
        let size = u16::try_from(HEADER + self.payload.len()).map_err(|_| {
            RtdeError::Usage(format!(
                "a {} of {} bytes exceeds RTDE's 65,535",
                kind::name(self.kind),
                self.payload.len()
            ))
        })?;
        let mut out = Vec::with_capacity(size as usize);
        out.extend_from_slice(&size.to_be_bytes());
        out.push(self.kind);
        out.extend_from_slice(&self.payload);
        Ok(out)
    }

    /// Reads one package. A peer that closes between packages is [`RtdeError::Closed`]; one
    /// that closes inside a package, [`RtdeError::Truncated`]; a size below the header's own,
    /// [`RtdeError::Malformed`] (the stream cannot be re-synchronised after it). A read timeout
    /// set on the stream surfaces as [`RtdeError::Timeout`].
    pub fn read(reader: &mut impl Read) -> Result<Self, RtdeError> {
        let mut header = [0u8; HEADER];
        let got = read_full(reader, &mut header)?;
        if got == 0 {
            return Err(RtdeError::Closed);
        }
        if got < HEADER {
            return Err(RtdeError::Truncated(format!("{got} of a header's 3 bytes")));
        }
        let size = u16::from_be_bytes([header[0], header[1]]) as usize;
        if size < HEADER {
            return Err(RtdeError::Malformed(format!("a package size of {size} bytes is below the header's 3")));
        }
        let mut payload = vec![0u8; size - HEADER];
        let got = read_full(reader, &mut payload)?;
        if got < payload.len() {
            return Err(RtdeError::Truncated(format!(
                "{got} of a {}'s {} payload bytes",
                kind::name(header[2]),
                payload.len()
            )));
        }
        Ok(Self { kind: header[2], payload })
    }
}

/// Fills `buf` unless the stream ends first; returns the bytes read.
fn read_full(reader: &mut impl Read, buf: &mut [u8]) -> Result<usize, RtdeError> {
    let mut filled = 0;
    while filled < buf.len() {
        match reader.read(&mut buf[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                return Err(RtdeError::Timeout(if filled == 0 {
                    "package".into()
                } else {
                    "rest of a package".into()
                }));
            }
            Err(e) => return Err(RtdeError::Io(e)),
        }
    }
    Ok(filled)
}

/// The controller's software version (`RTDE_GET_URCONTROL_VERSION`'s reply).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ControllerVersion {
    pub major: u32,
    pub minor: u32,
    pub bugfix: u32,
    pub build: u32,
}

impl ControllerVersion {
    pub fn encode(&self) -> Vec<u8> {
        [self.major, self.minor, self.bugfix, self.build].iter().flat_map(|v| v.to_be_bytes()).collect()
    }

    pub fn decode(payload: &[u8]) -> Result<Self, RtdeError> {
        if payload.len() != 16 {
            return Err(RtdeError::Malformed(format!("a controller version has 16 bytes, not {}", payload.len())));
        }
        let v = |i: usize| u32::from_be_bytes(payload[4 * i..4 * i + 4].try_into().unwrap());
        Ok(Self { major: v(0), minor: v(1), bugfix: v(2), build: v(3) })
    }
}

impl std::fmt::Display for ControllerVersion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}.{}.{}.{}", self.major, self.minor, self.bugfix, self.build)
    }
}

/// A text message's level (the guide's EXCEPTION, ERROR, WARNING, INFO).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MessageLevel {
    Exception = 0,
    Error = 1,
    Warning = 2,
    Info = 3,
}

/// `RTDE_TEXT_MESSAGE`, version 2 (both directions): uint8 length + message, uint8 length +
/// source, uint8 level.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TextMessage {
    pub level: MessageLevel,
    pub message: String,
    pub source: String,
}

impl TextMessage {
    /// The payload; message and source are cut to the 255 bytes their length fields hold (at a
    /// character boundary).
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::new();
        for text in [&self.message, &self.source] {
            let cut = truncate(text, 255);
            out.push(cut.len() as u8);
            out.extend_from_slice(cut.as_bytes());
        }
        out.push(self.level as u8);
        out
    }

    pub fn decode(payload: &[u8]) -> Result<Self, RtdeError> {
        let bad = |what: &str| RtdeError::Malformed(format!("text message: {what}"));
        let (message, rest) = take_text(payload).ok_or_else(|| bad("message longer than the package"))?;
        let (source, rest) = take_text(rest).ok_or_else(|| bad("source longer than the package"))?;
        let level = match rest {
            [0] => MessageLevel::Exception,
            [1] => MessageLevel::Error,
            [2] => MessageLevel::Warning,
            [3] => MessageLevel::Info,
            [other] => return Err(bad(&format!("level {other} is none of 0-3"))),
            _ => return Err(bad(&format!("{} bytes after the source, not the 1 of a level", rest.len()))),
        };
        Ok(Self { level, message, source })
    }
}

fn take_text(bytes: &[u8]) -> Option<(String, &[u8])> {
    let (&len, rest) = bytes.split_first()?;
    let len = len as usize;
    (rest.len() >= len).then(|| (String::from_utf8_lossy(&rest[..len]).into_owned(), &rest[len..]))
}

fn truncate(text: &str, max: usize) -> &str {
    let mut end = text.len().min(max);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    &text[..end]
}

/// A recipe setup's reply: the recipe's id (0: refused) and one type name per variable asked
/// for, `NOT_FOUND` for an unknown one and `IN_USE` for an input another client sets.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RecipeReply {
    pub id: u8,
    pub types: Vec<String>,
}

impl RecipeReply {
    pub fn encode(&self) -> Vec<u8> {
        let mut out = vec![self.id];
        out.extend_from_slice(self.types.join(",").as_bytes());
        out
    }

    pub fn decode(payload: &[u8]) -> Result<Self, RtdeError> {
        let (&id, rest) = payload.split_first().ok_or_else(|| RtdeError::Malformed("an empty recipe reply".into()))?;
        let text = std::str::from_utf8(rest)
            .map_err(|_| RtdeError::Malformed("a recipe reply's types are not UTF-8".into()))?;
        let types = if text.is_empty() { Vec::new() } else { text.split(',').map(str::to_string).collect() };
        Ok(Self { id, types })
    }
}

/// A comma-separated variable list (a setup request's names). Empty entries are skipped:
/// clients such as ur_rtde end the list with a comma.
pub fn names(text: &[u8]) -> Result<Vec<String>, RtdeError> {
    let text = std::str::from_utf8(text).map_err(|_| RtdeError::Malformed("variable names are not UTF-8".into()))?;
    let names: Vec<String> = text.split(',').map(str::trim).filter(|s| !s.is_empty()).map(str::to_string).collect();
    if names.is_empty() {
        return Err(RtdeError::Malformed("a recipe names no variable".into()));
    }
    Ok(names)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_package_round_trips_and_its_header_counts_itself() {
        let p = Package::new(kind::START, vec![]);
        assert_eq!(p.encode().unwrap(), vec![0, 3, b'S']);
        let p = Package::new(kind::REQUEST_PROTOCOL_VERSION, vec![0, 2]);
        let bytes = p.encode().unwrap();
        assert_eq!(bytes, vec![0, 5, 86, 0, 2]);
        assert_eq!(Package::read(&mut bytes.as_slice()).unwrap(), p);
    }

    #[test]
    fn closed_truncated_and_undersized_packages_are_told_apart() {
        assert!(matches!(Package::read(&mut [].as_slice()), Err(RtdeError::Closed)));
        assert!(matches!(Package::read(&mut [0u8, 5].as_slice()), Err(RtdeError::Truncated(_))));
        assert!(matches!(Package::read(&mut [0u8, 9, b'U', 1, 2].as_slice()), Err(RtdeError::Truncated(_))));
        assert!(matches!(Package::read(&mut [0u8, 2, b'U'].as_slice()), Err(RtdeError::Malformed(_))));
    }

    #[test]
    fn text_messages_and_recipe_replies_round_trip() {
        let m = TextMessage { level: MessageLevel::Warning, message: "watchdog".into(), source: "twinbots".into() };
        assert_eq!(TextMessage::decode(&m.encode()).unwrap(), m);
        let long = TextMessage { level: MessageLevel::Info, message: "é".repeat(200), source: String::new() };
        assert_eq!(TextMessage::decode(&long.encode()).unwrap().message.len(), 254, "cut at a character boundary");
        assert!(TextMessage::decode(&[5, b'a']).is_err());
        let r = RecipeReply { id: 1, types: vec!["VECTOR6D".into(), "NOT_FOUND".into()] };
        assert_eq!(RecipeReply::decode(&r.encode()).unwrap(), r);
        assert_eq!(names(b"actual_q,timestamp").unwrap(), vec!["actual_q", "timestamp"]);
        assert_eq!(names(b"actual_q,").unwrap(), vec!["actual_q"]);
        assert!(names(b"").is_err());
        assert!(names(b",").is_err());
    }
}
