//! A live view of a running twin over Foxglove's WebSocket protocol (`foxglove.sdk.v1`, the
//! ws-protocol's `foxglove.websocket.v1` under its current name, through Foxglove's own SDK):
//! open `ws://127.0.0.1:8765` in Foxglove or Lichtblick and the cell moves as it trains
//! (`train --live`). Channels:
//!
//! - `/tf` (`foxglove.FrameTransforms`, protobuf): every control step, `world` → `arena_<k>` (the
//!   arenas laid out on a grid, [`ARENA_SPACING`] apart) and `arena_<k>` → `arena_<k>/<link>` for
//!   every link;
//! - `/scene` (`foxglove.SceneUpdate`, protobuf): each link's visuals (boxes, cylinders, spheres,
//!   meshes as triangle lists), locked to its frame; sent when a viewer subscribes;
//! - `/arena_<k>/joint_states` (`sensor_msgs/JointState` as JSON): every control step, each
//!   movable joint's position, velocity and effort;
//! - `/episodes` (JSON): each episode as it ends, with its arena, score, length, success and
//!   figures.
//!
//! Messages are stamped with the simulated time (control steps × the control period), so one
//! control step apart on every channel.
//!
//! Bounded: nothing is encoded while no viewer subscribes to a channel, and the server queues at
//! most [`BACKLOG`] messages per viewer, dropping the oldest: a slow viewer misses messages,
//! the twin never waits for it.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use bevy::prelude::*;
use foxglove::messages::{
    Color, CubePrimitive, CylinderPrimitive, FrameTransform, FrameTransforms, Point3, Pose as FgPose, Quaternion,
    SceneEntity, SceneUpdate, SpherePrimitive, Timestamp, TriangleListPrimitive, Vector3,
};
use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{Channel, ChannelBuilder, Context, RawChannel, Schema, WebSocketServer, WebSocketServerHandle};
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::Shape;
use twinbots_sim::{
    Arena, InArena, Joint, JointState, Link, SimClock, SimSettings, SupervisorAccess, Visuals, physics_in,
};
use twinbots_task::Episode;

/// Where the live view listens unless told otherwise: Foxglove's default connection.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";
/// Metres between arenas in the view (they share the origin in the simulation).
pub const ARENA_SPACING: f64 = 3.0;
/// Messages queued per viewer before the oldest are dropped.
pub const BACKLOG: usize = 1024;
/// A mesh visual with more triangles than this is sent as its convex hull.
pub const MAX_SCENE_TRIANGLES: usize = 20_000;

/// `sensor_msgs/JointState` as JSON: the schema Foxglove shows its fields by.
const JOINT_STATE_SCHEMA: &str = r#"{"title":"sensor_msgs/JointState","type":"object","properties":{"header":{"type":"object","properties":{"stamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"frame_id":{"type":"string"}}},"name":{"type":"array","items":{"type":"string"}},"position":{"type":"array","items":{"type":"number"}},"velocity":{"type":"array","items":{"type":"number"}},"effort":{"type":"array","items":{"type":"number"}}}}"#;
const EPISODE_SCHEMA: &str = r#"{"title":"twinbots/Episode","type":"object","properties":{"arena":{"type":"integer"},"score":{"type":"number"},"length":{"type":"integer"},"success":{"type":["boolean","null"]},"metrics":{"type":"object"}}}"#;

/// The live view's server and its channels; what [`LivePlugin`] publishes to.
pub struct LiveServer {
    handle: WebSocketServerHandle,
    context: Arc<Context>,
    tf: Channel<FrameTransforms>,
    scene: Channel<SceneUpdate>,
    episodes: Arc<RawChannel>,
    /// `/arena_<k>/joint_states`, made for each arena the first time it publishes.
    joint_states: std::sync::Mutex<Vec<Arc<RawChannel>>>,
    scene_due: Arc<AtomicBool>,
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
    pub fn start(addr: SocketAddr, insecure: bool) -> anyhow::Result<Arc<LiveServer>> {
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
        let episodes = json_channel(&context, "/episodes", "twinbots/Episode", EPISODE_SCHEMA)?;
        Ok(Arc::new(LiveServer {
            handle,
            context,
            tf,
            scene,
            episodes,
            joint_states: std::sync::Mutex::new(Vec::new()),
            scene_due,
        }))
    }

    /// The port it listens on (the one asked for, or the one given for port 0).
    pub fn port(&self) -> u16 {
        self.handle.port()
    }

    /// How many viewers are connected.
    pub fn viewers(&self) -> usize {
        self.handle.client_count()
    }

    fn joint_state_channel(&self, arena: usize) -> anyhow::Result<Arc<RawChannel>> {
        let mut channels = self.joint_states.lock().map_err(|_| anyhow::anyhow!("live view poisoned"))?;
        while channels.len() <= arena {
            let topic = format!("/arena_{}/joint_states", channels.len());
            channels.push(json_channel(&self.context, &topic, "sensor_msgs/JointState", JOINT_STATE_SCHEMA)?);
        }
        Ok(channels[arena].clone())
    }
}

fn json_channel(context: &Arc<Context>, topic: &str, name: &str, schema: &str) -> anyhow::Result<Arc<RawChannel>> {
    ChannelBuilder::new(topic)
        .context(context)
        .schema(Schema::new(name, "jsonschema", schema.as_bytes().to_vec()))
        .message_encoding("json")
        .build_raw()
        .map_err(|e| anyhow::anyhow!("live view channel {topic}: {e}"))
}

/// Publishes the app's arenas to a [`LiveServer`] after every control step.
pub struct LivePlugin(pub Arc<LiveServer>);

#[derive(Resource, Clone)]
struct Live(Arc<LiveServer>);

impl Plugin for LivePlugin {
    fn build(&self, app: &mut App) {
        app.insert_resource(Live(self.0.clone())).add_systems(Last, publish);
    }
}

/// The arenas in index order, each with its index.
fn arenas(world: &mut World) -> Vec<(usize, Entity)> {
    let mut arenas: Vec<(usize, Entity)> =
        world.query::<(Entity, &Arena)>().iter(world).map(|(e, a)| (a.index, e)).collect();
    arenas.sort_unstable();
    arenas
}

fn publish(world: &mut World) {
    let Some(live) = world.get_resource::<Live>().map(|l| l.0.clone()) else { return };
    if live.viewers() == 0 {
        return;
    }
    let arenas = arenas(world);
    // Simulated time: consecutive messages of a channel are one control step apart, and a
    // viewer sees the twin's own clock (the SDK stamps each message's log time by the wall).
    let seconds = world.get_resource::<SimClock>().map_or(0, |c| c.control_steps) as f64
        * world.get_resource::<SimSettings>().map_or(0.0, |s| s.control_seconds());
    let stamp = Timestamp::new(seconds.trunc() as u32, ((seconds.fract() * 1e9).round() as u32).min(999_999_999));
    if live.tf.has_sinks() {
        live.tf.log(&transforms(world, &arenas, stamp));
    }
    if live.scene.has_sinks() && live.scene_due.swap(false, Ordering::Relaxed) {
        live.scene.log(&scene(world, &arenas, stamp));
    }
    for (index, arena) in &arenas {
        let Ok(channel) = live.joint_state_channel(*index) else { continue };
        if channel.has_sinks() {
            channel.log(joint_states(world, *arena, stamp).to_string().as_bytes());
        }
    }
    if live.episodes.has_sinks() {
        for (index, arena) in &arenas {
            if let Some(ended) = world.get::<Episode>(*arena).and_then(|e| e.ended.as_ref()) {
                let s = &ended.summary;
                let message = serde_json::json!({
                    "arena": index, "score": s.score, "length": s.length, "success": s.success, "metrics": s.metrics,
                });
                live.episodes.log(message.to_string().as_bytes());
            }
        }
    }
}

/// Where arena `index` sits in the view.
fn arena_origin(index: usize) -> Vector3 {
    let columns = 4;
    Vector3 { x: (index % columns) as f64 * ARENA_SPACING, y: (index / columns) as f64 * ARENA_SPACING, z: 0.0 }
}

fn frame(parent: String, child: String, pose: &Pose, stamp: Timestamp) -> FrameTransform {
    let (t, r) = (pose.translation, pose.rotation);
    FrameTransform {
        timestamp: Some(stamp),
        parent_frame_id: parent,
        child_frame_id: child,
        translation: Some(Vector3 { x: t.x as f64, y: t.y as f64, z: t.z as f64 }),
        rotation: Some(Quaternion { x: r.x as f64, y: r.y as f64, z: r.z as f64, w: r.w as f64 }),
    }
}

/// Every arena's frame in the world and every link's in its arena, from the physics (the
/// Supervisor's view: an app without it, a pattern-3 robot, shows its joints only).
fn transforms(world: &mut World, arenas: &[(usize, Entity)], stamp: Timestamp) -> FrameTransforms {
    let mut out = Vec::new();
    for &(index, _) in arenas {
        out.push(FrameTransform {
            timestamp: Some(stamp),
            parent_frame_id: "world".into(),
            child_frame_id: format!("arena_{index}"),
            translation: Some(arena_origin(index)),
            rotation: Some(Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }),
        });
    }
    if world.get_resource::<SupervisorAccess>().is_none() {
        return FrameTransforms { transforms: out };
    }
    let links: Vec<(Entity, Link)> =
        world.query::<(&Link, &InArena)>().iter(world).map(|(link, in_arena)| (in_arena.0, link.clone())).collect();
    for &(index, arena) in arenas {
        let Some(physics) = physics_in(world, arena) else { continue };
        for (_, link) in links.iter().filter(|(a, _)| *a == arena) {
            if let Some(body) = physics.bodies.get(link.body) {
                let pose = *body.position() * link.offset;
                out.push(frame(format!("arena_{index}"), format!("arena_{index}/{}", link.name), &pose, stamp));
            }
        }
    }
    FrameTransforms { transforms: out }
}

fn joint_states(world: &mut World, arena: Entity, stamp: Timestamp) -> serde_json::Value {
    let mut joints: Vec<(String, f32, f32, f32)> = world
        .query::<(&Joint, &JointState, &InArena)>()
        .iter(world)
        .filter(|(_, _, a)| a.0 == arena)
        .map(|(j, s, _)| (j.name.clone(), s.position, s.velocity, s.effort))
        .collect();
    joints.sort_by(|a, b| a.0.cmp(&b.0));
    serde_json::json!({
        "header": {"stamp": {"sec": stamp.sec(), "nsec": stamp.nsec()}, "frame_id": ""},
        "name": joints.iter().map(|j| j.0.clone()).collect::<Vec<_>>(),
        "position": joints.iter().map(|j| j.1).collect::<Vec<_>>(),
        "velocity": joints.iter().map(|j| j.2).collect::<Vec<_>>(),
        "effort": joints.iter().map(|j| j.3).collect::<Vec<_>>(),
    })
}

fn fg_pose(pose: &Pose) -> FgPose {
    let (t, r) = (pose.translation, pose.rotation);
    FgPose {
        position: Some(Vector3 { x: t.x as f64, y: t.y as f64, z: t.z as f64 }),
        orientation: Some(Quaternion { x: r.x as f64, y: r.y as f64, z: r.z as f64, w: r.w as f64 }),
    }
}

/// Every link's visuals, in its own frame (locked to it, so `/tf` moves them).
fn scene(world: &mut World, arenas: &[(usize, Entity)], stamp: Timestamp) -> SceneUpdate {
    let index_of = |arena: Entity| arenas.iter().find(|(_, a)| *a == arena).map(|(i, _)| *i);
    let mut entities = Vec::new();
    for (link, visuals, in_arena) in world.query::<(&Link, &Visuals, &InArena)>().iter(world) {
        let Some(index) = index_of(in_arena.0) else { continue };
        let frame_id = format!("arena_{index}/{}", link.name);
        let mut entity = SceneEntity {
            timestamp: Some(stamp),
            frame_id: frame_id.clone(),
            id: frame_id,
            frame_locked: true,
            ..Default::default()
        };
        for visual in &visuals.0 {
            let [r, g, b, a] = visual.rgba.map(f64::from);
            let color = Some(Color { r, g, b, a });
            let pose = Some(fg_pose(&visual.geometry.origin));
            match &visual.geometry.shape {
                Shape::Box { half_extents: h } => entity.cubes.push(CubePrimitive {
                    pose,
                    size: Some(Vector3 { x: 2.0 * h.x as f64, y: 2.0 * h.y as f64, z: 2.0 * h.z as f64 }),
                    color,
                }),
                Shape::Cylinder { radius, length } => entity.cylinders.push(CylinderPrimitive {
                    pose,
                    size: Some(Vector3 { x: 2.0 * *radius as f64, y: 2.0 * *radius as f64, z: *length as f64 }),
                    bottom_scale: 1.0,
                    top_scale: 1.0,
                    color,
                }),
                Shape::Sphere { radius } => {
                    let d = 2.0 * *radius as f64;
                    entity.spheres.push(SpherePrimitive { pose, size: Some(Vector3 { x: d, y: d, z: d }), color })
                }
                Shape::Mesh(mesh) => {
                    let points = mesh_points(&mesh.vertices, &mesh.triangles);
                    entity.triangles.push(TriangleListPrimitive { pose, points, color, ..Default::default() });
                }
            }
        }
        entities.push(entity);
    }
    SceneUpdate { deletions: Vec::new(), entities }
}

/// A mesh's triangles as a flat point list (three per triangle); one over
/// [`MAX_SCENE_TRIANGLES`] as its convex hull's.
fn mesh_points(vertices: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Point3> {
    let point = |v: Vec3| Point3 { x: v.x as f64, y: v.y as f64, z: v.z as f64 };
    if triangles.len() <= MAX_SCENE_TRIANGLES {
        return triangles.iter().flat_map(|t| t.map(|i| point(vertices[i as usize]))).collect();
    }
    let points: Vec<_> = vertices.iter().map(|v| twinbots_sim::rapier::math::Vector::new(v.x, v.y, v.z)).collect();
    let (hull, faces) = twinbots_sim::rapier::parry::transformation::convex_hull(&points);
    faces
        .iter()
        .flat_map(|f| f.map(|i| point(Vec3::new(hull[i as usize].x, hull[i as usize].y, hull[i as usize].z))))
        .collect()
}
