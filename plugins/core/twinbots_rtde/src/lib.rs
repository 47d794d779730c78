//! twinbots_rtde: Universal Robots' Real-Time Data Exchange, protocol version 2, written from
//! UR's published RTDE guide (docs/rtde.md says what of it is here and how the stand-in fills
//! each variable).
//!
//! - [`types`]: the wire's data types and values; [`variables`]: every output and input
//!   variable a recipe may name, with its type; [`package`]: the header and the payloads.
//! - [`client`]: [`client::RtdeClient`], what `deploy` and `monitor` talk to a controller with.
//! - [`server`]: the controller's side of the protocol for a stand-in: sessions, recipes,
//!   inputs held per client, outputs streamed at each recipe's frequency from the state the
//!   stand-in publishes every control cycle.

pub mod client;
pub mod package;
pub mod server;
pub mod types;
pub mod variables;

pub use client::{DataPackage, InputRecipe, OutputRecipe, RtdeClient};
pub use package::{ControllerVersion, MessageLevel, TextMessage};
pub use types::{DataType, Value};

/// RTDE's TCP port.
pub const DEFAULT_PORT: u16 = 30004;

/// The protocol version spoken here.
pub const PROTOCOL_VERSION: u16 = 2;

/// The fastest output frequency (Hz): the e-Series control loop's.
pub const MAX_FREQUENCY: f64 = 500.0;

/// What can go wrong on an RTDE link, named.
#[derive(Debug, thiserror::Error)]
pub enum RtdeError {
    // The I/O error is in the message, not the error's source, so a printed chain names it once.
    #[error("RTDE: cannot connect to {address}: {error}")]
    Connect { address: String, error: std::io::Error },
    #[error("RTDE: cannot listen on {address}: {error}")]
    Listen { address: String, error: std::io::Error },
    #[error("RTDE: bad address '{0}': expected HOST[:PORT]")]
    Address(String),
    #[error("RTDE: {0}")]
    Io(#[from] std::io::Error),
    #[error("RTDE: no {0} arrived in time (is the controller still sending?)")]
    Timeout(String),
    #[error("RTDE: the peer closed the connection")]
    Closed,
    #[error("RTDE: the connection closed inside a package: {0}")]
    Truncated(String),
    #[error("RTDE: malformed package: {0}")]
    Malformed(String),
    #[error("RTDE: the controller refused protocol version {0}")]
    VersionRefused(u16),
    #[error("RTDE: the controller refused {what}{}", reason.as_ref().map(|r| format!(": {r}")).unwrap_or_default())]
    Refused { what: String, reason: Option<String> },
    #[error("RTDE: the controller has no variable {0:?} (NOT_FOUND)")]
    NotFound(Vec<String>),
    #[error("RTDE: inputs {0:?} are set by another client (IN_USE)")]
    InUse(Vec<String>),
    #[error("RTDE: {0}")]
    Usage(String),
}

/// `HOST[:PORT]` (an IPv6 host in brackets) as host and port, the port RTDE's 30004 by default.
pub fn parse_address(address: &str) -> Result<(String, u16), RtdeError> {
    let bad = || RtdeError::Address(address.to_string());
    let (host, port) = if let Some(rest) = address.strip_prefix('[') {
        let (host, after) = rest.split_once(']').ok_or_else(bad)?;
        match after {
            "" => (host, None),
            p => (host, Some(p.strip_prefix(':').ok_or_else(bad)?)),
        }
    } else if address.matches(':').count() == 1 {
        let (h, p) = address.split_once(':').unwrap();
        (h, Some(p))
    } else {
        (address, None)
    };
    if host.is_empty() {
        return Err(bad());
    }
    let port = port.map(|p| p.parse::<u16>().map_err(|_| bad())).transpose()?.unwrap_or(DEFAULT_PORT);
    Ok((host.to_string(), port))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_take_rtdes_port_by_default() {
        assert_eq!(parse_address("192.168.0.10").unwrap(), ("192.168.0.10".into(), 30004));
        assert_eq!(parse_address("robot:30005").unwrap(), ("robot".into(), 30005));
        assert_eq!(parse_address("[::1]:1234").unwrap(), ("::1".into(), 1234));
        assert_eq!(parse_address("[::1]").unwrap(), ("::1".into(), 30004));
        assert!(parse_address("robot:port").is_err());
        assert!(parse_address(":30004").is_err());
        assert!(parse_address("robot:70000").is_err());
    }
}
