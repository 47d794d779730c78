//! Rendering camera sensors: each `CameraSensor` due this step gets the image its mount sees.
//! Sensors of one resolution render together, each arena's in its own tile of one frame, read
//! back once (`Renderer::tiled`).

use std::collections::BTreeMap;
use std::collections::HashMap;

use bevy::prelude::*;
use twinbots_sim::{CameraSensor, InArena, Link, Mount, SamplingPeriod, SimClock, physics_in};

use crate::{RenderError, Renderer, View};

/// One tiled renderer per camera resolution, built on first use and rebuilt with more tiles
/// when more cameras of that resolution are due at once.
#[derive(Default)]
pub struct CameraRig {
    renderers: HashMap<(u32, u32), Renderer>,
    /// At most this many images per frame (0: no limit): 1 draws one camera at a time.
    pub max_tiles: usize,
}

impl CameraRig {
    /// Renders every camera sensor of the sim world that is due on this control step.
    pub fn sample(&mut self, sim: &mut World) -> Result<usize, RenderError> {
        let step = sim.get_resource::<SimClock>().map_or(0, |c| c.control_steps);
        let mut cameras = sim.query::<(Entity, &CameraSensor, &Mount, &InArena, Option<&SamplingPeriod>)>();
        let due: Vec<(Entity, (u32, u32, f32), Mount, Entity)> = cameras
            .iter(sim)
            .filter(|(_, _, _, _, p)| SamplingPeriod::due(*p, step))
            .map(|(e, c, m, a, _)| (e, (c.width, c.height, c.fov_y), *m, a.0))
            .collect();
        // Shots by resolution, in entity order (a stable tile per camera).
        let mut groups: BTreeMap<(u32, u32), Vec<(Entity, (Entity, View))>> = BTreeMap::new();
        for (entity, (width, height, fov_y), mount, arena) in &due {
            let Some(link) = sim.get::<Link>(mount.link).cloned() else { continue };
            // A camera shows the true world: its mount's pose is read as the Supervisor would.
            let Some(pose) = physics_in(sim, *arena)
                .and_then(|w| w.bodies.get(link.body).map(|b| *b.position() * link.offset * mount.offset))
            else {
                continue;
            };
            groups.entry((*width, *height)).or_default().push((*entity, (*arena, View::from_mount(pose, *fov_y))));
        }
        for ((width, height), shots) in groups {
            let tiles = if self.max_tiles > 0 { shots.len().min(self.max_tiles) } else { shots.len() };
            if self.renderers.get(&(width, height)).is_none_or(|r| r.tiles() < tiles) {
                self.renderers.insert((width, height), Renderer::tiled(width, height, tiles)?);
            }
            let renderer = self.renderers.get_mut(&(width, height)).expect("made above");
            let views: Vec<(Entity, View)> = shots.iter().map(|(_, shot)| *shot).collect();
            let images = renderer.render_shots(sim, &views)?;
            for ((entity, _), image) in shots.iter().zip(images) {
                if let Some(mut c) = sim.get_mut::<CameraSensor>(*entity) {
                    c.image = image;
                    c.captured_at = Some(step);
                }
            }
        }
        Ok(due.len())
    }
}

/// Renders camera sensors inside the control step, in `SimSet::Sense` after the other sensors,
/// so a task's observation terms can read `CameraSensor::image`. Only apps whose robots carry
/// cameras add it; headless training without cameras never renders anything.
pub struct CameraPlugin;

impl Plugin for CameraPlugin {
    fn build(&self, app: &mut App) {
        app.insert_non_send(CameraRig::default()).add_systems(
            Update,
            sample_cameras.in_set(twinbots_sim::SimSet::Sense).after(twinbots_sim::devices::DeviceSampling),
        );
    }
}

fn sample_cameras(world: &mut World) {
    let Some(mut rig) = world.remove_non_send::<CameraRig>() else { return };
    if let Err(e) = rig.sample(world) {
        // No adapter here means the app was misconfigured: say so once, loudly.
        panic!("camera sensors cannot render: {e}");
    }
    world.insert_non_send(rig);
}
