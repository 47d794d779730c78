//! One frame of the live view: the transforms, scene, joint states and images of one or more
//! worlds at one instant, sent together.

use bevy::prelude::*;
use foxglove::messages::{
    CompressedImage, FrameTransform, FrameTransforms, Quaternion, SceneUpdate, Timestamp, Vector3,
};
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::{
    Arena, CameraSensor, InArena, Joint, JointState, Link, ObservedImage, SupervisorAccess, physics_in,
};

use crate::{ARENA_SPACING, JOINT_STATE, LiveServer};

/// Where a world's arenas appear in the view, and under what names.
#[derive(Clone, Copy, Debug)]
pub enum Place<'a> {
    /// Every arena, as `arena_<k>`, laid out on a grid [`ARENA_SPACING`] apart.
    Grid,
    /// The world's first arena, as `name`, at the origin.
    Named { name: &'a str },
    /// The world's first arena as a ghost of something else (a robot beside its twin), as
    /// `name` at the origin: its frames, and its visuals in `tint`; what the thing measures
    /// the caller publishes ([`LiveFrame::joint_state`]).
    Ghost { name: &'a str, tint: [f32; 4] },
}

/// What a [`LiveServer::frame`] collects; [`LiveFrame::send`] sends the transforms and scene
/// (joint states, images and JSON go out as they are added).
pub struct LiveFrame<'a> {
    server: &'a LiveServer,
    stamp: Timestamp,
    transforms: Vec<FrameTransform>,
    /// The scene's entities, when the scene goes out with this frame.
    scene: Option<Vec<foxglove::messages::SceneEntity>>,
}

impl<'a> LiveFrame<'a> {
    pub(crate) fn new(server: &'a LiveServer, seconds: f64, scene: bool) -> Self {
        let seconds = seconds.max(0.0);
        let stamp = Timestamp::new(seconds.trunc() as u32, ((seconds.fract() * 1e9).round() as u32).min(999_999_999));
        Self { server, stamp, transforms: Vec::new(), scene: scene.then(Vec::new) }
    }

    /// The frame's time.
    pub fn stamp(&self) -> Timestamp {
        self.stamp
    }

    /// A world's arenas, placed by `place`: their frames and links (from the physics: in an app
    /// without the Supervisor's privilege, a pattern-3 robot, the joints only), joint states,
    /// images, and the scene when it is due.
    pub fn world(&mut self, world: &mut World, place: Place) {
        let mut arenas: Vec<(usize, Entity)> =
            world.query::<(Entity, &Arena)>().iter(world).map(|(e, a)| (a.index, e)).collect();
        arenas.sort_unstable();
        let (ghost, tint) = match place {
            Place::Grid | Place::Named { .. } => (false, None),
            Place::Ghost { tint, .. } => (true, Some(tint)),
        };
        if !matches!(place, Place::Grid) {
            arenas.truncate(1);
        }
        let named: Vec<(String, Vector3, Entity)> = arenas
            .iter()
            .map(|&(index, arena)| match place {
                Place::Grid => (format!("arena_{index}"), grid_origin(index), arena),
                Place::Named { name } | Place::Ghost { name, .. } => {
                    (name.to_string(), Vector3 { x: 0.0, y: 0.0, z: 0.0 }, arena)
                }
            })
            .collect();
        for (name, origin, arena) in &named {
            self.transforms.push(FrameTransform {
                timestamp: Some(self.stamp),
                parent_frame_id: "world".into(),
                child_frame_id: name.clone(),
                translation: Some(*origin),
                rotation: Some(Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }),
            });
            self.links(world, name, *arena);
            if !ghost {
                self.joint_states(world, name, *arena);
                self.images(world, name, *arena);
            }
        }
        if let Some(entities) = self.scene.as_mut() {
            let names: Vec<(Entity, &str)> = named.iter().map(|(n, _, a)| (*a, n.as_str())).collect();
            entities.extend(crate::scene::entities(world, &names, self.stamp, tint));
        }
    }

    fn links(&mut self, world: &mut World, name: &str, arena: Entity) {
        if world.get_resource::<SupervisorAccess>().is_none() {
            return;
        }
        let links: Vec<Link> = world
            .query::<(&Link, &InArena)>()
            .iter(world)
            .filter(|(_, a)| a.0 == arena)
            .map(|(l, _)| l.clone())
            .collect();
        let Some(physics) = physics_in(world, arena) else { return };
        for link in &links {
            if let Some(body) = physics.bodies.get(link.body) {
                let pose = *body.position() * link.offset;
                self.transforms.push(transform(name.to_string(), format!("{name}/{}", link.name), &pose, self.stamp));
            }
        }
    }

    fn joint_states(&self, world: &mut World, name: &str, arena: Entity) {
        let Some(channel) = self.joint_state_channel(name) else { return };
        let mut joints: Vec<(String, f64, f64, f64)> = world
            .query::<(&Joint, &JointState, &InArena)>()
            .iter(world)
            .filter(|(_, _, a)| a.0 == arena)
            .map(|(j, s, _)| (j.name.clone(), s.position as f64, s.velocity as f64, s.effort as f64))
            .collect();
        joints.sort_by(|a, b| a.0.cmp(&b.0));
        channel.log(joint_state_json(self.stamp, &joints).to_string().as_bytes());
    }

    /// Publishes a joint state that is no world's (a robot's, as its controller reported it)
    /// on `/<name>/joint_states`, joints in the order given.
    pub fn joint_state(&self, name: &str, joints: &[(String, f64, f64, f64)]) {
        if let Some(channel) = self.joint_state_channel(name) {
            channel.log(joint_state_json(self.stamp, joints).to_string().as_bytes());
        }
    }

    /// `/<name>/joint_states`, if a viewer subscribes to it.
    fn joint_state_channel(&self, name: &str) -> Option<std::sync::Arc<foxglove::RawChannel>> {
        let channel = self.server.json_channel(&format!("/{name}/joint_states"), JOINT_STATE).ok()?;
        channel.has_sinks().then_some(channel)
    }

    /// Publishes `value` on a JSON channel with this frame (paced as the frame is).
    pub fn json(&self, topic: &str, schema: crate::JsonSchema, value: &serde_json::Value) {
        self.server.publish_json(topic, schema, value);
    }

    fn images(&self, world: &mut World, name: &str, arena: Entity) {
        if let Some(image) = world.get::<ObservedImage>(arena) {
            self.image(&format!("/{name}/image"), name, image.width, image.height, &image.rgb);
        }
        let mut cameras: Vec<(Entity, u32, u32, Vec<u8>)> = world
            .query::<(Entity, &CameraSensor, &InArena)>()
            .iter(world)
            .filter(|(_, c, a)| a.0 == arena && !c.image.is_empty())
            .map(|(e, c, _)| (e, c.width, c.height, c.image.clone()))
            .collect();
        cameras.sort_by_key(|c| c.0);
        for (i, (_, width, height, rgb)) in cameras.iter().enumerate() {
            self.image(&format!("/{name}/camera_{i}/image"), name, *width, *height, rgb);
        }
    }

    /// A PNG of `rgb` on `topic`, if a viewer subscribes to it.
    fn image(&self, topic: &str, frame_id: &str, width: u32, height: u32, rgb: &[u8]) {
        use image::ImageEncoder;
        let Some(channel) = self.server.image_channel(topic) else { return };
        if !channel.has_sinks() || rgb.len() != (width * height * 3) as usize {
            return;
        }
        let mut png = Vec::new();
        let encoded = image::codecs::png::PngEncoder::new(&mut png).write_image(
            rgb,
            width,
            height,
            image::ExtendedColorType::Rgb8,
        );
        if encoded.is_ok() {
            channel.log(&CompressedImage {
                timestamp: Some(self.stamp),
                frame_id: frame_id.to_string(),
                data: png.into(),
                format: "png".into(),
            });
        }
    }

    /// Sends the transforms, and the scene if it is due.
    pub fn send(self) {
        if self.server.tf.has_sinks() {
            self.server.tf.log(&FrameTransforms { transforms: self.transforms });
        }
        if let Some(entities) = self.scene {
            self.server.scene.log(&SceneUpdate { deletions: Vec::new(), entities });
        }
    }
}

fn joint_state_json(stamp: Timestamp, joints: &[(String, f64, f64, f64)]) -> serde_json::Value {
    serde_json::json!({
        "header": {"stamp": {"sec": stamp.sec(), "nsec": stamp.nsec()}, "frame_id": ""},
        "name": joints.iter().map(|j| j.0.clone()).collect::<Vec<_>>(),
        "position": joints.iter().map(|j| j.1).collect::<Vec<_>>(),
        "velocity": joints.iter().map(|j| j.2).collect::<Vec<_>>(),
        "effort": joints.iter().map(|j| j.3).collect::<Vec<_>>(),
    })
}

/// Where arena `index` sits in the view.
fn grid_origin(index: usize) -> Vector3 {
    let columns = 4;
    Vector3 { x: (index % columns) as f64 * ARENA_SPACING, y: (index / columns) as f64 * ARENA_SPACING, z: 0.0 }
}

fn transform(parent: String, child: String, pose: &Pose, stamp: Timestamp) -> FrameTransform {
    let (t, r) = (pose.translation, pose.rotation);
    FrameTransform {
        timestamp: Some(stamp),
        parent_frame_id: parent,
        child_frame_id: child,
        translation: Some(Vector3 { x: t.x as f64, y: t.y as f64, z: t.z as f64 }),
        rotation: Some(Quaternion { x: r.x as f64, y: r.y as f64, z: r.z as f64, w: r.w as f64 }),
    }
}
