//! An RTDE client: connect (protocol version 2), ask the controller's version, set up an output
//! recipe and input recipes, start and pause, receive data packages and send inputs. Every wait
//! is bounded by the client's timeout.

use std::io::Write;
use std::net::{TcpStream, ToSocketAddrs};
use std::sync::Arc;
use std::time::Duration;

use crate::package::{ControllerVersion, MessageLevel, Package, RecipeReply, TextMessage, kind};
use crate::types::{DataType, Value};
use crate::{PROTOCOL_VERSION, RtdeError, parse_address};

/// The outputs the controller streams: their names and types, in order.
#[derive(Clone, Debug)]
pub struct OutputRecipe {
    pub id: u8,
    pub names: Arc<Vec<String>>,
    pub types: Vec<DataType>,
    pub frequency: f64,
}

/// Inputs the client sets: their names and types, in order.
#[derive(Clone, Debug)]
pub struct InputRecipe {
    pub id: u8,
    pub names: Vec<String>,
    pub types: Vec<DataType>,
}

/// One data package of the output recipe.
#[derive(Clone, Debug)]
pub struct DataPackage {
    pub names: Arc<Vec<String>>,
    pub values: Vec<Value>,
}

impl DataPackage {
    /// The value of output `name`, if the recipe has it.
    pub fn get(&self, name: &str) -> Option<&Value> {
        self.names.iter().position(|n| n == name).map(|i| &self.values[i])
    }

    /// Output `name` as a double, if the recipe has it and it is one.
    pub fn double(&self, name: &str) -> Option<f64> {
        self.get(name).and_then(Value::as_f64)
    }

    /// Output `name` as six doubles (`VECTOR6D`, `VECTOR6INT32`, `VECTOR6UINT32`), if the recipe
    /// has it and it is one.
    pub fn vector6(&self, name: &str) -> Option<[f64; 6]> {
        self.get(name).and_then(Value::as_vector6)
    }
}

pub struct RtdeClient {
    stream: TcpStream,
    address: String,
    output: Option<OutputRecipe>,
    messages: Vec<TextMessage>,
    /// How long any wait may take: a reply, a data package.
    timeout: Duration,
}

/// Text messages kept between two [`RtdeClient::take_messages`]; older ones give way.
pub const MAX_MESSAGES: usize = 1000;

impl RtdeClient {
    /// Connects to `HOST[:PORT]` and negotiates protocol version 2; every later wait gives up
    /// after `timeout`.
    pub fn connect(address: &str, timeout: Duration) -> Result<Self, RtdeError> {
        let (host, port) = parse_address(address)?;
        let connect_error = |error| RtdeError::Connect { address: address.to_string(), error };
        let candidates = (host.as_str(), port).to_socket_addrs().map_err(connect_error)?;
        let mut last = None;
        let mut stream = None;
        for candidate in candidates {
            match TcpStream::connect_timeout(&candidate, timeout) {
                Ok(s) => {
                    stream = Some(s);
                    break;
                }
                Err(e) => last = Some(e),
            }
        }
        let stream = stream
            .ok_or_else(|| connect_error(last.unwrap_or_else(|| std::io::Error::other("the host has no address"))))?;
        stream.set_nodelay(true)?;
        stream.set_read_timeout(Some(timeout))?;
        stream.set_write_timeout(Some(timeout))?;
        let mut client = Self { stream, address: address.to_string(), output: None, messages: Vec::new(), timeout };
        let reply = client.request(kind::REQUEST_PROTOCOL_VERSION, PROTOCOL_VERSION.to_be_bytes().to_vec())?;
        if accepted(&reply, "protocol version")? {
            Ok(client)
        } else {
            Err(RtdeError::VersionRefused(PROTOCOL_VERSION))
        }
    }

    pub fn address(&self) -> &str {
        &self.address
    }

    /// The controller's software version.
    pub fn controller_version(&mut self) -> Result<ControllerVersion, RtdeError> {
        let reply = self.request(kind::GET_URCONTROL_VERSION, Vec::new())?;
        ControllerVersion::decode(&reply)
    }

    /// Asks for `names` at `frequency` Hz. An unknown name is [`RtdeError::NotFound`].
    pub fn setup_outputs(&mut self, names: &[&str], frequency: f64) -> Result<OutputRecipe, RtdeError> {
        let mut payload = frequency.to_be_bytes().to_vec();
        payload.extend_from_slice(names.join(",").as_bytes());
        let reply = RecipeReply::decode(&self.request(kind::SETUP_OUTPUTS, payload)?)?;
        let types = self.recipe_types("the output recipe", names, &reply)?;
        let recipe = OutputRecipe {
            id: reply.id,
            names: Arc::new(names.iter().map(|s| s.to_string()).collect()),
            types,
            frequency,
        };
        self.output = Some(recipe.clone());
        Ok(recipe)
    }

    /// Asks to set `names`. An unknown name is [`RtdeError::NotFound`]; one another client sets,
    /// [`RtdeError::InUse`].
    pub fn setup_inputs(&mut self, names: &[&str]) -> Result<InputRecipe, RtdeError> {
        let reply = RecipeReply::decode(&self.request(kind::SETUP_INPUTS, names.join(",").into_bytes())?)?;
        let types = self.recipe_types("the input recipe", names, &reply)?;
        Ok(InputRecipe { id: reply.id, names: names.iter().map(|s| s.to_string()).collect(), types })
    }

    /// Starts the output stream (and the controller's acceptance of inputs).
    pub fn start(&mut self) -> Result<(), RtdeError> {
        if self.output.is_none() {
            return Err(RtdeError::Usage("start before an output recipe: set one up first".into()));
        }
        let reply = self.request(kind::START, Vec::new())?;
        if accepted(&reply, "start")? { Ok(()) } else { Err(self.refused("start")) }
    }

    /// Pauses the output stream.
    pub fn pause(&mut self) -> Result<(), RtdeError> {
        let reply = self.request(kind::PAUSE, Vec::new())?;
        if accepted(&reply, "pause")? { Ok(()) } else { Err(self.refused("pause")) }
    }

    /// The next data package of the output recipe.
    pub fn receive(&mut self) -> Result<DataPackage, RtdeError> {
        if self.output.is_none() {
            return Err(RtdeError::Usage("receive before an output recipe".into()));
        }
        // Bounded in time as one read is: a peer that sends only other packages (text
        // messages) must not hold the client for ever.
        let began = std::time::Instant::now();
        let package = loop {
            let package = self.read()?;
            if package.kind == kind::DATA_PACKAGE {
                break package;
            }
            self.give_up_after(began, "a data package")?;
        };
        let recipe = self.output.as_ref().expect("checked above");
        let (&id, rest) =
            package.payload.split_first().ok_or_else(|| RtdeError::Malformed("an empty data package".into()))?;
        if id != recipe.id {
            return Err(RtdeError::Malformed(format!("a data package of recipe {id}; ours is {}", recipe.id)));
        }
        let values = Value::decode_all(recipe.types.iter().copied(), rest)?;
        Ok(DataPackage { names: recipe.names.clone(), values })
    }

    /// Sends `values` for `recipe`'s inputs, in its order and types.
    pub fn send(&mut self, recipe: &InputRecipe, values: &[Value]) -> Result<(), RtdeError> {
        if values.len() != recipe.types.len() {
            return Err(RtdeError::Usage(format!(
                "{} values for the {} inputs {:?}",
                values.len(),
                recipe.types.len(),
                recipe.names
            )));
        }
        let mut payload = vec![recipe.id];
        for ((value, &t), name) in values.iter().zip(&recipe.types).zip(&recipe.names) {
            if value.data_type() != t {
                return Err(RtdeError::Usage(format!(
                    "input {name} is {}, not {}",
                    t.name(),
                    value.data_type().name()
                )));
            }
            value.encode(&mut payload);
        }
        self.write(kind::DATA_PACKAGE, payload)
    }

    /// Sends a text message to the controller's log.
    pub fn send_message(&mut self, message: &str, source: &str, level: MessageLevel) -> Result<(), RtdeError> {
        let text = TextMessage { level, message: message.to_string(), source: source.to_string() };
        self.write(kind::TEXT_MESSAGE, text.encode())
    }

    /// The text messages the controller sent so far (cleared).
    pub fn take_messages(&mut self) -> Vec<TextMessage> {
        std::mem::take(&mut self.messages)
    }

    fn request(&mut self, kind: u8, payload: Vec<u8>) -> Result<Vec<u8>, RtdeError> {
        self.write(kind, payload)?;
        let began = std::time::Instant::now();
        loop {
            let package = self.read()?;
            if package.kind == kind {
                return Ok(package.payload);
            }
            self.give_up_after(began, "a reply")?;
            // Data packages still in flight (a pause's reply follows them) and text messages
            // (read() keeps them) are not the answer.
        }
    }

    fn write(&mut self, kind: u8, payload: Vec<u8>) -> Result<(), RtdeError> {
        let bytes = Package::new(kind, payload).encode()?;
        self.stream.write_all(&bytes).map_err(|e| match e.kind() {
            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut => RtdeError::Timeout("room to send".into()),
            _ => RtdeError::Io(e),
        })
    }

    /// The next package; text messages are kept on the way.
    fn read(&mut self) -> Result<Package, RtdeError> {
        let package = Package::read(&mut self.stream)?;
        if package.kind == kind::TEXT_MESSAGE {
            if self.messages.len() >= MAX_MESSAGES {
                self.messages.drain(..MAX_MESSAGES / 10);
            }
            self.messages.push(TextMessage::decode(&package.payload)?);
        }
        Ok(package)
    }

    /// An error once `what` has been awaited past the timeout since `began`.
    fn give_up_after(&self, began: std::time::Instant, what: &str) -> Result<(), RtdeError> {
        if began.elapsed() > self.timeout {
            return Err(RtdeError::Timeout(format!(
                "{what} (only other packages came for {:.1} s)",
                self.timeout.as_secs_f64()
            )));
        }
        Ok(())
    }

    fn recipe_types(&self, what: &str, names: &[&str], reply: &RecipeReply) -> Result<Vec<DataType>, RtdeError> {
        let marked = |marker: &str| -> Vec<String> {
            names.iter().zip(&reply.types).filter(|(_, t)| *t == marker).map(|(n, _)| n.to_string()).collect()
        };
        let missing = marked("NOT_FOUND");
        if !missing.is_empty() {
            return Err(RtdeError::NotFound(missing));
        }
        let in_use = marked("IN_USE");
        if !in_use.is_empty() {
            return Err(RtdeError::InUse(in_use));
        }
        if reply.id == 0 || reply.types.len() != names.len() {
            return Err(self.refused(what));
        }
        reply
            .types
            .iter()
            .map(|t| DataType::parse(t).ok_or_else(|| RtdeError::Malformed(format!("{what}: unknown type '{t}'"))))
            .collect()
    }

    /// A refusal, with the controller's last error message as its reason.
    fn refused(&self, what: &str) -> RtdeError {
        let reason = self.messages.iter().rev().find(|m| m.level <= MessageLevel::Error).map(|m| m.message.clone());
        RtdeError::Refused { what: what.to_string(), reason }
    }
}

fn accepted(reply: &[u8], what: &str) -> Result<bool, RtdeError> {
    match reply {
        [b] => Ok(*b != 0),
        _ => Err(RtdeError::Malformed(format!("the {what} reply has {} bytes, not 1", reply.len()))),
    }
}

impl PartialOrd for MessageLevel {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        (*self as u8).partial_cmp(&(*other as u8))
    }
}
