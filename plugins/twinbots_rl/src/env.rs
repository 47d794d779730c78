//! The vectorised env API (Gymnasium / Stable-Baselines3 VecEnv semantics) and its direct
//! implementation over a Bevy app whose arenas are the envs.

use bevy::prelude::*;
use twinbots_sim::Arena;

use crate::spaces::Space;
use crate::task::{Action, EnvReset, Episode, EpisodeSummary, TaskSpec};

/// What one vectorised step returns. Vectors are flat: env `i`'s observation is
/// `obs[i * obs_dim..(i + 1) * obs_dim]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepResult {
    pub obs: Vec<f32>,
    pub rewards: Vec<f32>,
    pub terminated: Vec<bool>,
    pub truncated: Vec<bool>,
    /// For envs whose episode ended this step: the last observation of that episode (the
    /// `obs` entry is already the first of the next one).
    pub final_obs: Vec<Option<Vec<f32>>>,
    pub episodes: Vec<Option<EpisodeSummary>>,
}

/// N environments stepped together, with auto-reset.
pub trait VecEnv {
    fn num_envs(&self) -> usize;
    fn observation_space(&self) -> &Space;
    fn action_space(&self) -> &Space;
    /// Resets every env; `seed` restarts their random streams (env `i` gets stream `i`).
    fn reset(&mut self, seed: Option<u64>) -> Vec<f32>;
    /// Applies `actions` (flat, `num_envs * action_dim`) and advances one control step.
    fn step(&mut self, actions: &[f32]) -> StepResult;
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
        app.finish();
        app.cleanup();
        app.update(); // start-up: arenas are built, no physics step yet
        let spec = app
            .world()
            .get_resource::<TaskSpec>()
            .cloned()
            .expect("the app has a robot task plugin (it inserts TaskSpec)");
        let mut arenas: Vec<(usize, Entity)> = app
            .world_mut()
            .query::<(Entity, &Arena)>()
            .iter(app.world())
            .map(|(e, a)| (a.index, e))
            .collect();
        arenas.sort();
        Self {
            app,
            arenas: arenas.into_iter().map(|(_, e)| e).collect(),
            spec,
        }
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

    fn episode(&self, i: usize) -> &Episode {
        self.app
            .world()
            .get::<Episode>(self.arenas[i])
            .expect("every arena has an Episode")
    }

    fn observations(&self) -> Vec<f32> {
        (0..self.arenas.len())
            .flat_map(|i| self.episode(i).observation.iter().copied())
            .collect()
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

    fn reset(&mut self, seed: Option<u64>) -> Vec<f32> {
        let world = self.app.world_mut();
        for &arena in &self.arenas {
            if let Some(seed) = seed
                && let Some(mut a) = world.get_mut::<Arena>(arena)
            {
                a.reseed(seed);
            }
            if let Some(mut e) = world.get_mut::<Episode>(arena) {
                e.needs_reset = true;
            }
        }
        world.run_schedule(EnvReset);
        self.observations()
    }

    fn step(&mut self, actions: &[f32]) -> StepResult {
        let dim = self.spec.action_space.dim();
        assert_eq!(
            actions.len(),
            dim * self.arenas.len(),
            "step: expected {} actions of dimension {dim}",
            self.arenas.len()
        );
        let world = self.app.world_mut();
        for (i, &arena) in self.arenas.iter().enumerate() {
            if let Some(mut a) = world.get_mut::<Action>(arena) {
                a.0.clear();
                a.0.extend_from_slice(&actions[i * dim..(i + 1) * dim]);
            }
        }
        self.app.update();
        let mut out = StepResult {
            obs: self.observations(),
            ..default()
        };
        for i in 0..self.arenas.len() {
            let e = self.episode(i);
            out.rewards.push(e.reward);
            out.terminated.push(e.terminated);
            out.truncated.push(e.truncated);
            out.final_obs.push(e.final_observation.clone());
            out.episodes.push(e.finished);
        }
        out
    }
}
