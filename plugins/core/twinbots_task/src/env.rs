//! The vectorised env API (Gymnasium / Stable-Baselines3 VecEnv semantics), the world-level
//! operations behind it, and its direct implementation over a Bevy app whose arenas are the envs.

use bevy::prelude::*;
use twinbots_sim::Arena;

use twinbots_api::{EnvState, Space, StepResult, StreamState, TaskSpec, VecEnv};

use crate::replay::{begin_episodes, env_state};
use crate::task::record::record_actions;
use crate::task::reset;
use crate::task::{Action, ActiveTask, episode, observations};

/// Arena entities in env order (by `Arena::index`), found once the world is built.
#[derive(Resource, Clone, Debug, Default)]
pub struct ArenaOrder(pub Vec<Entity>);

/// Finds the arenas and records their order; call after start-up.
pub fn index_arenas(world: &mut World) -> Vec<Entity> {
    let mut arenas: Vec<(usize, Entity)> =
        world.query::<(Entity, &Arena)>().iter(world).map(|(e, a)| (a.index, e)).collect();
    arenas.sort();
    let order: Vec<Entity> = arenas.into_iter().map(|(_, e)| e).collect();
    world.insert_resource(ArenaOrder(order.clone()));
    order
}

/// Resets every arena (re-seeding their streams if `seed` is given) and returns observations.
pub fn reset_arenas(world: &mut World, arenas: &[Entity], seed: Option<u64>) -> Vec<f32> {
    if let Some(seed) = seed {
        for &arena in arenas {
            if let Some(mut a) = world.get_mut::<Arena>(arena) {
                a.reseed(seed);
            }
        }
    }
    reset(world, arenas);
    observations(world, arenas)
}

/// Writes each arena's slice of the flat `actions` into its [`Action`].
pub fn write_actions(world: &mut World, arenas: &[Entity], actions: &[f32]) -> anyhow::Result<()> {
    let dim = world.resource::<ActiveTask>().action_space.dim();
    anyhow::ensure!(
        actions.len() == dim * arenas.len(),
        "step: got {} action values, expected {} arenas × dimension {dim}",
        actions.len(),
        arenas.len()
    );
    for (i, &arena) in arenas.iter().enumerate() {
        let own = &actions[i * dim..(i + 1) * dim];
        if let Some(mut a) = world.get_mut::<Action>(arena) {
            a.0.clear();
            a.0.extend_from_slice(own);
        }
        record_actions(world, arena, own);
    }
    Ok(())
}

/// What the last control step produced, for all arenas.
pub fn collect_step(world: &World, arenas: &[Entity]) -> StepResult {
    let mut out = StepResult { obs: observations(world, arenas), ..default() };
    for &arena in arenas {
        let e = episode(world, arena);
        out.rewards.push(e.step.reward);
        out.terminated.push(e.step.terminated);
        out.truncated.push(e.step.truncated);
        out.final_obs.push(e.ended.as_ref().map(|x| x.final_observation.clone()));
        out.episodes.push(e.finished().cloned());
        out.ended_by.push(e.step.ended_by.map(String::from));
    }
    out
}

/// Builds an app's world: plugins finished, start-up run (arenas exist), no step taken.
pub fn start(app: &mut App) -> anyhow::Result<(Vec<Entity>, TaskSpec)> {
    app.finish();
    app.cleanup();
    app.update();
    let spec = app
        .world()
        .get_resource::<ActiveTask>()
        .map(|task| task.0.clone())
        .ok_or_else(|| anyhow::anyhow!("the app has no robot task plugin (nothing inserted a TaskSpec)"))?;
    let arenas = index_arenas(app.world_mut());
    anyhow::ensure!(!arenas.is_empty(), "the app has no arenas");
    Ok((arenas, spec))
}

/// A Bevy app stepped directly on the caller's thread: one `update` per vectorised step.
pub struct AppVecEnv {
    app: App,
    arenas: Vec<Entity>,
    spec: TaskSpec,
}

impl AppVecEnv {
    /// Takes an app with the sim, task and robot plugins added, and builds its world.
    pub fn new(mut app: App) -> Self {
        let (arenas, spec) = start(&mut app).expect("a robot app with arenas");
        Self { app, arenas, spec }
    }

    pub fn app(&self) -> &App {
        &self.app
    }

    pub fn app_mut(&mut self) -> &mut App {
        &mut self.app
    }

    /// Arena entities in env order.
    pub fn arenas(&self) -> &[Entity] {
        &self.arenas
    }

    pub fn task(&self) -> &TaskSpec {
        &self.spec
    }
}

impl VecEnv for AppVecEnv {
    fn num_envs(&self) -> usize {
        self.arenas.len()
    }

    fn observation_space(&self) -> &Space {
        &self.spec.observation_space
    }

    fn action_space(&self) -> &Space {
        &self.spec.action_space
    }

    fn reset(&mut self, seed: Option<u64>) -> anyhow::Result<Vec<f32>> {
        Ok(reset_arenas(self.app.world_mut(), &self.arenas, seed))
    }

    fn step(&mut self, actions: &[f32]) -> anyhow::Result<StepResult> {
        write_actions(self.app.world_mut(), &self.arenas, actions)?;
        self.app.update();
        Ok(collect_step(self.app.world(), &self.arenas))
    }

    fn state(&mut self) -> anyhow::Result<Option<EnvState>> {
        Ok(env_state(self.app.world(), &self.arenas))
    }

    fn begin_episodes(&mut self, starts: &[(usize, StreamState)], clock: Option<u64>) -> anyhow::Result<Vec<f32>> {
        begin_episodes(self.app.world_mut(), &self.arenas, starts, clock)
    }
}
