//! Rendering camera sensors: each `CameraSensor` due this step gets the image its mount sees.

use std::collections::HashMap;

use bevy::prelude::*;
use twinbots_sim::{Arena, CameraSensor, InArena, Link, Mount, SamplingPeriod, SimClock};

use crate::{RenderError, Renderer, View};

/// One renderer per camera resolution, built on first use.
#[derive(Default)]
pub struct CameraRig {
    renderers: HashMap<(u32, u32), Renderer>,
}

impl CameraRig {
    /// Renders every camera sensor of the sim world that is due on this control step.
    pub fn sample(&mut self, sim: &mut World) -> Result<usize, RenderError> {
        let step = sim.get_resource::<SimClock>().map_or(0, |c| c.control_steps);
        let mut cameras = sim.query::<(Entity, &CameraSensor, &Mount, &InArena, Option<&SamplingPeriod>)>();
        let due: Vec<(Entity, CameraSensor, Mount, Entity)> = cameras
            .iter(sim)
            .filter(|(_, _, _, _, p)| SamplingPeriod::due(*p, step))
            .map(|(e, c, m, a, _)| (e, c.clone(), *m, a.0))
            .collect();
        for (entity, camera, mount, arena) in &due {
            let Some(link) = sim.get::<Link>(mount.link).cloned() else { continue };
            let Some(pose) = sim
                .get::<Arena>(*arena)
                .and_then(|a| a.world.bodies.get(link.body).map(|b| *b.position() * link.offset * mount.offset))
            else {
                continue;
            };
            let renderer = match self.renderers.entry((camera.width, camera.height)) {
                std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
                std::collections::hash_map::Entry::Vacant(v) => v.insert(Renderer::new(camera.width, camera.height)?),
            };
            renderer.sync(sim, *arena);
            renderer.set_view(View::from_mount(pose, camera.fov_y));
            let image = renderer.render()?;
            if let Some(mut c) = sim.get_mut::<CameraSensor>(*entity) {
                c.image = image;
                c.captured_at = Some(step);
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
        app.insert_non_send(CameraRig::default())
            .add_systems(Update, sample_cameras.in_set(twinbots_sim::SimSet::Sense).after(twinbots_sim::devices::DeviceSampling));
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
