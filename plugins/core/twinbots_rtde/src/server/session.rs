//! One RTDE client's session with the stand-in controller: the setup it asks for (protocol
//! version, controller version, recipes, start and pause), the inputs it sets, and the
//! streamer that sends its output recipe at its frequency.

use std::io::Write;
use std::net::{Shutdown, SocketAddr, TcpStream};
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_channel::{Receiver, Sender};

use super::{OutputState, SessionHandle, Shared, lock, push_event};
use crate::package::{MessageLevel, Package, RecipeReply, TextMessage, kind, names};
use crate::types::Value;
use crate::variables::{input_index, inputs, output_index, outputs};
use crate::{MAX_FREQUENCY, PROTOCOL_VERSION, RtdeError};

/// One client's conversation.
pub(super) struct Session {
    id: u64,
    peer: SocketAddr,
    shared: Arc<Shared>,
    writer: Arc<Mutex<TcpStream>>,
    version_agreed: bool,
    next_recipe: u8,
    output: Option<Arc<Recipe>>,
    input_recipes: Vec<Recipe>,
    streamer: Option<JoinHandle<()>>,
}

/// A recipe: variable indices (into [`outputs`] or [`inputs`]) and, for outputs, the frequency.
#[derive(Debug)]
struct Recipe {
    id: u8,
    variables: Vec<usize>,
    frequency: f64,
}

impl Session {
    pub(super) fn run(stream: TcpStream, peer: SocketAddr, shared: Arc<Shared>) {
        let _ = stream.set_nonblocking(false);
        let _ = stream.set_nodelay(true);
        // A client that stops reading must not stall the controller's streamers for long.
        let _ = stream.set_write_timeout(Some(Duration::from_secs(1)));
        let Ok(writer) = stream.try_clone() else {
            shared.active.fetch_sub(1, Ordering::SeqCst);
            return;
        };
        let id = shared.next_session.fetch_add(1, Ordering::SeqCst);
        let writer = Arc::new(Mutex::new(writer));
        lock(&shared.sessions).push(SessionHandle { id, writer: writer.clone(), stream: None });
        push_event(&shared, format!("{peer}: connected"));
        let mut session = Session {
            id,
            peer,
            shared,
            writer,
            version_agreed: false,
            next_recipe: 1,
            output: None,
            input_recipes: Vec::new(),
            streamer: None,
        };
        let mut reader = stream;
        // Until it starts its stream a client must speak within the idle limit; a started one
        // may only listen.
        let idle = session.shared.limits.idle;
        let mut listening = false;
        let _ = reader.set_read_timeout(Some(idle));
        let end = loop {
            if session.shared.stop.load(Ordering::SeqCst) {
                break "the controller stopped".to_string();
            }
            if session.streamer.is_some() != listening {
                listening = session.streamer.is_some();
                let _ = reader.set_read_timeout(if listening { None } else { Some(idle) });
            }
            match Package::read(&mut reader) {
                Ok(package) => {
                    if let Err(e) = session.handle(package) {
                        break e;
                    }
                }
                Err(RtdeError::Closed) => break "disconnected".into(),
                Err(RtdeError::Timeout(_)) => {
                    break format!("silent for {:.1} s before starting its stream", idle.as_secs_f64());
                }
                Err(e @ (RtdeError::Malformed(_) | RtdeError::Truncated(_))) => {
                    session.error(&format!("{e}; closing the connection"));
                    break e.to_string();
                }
                Err(e) => break e.to_string(),
            }
        };
        session.close(&end);
    }

    /// Answers one package; an `Err` ends the session.
    fn handle(&mut self, package: Package) -> Result<(), String> {
        let p = &package.payload;
        match package.kind {
            kind::REQUEST_PROTOCOL_VERSION => {
                let ok = p.len() == 2 && u16::from_be_bytes([p[0], p[1]]) == PROTOCOL_VERSION;
                if !ok {
                    let asked = if p.len() == 2 {
                        u16::from_be_bytes([p[0], p[1]]).to_string()
                    } else {
                        format!("a {}-byte payload", p.len())
                    };
                    self.event(format!("refused protocol version {asked}: this stand-in speaks version 2 only"));
                }
                self.version_agreed |= ok;
                self.reply(kind::REQUEST_PROTOCOL_VERSION, vec![ok as u8])
            }
            kind::GET_URCONTROL_VERSION => self.reply(kind::GET_URCONTROL_VERSION, self.shared.info.version.encode()),
            kind::TEXT_MESSAGE => {
                match TextMessage::decode(p) {
                    Ok(m) => self.event(format!("message ({:?}) from {}: {}", m.level, m.source, m.message)),
                    Err(e) => self.error(&e.to_string()),
                }
                Ok(())
            }
            kind::SETUP_OUTPUTS => self.setup_outputs(p),
            kind::SETUP_INPUTS => self.setup_inputs(p),
            kind::START => self.start(),
            kind::PAUSE => {
                self.set_stream(None);
                self.reply(kind::PAUSE, vec![1])
            }
            kind::DATA_PACKAGE => {
                if let Err(e) = self.apply_inputs(p) {
                    self.error(&e);
                }
                Ok(())
            }
            other => {
                self.error(&format!("unknown package type {other} ('{}'), ignored", other as char));
                Ok(())
            }
        }
    }

    /// Refuses a recipe setup (`kind`): an error message saying why, and a reply of id 0.
    fn refuse_recipe(&self, kind: u8, why: &str) -> Result<(), String> {
        let what = if kind == kind::SETUP_OUTPUTS { "output" } else { "input" };
        self.error(&format!("{what} recipe refused: {why}"));
        self.reply(kind, RecipeReply { id: 0, types: Vec::new() }.encode())
    }

    /// Why this session may not set up a recipe now, if it may not.
    fn setup_blocked(&self) -> Option<&'static str> {
        if !self.version_agreed {
            Some("negotiate protocol version 2 first (RTDE_REQUEST_PROTOCOL_VERSION)")
        } else if self.streaming() {
            Some("the session is started: pause first")
        } else {
            None
        }
    }

    fn setup_outputs(&mut self, p: &[u8]) -> Result<(), String> {
        if let Some(why) = self.setup_blocked() {
            return self.refuse_recipe(kind::SETUP_OUTPUTS, why);
        }
        if p.len() < 8 {
            return self.refuse_recipe(
                kind::SETUP_OUTPUTS,
                &format!("{} bytes: a frequency (8) and variable names are expected", p.len()),
            );
        }
        let frequency = f64::from_be_bytes(p[..8].try_into().unwrap());
        if !(frequency > 0.0 && frequency <= MAX_FREQUENCY) {
            return self
                .refuse_recipe(kind::SETUP_OUTPUTS, &format!("frequency {frequency} Hz outside (0, {MAX_FREQUENCY}]"));
        }
        let wanted = match names(&p[8..]) {
            Ok(n) => n,
            Err(e) => return self.refuse_recipe(kind::SETUP_OUTPUTS, &e.to_string()),
        };
        let found: Vec<Option<usize>> = wanted.iter().map(|n| output_index(n)).collect();
        let types =
            found.iter().map(|f| f.map_or("NOT_FOUND", |i| outputs()[i].data_type.name()).to_string()).collect();
        if found.iter().any(Option::is_none) {
            let missing: Vec<&String> =
                wanted.iter().zip(&found).filter(|(_, f)| f.is_none()).map(|(n, _)| n).collect();
            self.event(format!("output recipe: no variable {missing:?}"));
            return self.reply(kind::SETUP_OUTPUTS, RecipeReply { id: 0, types }.encode());
        }
        let id = self.take_recipe_id();
        self.output = Some(Arc::new(Recipe { id, variables: found.into_iter().flatten().collect(), frequency }));
        self.reply(kind::SETUP_OUTPUTS, RecipeReply { id, types }.encode())
    }

    fn setup_inputs(&mut self, p: &[u8]) -> Result<(), String> {
        if let Some(why) = self.setup_blocked() {
            return self.refuse_recipe(kind::SETUP_INPUTS, why);
        }
        let wanted = match names(p) {
            Ok(n) => n,
            Err(e) => return self.refuse_recipe(kind::SETUP_INPUTS, &e.to_string()),
        };
        let found: Vec<Option<usize>> = wanted.iter().map(|n| input_index(n)).collect();
        let (types, ok) = {
            let mut state = lock(&self.shared.inputs);
            let types: Vec<String> = found
                .iter()
                .map(|f| match f {
                    None => "NOT_FOUND".to_string(),
                    Some(i) if state.owners[*i] != 0 && state.owners[*i] != self.id => "IN_USE".to_string(),
                    Some(i) => inputs()[*i].data_type.name().to_string(),
                })
                .collect();
            let ok = types.iter().all(|t| t != "NOT_FOUND" && t != "IN_USE");
            if ok {
                found.iter().flatten().for_each(|&i| state.owners[i] = self.id);
            }
            (types, ok)
        };
        if !ok {
            self.event(format!("input recipe {wanted:?} refused: {types:?}"));
            return self.reply(kind::SETUP_INPUTS, RecipeReply { id: 0, types }.encode());
        }
        let id = self.take_recipe_id();
        self.input_recipes.push(Recipe { id, variables: found.into_iter().flatten().collect(), frequency: 0.0 });
        self.reply(kind::SETUP_INPUTS, RecipeReply { id, types }.encode())
    }

    fn start(&mut self) -> Result<(), String> {
        let Some(recipe) = self.output.clone() else {
            self.error("start refused: no output recipe (RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS first)");
            return self.reply(kind::START, vec![0]);
        };
        if !self.streaming() {
            // Room for a few cycles (a scheduling hiccup loses nothing); a streamer further behind
            // misses packages, as a busy controller skips them.
            let (tx, rx) = crossbeam_channel::bounded(4);
            let writer = self.writer.clone();
            let step = recipe.frequency / self.shared.info.cycle_hz;
            if let Some(old) = self.streamer.take() {
                let _ = old.join();
            }
            self.streamer = std::thread::Builder::new()
                .name(format!("rtde-out-{}", self.peer))
                .spawn(move || stream(rx, writer, recipe, step))
                .ok();
            self.set_stream(Some(tx));
        }
        self.reply(kind::START, vec![1])
    }

    fn apply_inputs(&mut self, p: &[u8]) -> Result<(), String> {
        let (&id, rest) = p.split_first().ok_or("an empty data package")?;
        let recipe = self.input_recipes.iter().find(|r| r.id == id).ok_or_else(|| {
            format!("a data package for recipe {id}, which is no input recipe of this client; ignored")
        })?;
        if !self.streaming() {
            return Err("inputs before RTDE_CONTROL_PACKAGE_START are ignored".into());
        }
        let types = recipe.variables.iter().map(|&i| inputs()[i].data_type);
        let values = Value::decode_all(types, rest).map_err(|e| format!("input recipe {id}: {e}; ignored"))?;
        let mut state = lock(&self.shared.inputs);
        for (&i, v) in recipe.variables.iter().zip(values) {
            state.values[i] = v;
        }
        Ok(())
    }

    fn streaming(&self) -> bool {
        lock(&self.shared.sessions).iter().any(|s| s.id == self.id && s.stream.is_some())
    }

    fn set_stream(&self, tx: Option<Sender<Arc<OutputState>>>) {
        if let Some(s) = lock(&self.shared.sessions).iter_mut().find(|s| s.id == self.id) {
            s.stream = tx;
        }
    }

    fn take_recipe_id(&mut self) -> u8 {
        let id = self.next_recipe;
        self.next_recipe = self.next_recipe.wrapping_add(1).max(1);
        id
    }

    fn reply(&self, kind: u8, payload: Vec<u8>) -> Result<(), String> {
        let bytes = Package::new(kind, payload).encode().map_err(|e| e.to_string())?;
        lock(&self.writer).write_all(&bytes).map_err(|e| format!("cannot reply: {e}"))
    }

    /// An error text message to the client, and an event.
    fn error(&self, message: &str) {
        self.event(message.to_string());
        let text = TextMessage {
            level: MessageLevel::Error,
            message: message.to_string(),
            source: self.shared.info.source.clone(),
        };
        let _ = self.reply(kind::TEXT_MESSAGE, text.encode());
    }

    fn event(&self, what: String) {
        push_event(&self.shared, format!("{}: {what}", self.peer));
    }

    /// Ends the session: its inputs are free again, its streamer stops.
    fn close(mut self, why: &str) {
        self.event(format!("closed ({why})"));
        self.shared.active.fetch_sub(1, Ordering::SeqCst);
        lock(&self.shared.sessions).retain(|s| s.id != self.id);
        let mut state = lock(&self.shared.inputs);
        for owner in state.owners.iter_mut().filter(|o| **o == self.id) {
            *owner = 0;
        }
        drop(state);
        let _ = lock(&self.writer).shutdown(Shutdown::Both);
        if let Some(streamer) = self.streamer.take() {
            let _ = streamer.join();
        }
    }
}

/// Sends `recipe`'s outputs of every `1 / step`-th cycle until the session pauses or ends.
fn stream(rx: Receiver<Arc<OutputState>>, writer: Arc<Mutex<TcpStream>>, recipe: Arc<Recipe>, step: f64) {
    // Due at the first cycle, then whenever the accumulated fraction reaches a whole package
    // (within rounding: 100 Hz is 0.2 of a cycle, which sums to 0.999…).
    let mut due = 1.0 - step;
    while let Ok(state) = rx.recv() {
        due += step;
        if due < 1.0 - 1e-9 {
            continue;
        }
        due -= 1.0;
        let mut payload = vec![recipe.id];
        for &i in &recipe.variables {
            state.0[i].encode(&mut payload);
        }
        let Ok(bytes) = Package::new(kind::DATA_PACKAGE, payload).encode() else { return };
        if lock(&writer).write_all(&bytes).is_err() {
            return;
        }
    }
}
