//! Pixel observations: the task observes a camera image of its arena instead of its state
//! (`[pixels]`), as Gymnasium's `PixelObservationWrapper` and the pixel envs of ManiSkill and
//! Isaac Lab do. Every control step all arenas render in one frame, each in its own tile
//! ([`Renderer::tiled`]), read back once; an arena that resets renders its first frame at once,
//! so the step that ends an episode has its final frame and the next episode's first one.
//! With `more_cameras`, each arena is seen through each camera at the same instant, and the
//! cameras' images lie side by side along the width, so that a CNN's filters read every view
//! alike (side by side along the channels, pixels of different views would share filters
//! without showing the same thing; measured in docs/pixels.md).
//!
//! The task's terms still run on its state (rewards, terminations, success); only what the
//! learner sees changes. The observation space becomes [`Space::Image`]: `height ×
//! width·cameras × 3·frames` whole numbers in [0, 255], the last `frames` images stacked along
//! the channels (oldest first), a new episode's first image repeated (gym's `FrameStack`).
//! With `state`, the robot's own readings the task observes follow the image
//! ([`Space::ImageAndState`]: image plus proprioception, as robosuite and ManiSkill give a
//! camera policy); a target is then known only from the image.

use std::collections::{HashMap, VecDeque};

use bevy::ecs::query::QueryFilter;
use bevy::prelude::*;
use serde::{Deserialize, Serialize};
use twinbots_api::{Space, TaskSpec};
use twinbots_sim::{Arena, Framing, KeepObservedImages, ObservedImage, SimSet};
use twinbots_task::task::{ActiveTask, EnvReset, Episode, ResetSet, Resetting, TaskSet};

use crate::{Renderer, View};

/// `[pixels]`: the camera a task observes through.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PixelSettings {
    /// One of the robot's framed cameras ([`Framing::CAMERAS`]).
    pub camera: String,
    /// Further framed cameras, whose images follow `camera`'s along the width: views from
    /// other sides, for what one camera sees only along its line of sight (depth).
    pub more_cameras: Vec<String>,
    /// Vertical field of view (degrees): narrower zooms in on the robot.
    pub fov: f32,
    pub width: u32,
    pub height: u32,
    /// How many of the latest images the observation holds, so that a policy sees motion.
    pub frames: u32,
    /// Observation terms of the task that follow the image, by name (`joint_positions`): the
    /// robot's own state. Empty: the image alone.
    pub state: Vec<String>,
}

impl Default for PixelSettings {
    /// A small image (64×64, one frame) through the robot's side camera at the framing's 45°.
    fn default() -> Self {
        Self {
            camera: "side".into(),
            more_cameras: Vec::new(),
            fov: 45.0,
            width: 64,
            height: 64,
            frames: 1,
            state: Vec::new(),
        }
    }
}

impl PixelSettings {
    /// A clear error naming the key of a setting out of range (`pixels.width = 0: …`).
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            Framing::CAMERAS.contains(&self.camera.as_str()),
            "pixels.camera = {:?}: must be one of {}",
            self.camera,
            Framing::CAMERAS.join(", ")
        );
        for (i, more) in self.more_cameras.iter().enumerate() {
            anyhow::ensure!(
                Framing::CAMERAS.contains(&more.as_str()),
                "pixels.more_cameras: {more:?} must be one of {}",
                Framing::CAMERAS.join(", ")
            );
            anyhow::ensure!(
                *more != self.camera && !self.more_cameras[..i].contains(more),
                "pixels.more_cameras: {more:?} is named twice (with camera = {:?})",
                self.camera
            );
        }
        anyhow::ensure!(self.fov > 0.0 && self.fov < 180.0, "pixels.fov = {}: must be in (0, 180) degrees", self.fov);
        for (key, value) in [("width", self.width), ("height", self.height)] {
            anyhow::ensure!((8..=1024).contains(&value), "pixels.{key} = {value}: must be a whole number in 8..=1024");
        }
        anyhow::ensure!(
            (1..=8).contains(&self.frames),
            "pixels.frames = {}: must be a whole number in 1..=8",
            self.frames
        );
        Ok(())
    }

    /// The cameras in the order their images lie along the width.
    pub fn cameras(&self) -> impl Iterator<Item = &str> {
        std::iter::once(self.camera.as_str()).chain(self.more_cameras.iter().map(String::as_str))
    }

    /// The image's space: `height × width·cameras × 3·frames`.
    pub fn space(&self) -> Space {
        let width = self.width as usize * self.cameras().count();
        Space::Image { height: self.height as usize, width, channels: 3 * self.frames as usize }
    }

    /// `task` as it is observed through this camera: its observation space, plausible range and
    /// names become the image's, followed by the `state` terms' (the one place a task's spec
    /// becomes a pixel task's). Returns where the kept values are in the task's own
    /// observation; a term the task lacks is an error naming the key and the task's terms.
    pub fn observe_task(&self, task: &mut TaskSpec) -> anyhow::Result<Vec<usize>> {
        let kept = self.state_values(task)?;
        let image = self.space();
        let Space::Image { height, width, channels } = image else { unreachable!("space() is an image") };
        let pick = |v: &[f32]| kept.iter().map(|&i| v[i]).collect();
        let with_state = |space: &Space| match space {
            _ if kept.is_empty() => image.clone(),
            Space::Box { low, high } => {
                Space::ImageAndState { height, width, channels, low: pick(low), high: pick(high) }
            }
            _ => Space::ImageAndState {
                height,
                width,
                channels,
                low: vec![f32::NEG_INFINITY; kept.len()],
                high: vec![f32::INFINITY; kept.len()],
            },
        };
        task.observation_space = with_state(&task.observation_space);
        task.observation_plausible = with_state(&task.observation_plausible);
        let names = kept.iter().map(|&i| task.observation_names[i].clone());
        task.observation_names = std::iter::once(format!("pixels {image}")).chain(names).collect();
        // Where a goal's values were no longer exists: a goal seen by a camera is not relabelled.
        task.goal = None;
        Ok(kept)
    }

    /// Indices, in `task`'s observation, of the `state` terms' values, in the order named.
    fn state_values(&self, task: &TaskSpec) -> anyhow::Result<Vec<usize>> {
        let term = |name: &str| name.split_once('[').map_or(name, |(term, _)| term).to_string();
        let mut kept = Vec::new();
        for wanted in &self.state {
            let at: Vec<usize> =
                (0..task.observation_names.len()).filter(|&i| term(&task.observation_names[i]) == *wanted).collect();
            if at.is_empty() {
                let mut terms: Vec<String> = task.observation_names.iter().map(|n| term(n)).collect();
                terms.dedup();
                anyhow::bail!(
                    "pixels.state: the task {} observes no '{wanted}'; its terms: {}",
                    task.name,
                    terms.join(", ")
                );
            }
            anyhow::ensure!(!kept.contains(&at[0]), "pixels.state: '{wanted}' is named twice");
            kept.extend(at);
        }
        Ok(kept)
    }

    /// The settings' errors for a robot's `app` (its plugin added): a key out of range, a
    /// `state` term its task lacks.
    pub fn check(&self, app: &App) -> anyhow::Result<()> {
        self.validate()?;
        if let Some(task) = app.world().get_resource::<ActiveTask>() {
            self.observe_task(&mut task.0.clone())?;
        }
        Ok(())
    }

    /// Adds pixel observations to a robot's app (before its start-up), its camera framed by
    /// `framing`. Fails as [`PixelSettings::check`] does, or when no graphics adapter exists.
    pub fn install(&self, app: &mut App, framing: &Framing, arenas: usize) -> anyhow::Result<()> {
        self.check(app)?;
        let views = self
            .cameras()
            .map(|name| View {
                fov_y: self.fov.to_radians(),
                ..View::framed(framing, name).expect("validated: a framed camera")
            })
            .collect();
        let renderer = Renderer::tiled(self.width, self.height, arenas.max(1))?;
        app.insert_non_send(PixelCamera {
            renderer,
            views,
            width: self.width as usize,
            frames: self.frames as usize,
            state: Vec::new(),
            stacks: HashMap::new(),
        })
        .insert_resource(PixelTask(self.clone()))
        .add_plugins(PixelObservationPlugin);
        Ok(())
    }
}

/// What the task's terms observed of an arena's state this step (its own observation, before
/// the camera's image took its place): for a teacher that sees the state (`twinbots distill`),
/// never for the policy. Set with every pixel observation, the reset's too.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct TaskObservation(pub Vec<f32>);

/// The settings the task is observed with.
#[derive(Resource, Clone, Debug)]
struct PixelTask(PixelSettings);

/// The renderer and each arena's latest images (all its cameras' at one instant).
struct PixelCamera {
    renderer: Renderer,
    /// One per camera, in the order their images lie along the width.
    views: Vec<View>,
    /// One camera's image width, pixels.
    width: usize,
    frames: usize,
    /// Where the values kept beside the image are in the task's own observation.
    state: Vec<usize>,
    stacks: HashMap<Entity, VecDeque<Vec<u8>>>,
}

/// Renders the arenas' observations (added by [`PixelSettings::install`]).
struct PixelObservationPlugin;

impl Plugin for PixelObservationPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(Update, observe_step.in_set(SimSet::Task).after(TaskSet::Evaluate).before(TaskSet::Report))
            .add_systems(EnvReset, observe_reset.after(ResetSet::Observe));
    }

    /// The task's spec says what its observation now is (its plugin inserted it in `build`).
    fn finish(&self, app: &mut App) {
        let settings = app.world().resource::<PixelTask>().0.clone();
        let Some(mut task) = app.world_mut().get_resource_mut::<ActiveTask>() else { return };
        // Checked by `install` (the robot's plugin comes first).
        let state = settings.observe_task(&mut task.0).unwrap_or_else(|e| panic!("{e}"));
        if let Some(mut camera) = app.world_mut().get_non_send_mut::<PixelCamera>() {
            camera.state = state;
        }
    }
}

fn observe_step(world: &mut World) {
    let arenas = in_order::<With<Episode>>(world);
    observe(world, arenas, false);
}

fn observe_reset(world: &mut World) {
    let arenas = in_order::<(With<Episode>, With<Resetting>)>(world);
    observe(world, arenas, true);
}

/// The arenas `F` selects, in env order (by `Arena::index`), so each keeps its tile.
fn in_order<F: QueryFilter>(world: &mut World) -> Vec<Entity> {
    let mut arenas: Vec<(usize, Entity)> =
        world.query_filtered::<(Entity, &Arena), F>().iter(world).map(|(e, a)| (a.index, e)).collect();
    arenas.sort();
    arenas.into_iter().map(|(_, e)| e).collect()
}

/// Renders `arenas` in one frame and makes each one's observation its stack of latest images;
/// `fresh` starts new stacks (a new episode).
fn observe(world: &mut World, arenas: Vec<Entity>, fresh: bool) {
    if arenas.is_empty() {
        return;
    }
    let Some(mut camera) = world.remove_non_send::<PixelCamera>() else { return };
    // Camera by camera, so that each frame draws every arena once (its tile).
    let shots: Vec<(Entity, View)> =
        camera.views.iter().flat_map(|&view| arenas.iter().map(move |&a| (a, view))).collect();
    let shot_images = match camera.renderer.render_shots(world, &shots) {
        Ok(images) => images,
        // Rendering worked when the renderer was made: a failure now is the machine's.
        Err(e) => panic!("pixel observations cannot render: {e}"),
    };
    let images = side_by_side(shot_images, arenas.len(), 3 * camera.width);
    let frames = camera.frames;
    let width = (camera.width * camera.views.len()) as u32;
    let keep = world.contains_resource::<KeepObservedImages>();
    for (arena, image) in arenas.into_iter().zip(images) {
        if keep {
            let height = (image.len() / (3 * width as usize).max(1)) as u32;
            world.entity_mut(arena).insert(ObservedImage { width, height, rgb: image.clone() });
        }
        let stack = camera.stacks.entry(arena).or_default();
        if fresh || stack.is_empty() {
            stack.clear();
            stack.extend(std::iter::repeat_n(image, frames));
        } else {
            stack.pop_front();
            stack.push_back(image);
        }
        let stack = &*stack;
        if let Some(mut episode) = world.get_mut::<Episode>(arena) {
            // The task's terms just observed the state: its kept values follow the image.
            let observed = TaskObservation(episode.observation.clone());
            let state: Vec<f32> = camera.state.iter().map(|&i| episode.observation[i]).collect();
            write_stack(stack, &mut episode.observation);
            episode.observation.extend(state);
            world.entity_mut(arena).insert(observed);
        }
    }
    world.insert_non_send(camera);
}

/// Each arena's image from `shots` (camera-major: every arena's shot through the first camera,
/// then through the next; rows of `row` bytes): row by row, the first camera's row, then the
/// next camera's.
fn side_by_side(shots: Vec<Vec<u8>>, arenas: usize, row: usize) -> Vec<Vec<u8>> {
    let cameras = shots.len() / arenas.max(1);
    if cameras == 1 {
        return shots;
    }
    (0..arenas)
        .map(|a| {
            let rows = shots[a].len() / row;
            let mut image = Vec::with_capacity(rows * row * cameras);
            for r in 0..rows {
                for c in 0..cameras {
                    image.extend_from_slice(&shots[c * arenas + a][r * row..(r + 1) * row]);
                }
            }
            image
        })
        .collect()
}

/// `height × width × 3·frames`: pixel by pixel, each frame's RGB in turn (oldest first).
fn write_stack(stack: &VecDeque<Vec<u8>>, out: &mut Vec<f32>) {
    out.clear();
    let pixels = stack.front().map_or(0, |f| f.len() / 3);
    out.reserve(pixels * 3 * stack.len());
    for p in 0..pixels {
        for frame in stack {
            out.extend(frame[p * 3..p * 3 + 3].iter().map(|&v| v as f32));
        }
    }
}
