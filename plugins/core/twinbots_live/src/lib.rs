//! A live view of a running twin over Foxglove's WebSocket protocol (`foxglove.sdk.v1`, the
//! ws-protocol's `foxglove.websocket.v1` under its current name, through Foxglove's own SDK):
//! open `ws://127.0.0.1:8765` in Foxglove or Lichtblick and the cell moves as it trains
//! (`train --live`), is evaluated, viewed, monitored or deployed. Channels, for each published
//! world's arenas (`arena_<k>` under [`Place::Grid`], a name such as `twin` or `robot` under
//! [`Place::Named`]):
//!
//! - `/tf` (`foxglove.FrameTransforms`, protobuf): `world` → `<arena>` (arenas laid out on a
//!   grid, [`ARENA_SPACING`] apart) and `<arena>` → `<arena>/<link>` for every link;
//! - `/scene` (`foxglove.SceneUpdate`, protobuf): each link's visuals (boxes, cylinders, spheres,
//!   meshes as triangle lists), locked to its frame; sent when a viewer subscribes;
//! - `/<arena>/joint_states` (`sensor_msgs/JointState` as JSON): each movable joint's position,
//!   velocity and effort;
//! - `/<arena>/image` (`foxglove.CompressedImage`, PNG): what a pixel task observed, and
//!   `/<arena>/camera_<i>/image` for each camera device that has an image;
//! - `/episodes` (JSON): each episode as it ends, with its arena, score, length, success and
//!   figures;
//! - whatever a command adds through a [`LiveFrame`] (`monitor`: `/robot/joint_states`,
//!   `/residuals`, `/alarms`).
//!
//! Messages are stamped with the twin's time (control steps × the control period, or the
//! controller's clock).
//!
//! Paced and bounded: by default the streams go out at most once per control period of wall
//! time ([`Pace::RealTime`]), so a viewer watches a twin that trains 1,000 times faster than
//! real time at the twin's own control rate, and the run does not pay for encoding what no
//! screen could show ([`Pace::EveryStep`] sends every control step). Nothing is encoded while no
//! viewer subscribes to a channel, and the server queues at most [`BACKLOG`] messages per
//! viewer, dropping the oldest: a slow viewer misses messages, the twin never waits for it.

mod frame;
mod scene;

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bevy::prelude::*;
use foxglove::messages::{CompressedImage, FrameTransforms, SceneUpdate};
use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{Channel, ChannelBuilder, Context, RawChannel, Schema, WebSocketServer, WebSocketServerHandle};
use twinbots_sim::{Arena, KeepObservedImages, SimClock, SimSettings};
use twinbots_task::Episode;

pub use frame::{LiveFrame, Place};

/// Where the live view listens unless told otherwise: Foxglove's default connection.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";
/// Metres between arenas in the view (they share the origin in the simulation).
pub const ARENA_SPACING: f64 = 3.0;
/// Messages queued per viewer before the oldest are dropped.
pub const BACKLOG: usize = 1024;
/// A mesh visual with more triangles than this is sent as its convex hull.
pub const MAX_SCENE_TRIANGLES: usize = 20_000;

/// A JSON channel's schema: its name and its JSON Schema, which Foxglove shows the fields by.
#[derive(Clone, Copy, Debug)]
pub struct JsonSchema {
    pub name: &'static str,
    pub schema: &'static str,
}

/// `sensor_msgs/JointState`.
pub const JOINT_STATE: JsonSchema = JsonSchema {
    name: "sensor_msgs/JointState",
    schema: r#"{"title":"sensor_msgs/JointState","type":"object","properties":{"header":{"type":"object","properties":{"stamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"frame_id":{"type":"string"}}},"name":{"type":"array","items":{"type":"string"}},"position":{"type":"array","items":{"type":"number"}},"velocity":{"type":"array","items":{"type":"number"}},"effort":{"type":"array","items":{"type":"number"}}}}"#,
};
/// An episode as it ended.
pub const EPISODE: JsonSchema = JsonSchema {
    name: "twinbots/Episode",
    schema: r#"{"title":"twinbots/Episode","type":"object","properties":{"arena":{"type":"integer"},"score":{"type":"number"},"length":{"type":"integer"},"success":{"type":["boolean","null"]},"metrics":{"type":"object"}}}"#,
};

/// How often a live view's streams go out.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Pace {
    /// At most once per control period of wall time: the twin at its own control rate,
    /// however fast it runs (the default).
    #[default]
    RealTime,
    /// Every control step, however fast: a training run's every step, at a cost to it
    /// (docs/benchmarks.md).
    EveryStep,
}

/// The live view's server and its channels; what [`LivePlugin`] and a [`LiveFrame`] publish to.
pub struct LiveServer {
    handle: WebSocketServerHandle,
    context: Arc<Context>,
    tf: Channel<FrameTransforms>,
    scene: Channel<SceneUpdate>,
    /// The JSON channels by topic, made the first time something is published on them.
    json: Mutex<HashMap<String, Arc<RawChannel>>>,
    /// The image channels by topic, made as the JSON channels are.
    images: Mutex<HashMap<String, Arc<Channel<CompressedImage>>>>,
    scene_due: Arc<AtomicBool>,
    pace: Pace,
    /// When the next frame is due (wall clock) under [`Pace::RealTime`].
    next_frame: Mutex<Option<Instant>>,
}

/// Asks for the scene again whenever a viewer subscribes to it (a late viewer sees the cell).
struct SceneOnSubscribe(Arc<AtomicBool>);

impl ServerListener for SceneOnSubscribe {
    fn on_subscribe(&self, _client: Client, channel: ChannelView) {
        if channel.topic() == "/scene" {
            self.0.store(true, Ordering::Relaxed);
        }
    }
}

impl LiveServer {
    /// Starts the server on `addr`. An address beyond loopback is refused unless `insecure`:
    /// the protocol has no authentication, and anyone who can reach it sees the cell (as the
    /// RobotServer refuses to listen beyond loopback without TLS and a token).
    pub fn start(addr: SocketAddr, insecure: bool, pace: Pace) -> anyhow::Result<Arc<LiveServer>> {
        anyhow::ensure!(
            addr.ip().is_loopback() || insecure,
            "--live {addr}: the live view has no authentication; beyond loopback it needs --insecure"
        );
        let context = Context::new();
        let scene_due = Arc::new(AtomicBool::new(true));
        let handle = WebSocketServer::new()
            .name("twinbots")
            .bind(addr.ip().to_string(), addr.port())
            .context(&context)
            .message_backlog_size(BACKLOG)
            .listener(Arc::new(SceneOnSubscribe(scene_due.clone())))
            .start_blocking()
            .map_err(|e| anyhow::anyhow!("--live {addr}: {e}"))?;
        let tf = ChannelBuilder::new("/tf").context(&context).build::<FrameTransforms>();
        let scene = ChannelBuilder::new("/scene").context(&context).build::<SceneUpdate>();
        let server = LiveServer {
            handle,
            context,
            tf,
            scene,
            json: Mutex::new(HashMap::new()),
            images: Mutex::new(HashMap::new()),
            scene_due,
            pace,
            next_frame: Mutex::new(None),
        };
        // Advertised from the start, so a viewer can subscribe before the first episode ends.
        server.advertise("/episodes", EPISODE)?;
        Ok(Arc::new(server))
    }

    /// The port it listens on (the one asked for, or the one given for port 0).
    pub fn port(&self) -> u16 {
        self.handle.port()
    }

    /// How many viewers are connected.
    pub fn viewers(&self) -> usize {
        self.handle.client_count()
    }

    /// A frame of the streams at the twin's time `seconds`, its control period `period`
    /// seconds: `None` while no viewer is connected, or (under [`Pace::RealTime`]) until a
    /// control period of wall time has passed since the last frame.
    pub fn frame(&self, seconds: f64, period: f64) -> Option<LiveFrame<'_>> {
        if self.viewers() == 0 || !self.due(period) {
            return None;
        }
        let scene = self.scene.has_sinks() && self.scene_due.swap(false, Ordering::Relaxed);
        Some(LiveFrame::new(self, seconds, scene))
    }

    /// Whether a frame is due now; under [`Pace::RealTime`] the next is then a period later
    /// (a late frame shortens the next wait, never sends two at once).
    fn due(&self, period: f64) -> bool {
        if self.pace == Pace::EveryStep {
            return true;
        }
        let Ok(mut next) = self.next_frame.lock() else { return false };
        let now = Instant::now();
        if next.is_some_and(|n| now < n) {
            return false;
        }
        let period = Duration::try_from_secs_f64(period).unwrap_or(Duration::ZERO);
        *next = Some(match *next {
            Some(n) if now < n + period => n + period,
            _ => now + period,
        });
        true
    }

    /// Advertises the JSON channel `topic` now, so that a viewer can subscribe to it before
    /// its first message (an alarm that has not been raised yet).
    pub fn advertise(&self, topic: &str, schema: JsonSchema) -> anyhow::Result<()> {
        self.json_channel(topic, schema).map(|_| ())
    }

    /// Publishes `value` on the JSON channel `topic` (made on first use, with `schema`), if a
    /// viewer subscribes to it. Not paced: for what happens rarely (an episode's end, an alarm).
    pub fn publish_json(&self, topic: &str, schema: JsonSchema, value: &serde_json::Value) {
        if let Ok(channel) = self.json_channel(topic, schema)
            && channel.has_sinks()
        {
            channel.log(value.to_string().as_bytes());
        }
    }

    fn json_channel(&self, topic: &str, schema: JsonSchema) -> anyhow::Result<Arc<RawChannel>> {
        let mut channels = self.json.lock().map_err(|_| anyhow::anyhow!("live view poisoned"))?;
        if let Some(channel) = channels.get(topic) {
            return Ok(channel.clone());
        }
        let channel = ChannelBuilder::new(topic)
            .context(&self.context)
            .schema(Schema::new(schema.name, "jsonschema", schema.schema.as_bytes().to_vec()))
            .message_encoding("json")
            .build_raw()
            .map_err(|e| anyhow::anyhow!("live view channel {topic}: {e}"))?;
        channels.insert(topic.to_string(), channel.clone());
        Ok(channel)
    }

    fn image_channel(&self, topic: &str) -> Option<Arc<Channel<CompressedImage>>> {
        let mut channels = self.images.lock().ok()?;
        let channel = channels
            .entry(topic.to_string())
            .or_insert_with(|| Arc::new(ChannelBuilder::new(topic).context(&self.context).build::<CompressedImage>()));
        Some(channel.clone())
    }
}

/// Publishes the app's arenas to a [`LiveServer`] after every control step (paced as the
/// server is), and every episode as it ends.
pub struct LivePlugin(pub Arc<LiveServer>);

#[derive(Resource, Clone)]
struct Live(Arc<LiveServer>);

impl Plugin for LivePlugin {
    fn build(&self, app: &mut App) {
        app.insert_resource(Live(self.0.clone())).insert_resource(KeepObservedImages).add_systems(Last, publish);
    }
}

fn publish(world: &mut World) {
    let Some(live) = world.get_resource::<Live>().map(|l| l.0.clone()) else { return };
    if live.viewers() == 0 {
        return;
    }
    let period = world.get_resource::<SimSettings>().map_or(0.0, |s| s.control_seconds());
    let seconds = world.get_resource::<SimClock>().map_or(0, |c| c.control_steps) as f64 * period;
    if let Some(mut frame) = live.frame(seconds, period) {
        frame.world(world, Place::Grid);
        frame.send();
    }
    let ended: Vec<serde_json::Value> = world
        .query::<(&Arena, &Episode)>()
        .iter(world)
        .filter_map(|(arena, episode)| {
            let s = &episode.ended.as_ref()?.summary;
            Some(serde_json::json!({
                "arena": arena.index, "score": s.score, "length": s.length, "success": s.success, "metrics": s.metrics,
            }))
        })
        .collect();
    for message in &ended {
        live.publish_json("/episodes", EPISODE, message);
    }
}
